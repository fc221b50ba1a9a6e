"""Buildability sweeps of many candidates at once, exactly, in JAX (backend 'jax').

`sweep.sweep` asks MuJoCo for contacts at poses stepped along the approach. Here the same question
is answered without stepping. Two convex pieces A and B overlap by depth = min over axes n of
min(max A.n - min B.n, max B.n - min A.n), n over the separating-axis candidates (face normals of
both, cross products of their edge directions): each value is how far A must move along +-n to
clear B, any direction's value bounds the depth from above, and the Minkowski difference's facets
have normals among these candidates, so the minimum is the penetration depth (the translation
MuJoCo's EPA reports); where the pieces are apart some candidate separates them and the minimum is
<= 0. Moving A back by s along d shifts A.n by -s (d.n): each of those values is linear in s, so
{s : depth(s) > tau} = {s : every one of them > tau} is one open interval, found per piece pair in
one pass (`_pair_interval`). Requires tau >= 0 (overlap = depth + both insets, so a tolerance of at
least both insets, 0.5 LDU by default); with tau < 0 the minimum is not the distance, and the
whole call is swept on the CPU instead.

**Rules** (`CollisionScene.penetration`), per pair of a unit piece and a structure part's piece:
- not connected, body-body or stud-stud: counted where depth + insets > tolerance; exact;
- connected, body-body: depth + insets - CONNECTED_SLACK_LDU, and either piece's centre inside the
  other deeper than the tolerance (the scene's coincidence test, which has no slack; for other
  pairs it never exceeds the depth), both only on the stretches of s the CPU sweep queries at all
  (where the unit's box overlaps a part it is not connected to: `sweep._overlap_intervals`);
- connected, with a stud: never counted;
- not connected, stud-body: the scene ignores a stud standing in the other part's hollow
  (`collide.stud_crosses`, a probe of the real surface at each pose), which is not written here.
  Such a pair is **undecided**: a candidate blocked by a decided pair is blocked whatever it does;
  one that only an undecided pair could block is swept by `sweep.sweep` on the CPU (`COUNTS`).

A unit is blocked when a counted interval meets s > 0 (s = 0, the final pose, is the collision
check's). One blocked only further out than `sweep.PRESS_LDU` is swept by `sweep.sweep` on the
CPU, which then asks whether it comes in from the side and is pressed on only over that last
stretch (`sweep._pressed_last`): the same rule on both backends; one blocked within that
stretch but clear over the fingertip's end (`sweep.PRESS_MIN_LDU`) is rare and swept on the CPU. The blocking pose reported (`at_ldu`) is the outer end of the outermost interval, where
the unit coming from outside first overlaps beyond the tolerance; `blocked_by` names the parts
whose decided intervals hold a pose just inside it (`MIN_STEP_LDU` / 4 in, or the interval's middle
if shorter). The depth there is not computed (`depth_ldu` is nan); no contact query is made.

**Guarantee** vs the stepped reference: every pose on the path is judged, so every overlap beyond
the tolerance is found, where the reference finds those beyond tolerance + `MIN_STEP_LDU` / 2 and
may miss shallower ones between its poses; depths are those of the pieces' hulls in float64
(MuJoCo's agree to its solver tolerance). Verdicts differ only where the deepest overlap on the path
lies within that band of the tolerance, or where MuJoCo's depth and the exact one fall on two sides
of it.

**Device layout**: pieces are precomputed once per collision shape (hull vertices, unit face
normals and edge directions, one per direction up to sign), placed in the world once per structure
(kept for the last structure) and in the unit's frame once per call. Pairs are chosen on the host
by boxes swept along d (parts' boxes with the reference's margin, then pieces' boxes), grouped by
the size buckets of both pieces (vertices, normals, edges: powers of two), and each group runs in
one jitted vmap over pairs, its counts padded to powers of two, at most `MAX_WORK` projections per
launch: so a run compiles once per shape met (`COMPILES`), never per call.
"""

from __future__ import annotations

import math
import os
import weakref
from collections import Counter
from concurrent.futures import ThreadPoolExecutor
from functools import cache, partial
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy.spatial import ConvexHull

from factory import gpus
from factory.parts import Part
from factory.physics.collide import CONNECTED_SLACK_LDU, CollisionScene
from factory.physics.geometry import INSET_LDU, collision_shape
from factory.physics import jax_export
from factory.physics.jax_cache import enable as enable_compile_cache
from factory.physics.keep_last import KeepLast
from factory.physics.structure import Placed, Structure
from factory.physics.sweep import (PRESS_LDU, PRESS_MIN_LDU, MIN_STEP_LDU, SweepResult, _boxes, _overlap_intervals, across,
                                   approaches_from, box_interval, seating_directions, sweep)
from factory.pose import Pose

COMPILES: list[tuple] = []
"""(kernel kind, edge axes or not, pairs, unit table rows, structure table rows, candidates, and
vertices, normals, edges of both pieces) of every launch shape compiled in this process."""
_CLEAR, _BLOCKED, _UNDECIDED = 0, 1, 2
"""States of a side sweep's unit (`_SweepJob.states`)."""
COUNTS: Counter = Counter()
"""Candidates by how they were judged: 'device', 'referred' (swept on the CPU: only an undecided
stud-body pair could block them), 'not-judged' (no approach), 'cpu' (tolerance below the insets)."""
LEVELS = ((8, 4, 4), (32, 16, 32), (64, 32, 64), (128, 64, 128))
"""Padded piece sizes (vertices, normals, edges): boxes; studs (16-gon prisms), slopes and round
cut pieces; larger cut pieces; coacd's."""
MIN_ROWS = 256
"""Smallest padded count of pairs, candidates and table rows per launch: fewer shapes to compile."""
GPU_MIN_PAIRS = 1024
"""Smallest padded count of a launch's pairs on a GPU (at most the launch's `MAX_WORK` chunk)."""
GPU_MIN_STRUCTURE_ROWS = 1024
"""Smallest padded row count of a round's structure-side piece tables on a GPU.

Both are the sizes a default build's worker reaches within its first shard anyway (a padded size
only grows, `_grown`): starting there, a process meets each kernel at its working size at once
instead of compiling it at two or three sizes on the way. Measured on a lent H100 machine, one
process growing four shards of four objects (the default config) from an empty cache: 35 kernel
shapes, 30.5 s of the first shard's 97.5 s in the first launches of 32 of them (2.2 s with the
cache warm). On a lent H200 machine a 16-worker `N=700` build from an empty cache finished its first
shards about 30 s after the reference's, every worker waiting for each shape's one compile
(`jax_export`). A GPU runs a launch of a few pairs in about the time of one of thousands, so the
padding costs little there; on the CPU it would cost compute, so the CPU keeps `MIN_ROWS`."""
MAX_WORK = 1 << 25
"""Vertex-axis projections per launch (memory: a few times this many floats)."""


@dataclass(frozen=True)
class _Piece:
    """A convex piece (inset, as the scene's) ready for separating axes."""

    verts: np.ndarray
    normals: np.ndarray
    """Unit face normals, one per direction up to sign."""
    edges: np.ndarray
    """Unit edge directions, one per direction up to sign."""
    stud: bool
    inset: float
    prism: np.ndarray
    """(3, 3): up to three directions along which the piece is a right prism (zero rows pad)."""

    @property
    def bucket(self) -> tuple[int, int, int]:
        """Padded (vertices, normals, edges): the first of `LEVELS` that holds the piece, else
        powers of two (few levels, few shapes to compile)."""
        size = len(self.verts), len(self.normals), len(self.edges)
        for level in LEVELS:
            if all(n <= m for n, m in zip(size, level)):
                return level
        return tuple(_pow2(n, 1) for n in size)  # type: ignore[return-value]


def _pow2(n: int, minimum: int) -> int:
    return max(minimum, 1 << max(0, math.ceil(math.log2(max(n, 1)))))


@cache
def _on_gpu() -> bool:
    """Whether JAX's default device is a GPU (asked at the first launch, not at import)."""
    import jax  # optional: the [jax] extra; the 'cpu' backend needs none

    enable_compile_cache()
    return jax.default_backend() == "gpu"


_HIGH: dict[tuple, int] = {}
"""The largest padded size met so far in this process per kind of array (`_grown`)."""


def _grown(key: tuple, n: int, minimum: int = MIN_ROWS) -> int:
    """`_pow2(n)`, or the largest size met before for `key` if larger: a padded size only grows
    during a run, so objects finishing (fewer tables stacked, fewer candidates) meet no new shape."""
    size = max(_pow2(n, minimum), _HIGH.get(key, 0))
    _HIGH[key] = size
    return size


def _table_rows(key: tuple, n: int) -> int:
    """The padded rows of a round's piece table for `key` = (side 'u' or 's', piece bucket) holding
    `n` rows (`_grown`; on a GPU the structure side from `GPU_MIN_STRUCTURE_ROWS`)."""
    floor = GPU_MIN_STRUCTURE_ROWS if key[0] == "s" and _on_gpu() else MIN_ROWS
    return _grown(("rows", *key), n, floor)


def _directions(v: np.ndarray) -> np.ndarray:
    """Unit vectors, one per direction up to sign (near-duplicates may both stay: harmless)."""
    v = v / np.linalg.norm(v, axis=1, keepdims=True)
    lead = np.argmax(np.abs(v) > 1e-9, axis=1)
    v = v * np.sign(v[np.arange(len(v)), lead])[:, None]
    _, first = np.unique(np.round(v * 1e7).astype(np.int64), axis=0, return_index=True)
    return v[np.sort(first)]


def _piece(verts: np.ndarray, stud: bool, inset: float) -> _Piece:
    hull = ConvexHull(verts)
    normals = hull.equations[:, :3]
    edges = []
    for f, simplex in enumerate(hull.simplices):
        for j in range(3):
            nb = hull.neighbors[f][j]
            # A triangle edge is an edge of the polytope only between facets of two planes.
            if nb > f and normals[f] @ normals[nb] < 1 - 1e-9:
                a, b = np.delete(simplex, j)
                edges.append(hull.points[b] - hull.points[a])
    normals, edges = _directions(normals), _directions(np.array(edges))
    return _Piece(np.ascontiguousarray(hull.points[hull.vertices]), normals, edges, stud, inset,
                  _prism_axes(normals, edges))


def _prism_axes(normals: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Face normals a along which the piece is a right prism: every edge along a or across it, and
    a x e a face normal for every edge e across it. Two pieces that are right prisms along one
    direction need no edge-edge axis: a x a = 0, a x e is a side normal, e x e' lies along a, the
    caps' normal (why most pairs, boxes, studs and slopes standing as built, skip them)."""
    out = np.zeros((3, 3))
    n = 0
    for a in normals:
        along = np.abs(edges @ a)
        if not np.all((along > 1 - 1e-9) | (along < 1e-9)):
            continue
        side = np.cross(a, edges[along < 1e-9])
        side /= np.linalg.norm(side, axis=1, keepdims=True)
        if np.all(np.abs(side @ normals.T).max(axis=1) > 1 - 1e-9) and n < 3:
            out[n] = a
            n += 1
    return out


def _padded(pieces: Sequence[_Piece]) -> dict[tuple, tuple]:
    """The pieces grouped by bucket: {bucket: (piece indices, vertices, normals, edges)}, each
    piece's arrays padded to the bucket's sizes by repeating its first row (which changes no
    extreme value)."""
    def pad(a: np.ndarray, n: int) -> np.ndarray:
        return np.concatenate([a, np.repeat(a[:1], n - len(a), 0)])

    out: dict[tuple, list] = {}
    for i, p in enumerate(pieces):
        out.setdefault(p.bucket, []).append(i)
    return {b: (np.array(idx, np.int64),
                *(np.stack([pad(getattr(pieces[i], name), n) for i in idx]) for name, n in zip(("verts", "normals", "edges"), b)))
            for b, idx in out.items()}


@dataclass(frozen=True, eq=False)
class _Template:
    """One part's collision pieces (body, then studs) in its frame, laid out once for `_Set`."""

    stud: np.ndarray
    inset: np.ndarray
    prism: np.ndarray
    centres: np.ndarray
    """Each piece's centre as the scene's coincidence test takes it (the mean of its vertices)."""
    rows: dict
    """`_padded` of the pieces."""


_SHAPES: dict[int, tuple] = {}


def _template(part: Part) -> _Template:
    shape = collision_shape(part)
    if id(shape) not in _SHAPES:
        pieces = [_piece(v, False, shape.body_inset) for v in shape.body]
        pieces += [_piece(v, True, INSET_LDU) for v in shape.studs]
        centres = np.array([v.mean(axis=0) for v in (*shape.body, *shape.studs)]).reshape(-1, 3)
        template = _Template(np.array([p.stud for p in pieces], bool), np.array([p.inset for p in pieces]),
                             np.stack([p.prism for p in pieces]) if pieces else np.zeros((0, 3, 3)), centres,
                             _padded(pieces))
        _SHAPES[id(shape)] = (shape, template)  # the shape is kept, so its id is not reused
    return _SHAPES[id(shape)][1]


class _Set:
    """Placed pieces (world or unit frame) with their owner, grouped into padded bucket tables.

    `rows`: {bucket: (piece indices, ascending; vertices, normals, edges padded to the bucket)};
    `tables`: per bucket (vertices, normals, edges, centres), the rows `_gathered` picks from."""

    def __init__(self, stud: np.ndarray, inset: np.ndarray, prism: np.ndarray, centres: np.ndarray,
                 owner: np.ndarray, owners: int, rows: dict, box: np.ndarray | None = None):
        self.stud, self.inset, self.prism, self.centres = stud, inset, prism, centres
        self.owner, self.owners, self.n = owner, owners, len(stud)
        self.box = _piece_boxes(self.n, rows) if box is None else box
        self.start = np.searchsorted(self.owner, np.arange(self.owners + 1))  # pieces by owner
        # The box around each owner's pieces (an empty box where it has none).
        self.owner_box = np.empty((self.owners, 2, 3))
        self.owner_box[:, 0], self.owner_box[:, 1] = np.inf, -np.inf
        np.minimum.at(self.owner_box[:, 0], self.owner, self.box[:, 0])
        np.maximum.at(self.owner_box[:, 1], self.owner, self.box[:, 1])
        self.buckets = sorted(rows)
        self.bucket_of = np.zeros(self.n, np.int64)
        self.local = np.zeros(self.n, np.int64)
        self.tables = []
        self.verts = []
        for b, shape in enumerate(self.buckets):
            idx, verts, normals, edges = rows[shape]
            self.bucket_of[idx] = b
            self.local[idx] = np.arange(len(idx))
            self.tables.append((verts, normals, edges, self.centres[idx]))
            self.verts.append((verts, self.inset[idx]))

    @classmethod
    def of_pieces(cls, pieces: Sequence[_Piece], centres: np.ndarray, owner: np.ndarray, owners: int) -> "_Set":
        return cls(np.array([p.stud for p in pieces], bool), np.array([p.inset for p in pieces]),
                   np.stack([p.prism for p in pieces]) if pieces else np.zeros((0, 3, 3)), centres, owner, owners,
                   _padded(pieces))


def _piece_boxes(n: int, rows: dict) -> np.ndarray:
    """(n, 2, 3): each piece's box (lowest and highest corner) from its bucket's vertices."""
    box = np.zeros((n, 2, 3))
    for idx, verts, _, _ in rows.values():
        box[idx, 0], box[idx, 1] = verts.min(axis=1), verts.max(axis=1)
    return box


@dataclass(frozen=True, eq=False)
class _PartPieces:
    """One part's pieces at its pose (`_Template` turned and moved), as `_joined` takes them."""

    stud: np.ndarray
    inset: np.ndarray
    prism: np.ndarray
    centres: np.ndarray
    rows: dict
    """{bucket: (the part's piece indices, vertices, normals, edges)}."""
    box: np.ndarray


def _part_pieces(part: Part, pose: Pose) -> _PartPieces:
    tp = _template(part)
    RT, t = pose.R.T, pose.t
    rows = {b: (idx, np.matmul(verts, RT) + t, np.matmul(normals, RT), np.matmul(edges, RT))
            for b, (idx, verts, normals, edges) in tp.rows.items()}
    return _PartPieces(tp.stud, tp.inset, np.matmul(tp.prism, RT), np.matmul(tp.centres, RT) + t, rows,
                       _piece_boxes(len(tp.stud), rows))


_PLACED: "weakref.WeakKeyDictionary[Placed, _PartPieces]" = weakref.WeakKeyDictionary()
"""A structure's parts' pieces, by part placed: a structure grown by one part turns and moves only
that part's (it was a whole rebuild at every step, about 7 ms for 80 parts on the development
machine)."""


def _joined(pieces: Sequence[_PartPieces]) -> _Set:
    """The `_Set` of parts' pieces, part after part."""
    counts = np.array([len(p.stud) for p in pieces], np.int64)
    owner = np.repeat(np.arange(len(pieces)), counts)
    if not counts.sum():
        return _Set(np.zeros(0, bool), np.zeros(0), np.zeros((0, 3, 3)), np.zeros((0, 3)), owner, len(pieces), {})
    first = np.cumsum(counts) - counts
    gathered: dict[tuple, list] = {}
    for i, p in enumerate(pieces):
        for b, (idx, verts, normals, edges) in p.rows.items():
            gathered.setdefault(b, []).append((idx + first[i], verts, normals, edges))
    rows = {b: tuple(np.concatenate(x) for x in zip(*chunks)) for b, chunks in gathered.items()}
    return _Set(*(np.concatenate([getattr(p, name) for p in pieces]) for name in ("stud", "inset", "prism", "centres")),
                owner, len(pieces), rows, np.concatenate([p.box for p in pieces]))


def _set_of(items: Sequence[tuple[Part, Pose]]) -> _Set:
    """The pieces of parts at poses: each part's `_Template` turned and moved."""
    return _joined([_part_pieces(part, pose) for part, pose in items])


_STRUCTURE, _UNIT = KeepLast(), KeepLast()
"""The last structure's and unit's pieces: the sampler checks one part against one structure in
several calls per step."""


def _unit_set(rel: Sequence[tuple[Part, Pose]]) -> _Set:
    """The unit's pieces in its own frame, kept for the last unit."""
    key = tuple((id(part), pose.R.tobytes(), pose.t.tobytes()) for part, pose in rel)
    return _UNIT.get(key, [part for part, _ in rel], lambda: _set_of(rel))


def _structure_set(structure: Structure) -> tuple[_Set, np.ndarray]:
    """The structure's pieces in the world and its parts' boxes, kept for the last structure."""
    def build():
        pieces = []
        for p in structure.placed:
            if p not in _PLACED:
                _PLACED[p] = _part_pieces(p.part, p.pose)
            pieces.append(_PLACED[p])
        return _joined(pieces), _boxes([(p.part, p.pose) for p in structure.placed])

    return _STRUCTURE.get(tuple(id(p) for p in structure.placed), list(structure.placed), build)


# --- The device part -----------------------------------------------------------------------------

_KERNEL = None


def _kernel():
    """The jitted batches of pairs by kind: 'sweep' (intervals of s) and 'still' (depths at the
    candidate's pose, `collide_jax`). JAX is imported here: the 'cpu' backend needs none."""
    global _KERNEL
    if _KERNEL is None:
        import jax  # optional: the [jax] extra
        import jax.numpy as jnp

        enable_compile_cache()

        def interval(av, bv, axes, valid, d, thr):
            """Open interval of s where every axis's two overlaps of (A - s d) and B exceed thr."""
            pa, pb = av @ axes.T, bv @ axes.T
            dn = axes @ d
            c = jnp.concatenate([pa.max(0) - pb.min(0), pb.max(0) - pa.min(0)])
            m = jnp.concatenate([-dn, dn])
            ok = jnp.concatenate([valid, valid])
            r = (thr - c) / jnp.where(m == 0, 1.0, m)  # c + m s > thr  <=>  s > r (m > 0), s < r (m < 0)
            lo = jnp.max(jnp.where(ok & (m > 0), r, -jnp.inf))
            hi = jnp.min(jnp.where(ok & (m < 0), r, jnp.inf))
            flat_fails = jnp.any(ok & (m == 0) & (c <= thr))
            return lo, jnp.where(flat_fails, -jnp.inf, hi)

        def pair(crosses, ut, st, R, t, d, u, s, k, thr, thr_c):
            uv, un, ue, uc = (x[u] for x in ut)
            sv, sn, se, sc = (x[s] for x in st)
            Rk, tk, dk = R[k], t[k], d[k]
            av, an, ae, ac = uv @ Rk.T + tk, un @ Rk.T, ue @ Rk.T, uc @ Rk.T + tk
            axes, valid = jnp.concatenate([an, sn]), jnp.ones(len(an) + len(sn), bool)
            if crosses:
                cross = jnp.cross(ae[:, None, :], se[None, :, :]).reshape(-1, 3)
                size = jnp.linalg.norm(cross, axis=1)
                ok = size > 1e-9  # parallel edges give no axis
                axes = jnp.concatenate([axes, cross / jnp.where(ok, size, 1.0)[:, None]])
                valid = jnp.concatenate([valid, ok])
            lo, hi = interval(av, sv, axes, valid, dk, thr)
            ones_s, ones_u = jnp.ones(len(sn), bool), jnp.ones(len(an), bool)
            lo_a, hi_a = interval(ac[None], sv, sn, ones_s, dk, thr_c)  # the unit piece's centre in s
            lo_b, hi_b = interval(av, sc[None], an, ones_u, dk, thr_c)  # the structure piece's in u
            return jnp.stack([lo, hi, lo_a, hi_a, lo_b, hi_b])

        def depth(a, b, axes, valid):
            """Separating-axis depth of point sets a into b: > 0 overlap (exact), <= 0 apart."""
            pa, pb = a @ axes.T, b @ axes.T
            c = jnp.minimum(pa.max(0) - pb.min(0), pb.max(0) - pa.min(0))
            return jnp.min(jnp.where(valid, c, jnp.inf))

        def still(crosses, ut, st, R, t, d, u, s, k, thr, thr_c):
            """At the candidate's pose (s = 0): the pieces' depth, then each centre's inside the other."""
            uv, un, ue, uc = (x[u] for x in ut)
            sv, sn, se, sc = (x[s] for x in st)
            Rk, tk = R[k], t[k]
            av, an, ae, ac = uv @ Rk.T + tk, un @ Rk.T, ue @ Rk.T, uc @ Rk.T + tk
            axes, valid = jnp.concatenate([an, sn]), jnp.ones(len(an) + len(sn), bool)
            if crosses:
                cross = jnp.cross(ae[:, None, :], se[None, :, :]).reshape(-1, 3)
                size = jnp.linalg.norm(cross, axis=1)
                ok = size > 1e-9
                axes = jnp.concatenate([axes, cross / jnp.where(ok, size, 1.0)[:, None]])
                valid = jnp.concatenate([valid, ok])
            ones_s, ones_u = jnp.ones(len(sn), bool), jnp.ones(len(an), bool)
            return jnp.stack([depth(av, sv, axes, valid), depth(ac[None], sv, sn, ones_s),
                              depth(av, sc[None], an, ones_u)])

        def split(table, v, n, e):
            """A packed table's (vertices, normals, edges, centres) (`_gathered`)."""
            return table[:, :v], table[:, v:v + n], table[:, v + n:v + n + e], table[:, v + n + e]

        def run(fn, crosses, sizes, ut, st, poses, pairs):
            # Packed arguments (`_launch`): the tables and the candidates' poses, already on the
            # device, and one host array of the pairs (their indices exact in float64).
            ut, st = split(ut, *sizes[:3]), split(st, *sizes[3:])
            R, t, d = poses[:, :9].reshape(-1, 3, 3), poses[:, 9:12], poses[:, 12:15]
            u, s, k = (pairs[:, i].astype(jnp.int64) for i in range(3))
            thr, thr_c = pairs[:, 3], pairs[:, 4]
            return jax.vmap(partial(fn, crosses), in_axes=(None, None, None, None, None, 0, 0, 0, 0, 0))(
                ut, st, R, t, d, u, s, k, thr, thr_c)

        _KERNEL = {"sweep": jax.jit(partial(run, pair), static_argnums=(0, 1)),
                   "still": jax.jit(partial(run, still), static_argnums=(0, 1))}
    return _KERNEL


WIDTH = {"sweep": 6, "still": 3}
"""Values per pair of each kernel kind."""


def _chunk(crosses: bool, us: tuple, ss: tuple) -> int:
    """Pairs per launch of the kernel of buckets `us`, `ss` (a power of two, at least 256): as many
    as keep its vertex-axis projections within `MAX_WORK`; edge-edge axes only with `crosses`."""
    nv = us[0] + ss[0]
    axes = us[1] + ss[1] + crosses * us[2] * ss[2]
    return max(256, 1 << int(math.log2(max(1, MAX_WORK // (nv * axes)))))


def _launch(crosses: bool, ut, us: tuple, st, ss: tuple, poses, u, s, k, thr, thr_c, kind: str = "sweep") -> list:
    """Starts the launches of pairs (u, s, k, thr, thr_c) and returns them, each (first pair,
    pairs, device result) (`_results`): (n, 6) intervals of the pairs (lo, hi of the overlap, then
    of the two centre tests), or for kind 'still' (n, 3) depths (of the pieces, of each centre in
    the other); edge-edge axes only with `crosses`. `ut`, `st`: `_gathered` tables of buckets
    `us`, `ss`; `poses`: the candidates' packed poses on the device (`_on_device`). A caller
    starts all its launches before it waits for any: the device runs them back to back, and the
    host waits once."""
    import jax  # optional: the [jax] extra

    n = len(u)
    chunk = _chunk(crosses, us, ss)
    pairs = np.stack([u, s, k, thr, thr_c], axis=1).astype(np.float64)  # indices < 2**53: exact
    sizes = (*us, *ss)
    dims = (kind, crosses, *sizes)
    started = []
    with jax.enable_x64(True):
        for a in range(0, n, chunk):
            m = min(chunk, n - a)
            # On a GPU a launch of a few pairs costs about what one of thousands does: pairs are
            # padded to the most met (at least `GPU_MIN_PAIRS`), so a run compiles few pair counts.
            rows = min(chunk, _grown(("pairs", *dims), m, GPU_MIN_PAIRS)) if _on_gpu() else _pow2(m, MIN_ROWS)
            shape = (kind, int(crosses), rows, ut.shape[0], st.shape[0], poses.shape[0], *sizes)
            if shape not in COMPILES:
                COMPILES.append(shape)
            # Through its export: a shape this process has not met is not traced again (`jax_export`).
            # The bucket sizes name it: they split the packed tables.
            res = jax_export.call(f"{kind}-{int(crosses)}-{'.'.join(map(str, sizes))}",
                                  partial(_kernel()[kind], crosses, sizes), ut, st, poses,
                                  np.concatenate([pairs[a:a + m], np.repeat(pairs[a:a + 1], rows - m, 0)]),
                                  source=__file__)
            started.append((a, m, res))
    return started


def _results(launches: list, kind: str) -> list[np.ndarray]:
    """The (pairs, `WIDTH[kind]`) results of `_launch`es, copied to the host together (one wait,
    not one per launch)."""
    import jax  # optional: the [jax] extra

    host = iter(jax.device_get([res for started in launches for _, _, res in started]))
    out = []
    for started in launches:
        got = np.empty((sum(m for _, m, _ in started), WIDTH[kind]))
        for a, m, _ in started:
            got[a:a + m] = np.asarray(next(host))[:m]
        out.append(got)
    return out


def _on_device(arrays: list[np.ndarray]) -> list:
    """Host arrays on the device, float64 as on the host, in one call."""
    import jax  # optional: the [jax] extra

    with jax.enable_x64(True):
        return jax.device_put(arrays)


WARM_LEVELS = LEVELS[:2]
"""Piece sizes whose kernels a GPU process has ready before its first round (`warm_up`): boxes and
studs, which nearly every part has."""
_WARMED = False


def warm_shapes() -> list[tuple]:
    """(kind, crosses, unit piece size, structure piece size) of every kernel `warm_up` readies."""
    return [(kind, crosses, us, ss) for kind in ("still", "sweep") for crosses in (False, True)
            for us in WARM_LEVELS for ss in WARM_LEVELS]


def warm_up() -> int:
    """Once per process on a GPU, before its first round: every kernel of `warm_shapes` at the sizes
    a first round uses (`MIN_ROWS` unit rows and candidates, `GPU_MIN_STRUCTURE_ROWS`,
    `GPU_MIN_PAIRS`), compiled or loaded (`jax_export`), starting at this worker's number
    (`gpus.slot`; else at its pid) and going round. The workers of a fresh machine then compile
    different shapes at once, each under its shape's lock, and load the others' from the cache;
    meeting each shape in a round, together, they waited in turn for its one compile (about 1 s a
    shape on a lent H100).
    Returns the kernels readied here (0 when not on a GPU, or done before)."""
    global _WARMED
    if _WARMED or not _on_gpu():
        return 0
    _WARMED = True
    import jax  # optional: the [jax] extra

    shapes = warm_shapes()
    # A build's workers are numbered; other processes (Ray tasks, say) start by their pid instead.
    slot = gpus.slot()
    start = (os.getpid() if slot is None else slot) % len(shapes)
    one = np.zeros(1, np.int64)
    launches = []
    for kind, crosses, us, ss in shapes[start:] + shapes[:start]:
        ut, st, poses = _on_device([np.zeros((_table_rows(("u", us), 1), sum(us) + 1, 3)),
                                    np.zeros((_table_rows(("s", ss), 1), sum(ss) + 1, 3)),
                                    np.zeros((_grown(("candidates",), 1), 15))])
        launches.append(_launch(crosses, ut, us, st, ss, poses, one, one, one, np.zeros(1), np.zeros(1), kind))
    jax.block_until_ready([res for started in launches for _, _, res in started])
    return len(shapes)


def _gathered(tables: list[tuple], rows: np.ndarray, size: int) -> np.ndarray:
    """The rows `rows` (ascending) of `tables` (one bucket's (vertices, normals, edges, centres) of
    several sets, counted one after the other) packed in one (size, vertices + normals + edges + 1,
    3) array, padded to `size` by repeating its first row. A launch takes only the pieces its
    pairs name: a round's whole tables were 14.5 MB a launch on average (docs/concepts/batched-checks.md), and
    every host array is copied again on its way to the device."""
    chunks, start = [], 0
    for table in tables:
        end = start + len(table[0])
        local = rows[np.searchsorted(rows, start):np.searchsorted(rows, end)] - start
        if len(local):
            chunks.append(np.concatenate([table[0][local], table[1][local], table[2][local],
                                          table[3][local][:, None]], axis=1))
        start = end
    packed = np.concatenate(chunks)
    return np.concatenate([packed, np.repeat(packed[:1], size - len(packed), 0)])


def _intervals_many(jobs, kind: str = "sweep") -> list[np.ndarray]:
    """For each job (unit set, structure set, R, t, d, k, u, s, thr, thr_c): the (pairs, 6)
    intervals of unit piece u[i] of candidate k[i] (pose R, t; direction d) against structure piece
    s[i] (`_launch`; with kind 'still' their depths at the pose). One launch per group of pairs
    with the same piece buckets (and alignment) whatever job they come from: per side and bucket,
    the rows the pairs name, of every job's sets, in one table (`_gathered`); the tables and all
    candidates' poses go to the device in one call, every launch starts before the first result
    is waited for, and the results come back in one copy (`_results`)."""
    out = [np.empty((len(j[5]), WIDTH[kind])) for j in jobs]
    if not jobs:
        return out
    warm_up()
    # Bucket shapes (vertices, normals, edges) of every set, and where each set's table of a bucket
    # starts when the tables of that shape are counted one after the other.
    tables: dict[tuple, list] = {}
    offset: dict[tuple[int, tuple], int] = {}

    def place(the_set: _Set, side: str) -> None:
        for b, shape in enumerate(the_set.buckets):
            key = (id(the_set), side, shape)
            if key not in offset:
                rows = tables.setdefault((side, shape), [])
                offset[key] = sum(len(t[0]) for t in rows)
                rows.append(the_set.tables[b])

    for uset, sset, *_ in jobs:
        place(uset, "u")
        place(sset, "s")
    # Candidates of all jobs in one array; pairs labelled by their group.
    k_start = np.cumsum([0] + [len(j[2]) for j in jobs])
    kp = _grown(("candidates",), int(k_start[-1]))
    Rs, ts, ds = (np.concatenate([j[i] for j in jobs]) for i in (2, 3, 4))
    Rp, tp, dp = (np.concatenate([x, np.repeat(x[:1], kp - len(x), 0)]) for x in (Rs, ts, ds))
    shapes: dict[tuple, int] = {}
    per_job = []
    for n, (uset, sset, R, t, d, k, u, s, thr, thr_c) in enumerate(jobs):
        # Pairs of right prisms along one direction need no edge-edge axes (`_prism_axes`).
        up = np.einsum("pij,pkj->pki", R[k], uset.prism[u])
        aligned = (np.abs(np.einsum("pai,pbi->pab", up, sset.prism[s])) > 1 - 1e-9).any(axis=(1, 2))
        ushape, sshape = uset.buckets, sset.buckets
        codes = np.array([shapes.setdefault((us, ss, al), len(shapes))
                          for us in ushape for ss in sshape for al in (False, True)], np.int64)
        group = codes[(uset.bucket_of[u] * len(sshape) + sset.bucket_of[s]) * 2 + aligned]
        uoff = np.array([offset[(id(uset), "u", sh)] for sh in ushape], np.int64)[uset.bucket_of[u]]
        soff = np.array([offset[(id(sset), "s", sh)] for sh in sshape], np.int64)[sset.bucket_of[s]]
        per_job.append((group, uset.local[u] + uoff, sset.local[s] + soff, k + k_start[n], thr, thr_c))
    groups = []
    for (us, ss, al), code in shapes.items():
        sel = [np.flatnonzero(g[0] == code) for g in per_job]
        if sum(len(x) for x in sel):
            groups.append((us, ss, al, sel, *(np.concatenate([pj[i][x] for pj, x in zip(per_job, sel)])
                                              for i in (1, 2, 3, 4, 5))))
    # Per side and bucket, the rows some pair names, in one table on the device.
    named: dict[tuple, list] = {}
    for us, ss, al, sel, gu, gs, *_ in groups:
        named.setdefault(("u", us), []).append(gu)
        named.setdefault(("s", ss), []).append(gs)
    rows = {key: np.unique(np.concatenate(x)) for key, x in named.items()}
    keys = list(rows)
    # The tables and the candidates' poses go to the device in one call.
    *tables_on, poses = _on_device([_gathered(tables[key], rows[key], _table_rows(key, len(rows[key])))
                                    for key in keys] + [np.concatenate([Rp.reshape(kp, 9), tp, dp], axis=1)])
    packed = dict(zip(keys, tables_on))
    launches = []
    for us, ss, al, sel, gu, gs, gk, gthr, gthc in groups:
        u_at, s_at = np.searchsorted(rows[("u", us)], gu), np.searchsorted(rows[("s", ss)], gs)
        launches.append(_launch(not al, packed[("u", us)], us, packed[("s", ss)], ss, poses, u_at, s_at, gk, gthr, gthc,
                                kind))
    # Every group is started before the first is waited for.
    for (_, _, _, sel, *_), res in zip(groups, _results(launches, kind)):
        at = 0
        for n, x in enumerate(sel):
            out[n][x] = res[at:at + len(x)]
            at += len(x)
    return out


def exact_intervals(a: Sequence[np.ndarray], b: Sequence[np.ndarray], d: np.ndarray, thr: np.ndarray) -> np.ndarray:
    """(n, 2): for convex point sets a[i], b[i] (world), the open interval of s where the depth of
    a[i] moved by -s d[i] into b[i] exceeds thr[i] >= 0 (empty: hi <= lo). For tests and checks."""
    n = len(a)
    ua = _Set.of_pieces([_piece(v, False, 0.0) for v in a], np.array([v.mean(0) for v in a]), np.arange(n), n)
    sb = _Set.of_pieces([_piece(v, False, 0.0) for v in b], np.array([v.mean(0) for v in b]), np.arange(n), n)
    idx = np.arange(n)
    R, t = np.repeat(np.eye(3)[None], n, 0), np.zeros((n, 3))
    (res,) = _intervals_many([(ua, sb, R, t, np.asarray(d, float), idx, idx, idx, np.asarray(thr, float),
                               np.full(n, np.inf))])
    return res[:, :2]


# --- The sweep -----------------------------------------------------------------------------------


def _swept_boxes_meet(lo: np.ndarray, hi: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Whether some s > 0 has s d in (lo, hi) along every axis (last dimension)."""
    start, end = box_interval(lo, hi, d)
    return start < end


def near_pairs(uset: _Set, sset: _Set, sboxes, rel, R, t, d, conn, part_margin: float = 0.0,
               piece_margin: float = 0.0):
    """The piece pairs whose boxes meet at some s >= 0 along each candidate's d (d = 0: at its pose),
    overlapping by more than the margin along every axis (a negative margin: apart by less than
    it): (candidate, unit piece, structure piece, part, connected). Each member's box against each
    part's (`part_margin`), then each of its pieces against the box of the part's pieces, then
    against each of them (`piece_margin`); stud pieces of parts the candidate connects to are left
    out (they never collide). `conn`: (candidates, parts) connected."""
    def meet(a_lo, a_hi, b_lo, b_hi, dk, margin):
        return _swept_boxes_meet(a_lo - b_hi + margin, a_hi - b_lo - margin, dk)

    mb = np.stack([part.bbox for part, _ in rel])
    mR = np.stack([p.R for _, p in rel])
    mt = np.stack([p.t for _, p in rel])
    wR = np.einsum("kij,mjl->kmil", R, mR)
    centre = np.einsum("kmij,mj->kmi", wR, mb.mean(axis=1)) + np.einsum("kij,mj->kmi", R, mt) + t[:, None]
    half = np.einsum("kmij,mj->kmi", np.abs(wR), (mb[:, 1] - mb[:, 0]) / 2)
    kk, mm, jj = np.nonzero(meet((centre - half)[:, :, None], (centre + half)[:, :, None], sboxes[None, None, :, 0],
                                 sboxes[None, None, :, 1], d[:, None, None], part_margin))
    # Pieces: each piece of the member (its world box at each candidate, computed once per
    # candidate and piece) against the box of all the part's pieces, then against each of them.
    ubox = uset.box
    wc = np.einsum("kij,uj->kui", R, ubox.mean(axis=1)) + t[:, None]
    wh = np.einsum("kij,uj->kui", np.abs(R), (ubox[:, 1] - ubox[:, 0]) / 2)
    nu = np.diff(uset.start)[mm]
    rep = np.repeat(np.arange(len(kk)), nu)
    k, j = kk[rep], jj[rep]
    u = uset.start[mm[rep]] + np.arange(len(rep)) - np.repeat(np.cumsum(nu) - nu, nu)
    pbox = sset.owner_box
    lo_u, hi_u = wc[k, u] - wh[k, u], wc[k, u] + wh[k, u]
    near = meet(lo_u, hi_u, pbox[j, 0], pbox[j, 1], d[k], piece_margin)
    k, j, u, lo_u, hi_u = k[near], j[near], u[near], lo_u[near], hi_u[near]
    ns = np.diff(sset.start)[j]
    rep = np.repeat(np.arange(len(k)), ns)
    s = sset.start[j[rep]] + np.arange(len(rep)) - np.repeat(np.cumsum(ns) - ns, ns)
    k, j, u, lo_u, hi_u = k[rep], j[rep], u[rep], lo_u[rep], hi_u[rep]
    is_conn = conn[k, j]
    sb = sset.box[s]
    near = ~(is_conn & (uset.stud[u] | sset.stud[s]))
    near &= meet(lo_u, hi_u, sb[:, 0], sb[:, 1], d[k], piece_margin)
    return k[near], u[near], s[near], j[near], is_conn[near]


def _pairs(uset: _Set, sset: _Set, sboxes, rel, R, t, d, conn, tol: float, margin: float, a: int, b: int):
    """The piece pairs of candidates a..b-1 whose boxes meet somewhere along the approach
    (`near_pairs`: parts' boxes shrunk by the reference's margin, the parts it connects to kept:
    their pieces count too, with the slack), with their thresholds: (candidate, unit piece,
    structure piece, part, connected, thr, thr_c, undecided)."""
    k, u, s, j, is_conn = near_pairs(uset, sset, sboxes, rel, R[a:b], t[a:b], d[a:b], conn[a:b], margin)
    thr = tol - uset.inset[u] - sset.inset[s] + np.where(is_conn, CONNECTED_SLACK_LDU, 0.0)
    thr_c = np.where(is_conn, tol, np.inf)
    undecided = ~is_conn & (uset.stud[u] != sset.stud[s])
    return k + a, u, s, j, is_conn, thr, thr_c, undecided


PAIR_CHUNK = 512
"""Candidates per chunk of pair selection; chunks run on `PAIR_THREADS` threads (numpy releases
the interpreter lock in its array operations, so a many-core host selects pairs in parallel
while the device computes)."""
PAIR_THREADS = min(8, os.cpu_count() or 1)


def _in_chunks(fn, count: int) -> tuple:
    """fn(a, b) over candidates a..b-1 in chunks of `PAIR_CHUNK` on `PAIR_THREADS` threads, each
    returned array joined in candidate order (the same arrays as one call over all gives)."""
    spans = [(a, min(a + PAIR_CHUNK, count)) for a in range(0, count, PAIR_CHUNK)]
    if len(spans) <= 1 or PAIR_THREADS <= 1:
        parts = [fn(a, b) for a, b in spans]
    else:
        with ThreadPoolExecutor(min(PAIR_THREADS, len(spans))) as pool:
            parts = list(pool.map(lambda span: fn(*span), spans))
    return tuple(np.concatenate(x) for x in zip(*parts))


def near_pairs_threaded(uset: _Set, sset: _Set, sboxes, rel, R, t, d, conn, part_margin: float = 0.0,
                        piece_margin: float = 0.0):
    """`near_pairs` of all candidates, in chunks on threads (`_in_chunks`)."""
    def chunk(a, b):
        k, *rest = near_pairs(uset, sset, sboxes, rel, R[a:b], t[a:b], d[a:b], conn[a:b], part_margin, piece_margin)
        return (k + a, *rest)

    return _in_chunks(chunk, len(R))


def _pairs_threaded(uset, sset, sboxes, rel, R, t, d, conn, tol, margin):
    """`_pairs` of all candidates, in chunks on threads (`_in_chunks`)."""
    return _in_chunks(lambda a, b: _pairs(uset, sset, sboxes, rel, R, t, d, conn, tol, margin, a, b), len(R))


def sweep_many(
    scene: CollisionScene | None,
    structure: Structure,
    units: Sequence[Sequence[tuple[Part, Pose]]],
    connected: Sequence[set[int]],
    max_penetration_ldu: float = 0.5,
    directions: Sequence[np.ndarray] | None = None,
) -> list[SweepResult]:
    """`sweep.sweep` for every unit (module docstring for the method and what may differ).

    The units share their parts and relative layout up to one rigid motion (as `check.check_units`
    requires), each placed in world poses, its pose that of its first part; `scene` is their
    collision scene as `check_units` builds it, or a function building it on first need (None: built
    here if a candidate is referred to the CPU). `directions`: each unit's seating directions (`sweep.seating_directions`), if known.
    """
    return sweep_groups([(scene, structure, units, connected, max_penetration_ldu, directions)])[0]


def sweep_groups(groups: Sequence[tuple]) -> list[list[SweepResult]]:
    """`sweep_many(*group)` of every group (each its own structure: objects grown in lockstep),
    with the pairs of all groups in one launch per piece-bucket shape (`_intervals_many`). Units
    blocked on their axis only further out than `sweep.PRESS_LDU` are then swept from the side
    (`_SweepJob.sides`), every group's in one more launch."""
    jobs = [_SweepJob(*g) for g in groups]
    _launch_all(jobs)
    sides = [(j, j.sides()) for j in jobs]
    sides = [(j, sj) for j, sj in sides if sj is not None]
    _launch_all([sj for _, sj in sides])
    for j, sj in sides:
        j.after_sides(sj)
    return [j.results for j in jobs]  # type: ignore[misc]


def _launch_all(jobs: Sequence[_SweepJob]) -> None:
    live = [j for j in jobs if j.pairs is not None]
    for j, res in zip(live, _intervals_many([j.launch_args() for j in live])):
        j.finish(res)


class _SweepJob:
    """One `sweep_many` call: approaches and piece pairs on the host at construction (`pairs` None
    when nothing is left for the device), the intervals from the device, then `finish`.

    With `ways` (one direction per unit) the units are swept along those as given, with nothing
    connected, and `finish` only records each unit's state (`states`): the side sweeps of
    `sides`, whose verdicts their parent job draws (`after_sides`)."""

    def __init__(self, scene, structure, units, connected, max_penetration_ldu=0.5, directions=None, ways=None):
        self.structure, self.units, self.connected = structure, units, connected
        self.tol = tol = max_penetration_ldu
        self.results: list[SweepResult | None] = [None] * len(units)
        self.pairs = None
        self.side_of = ways is not None
        self.pending: list[int] = []  # rows blocked only further out than PRESS_LDU: asked from the side
        if not units:
            return
        if ways is not None:
            dirs = list(enumerate(ways))
        else:
            dirs = []
            found_all = approaches_from([directions[i] if directions is not None else seating_directions(structure, unit)
                                         for i, unit in enumerate(units)])
            for i, found in enumerate(found_all):
                if found.direction is None:
                    COUNTS["not-judged"] += 1
                    self.results[i] = SweepResult(False if found.reason == "clamped" else None, found.reason, (), 0.0,
                                                  0.0, 0)
                else:
                    dirs.append((i, found.direction))
        first = units[0]
        anchor = first[0][1]
        self.rel = rel = [(part, anchor.inverse() @ pose) for part, pose in first]
        self.scene = scene
        self.idx = np.array([i for i, _ in dirs], np.int64)
        self.states = np.zeros(len(self.idx), np.int8)  # side sweeps: _CLEAR until finished
        if not dirs:
            return
        self.sset, self.sboxes = sset, sboxes = _structure_set(structure)
        self.uset = uset = _unit_set(rel)
        if tol < uset.inset.max(initial=0.0) + sset.inset.max(initial=0.0):
            # Below both insets the separating-axis minimum is not the distance (module docstring).
            self.states[:] = _UNDECIDED
            if not self.side_of:
                for i, _ in dirs:
                    COUNTS["cpu"] += 1
                    self.results[i] = self.cpu(i)
            return
        idx = self.idx
        self.d = d = np.array([v for _, v in dirs])
        self.R = R = np.stack([units[i][0][1].R for i in idx])
        self.t = t = np.stack([units[i][0][1].t for i in idx])
        self.margin = margin = min(tol, 2 * INSET_LDU)
        conn = np.zeros((len(idx), len(structure)), bool)
        sizes = [len(connected[i]) for i in idx]
        conn[np.repeat(np.arange(len(idx)), sizes), np.fromiter((q for i in idx for q in connected[i]), np.int64, sum(sizes))] = True
        self.pairs = _pairs_threaded(uset, sset, sboxes, rel, R, t, d, conn, tol, margin)

    def sides(self) -> _SweepJob | None:
        """The side sweeps of this job's pending units (`sweep._pressed_last`): each unit backed out
        `PRESS_LDU` along its axis, studs out of their sockets (nothing connected), swept along the
        four directions `across` the axis."""
        if not self.pending:
            return None
        units, ways = [], []
        for row in self.pending:
            back = PRESS_LDU * self.d[row]
            moved = [(part, Pose(pose.R, pose.t - back)) for part, pose in self.units[self.idx[row]]]
            for way in across(self.d[row]):
                units.append(moved)
                ways.append(way)
        return _SweepJob(self.scene, self.structure, units, [set()] * len(units), self.tol, ways=ways)

    def after_sides(self, side: _SweepJob) -> None:
        """Pending units' verdicts from their side sweeps: buildable when one side is clear; the
        straight verdict (kept in `results`) when every side is blocked; else swept on the CPU."""
        states = side.states.reshape(len(self.pending), 4)
        for row, st in zip(self.pending, states):
            i = self.idx[row]
            if (st == _CLEAR).any():
                COUNTS["device"] += 1
                self.results[i] = SweepResult(True, None, (), float("nan"), PRESS_LDU, 0)
            elif (st == _BLOCKED).all():
                COUNTS["device"] += 1
            else:
                COUNTS["referred"] += 1
                self.results[i] = self.cpu(i)
        self.pending = []

    def cpu(self, i: int) -> SweepResult:
        if self.scene is None:
            self.scene = CollisionScene(self.structure, self.rel, 1e6)
        elif not isinstance(self.scene, CollisionScene):
            self.scene = self.scene()  # built on first need
        return sweep(self.scene, self.structure, self.units[i], self.connected[i], self.tol)

    def launch_args(self) -> tuple:
        k, u, s, j, is_conn, thr, thr_c, undecided = self.pairs
        return (self.uset, self.sset, self.R, self.t, self.d, k, u, s, thr, thr_c)

    def finish(self, res: np.ndarray) -> None:
        structure, units, connected, idx, d = self.structure, self.units, self.connected, self.idx, self.d
        k, _, _, j, is_conn, _, _, undecided = self.pairs
        results = self.results
        # Counted stretches of s > 0: (candidate, part, lo, hi, decided).
        hits = []
        for col in (0, 2, 4):
            lo_, hi_ = np.maximum(res[:, col], 0.0), res[:, col + 1]
            ok = hi_ > lo_
            if col:
                ok &= is_conn
            hits.append((k[ok], j[ok], lo_[ok], hi_[ok], ~undecided[ok], is_conn[ok]))
        hk, hj, hlo, hhi, hdec, hconn = (np.concatenate(x) for x in zip(*hits))
        # Parts the unit is connected to count only where the reference queries at all: where its box
        # overlaps a part it is not connected to. Rare (the unit backs away from them): a loop.
        plain = ~hconn
        clipped = []
        for e in np.flatnonzero(hconn):
            i = idx[hk[e]]
            others = [q for q in range(len(structure)) if q not in connected[i]]
            span = _overlap_intervals(_boxes(units[i]), self.sboxes[others], d[hk[e]], self.margin)
            for a, b in span:
                if min(b, hhi[e]) > max(a, hlo[e]):
                    clipped.append((hk[e], hj[e], max(a, hlo[e]), min(b, hhi[e])))
        ck, cj, clo, chi = (np.array(x).reshape(-1) for x in zip(*clipped)) if clipped else [np.zeros(0)] * 4
        dk = np.concatenate([hk[plain & hdec], ck.astype(np.int64)])
        dj = np.concatenate([hj[plain & hdec], cj.astype(np.int64)])
        dlo = np.concatenate([hlo[plain & hdec], clo])
        dhi = np.concatenate([hhi[plain & hdec], chi])
        top = np.full(len(idx), -np.inf)
        np.maximum.at(top, dk, dhi)
        # The pose just inside the outermost decided interval: who is in the way there.
        outer = dhi >= top[dk]
        floor_ = np.full(len(idx), -np.inf)
        np.maximum.at(floor_, dk[outer], dlo[outer])
        probe = np.maximum(top - MIN_STEP_LDU / 4, (top + floor_) / 2)
        there = (dlo < probe[dk]) & (probe[dk] < dhi)
        blockers: dict[int, set[int]] = {}
        for a, b in zip(dk[there], dj[there]):
            blockers.setdefault(int(a), set()).add(int(b))
        maybe = np.zeros(len(idx), bool)
        maybe[hk[~hdec & plain]] = True
        maybe_near = np.zeros(len(idx), bool)  # within the stretch pressed along: all a side entry needs
        maybe_near[hk[~hdec & plain & (hlo < PRESS_LDU)]] = True
        # Blocked within the stretch it is pressed along (`sweep.PRESS_LDU`): no side approach helps.
        pressed = np.zeros(len(idx), bool)
        pressed[dk[dlo < PRESS_LDU]] = True
        # ... but clear over the fingertip's end (`sweep.PRESS_MIN_LDU`): rare, swept on the CPU.
        pressed_min = np.zeros(len(idx), bool)
        pressed_min[dk[dlo < PRESS_MIN_LDU]] = True
        if self.side_of:
            self.states = np.where(np.isfinite(top), _BLOCKED, np.where(maybe, _UNDECIDED, _CLEAR)).astype(np.int8)
            return
        for row, i in enumerate(idx):
            if np.isfinite(top[row]) and not pressed[row]:
                # Blocked only further out: whether the unit comes in from the side instead
                # (`sweep._pressed_last`) is asked of the device too (`sides`), unless an undecided
                # pair may block it, when the CPU sweeps it.
                if maybe_near[row]:
                    COUNTS["referred"] += 1
                    results[i] = self.cpu(i)
                else:
                    self.pending.append(row)
                    results[i] = SweepResult(False, "blocked", tuple(sorted(blockers.get(row, ()))), float("nan"),
                                             round(float(top[row]), 4), 0)
            elif np.isfinite(top[row]) and not pressed_min[row]:
                COUNTS["referred"] += 1
                results[i] = self.cpu(i)
            elif np.isfinite(top[row]):
                COUNTS["device"] += 1
                results[i] = SweepResult(False, "blocked", tuple(sorted(blockers.get(row, ()))), float("nan"),
                                         round(float(top[row]), 4), 0)
            elif maybe[row]:
                COUNTS["referred"] += 1
                results[i] = self.cpu(i)
            else:
                COUNTS["device"] += 1
                results[i] = SweepResult(True, None, (), float("nan"), 0.0, 0)
