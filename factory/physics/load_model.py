"""The whole-structure load model (`statics` judges it): a structure's bodies, stud connections,
rigid links and ground supports as arrays (`LoadModel`), for the component of the connection graph
that holds some parts (`load_model`) or holds a candidate added to a structure (`LoadBase`,
computed once for all candidates of a call), and the support polygon on the ground.

- every part is a rigid body with its weight at its centre of mass;
- every stud connection (a stud of part `a` in a socket of part `b`, stud base `p`, stud axis `n`
  pointing from `a` into `b`) acts on `b` through four normal forces `g` along `n` at the stud's
  rim (`p ± r e1`, `p ± r e2`, r = stud radius), a shear force `t` across `n` at `p` and a torsion
  `tau` about `n`, and on `a` through the opposite. Compression (`g > 0`, pushing `b` away from
  `a`) is free; tension is at most `clutch_n / 4` per rim point (the stud's clutch, split over its
  rim, so one stud also holds a moment of `clutch_n * r`); `|t| <= shear_n` per axis;
  `|tau| <= clutch_n * r`;
- the ground only pushes: at each support point (a part's collision vertices within
  `ground_tol_ldu` of the ground, reduced to their hull) a force inside the friction pyramid;
- a joint (Technic pins and axles, clips, hinges, wheels, minifigure joints: `Link`) carries a
  force along its axis and across it, and a moment about it and across it, each within its kind's
  capacity (`joint_capacity`): a pin that turns freely carries no moment about its axis. A
  connection the checker cannot place (`unsupported-connection`) is a rigid link: free force and
  moment.

Its program is `load_program`'s (`to_lp`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from factory.connections import STUD_RADIUS
from factory.physics.check_state import current
from factory.physics.geometry import collision_shape
from factory.physics.joint_capacity import capacity
from factory.physics.mass import part_mass_properties
from factory.physics.structure import Placed, lowest_point

UP = np.array([0.0, -1.0, 0.0])
"""LDraw's up (y grows downward): the ground pushes this way, gravity pulls the other."""


@dataclass(frozen=True)
class LoadConfig:
    """Constants of the whole-structure load model (docs/concepts/physics.md: why these)."""

    clutch_n: float = 1.0
    """Tension one stud connection holds (N): StableLego and BrickGPT use 0.98 N per contact point,
    one per stud; BrickSim's 3.5 N preload with friction 0.2 gives 0.7 N."""
    shear_n: float = 10.0
    """Shear one stud holds across its axis (N, per axis): the stud is boxed in by the socket's
    walls and breaks rather than slips; ten times the clutch, so it binds only for studs that
    point sideways and carry weight across their axis."""
    friction: float = 0.8
    """Ground friction coefficient (the pyramid's slope)."""
    ground_tol_ldu: float = 0.5
    """A part's collision vertices this close to the ground support it."""
    support_points: int = 8
    """At most this many support points per part on the ground (its footprint's hull, subsampled)."""
    tolerance: float = 1e-6
    """Relative slack on `s <= 1` and on the centre of mass over the support polygon (LDU)."""

    @property
    def torsion_nldu(self) -> float:
        """Torsion one stud holds about its axis (N LDU): its clutch at its rim."""
        return self.clutch_n * STUD_RADIUS


@dataclass(frozen=True)
class Link:
    """A joint between two parts (`joint_capacity`), or a rigid link where its kind is 'rigid'."""

    a: int
    b: int
    point: tuple[float, float, float]
    """Where it holds (LDU)."""
    kind: str = "rigid"
    """A key of `joint_capacity.JOINT_CAPACITY`, or 'rigid'."""
    axis: tuple[float, float, float] | None = None
    """Its unit axis, where it has one (a pin's, a bar's, a hinge's)."""

    def moved(self, by: int) -> "Link":
        """The same link between parts numbered `by` later."""
        return Link(self.a + by, self.b + by, self.point, self.kind, self.axis)


@dataclass(frozen=True)
class LoadModel:
    """One structure's bodies, connections and supports as arrays (LDU, LDraw frame). Body `k` is
    part `parts[k]` of the caller's numbering."""

    parts: np.ndarray
    mass: np.ndarray
    """(nb,) kg."""
    com: np.ndarray
    """(nb, 3) centres of mass."""
    conn_a: np.ndarray
    """(nc,) body holding the stud."""
    conn_b: np.ndarray
    """(nc,) body holding the socket."""
    conn_pos: np.ndarray
    """(nc, 3) stud base."""
    conn_axis: np.ndarray
    """(nc, 3) unit stud axis, from `a` into `b`."""
    ground_body: np.ndarray
    ground_pos: np.ndarray
    link_a: np.ndarray
    link_b: np.ndarray
    link_pos: np.ndarray
    link_axis: np.ndarray
    """(nl, 3) each link's unit axis (any unit vector where it has none)."""
    link_cap: np.ndarray
    """(nl, 6) each link's capacities in its columns' order (`JointCapacity.as_row`; inf: free)."""
    link_kind: np.ndarray
    """(nl,) each link's kind (`Link.kind`)."""

    @property
    def n_bodies(self) -> int:
        return len(self.mass)


def support_points(placed: Placed, floor_y: float, cfg: LoadConfig) -> np.ndarray:
    """(k, 3) support points of a part on the ground at LDraw height floor_y (may be empty)."""
    key = (id(placed), round(floor_y, 6), cfg.ground_tol_ldu, cfg.support_points)
    kept = current().supports  # the checker's (`CheckState.supports`)
    hit = kept.get(key)
    if hit is not None and hit[0] is placed:
        return hit[1]
    shape = collision_shape(placed.part)
    verts = placed.pose.apply(np.concatenate(list(shape.body) + list(shape.studs)))
    low = verts[verts[:, 1] >= floor_y - cfg.ground_tol_ldu]
    if len(low):
        xz = np.unique(np.round(low[:, [0, 2]], 6), axis=0)
        xz = hull_xz(xz)
        if len(xz) > cfg.support_points:
            xz = xz[np.linspace(0, len(xz), cfg.support_points, endpoint=False).astype(int)]
        out = np.column_stack([xz[:, 0], np.full(len(xz), floor_y), xz[:, 1]])
    else:
        out = np.zeros((0, 3))
    if len(kept) > 4096:
        kept.clear()
    kept[key] = (placed, out)
    return out


def hull_xz(xz: np.ndarray) -> np.ndarray:
    """The hull's corners in order; for a collinear set, its two ends."""
    if len(xz) < 3:
        return xz
    try:
        return xz[ConvexHull(xz).vertices]
    except QhullError:
        d = xz - xz.mean(0)
        u = np.linalg.svd(d, full_matrices=False)[2][0]
        proj = d @ u
        return xz[[int(proj.argmin()), int(proj.argmax())]]


class LoadBase:
    """A structure's parts as the load model needs them, computed once for every candidate of a
    call (`check_units` judges hundreds against one structure): masses, centres of mass, support
    points, its connections and links as arrays and its components (union-find). `of(seeds)` is the
    model of the component holding some of its parts (`load_model`); `model(unit, conns,
    unit_links)` that of a unit added to it, in array operations instead of a walk over the whole
    structure per candidate."""

    def __init__(self, placed: Sequence[Placed], connections, floor_y: float | None,
                 links: Sequence[Link] = (), cfg: LoadConfig = LoadConfig()):
        self.placed, self.floor_y, self.cfg = list(placed), floor_y, cfg
        n = self.n = len(self.placed)
        props = [part_mass_properties(p.part) for p in self.placed]
        self.mass = np.array([m for m, _, _ in props], float)
        self.com = np.array([p.pose.apply(c) for p, (_, c, _) in zip(self.placed, props)], float).reshape(-1, 3)
        self.conn_a, self.conn_b, self.conn_pos, self.conn_axis = connection_arrays(connections)
        self.link_a, self.link_b, self.link_pos, self.link_axis, self.link_cap, self.link_kind = _link_arrays(links)
        parent = np.arange(n)

        def root(i):
            while parent[i] != i:
                parent[i] = parent[parent[i]]
                i = parent[i]
            return i

        for a, b in zip(np.r_[self.conn_a, self.link_a], np.r_[self.conn_b, self.link_b]):
            ra, rb = root(int(a)), root(int(b))
            if ra != rb:
                parent[max(ra, rb)] = min(ra, rb)
        self.label = np.array([root(i) for i in range(n)], np.int64)
        self._supports: dict[float, list[np.ndarray]] = {}
        self._hull: np.ndarray | None = None

    def _support(self, floor_y: float) -> list[np.ndarray]:
        key = round(floor_y, 6)
        if key not in self._supports:
            self._supports[key] = [support_points(p, floor_y, self.cfg) for p in self.placed]
        return self._supports[key]

    def _model(self, member: np.ndarray, unit: Sequence[Placed] = (), conns=(), unit_links: Sequence[Link] = ()) -> LoadModel:
        """The structure's parts in `member` (a mask), then the unit's (numbered after the
        structure's), with the connections and links among them and the new ones."""
        n, k = self.n, len(unit)
        comp = np.r_[np.flatnonzero(member), n + np.arange(k)].astype(np.int64)
        body = np.full(n + k, -1, np.int64)
        body[comp] = np.arange(len(comp))
        props = [part_mass_properties(p.part) for p in unit]
        floor_y = self.floor_y
        if floor_y is None:  # the component rests on its own lowest point
            floor_y = lowest_point([self.placed[i] for i in comp[comp < n]] + list(unit))
        base_pts = self._support(floor_y)
        gp = [base_pts[i] for i in comp[comp < n]] + [support_points(p, floor_y, self.cfg) for p in unit]
        keep, lk = member[self.conn_a], member[self.link_a]
        new_a, new_b, new_pos, new_axis = connection_arrays(conns)
        ul_a, ul_b, ul_pos, ul_axis, ul_cap, ul_kind = _link_arrays(unit_links)
        return LoadModel(
            parts=comp, mass=np.r_[self.mass[member], [m for m, _, _ in props]],
            com=np.concatenate([self.com[member], np.array([p.pose.apply(c) for p, (_, c, _) in zip(unit, props)]).reshape(-1, 3)]),
            conn_a=body[np.r_[self.conn_a[keep], new_a]], conn_b=body[np.r_[self.conn_b[keep], new_b]],
            conn_pos=np.concatenate([self.conn_pos[keep], new_pos]),
            conn_axis=np.concatenate([self.conn_axis[keep], new_axis]),
            ground_body=np.repeat(np.arange(len(comp)), [len(g) for g in gp]).astype(np.int64),
            ground_pos=np.concatenate(gp) if gp else np.zeros((0, 3)),
            link_a=body[np.r_[self.link_a[lk], ul_a]], link_b=body[np.r_[self.link_b[lk], ul_b]],
            link_pos=np.concatenate([self.link_pos[lk], ul_pos]),
            link_axis=np.concatenate([self.link_axis[lk], ul_axis]),
            link_cap=np.concatenate([self.link_cap[lk], ul_cap]),
            link_kind=np.concatenate([self.link_kind[lk], ul_kind]),
        )

    def of(self, seeds: Sequence[int]) -> LoadModel:
        """The model of the component holding `seeds` (structure part indices)."""
        return self._model(np.isin(self.label, self.label[np.asarray(seeds, np.int64)]))

    def model(self, unit: Sequence[Placed], conns, unit_links: Sequence[Link] = ()) -> LoadModel:
        """The model of the component holding `unit` (numbered after the structure's parts), with
        its connections `conns` (structure and unit, in that numbering) and `unit_links` (rigid
        links, in that numbering). The unit's parts are all seeds: the component is them and the
        structure's components any new edge reaches (an edge between two unit parts reaches none)."""
        ends = np.r_[[c[0] for c in conns], [c[1] for c in conns],
                     [l.a for l in unit_links], [l.b for l in unit_links]].astype(np.int64)
        return self._model(np.isin(self.label, self.label[ends[ends < self.n]]), unit, conns, unit_links)

    # -- many one-part candidates on one connected structure --------------------------------------
    def shared(self) -> bool:
        """Whether every one-part candidate joined to the structure has the whole structure as its
        component, on a fixed ground: then its load program is the structure's columns (the same
        for all of them) plus its own, and `statics.judge_on_base` takes the batched route."""
        return self.floor_y is not None and self.n > 0 and bool((self.label == self.label[0]).all())

    def alone(self) -> LoadModel:
        """The structure's own model (all its parts, connections, supports and links)."""
        return self._model(np.ones(self.n, bool))

    def hull(self) -> np.ndarray:
        """The structure's support polygon (xz) on its ground, kept."""
        if self._hull is None:
            g = self.alone().ground_pos
            self._hull = hull_xz(np.unique(np.round(g[:, [0, 2]], 6), axis=0)) if len(g) else np.zeros((0, 2))
        return self._hull


def connection_arrays(connections) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(stud part, socket part, stud base, stud axis) tuples as four arrays."""
    return (np.array([c[0] for c in connections], np.int64), np.array([c[1] for c in connections], np.int64),
            np.array([c[2] for c in connections], float).reshape(-1, 3),
            np.array([c[3] for c in connections], float).reshape(-1, 3))


def _link_arrays(links: Sequence[Link]) -> tuple[np.ndarray, ...]:
    """(a, b, point, axis, capacities, kind) of links as arrays (`LoadModel`'s link fields)."""
    return (np.array([l.a for l in links], np.int64), np.array([l.b for l in links], np.int64),
            np.array([l.point for l in links], float).reshape(-1, 3),
            np.array([l.axis if l.axis is not None else (0.0, 1.0, 0.0) for l in links], float).reshape(-1, 3),
            np.array([capacity(l.kind).as_row() for l in links], float).reshape(-1, 6),
            np.array([l.kind for l in links], dtype=object))


NO_LINKS = dict(link_a=np.zeros(0, np.int64), link_b=np.zeros(0, np.int64), link_pos=np.zeros((0, 3)),
                link_axis=np.zeros((0, 3)), link_cap=np.zeros((0, 6)), link_kind=np.zeros(0, dtype=object))
"""`LoadModel`'s link fields of a model without links."""


def load_model(placed: Sequence[Placed], connections: Sequence[tuple[int, int, np.ndarray, np.ndarray]],
               floor_y: float | None, seeds: Sequence[int], links: Sequence[Link] = (),
               cfg: LoadConfig = LoadConfig()) -> LoadModel:
    """The component holding `seeds` (part indices) of the parts `placed`, with their stud
    connections `(stud part, socket part, stud base, stud axis)`, rigid links and the ground at
    LDraw height `floor_y`; None: the component rests on its own lowest point (a human build, where
    parts laid on the table wait to be joined and a car body waits for its wheels)."""
    return LoadBase(placed, connections, floor_y, links, cfg).of(seeds)


def inside_polygon(poly: np.ndarray, c: np.ndarray, tol: float) -> bool:
    return bool(inside_polygon_many(poly, np.asarray(c)[None], tol)[0])


def inside_polygon_many(poly: np.ndarray, pts: np.ndarray, tol: float) -> np.ndarray:
    """Whether each point (k, 2) lies in the convex polygon `poly` (counter-clockwise, as
    `hull_xz` gives it; a point or a segment when it has one or two corners), within tol."""
    if len(poly) == 1:
        return np.linalg.norm(pts - poly[0], axis=1) <= tol
    if len(poly) == 2:
        a, b = poly
        ab = b - a
        t = np.clip((pts - a) @ ab / (ab @ ab), 0.0, 1.0)
        return np.linalg.norm(a + t[:, None] * ab - pts, axis=1) <= tol
    # ConvexHull orders 2-D vertices counter-clockwise: inside is left of every edge.
    e = np.roll(poly, -1, axis=0) - poly
    d = pts[:, None, :] - poly[None]
    cross = e[:, 0] * d[:, :, 1] - e[:, 1] * d[:, :, 0]
    return (cross >= -tol * np.linalg.norm(e, axis=1)).all(axis=1)
