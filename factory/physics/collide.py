"""Contact-only collision checks with MuJoCo: the structure as static bodies, the candidate free.

One MuJoCo model per (structure, candidate part type); each candidate pose costs one
`mj_fwdPosition` (kinematics and collision, no dynamics). A contact between inset pieces is a real
overlap; contacts between a stud and the part it is connected into are ignored (the coarse body
pieces fill the hollow a connected stud sits in), and so is a stud of any other part that sits in
such a hollow without touching the part's own surface (a bracket's side stud under a wedge's
slope): only a stud that crosses a wall or a face of the other part collides.
"""

from __future__ import annotations

import functools
import hashlib
from dataclasses import dataclass, field
from typing import Callable
from importlib import resources

import mujoco
import numpy as np
from scipy.spatial import ConvexHull

from factory.connections import STUD_HEIGHT, STUD_RADIUS
from factory.parts import Part
from factory.physics.check_state import current
from factory.physics.geometry import INSET_LDU, CollisionShape, collision_shape
from factory.physics.structure import Structure
from factory.physics.unmodelled import in_zone
from factory.pose import LDRAW_TO_MUJOCO, LDU_M, Pose, points_to_mujoco

@functools.cache
def _template(name: str) -> str:
    """An MJCF template of the `mjcf_templates` package (package data: found in a wheel too)."""
    return resources.files("mjcf_templates").joinpath(name).read_text(encoding="utf-8")


def _pieces(items) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Body pieces placed by poses: face planes (k, 4) with piece index (the planes of each piece
    together, pieces in order), owner, centre and box ((n, 2, 3): low and high corner) per piece."""
    planes, piece_of, owners, centres, boxes = [], [], [], [], []
    for pose, shape, owner in items:
        for verts in shape.body:
            world = pose.apply(verts)
            eq = ConvexHull(world).equations
            planes.append(eq)
            piece_of.append(np.full(len(eq), len(centres)))
            owners.append(owner)
            centres.append(world.mean(axis=0))
            boxes.append((world.min(axis=0), world.max(axis=0)))
    if not centres:
        return _NO_PIECES
    return (np.concatenate(planes), np.concatenate(piece_of), np.array(owners), np.array(centres),
            np.array(boxes, float).reshape(-1, 2, 3))


_NO_PIECES = (np.zeros((0, 4)), np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)),
              np.zeros((0, 2, 3)))


def _inside_depth(planes: np.ndarray, piece: np.ndarray, boxes: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(n_pieces, n_points): how deep each point lies inside each piece (<= 0 outside).

    Only pieces whose box holds a point are measured (a point outside a piece's box is outside the
    piece: 0 there): with real parts a structure holds thousands of pieces, and measuring every
    point against every face was most of the sampler's time. Points and pieces are first narrowed
    by their boxes, and a piece's faces found by bisection (`planes` hold each piece's faces
    together, `piece` ascending): every piece's box against every point, and the faces picked by
    membership, made this test 413 of the reference's 1,519 check worker-seconds in a profiled
    build of 96 objects of 40 real parts on a lent H200."""
    out = np.zeros((len(boxes), len(points)))
    if not len(boxes) or not len(points):
        return out
    # Points within all pieces' box, then pieces whose box meets those points' box: both cheap,
    # and the pairwise test below is then of a few pieces and points.
    pts = np.flatnonzero(np.all((points >= boxes[:, 0].min(axis=0)) & (points <= boxes[:, 1].max(axis=0)), axis=1))
    if not len(pts):
        return out
    p = points[pts]
    near = np.flatnonzero(np.all((boxes[:, 0] <= p.max(axis=0)) & (boxes[:, 1] >= p.min(axis=0)), axis=1))
    if not len(near):
        return out
    inbox = np.all((p[None] >= boxes[near, None, 0]) & (p[None] <= boxes[near, None, 1]), axis=2)
    rows = near[inbox.any(axis=1)]
    if not len(rows):
        return out
    first, last = np.searchsorted(piece, rows), np.searchsorted(piece, rows, side="right")
    counts = last - first
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    chosen = planes[np.repeat(first - starts, counts) + np.arange(counts.sum())]
    signed = p @ chosen[:, :3].T + chosen[:, 3]  # (points, planes), > 0 outside a face
    out[np.ix_(rows, pts)] = -np.maximum.reduceat(signed, starts, axis=1).T
    return out


def _fmt(a: np.ndarray) -> str:
    return " ".join(f"{v:.7g}" for v in np.asarray(a).ravel())


# The checker's `CheckState.meshes`: per (shape, piece kind), the shape (kept so that its id is
# not reused) and each piece as (mesh name, vertices text, geom position text).


def _placed_pieces(shape: CollisionShape, kind: str) -> tuple:
    """A shape's pieces as MJCF meshes about their own centres, each placed by its geom's
    position. Pieces equal up to a translation (every stud of a part, the studs of different parts)
    share one mesh: compiling a scene's meshes (a hull and inertia each) cost ~7x more than the
    rest of the model with one mesh per stud (0.084 s against 0.011 s for a 60-part scene)."""
    kept = current().meshes
    hit = kept.get((id(shape), kind))
    if hit is None or hit[0] is not shape:
        rows = []
        for verts in (shape.body if kind == "b" else shape.studs):
            centre = verts.mean(axis=0)
            local = points_to_mujoco(verts - centre)
            digest = hashlib.sha1((np.round(local, 9) + 0.0).tobytes()).hexdigest()[:16]
            rows.append((f"p{digest}", _fmt(local), _fmt(points_to_mujoco(centre))))
        hit = kept[(id(shape), kind)] = (shape, tuple(rows))
    return hit[1]


@dataclass(frozen=True)
class _GeomInfo:
    owner: int
    """Index of the structure part, -1 for the candidate, -2 for the floor."""
    stud: bool
    inset: float
    member: int = 0
    """Which part of the candidate unit (for the candidate's geoms)."""
    stud_at: tuple | None = None
    """A stud's base centre and axis in its part's frame."""


STUD_PROBE_INSET_LDU = 0.5
"""How far inside a stud's surface the probe segments run: a face the stud merely touches (a
plate's underside on a stud's top, the tolerance) is not crossed."""


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a x b over the last axis (broadcast); np.cross's generality costs more than the product
    itself at the sizes of a stud probe."""
    return np.stack([a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1],
                     a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
                     a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]], axis=-1)


@dataclass(frozen=True)
class Surface:
    """A part's triangles in its own frame, with what every stud probe needs of them."""

    tris: np.ndarray
    lo: np.ndarray
    """(n, 3) per-triangle box corners."""
    hi: np.ndarray
    e1: np.ndarray
    e2: np.ndarray

    @classmethod
    def of(cls, tris: np.ndarray) -> "Surface":
        tris = np.asarray(tris, float).reshape(-1, 3, 3)
        return cls(tris, tris.min(axis=1), tris.max(axis=1), tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])


_SURFACES: dict[int, tuple[Part, Surface]] = {}
"""Surfaces by part (the part is kept so that its id is not reused); a library has a few hundred."""


def part_surface(part: Part) -> Surface:
    hit = _SURFACES.get(id(part))
    if hit is None or hit[0] is not part:
        hit = _SURFACES[id(part)] = (part, Surface.of(part.flat.triangles))
    return hit[1]


def _segments_hit(surf: Surface, tri: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """For each row i: whether any segment a[i, j]-b[i, j] crosses triangle tri[i] (Moller-Trumbore,
    both faces)."""
    v0, e1, e2 = surf.tris[tri, 0][:, None], surf.e1[tri][:, None], surf.e2[tri][:, None]
    d = b - a
    p = _cross(d, e2)
    det = (p * e1).sum(-1)
    ok = np.abs(det) > 1e-12
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    o = a - v0
    u = (o * p).sum(-1) * inv
    q = _cross(o, e1)
    v = (q * d).sum(-1) * inv
    t = (q * e2).sum(-1) * inv
    return (ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t >= 0) & (t <= 1)).any(axis=1)


PROBE_PAIRS = 1 << 16
"""(stud, triangle) pairs tested at once by `studs_cross` (each holds a dozen arrays of its 17
segments' vectors, about 3 kB in float64)."""


# `studs_cross` answers are kept in the current checker's `CheckState.crossed`, by (surface, the
# stud's base and axis as exact bytes); the surface is kept with the answer so that its id is not
# reused. A sampled object asks the same probe again about three times in four (5,043 probes,
# 1,220 distinct, one 40-part object): candidates sit on a lattice, so a stud often lands at
# exactly the same place relative to a part.

CROSSED_KEPT = 1 << 18
"""Answers kept before the store is emptied (each a few hundred bytes)."""


def studs_cross(pos: np.ndarray, axis: np.ndarray, surface: Surface) -> np.ndarray:
    """For each stud (base centre (n, 3), unit axis (n, 3); in the surface's frame): whether it
    crosses the surface: a wall or face of another part cuts into it, as opposed to the stud
    standing in that part's hollow. Probed by segments just inside the stud (its axis, 8 lines
    along its side, 8 radii of its top) and by any vertex of the surface inside it, against the
    triangles near the stud. Each stud's answer depends on it alone, so answers asked before
    (exactly the same inputs) are taken from the checker's store (`CheckState.crossed`)."""
    crossed_kept = current().crossed
    pos, axis = np.asarray(pos, float).reshape(-1, 3), np.asarray(axis, float).reshape(-1, 3)
    keys = [(id(surface), p.tobytes(), a.tobytes()) for p, a in zip(pos, axis)]
    out = np.zeros(len(pos), bool)
    miss = []
    for i, k in enumerate(keys):
        hit = crossed_kept.get(k)
        if hit is not None and hit[0] is surface:
            out[i] = hit[1]
        else:
            miss.append(i)
    if miss:
        found = _studs_cross(pos[miss], axis[miss], surface)
        if len(crossed_kept) > CROSSED_KEPT:
            crossed_kept.clear()
        for i, crossed in zip(miss, found):
            out[i] = crossed
            crossed_kept[keys[i]] = (surface, bool(crossed))
    return out


def _studs_cross(pos: np.ndarray, axis: np.ndarray, surface: Surface) -> np.ndarray:
    """`studs_cross` computed."""
    r, h0, h1 = STUD_RADIUS - STUD_PROBE_INSET_LDU, STUD_PROBE_INSET_LDU, STUD_HEIGHT - STUD_PROBE_INSET_LDU
    centre = pos + axis * (STUD_HEIGHT / 2)
    reach = STUD_RADIUS + STUD_HEIGHT
    near = ((surface.lo[None] < (centre + reach)[:, None]) & (surface.hi[None] > (centre - reach)[:, None])).all(axis=2)
    stud, tri = np.nonzero(near)
    out = np.zeros(len(pos), bool)
    if not len(stud):
        return out
    # Any vertex of a near triangle inside the stud.
    rel = surface.tris[tri] - pos[stud][:, None]
    along = (rel * axis[stud][:, None]).sum(-1)
    radial = np.linalg.norm(rel - along[..., None] * axis[stud][:, None], axis=-1)
    out[stud[((along > h0) & (along < h1) & (radial < r)).any(axis=1)]] = True
    # Segments just inside each stud not yet known to cross.
    ref = np.where((np.abs(axis[:, 0]) < 0.9)[:, None], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0])
    u = _cross(axis, ref)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = _cross(axis, u)
    ang = np.arange(8) * (np.pi / 4)
    ring = r * (np.cos(ang)[None, :, None] * u[:, None] + np.sin(ang)[None, :, None] * v[:, None])  # (n, 8, 3)
    base, top = (pos + h0 * axis)[:, None], (pos + h1 * axis)[:, None]
    a = np.concatenate([base, base + ring, np.repeat(top, 8, axis=1)], axis=1)  # (n, 17, 3)
    b = np.concatenate([top, top + ring, top + ring], axis=1)
    left = ~out[stud]
    stud, tri = stud[left], tri[left]
    for at in range(0, len(stud), PROBE_PAIRS):
        s_, t_ = stud[at:at + PROBE_PAIRS], tri[at:at + PROBE_PAIRS]
        out[s_[_segments_hit(surface, t_, a[s_], b[s_])]] = True
    return out


def stud_crosses(pos: np.ndarray, axis: np.ndarray, surface: Surface) -> bool:
    """`studs_cross` of one stud."""
    return bool(studs_cross(pos[None], axis[None], surface)[0])


_I3 = np.eye(3)


def probe_frame(stud_at, stud_pose: Pose, body_part: Part, body_pose: Pose) -> tuple[np.ndarray, np.ndarray, Surface]:
    """(stud base, stud axis, surface) for `studs_cross`: a stud (base and axis in its part's frame,
    `CollisionShape.stud_at`) of a part at `stud_pose` against `body_part` at `body_pose`, in the
    body part's own frame (its surface read once per part, `part_surface`); a scaled or sheared
    placement (rare in LDraw) has its surface moved into the world instead."""
    pos, axis = (np.asarray(v, float) for v in stud_at)
    rb = body_pose.R
    if (np.abs(rb @ rb.T - _I3) <= 1e-9 + 1e-5 * _I3).all():  # np.allclose(.., atol=1e-9), cheaper
        # body_pose.inverse() @ stud_pose, written out: the same operations on the same array
        # layouts as `Pose` does them (so the same bits), without two `Pose`s' checks and copies.
        inv_r = np.array(rb.T)
        inv_t = -rb.T @ body_pose.t
        r, t = inv_r @ stud_pose.R, inv_r @ stud_pose.t + inv_t
        surface = part_surface(body_part)
    else:
        r, t = stud_pose.R, stud_pose.t
        surface = Surface.of(body_pose.apply(body_part.flat.triangles.reshape(-1, 3)))
    return (pos[None] @ r.T + t)[0], r @ axis, surface


@dataclass(frozen=True)
class Penetration:
    """One candidate pose's collision facts (`CollisionScene.penetration`, or `collide_jax` for
    many at once)."""

    depth: float
    """Deepest overlap (LDU) with the structure or the ground; 0 where nothing overlaps."""
    near: frozenset[int]
    """Structure parts it touches or overlaps."""
    apart: Callable[[set[int]], float] | None = field(default=None, compare=False, repr=False)
    """For a device result (`collide_jax`): the depth again with the overlap with some structure
    parts left out, from the same pair results (None for the scene's)."""


NEAR_LDU = 1.0
"""A candidate this close to the structure (real gap, LDU) touches it."""

CONNECTED_SLACK_LDU = 4.0
"""Overlap ignored between a candidate and a part it is stud-connected to (a stud's height): the
filled hollow under a part reaches that far into whatever its sockets hold (a wheel holder's
raised stud base, a plate's recessed top), and stud mating already fixes their relative place."""


# The current checker's `CheckState.bodies`: per placed structure part (by id; the `Placed` is
# kept so that its id is not reused): its index, its MJCF body, the meshes its geoms name, their
# `_GeomInfo`s and its body pieces' faces (`_pieces`). A growing structure keeps its parts, so
# each step's scene writes and hulls only the new part's. Before, every scene did it for every
# part again: 8.8 s of 44 s of checks in a 3-object build (20-90 parts, 226 steps, one process,
# cProfile) on the 2-core machine; 5.2 s after, of which MuJoCo's compile 2.4 s and the
# candidate's pieces 2.0 s (kept since: `unit_pieces`).

BODIES_KEPT = 8192
"""Placed parts kept before a checker's `bodies` is emptied (a few kB each)."""


def _structure_body(placed, idx: int) -> tuple:
    """(body MJCF, ((mesh name, vertices text), ...), geom infos, pieces) of structure part `idx`."""
    kept = current().bodies
    hit = kept.get(id(placed))
    if hit is None or hit[0] is not placed or hit[1] != idx:
        shape = collision_shape(placed.part)
        meshes: dict[str, str] = {}
        info: list[_GeomInfo] = []
        pos, quat = placed.pose.to_mujoco_quat()
        geoms = CollisionScene._geoms(shape, meshes, idx, info)
        body = f'<body name="s{idx}" pos="{_fmt(pos)}" quat="{_fmt(quat)}">{geoms}</body>'
        if len(kept) >= BODIES_KEPT:
            kept.clear()
        hit = kept[id(placed)] = (placed, idx, body, tuple(meshes.items()), tuple(info),
                                     _pieces([(placed.pose, shape, idx)]))
    return hit[2:]


# The current checker's `CheckState.unit_pieces`: `_pieces` of a candidate unit by its shapes and
# their poses in the unit (the shapes are kept so that their ids are not reused): the sampler
# builds a scene per structure and part type, and the part's pieces, in the unit's frame, are the
# same in every one.


def _unit_pieces(unit) -> tuple:
    shapes = [collision_shape(part) for part, _ in unit]
    key = tuple((id(shape), rel.R.tobytes(), rel.t.tobytes()) for shape, (_, rel) in zip(shapes, unit))
    kept = current().unit_pieces
    hit = kept.get(key)
    if hit is None or any(a is not b for a, b in zip(hit[0], shapes)):
        if len(kept) >= BODIES_KEPT:
            kept.clear()
        hit = kept[key] = (shapes, _pieces([(rel, shape, -1) for shape, (_, rel) in zip(shapes, unit)]))
    return hit[1]


def _joined_pieces(parts: list[tuple]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """`_pieces` of several items from each one's own `_pieces` (piece indices renumbered)."""
    parts = [p for p in parts if len(p[3])]
    if not parts:
        return _NO_PIECES
    offsets = np.cumsum([0] + [len(p[3]) for p in parts[:-1]])
    return (np.concatenate([p[0] for p in parts]), np.concatenate([p[1] + o for p, o in zip(parts, offsets)]),
            np.concatenate([p[2] for p in parts]), np.concatenate([p[3] for p in parts]),
            np.concatenate([p[4] for p in parts]))


def _deepest(overlap: np.ndarray, plain: np.ndarray, studs: np.ndarray, crosses) -> float:
    """The deepest overlap (0.0 when none) of the `plain` contacts and of the stud-on-body contacts
    `studs` (indices) whose stud `crosses(i)` a wall or face of the body. A stud standing in the
    body's hollow only lowers its contact to 0, so the studs are asked deepest first and only while
    an answer could raise the result: the same number as asking every one (the stud probes were 17 %
    of the checks' time in a build on a lent H200, and most contacts asked lay under a deeper one)."""
    deepest = float(overlap[plain].max()) if plain.any() else 0.0
    for i in studs[np.argsort(-overlap[studs], kind="stable")]:
        if overlap[i] <= deepest:
            break
        if crosses(int(i)):
            return float(overlap[i])
    return deepest


class CollisionScene:
    """A compiled scene for checking one candidate (a part, or a rigid unit of parts given with
    their poses in the unit's frame) against one structure."""

    def __init__(self, structure: Structure, unit: list[tuple[Part, Pose]], floor_y: float):
        self.structure = structure
        self.unit = unit
        meshes: dict[str, str] = {}
        bodies = []
        info: list[_GeomInfo] = []
        pieces = []
        for idx, placed in enumerate(structure.placed):
            body, body_meshes, body_info, body_pieces = _structure_body(placed, idx)
            bodies.append(body)
            for name, verts in body_meshes:
                meshes.setdefault(name, verts)
            info.extend(body_info)
            pieces.append(body_pieces)
        # Piece centres and faces for the coincidence test (MuJoCo's convex collision misses a
        # piece sitting exactly on an identical one: no direction separates their centres).
        self._s_planes, self._s_piece, self._s_owner, self._s_centre, self._s_box = _joined_pieces(pieces)
        self._c_planes, self._c_piece, _, self._c_centre, self._c_box = _unit_pieces(unit)
        cand_geoms = ""
        for member, (part, rel) in enumerate(unit):
            pos, quat = rel.to_mujoco_quat()
            inner = self._geoms(collision_shape(part), meshes, -1, info, member)
            cand_geoms += f'<body pos="{_fmt(pos)}" quat="{_fmt(quat)}">{inner}</body>'
        floor_z = -floor_y * LDU_M
        template = _template("collision.xml")
        xml = template.format(
            assets="".join(f'<mesh name="{n}" vertex="{v}"/>' for n, v in meshes.items()),
            floor_z=f"{floor_z:.7g}",
            margin=f"{(NEAR_LDU + 0.5) * LDU_M:.7g}",
            structure="".join(bodies),
            candidate=cand_geoms,
        )
        self.model = mujoco.MjModel.from_xml_string(xml)
        self.data = mujoco.MjData(self.model)
        floor_id = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_GEOM, "floor")
        # Geoms were written in order after the floor; map MuJoCo geom ids to owners.
        self.owner = np.full(self.model.ngeom, -2, np.int64)
        self.is_stud = np.zeros(self.model.ngeom, bool)
        self.inset = np.zeros(self.model.ngeom)
        self.info: dict[int, _GeomInfo] = {}
        order = [g for g in range(self.model.ngeom) if g != floor_id]
        for g, gi in zip(order, info):
            self.owner[g] = gi.owner
            self.is_stud[g] = gi.stud
            self.inset[g] = gi.inset
            self.info[g] = gi

    @staticmethod
    def _geoms(shape: CollisionShape, meshes: dict, owner: int, info: list, member: int = 0) -> str:
        out = []
        for kind, pieces in (("b", shape.body), ("s", shape.studs)):
            for i, (name, verts, pos) in enumerate(_placed_pieces(shape, kind)):
                meshes.setdefault(name, verts)
                cls = "stud" if kind == "s" else "body"
                out.append(f'<geom class="{cls}" mesh="{name}" pos="{pos}"/>')
                info.append(_GeomInfo(owner, kind == "s", shape.body_inset if kind == "b" else INSET_LDU,
                                      member, shape.stud_at[i] if kind == "s" else None))
        return "".join(out)

    def _stud_in_hollow(self, stud_g: int, body_g: int, pose: Pose, memo: dict) -> bool:
        """Whether the stud of geom `stud_g` stands in a hollow of the part owning `body_g` (inside
        its filled collision piece, crossing none of its walls or faces)."""
        stud, body = self.info[stud_g], self.info[body_g]
        key = (stud_g, body.owner, body.member)
        if key not in memo:
            part = self.structure.placed[body.owner].part if body.owner >= 0 else self.unit[body.member][0]
            pos, axis, surface = probe_frame(stud.stud_at, self._pose_of(stud, pose), part, self._pose_of(body, pose))
            memo[key] = not stud_crosses(pos, axis, surface)
        return memo[key]

    def _pose_of(self, gi: _GeomInfo, pose: Pose) -> Pose:
        if gi.owner >= 0:
            return self.structure.placed[gi.owner].pose
        return pose @ self.unit[gi.member][1]

    def penetration(self, pose: Pose, connected: set[int], joints: dict | None = None) -> tuple[float, set[int]]:
        """(Deepest overlap in LDU with the structure or the floor, structure parts it touches).

        Overlap = depth between inset pieces + both insets; 0 when no inset pieces touch. Stud
        contacts with parts in `connected` are ignored; a stud standing in another part's hollow
        (crossing none of its faces) touches it without overlapping. Touching = a real gap under
        NEAR_LDU. `joints`: structure part -> (stretches of axis (k, 3, 3), radii (k,)) where the
        candidate meets it at a joint (`unmodelled.joints_between`); an overlap with that part
        within a radius of such an axis (`unmodelled.in_zone`: a contact's position, a piece's
        centre) is the joint's and left out; None for a part holding it by a joint with no axis (a minifigure joint, a tyre on its
        rim): all its overlap with that part is left out.
        """
        pos, quat = pose.to_mujoco_quat()
        self.data.qpos[:3] = pos
        self.data.qpos[3:7] = quat
        mujoco.mj_fwdPosition(self.model, self.data)
        deepest = 0.0
        near: set[int] = set()
        n = self.data.ncon
        if n:
            # The contacts as arrays (a Python loop over MjContact structs cost most of this call).
            con = self.data.contact
            g1, g2 = np.asarray(con.geom1[:n], np.int64), np.asarray(con.geom2[:n], np.int64)
            o1, o2 = self.owner[g1], self.owner[g2]
            cand_first = o1 == -1
            other = np.where(cand_first, o2, o1)
            other_g, cand_g = np.where(cand_first, g2, g1), np.where(cand_first, g1, g2)
            # Candidate against structure or floor only (not within the candidate's unit).
            keep = ((o1 == -1) | (o2 == -1)) & (other != -1)
            if joints:
                at = np.asarray(con.pos[:n], float) @ LDRAW_TO_MUJOCO / LDU_M
                for owner, zones in joints.items():
                    mine = keep & (other == owner)
                    if zones is not None:
                        mine[mine] = in_zone(at[mine], zones)
                    keep &= ~mine
            conn = (other >= 0) & np.isin(other, np.fromiter(connected, np.int64, len(connected)))
            keep &= ~(conn & (self.is_stud[other_g] | self.is_stud[cand_g]))
            overlap = -np.asarray(con.dist[:n], float) / LDU_M + self.inset[g1] + self.inset[g2]
            overlap = np.where(conn, overlap - CONNECTED_SLACK_LDU, overlap)
            hollow = keep & (overlap > 0) & (other >= 0) & (self.is_stud[g1] != self.is_stud[g2])
            memo: dict = {}

            def crosses(i: int) -> bool:
                stud_g, body_g = (int(g1[i]), int(g2[i])) if self.is_stud[g1[i]] else (int(g2[i]), int(g1[i]))
                return not self._stud_in_hollow(stud_g, body_g, pose, memo)

            deepest = _deepest(overlap, keep & (overlap > 0) & ~hollow, np.flatnonzero(hollow), crosses)
            # A stud in a hollow touches the part (its overlap counts as 0 > -NEAR_LDU): near either way.
            near = {int(o) for o in np.unique(other[keep & (other >= 0) & (overlap > -NEAR_LDU)])}
        depth, owners = self._coincident(pose, joints)
        near |= owners
        return max(deepest, depth), near

    def depths_alone(self, pose: Pose, connected: set[int], parts: list[int], joints: dict | None = None) -> list[float]:
        """`penetration`'s depth with each of `parts` alone (the others of `parts` left out; the
        overlap round `joints` left out as there): how deep the candidate meets each part it meets."""
        return [self.penetration(pose, connected, {**(joints or {}), **{j: None for j in parts if j != i}})[0]
                for i in parts]

    def _coincident(self, pose: Pose, joints: dict | None = None) -> tuple[float, set[int]]:
        """Depth of a candidate piece centre inside a structure piece, or the reverse (a centre
        within a joint's zone with that piece's part left out: `penetration`)."""
        if not len(self._s_centre) or not len(self._c_centre):
            return 0.0, set()
        centres = pose.apply(self._c_centre)
        a = _inside_depth(self._s_planes, self._s_piece, self._s_box, centres)
        inv = pose.inverse()
        b = _inside_depth(self._c_planes, self._c_piece, self._c_box, inv.apply(self._s_centre))
        for owner, zones in (joints or {}).items():
            mine = self._s_owner == owner
            if zones is None:
                a[mine] = 0.0
                b[:, mine] = 0.0
                continue
            a[np.ix_(mine, in_zone(centres, zones))] = 0.0
            b[:, mine & in_zone(self._s_centre, zones)] = 0.0
        depth_s = a.max(axis=1)  # per structure piece: deepest candidate centre inside it
        depth_c = b.max(axis=0)  # per structure centre: deepest inside a candidate piece
        per_piece = np.maximum(depth_s, depth_c)
        hit = per_piece > 0
        return (float(per_piece.max()) if hit.any() else 0.0), {int(o) for o in self._s_owner[hit]}


