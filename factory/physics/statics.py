"""Whole-structure statics: can every part's weight be carried to the ground with every stud
connection within its capacity?

A merged rigid body on flat ground stands exactly when its centre of mass lies over its support
polygon, so a rollout of the merged object adds nothing a point-in-polygon test does not give, and
it never asks what the connections inside the structure must carry. This module asks it, as a
linear program per structure (StableLego's formulation, as BrickGPT uses it, with our constants;
docs/concepts/physics.md says why):

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
- a connection the checker does not model (Technic, clips, hinges: `Link`) is rigid: a free force
  and moment between the two parts.

Minimising `s`, the largest share of any capacity used (all tension, shear and torsion limits
scaled by `s`), gives the structure's load: it stands when `s <= 1`, and the connections at `s`
are the ones that fail first. Before the program, the cheap rule: the candidate's component must
have its centre of mass over its support polygon (else it tips, whatever the connections hold);
that also makes every program feasible (with `s` large enough the connections are rigid), which a
batched first-order solver needs.

Only the component of the connection graph that holds the candidate is judged: loads elsewhere
did not change when it was added.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import Callable, Sequence

import numpy as np
import scipy.sparse as sp
from scipy.spatial import ConvexHull, QhullError

from factory.connections import STUD_RADIUS
from factory.physics.geometry import collision_shape
from factory.physics.lp import BASIS_STATUS, Basis, LinearProgram, LPResult, solve_highs, solve_highs_from
from factory.physics.mass import GRAVITY, part_mass_properties
from factory.physics.structure import Placed, lowest_point

LEVER_LDU = 20.0
"""Moment rows are written in newton-studs (lever arms in units of 20 LDU), so that force and
moment coefficients are of one size for the solver."""

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
    """A rigid connection the checker does not model (Technic, clip, hinge) between two parts."""

    a: int
    b: int
    point: tuple[float, float, float]


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

    @property
    def n_bodies(self) -> int:
        return len(self.mass)


@dataclass(frozen=True)
class Failure:
    """A connection at the model's largest load: the stud's part, the socket's part (caller's
    numbering) and the stud's base (LDU)."""

    stud_part: int
    socket_part: int
    stud: tuple[float, float, float]
    load: float

    def to_json(self) -> dict:
        return {"stud_part": self.stud_part, "socket_part": self.socket_part,
                "stud": [round(v, 3) for v in self.stud], "load": round(self.load, 4)}


@dataclass(frozen=True)
class LoadVerdict:
    stands: bool
    reason: str | None
    """None, 'unstable' (the component tips: its centre of mass is not over its support polygon)
    or 'overload' (some connection would carry more than its capacity)."""
    load: float | None
    """The largest share of a capacity used (None when it tips)."""
    failing: tuple[Failure, ...] = field(default=())
    rigid_links: int = 0
    """Connections in the component held rigid because the checker does not model them."""


# -- the model -------------------------------------------------------------------------------------
_SUPPORT_CACHE: dict = {}


def support_points(placed: Placed, floor_y: float, cfg: LoadConfig) -> np.ndarray:
    """(k, 3) support points of a part on the ground at LDraw height floor_y (may be empty)."""
    key = (id(placed), round(floor_y, 6), cfg.ground_tol_ldu, cfg.support_points)
    hit = _SUPPORT_CACHE.get(key)
    if hit is not None and hit[0] is placed:
        return hit[1]
    shape = collision_shape(placed.part)
    verts = placed.pose.apply(np.concatenate(list(shape.body) + list(shape.studs)))
    low = verts[verts[:, 1] >= floor_y - cfg.ground_tol_ldu]
    if len(low):
        xz = np.unique(np.round(low[:, [0, 2]], 6), axis=0)
        xz = _hull_xz(xz)
        if len(xz) > cfg.support_points:
            xz = xz[np.linspace(0, len(xz), cfg.support_points, endpoint=False).astype(int)]
        out = np.column_stack([xz[:, 0], np.full(len(xz), floor_y), xz[:, 1]])
    else:
        out = np.zeros((0, 3))
    if len(_SUPPORT_CACHE) > 4096:
        _SUPPORT_CACHE.clear()
    _SUPPORT_CACHE[key] = (placed, out)
    return out


def _hull_xz(xz: np.ndarray) -> np.ndarray:
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
        self.conn_a, self.conn_b, self.conn_pos, self.conn_axis = _connection_arrays(connections)
        self.link_a, self.link_b, self.link_pos = _link_arrays(links)
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
        new_a, new_b, new_pos, new_axis = _connection_arrays(conns)
        ul_a, ul_b, ul_pos = _link_arrays(unit_links)
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
        for all of them) plus its own, and `judge_on_base` takes the batched route."""
        return self.floor_y is not None and self.n > 0 and bool((self.label == self.label[0]).all())

    def alone(self) -> LoadModel:
        """The structure's own model (all its parts, connections, supports and links)."""
        return self._model(np.ones(self.n, bool))

    def hull(self) -> np.ndarray:
        """The structure's support polygon (xz) on its ground, kept."""
        if self._hull is None:
            g = self.alone().ground_pos
            self._hull = _hull_xz(np.unique(np.round(g[:, [0, 2]], 6), axis=0)) if len(g) else np.zeros((0, 2))
        return self._hull


def _connection_arrays(connections) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(stud part, socket part, stud base, stud axis) tuples as four arrays."""
    return (np.array([c[0] for c in connections], np.int64), np.array([c[1] for c in connections], np.int64),
            np.array([c[2] for c in connections], float).reshape(-1, 3),
            np.array([c[3] for c in connections], float).reshape(-1, 3))


def _link_arrays(links: Sequence[Link]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return (np.array([l.a for l in links], np.int64), np.array([l.b for l in links], np.int64),
            np.array([l.point for l in links], float).reshape(-1, 3))


def load_model(placed: Sequence[Placed], connections: Sequence[tuple[int, int, np.ndarray, np.ndarray]],
               floor_y: float | None, seeds: Sequence[int], links: Sequence[Link] = (),
               cfg: LoadConfig = LoadConfig()) -> LoadModel:
    """The component holding `seeds` (part indices) of the parts `placed`, with their stud
    connections `(stud part, socket part, stud base, stud axis)`, rigid links and the ground at
    LDraw height `floor_y`; None: the component rests on its own lowest point (a human build, where
    parts laid on the table wait to be joined and a car body waits for its wheels)."""
    return LoadBase(placed, connections, floor_y, links, cfg).of(seeds)


def judge_on_base(base: LoadBase, units: Sequence[Sequence[Placed]], conns: Sequence, cfg: LoadConfig,
                  solve_on_base: Callable, explain: bool = True) -> list[LoadVerdict]:
    """`judge_many` of `base.model(unit, conns)` for one-part units on a `base.shared()` structure,
    without a model per candidate: the tipping rule at once for those that do not touch the ground
    (the structure's support polygon, kept), then `solve_on_base(base, units, conns, cfg)` for those
    that stand (`lp_jax.solve_on_base`). Models are built only for parts on the ground and for the
    failing connections of an overload (`explain`)."""
    return judge_on_bases([(base, units, conns)], cfg,
                          lambda groups, c: [solve_on_base(*g, c) for g in groups], explain)[0]


def judge_on_bases(groups: Sequence[tuple], cfg: LoadConfig, solve_on_bases: Callable,
                   explain: bool = True) -> list[list[LoadVerdict]]:
    """`judge_on_base` of every (base, units, conns) group, the programs of all groups solved in one
    `solve_on_bases(groups, cfg)` call (`lp_jax.solve_on_bases`: objects grown in lockstep)."""
    todo_all, tipping_all = [], []
    for base, units, conns in groups:
        props = [part_mass_properties(u[0].part) for u in units]
        masses = np.array([m for m, _, _ in props])
        coms = np.array([u[0].pose.apply(c) for u, (_, c, _) in zip(units, props)]).reshape(-1, 3)
        centre = (base.mass @ base.com + masses[:, None] * coms) / (base.mass.sum() + masses)[:, None]
        grounded = np.array([len(support_points(u[0], base.floor_y, cfg)) > 0 for u in units], bool)
        hull = base.hull()
        tipping = ~_inside_many(hull, centre[:, [0, 2]], cfg.tolerance) if len(hull) else np.ones(len(units), bool)
        for i in np.flatnonzero(grounded):  # its own supports widen the polygon
            tipping[i] = tips(base.model(units[i], conns[i]), cfg)
        todo_all.append(np.flatnonzero(~tipping))
        tipping_all.append(tipping)
    solved = solve_on_bases([(base, [units[i] for i in todo], [conns[i] for i in todo])
                             for (base, units, conns), todo in zip(groups, todo_all)], cfg)
    out_all = []
    for (base, units, conns), todo, results in zip(groups, todo_all, solved):
        links = len(base.link_a)
        out: list[LoadVerdict] = [LoadVerdict(False, "unstable", None, rigid_links=links)] * len(units)
        for i, r in zip(todo, results):
            if r.status != "optimal":
                raise RuntimeError(f"load program not solved: {r.status}")
            load = max(float(r.objective), 0.0)
            if load <= 1.0 + cfg.tolerance:
                out[i] = LoadVerdict(True, None, load, (), links)
            else:
                failing = _failing(base.model(units[i], conns[i]), load, cfg) if explain else ()
                out[i] = LoadVerdict(False, "overload", load, failing, links)
        out_all.append(out)
    return out_all


def tips(model: LoadModel, cfg: LoadConfig = LoadConfig()) -> bool:
    """Whether the component's centre of mass lies outside its support polygon (or it has none)."""
    if not len(model.ground_pos):
        return True
    c = (model.mass @ model.com / model.mass.sum())[[0, 2]]
    xz = _hull_xz(np.unique(np.round(model.ground_pos[:, [0, 2]], 6), axis=0))
    return not _inside(xz, c, cfg.tolerance)


def _inside(poly: np.ndarray, c: np.ndarray, tol: float) -> bool:
    return bool(_inside_many(poly, np.asarray(c)[None], tol)[0])


def _inside_many(poly: np.ndarray, pts: np.ndarray, tol: float) -> np.ndarray:
    """Whether each point (k, 2) lies in the convex polygon `poly` (counter-clockwise, as
    `_hull_xz` gives it; a point or a segment when it has one or two corners), within tol."""
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


# -- the linear program ----------------------------------------------------------------------------
def _basis(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors across each axis (nc, 3): x and z for a vertical axis."""
    ref = np.where(np.abs(n[:, [0]]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 0.0, 1.0]])
    e1 = np.cross(n, ref)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(n, e1)
    vertical = np.abs(n[:, 1]) > 0.999
    e1[vertical], e2[vertical] = [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]
    return e1, e2


# Variables per connection: 4 rim forces, 2 shears, 1 torsion.
PER_CONNECTION = 7
PER_SUPPORT = 4
PER_LINK = 6


def layout(model: LoadModel) -> dict[str, slice]:
    """Column ranges of the program's variables: `s`, then connections, supports, links."""
    nc, ng, nl = len(model.conn_a), len(model.ground_body), len(model.link_a)
    o1 = 1 + PER_CONNECTION * nc
    o2 = o1 + PER_SUPPORT * ng
    return {"s": slice(0, 1), "conn": slice(1, o1), "ground": slice(o1, o2), "link": slice(o2, o2 + PER_LINK * nl)}


def connection_columns(pos: np.ndarray, axis: np.ndarray) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """The 7 columns of each stud connection (nc, 3 each), as (force direction, point, moment)
    acting on the socket's part: the four rim forces along the axis, two shears, the torsion."""
    e1, e2 = _basis(axis)
    r = STUD_RADIUS
    z = np.zeros_like(pos)
    rims = [(axis, pos + r * e1, z), (axis, pos - r * e1, z), (axis, pos + r * e2, z), (axis, pos - r * e2, z)]
    return rims + [(e1, pos, z), (e2, pos, z), (z, pos, axis)]


def capacity_rows(cfg: LoadConfig) -> list[tuple[int, float, float]]:
    """(column of the connection, sign, capacity): each row sign * x[column] <= s * capacity."""
    rows = [(j, -1.0, cfg.clutch_n / 4) for j in range(4)]  # tension per rim point
    rows += [(j, sign, cfg.shear_n) for j in (4, 5) for sign in (1.0, -1.0)]
    return rows + [(6, sign, cfg.torsion_nldu) for sign in (1.0, -1.0)]


def support_columns(pos: np.ndarray, cfg: LoadConfig) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """The 4 columns of each ground support point: the edges of its friction pyramid."""
    z = np.zeros_like(pos)
    return [(np.broadcast_to(UP + cfg.friction * np.array(d, float), pos.shape), pos, z)
            for d in ([1, 0, 0], [-1, 0, 0], [0, 0, 1], [0, 0, -1])]


def link_columns(pos: np.ndarray) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """The 6 columns of each rigid link: a free force, then a free moment, along x, y, z."""
    z = np.zeros_like(pos)
    axes = [np.broadcast_to(np.eye(3)[j], pos.shape) for j in range(3)]
    return [(v, pos, z) for v in axes] + [(z, pos, v) for v in axes]


def to_lp(model: LoadModel, cfg: LoadConfig = LoadConfig()) -> LinearProgram:
    """The minimax load program of a model (module docstring); `s` is variable 0."""
    cols = layout(model)
    n = cols["link"].stop
    # Every column is a force `f` at point `p` (or a pure moment `m`) acting on body `on` with sign.
    on, sign, col, force, point, moment = [], [], [], [], [], []

    def add(bodies, signs, columns, f, p, m):
        on.append(bodies), sign.append(signs), col.append(columns)
        force.append(f), point.append(p), moment.append(m)

    nc, ng, nl = len(model.conn_a), len(model.ground_body), len(model.link_a)
    for j, (f, p, m) in enumerate(connection_columns(model.conn_pos, model.conn_axis) if nc else []):
        for bodies, s in ((model.conn_b, 1.0), (model.conn_a, -1.0)):
            add(bodies, np.full(nc, s), cols["conn"].start + PER_CONNECTION * np.arange(nc) + j, f, p, m)
    for j, (f, p, m) in enumerate(support_columns(model.ground_pos, cfg) if ng else []):
        add(model.ground_body, np.ones(ng), cols["ground"].start + PER_SUPPORT * np.arange(ng) + j, f, p, m)
    for j, (f, p, m) in enumerate(link_columns(model.link_pos) if nl else []):
        for bodies, s in ((model.link_b, 1.0), (model.link_a, -1.0)):
            add(bodies, np.full(nl, s), cols["link"].start + PER_LINK * np.arange(nl) + j, f, p, m)

    rows, cc, vals = [], [], []
    if on:
        on_ = np.concatenate(on)
        sg = np.concatenate(sign)
        cl = np.concatenate(col)
        f = np.concatenate(force)
        p = np.concatenate(point)
        m = np.concatenate(moment)
        torque = (np.cross(p - model.com[on_], f) + m) / LEVER_LDU
        for k in range(3):
            rows += [6 * on_ + k, 6 * on_ + 3 + k]
            cc += [cl, cl]
            vals += [sg * f[:, k], sg * torque[:, k]]
    a_eq = sp.csr_matrix((np.concatenate(vals) if vals else [], (np.concatenate(rows) if rows else [],
                          np.concatenate(cc) if cc else [])), shape=(6 * model.n_bodies, n))
    b_eq = np.zeros(6 * model.n_bodies)
    b_eq[1::6] = -model.mass * GRAVITY  # contacts balance the weight, which pulls along +y (down)
    # Capacities scaled by s: tension per rim point, shear per axis (both signs), torsion (both signs).
    ub_cols, ub_vals, ub_cap = [], [], []
    if nc:
        base = cols["conn"].start + PER_CONNECTION * np.arange(nc)
        for j, s, cap in capacity_rows(cfg):
            ub_cols.append(base + j)
            ub_vals.append(np.full(nc, s))
            ub_cap.append(np.full(nc, cap))
    k = sum(len(c) for c in ub_cols)
    if k:
        r = np.arange(k)
        a_ub = sp.csr_matrix((np.concatenate([np.concatenate(ub_vals), -np.concatenate(ub_cap)]),
                              (np.concatenate([r, r]), np.concatenate([np.concatenate(ub_cols), np.zeros(k, np.int64)]))),
                             shape=(k, n))
    else:
        a_ub = sp.csr_matrix((0, n))
    lower = np.full(n, -np.inf)
    lower[0] = 0.0
    lower[cols["ground"]] = 0.0
    c = np.zeros(n)
    c[0] = 1.0
    return LinearProgram(c, a_eq, b_eq, a_ub, np.zeros(k), lower, np.full(n, np.inf))


def connection_loads(model: LoadModel, x: np.ndarray, cfg: LoadConfig = LoadConfig()) -> np.ndarray:
    """(nc,) the largest share of a capacity each connection uses in the solution x."""
    nc = len(model.conn_a)
    if not nc:
        return np.zeros(0)
    v = x[layout(model)["conn"]].reshape(nc, PER_CONNECTION)
    tension = np.maximum(-v[:, :4], 0).max(axis=1) / (cfg.clutch_n / 4)
    shear = np.abs(v[:, 4:6]).max(axis=1) / cfg.shear_n
    torsion = np.abs(v[:, 6]) / cfg.torsion_nldu
    return np.maximum(np.maximum(tension, shear), torsion)


def judge(model: LoadModel, cfg: LoadConfig = LoadConfig(),
          solve: Callable[[LinearProgram], LPResult] = solve_highs) -> LoadVerdict:
    """The load verdict of one model: tips, overloaded (with the connections that fail) or stands."""
    return verdict_of(model, None if tips(model, cfg) else solve(to_lp(model, cfg)), cfg)


def verdict_of(model: LoadModel, result: LPResult | None, cfg: LoadConfig = LoadConfig(),
               explain: bool = True) -> LoadVerdict:
    """A verdict from a solved program (None: the model tips and was not solved); `explain=False`
    leaves `failing` empty (finding the failing connections costs a second program)."""
    links = len(model.link_a)
    if result is None or result.status == "infeasible":
        return LoadVerdict(False, "unstable", None, rigid_links=links)
    if result.status != "optimal":
        raise RuntimeError(f"load program not solved: {result.status}")
    s = max(float(result.objective), 0.0)
    if s > 1.0 + cfg.tolerance:
        return LoadVerdict(False, "overload", s, _failing(model, s, cfg) if explain else (), links)
    return LoadVerdict(True, None, s, (), links)


def _failing(model: LoadModel, s: float, cfg: LoadConfig) -> tuple[Failure, ...]:
    """The connections that must carry the largest load `s` in every solution. The minimax optimum
    is degenerate (a solver may leave any connection at `s` that could carry less), so a second
    program gives each connection its own load variable, capped at `s`, and minimises their sum:
    a connection still at `s` there cannot be relieved."""
    lp = to_lp(model, cfg)
    nc = len(model.conn_a)
    coo = lp.a_ub.tocoo()
    row_conn = np.arange(lp.a_ub.shape[0]) % nc  # capacity rows come in blocks of one per connection
    col = np.where(coo.col == 0, lp.n + row_conn[coo.row], coo.col)
    a_ub = sp.csr_matrix((coo.data, (coo.row, col)), shape=(lp.a_ub.shape[0], lp.n + nc))
    a_eq = sp.hstack([lp.a_eq, sp.csr_matrix((lp.a_eq.shape[0], nc))]).tocsr()
    c = np.concatenate([np.zeros(lp.n), np.ones(nc)])
    lower = np.concatenate([lp.lower, np.zeros(nc)])
    upper = np.concatenate([lp.upper, np.full(nc, s * (1 + 1e-9) + 1e-12)])
    lower[0] = upper[0] = 0.0
    res = solve_highs(LinearProgram(c, a_eq, lp.b_eq, a_ub, lp.b_ub, lower, upper))
    if res.status != "optimal":
        loads = np.full(nc, s)  # cannot happen for a solved minimax; keep every connection
    else:
        loads = res.x[lp.n:]
    worst = np.flatnonzero(loads >= s * (1 - 1e-6))
    return tuple(
        Failure(int(model.parts[model.conn_a[k]]), int(model.parts[model.conn_b[k]]),
                tuple(float(v) for v in model.conn_pos[k]), float(loads[k]))
        for k in worst
    )


def solve_loads_highs(models: Sequence[LoadModel], cfg: LoadConfig = LoadConfig()) -> list[LPResult]:
    """The load program of each model, one at a time with HiGHS (the CPU reference)."""
    return [solve_highs(to_lp(m, cfg)) for m in models]


# -- programs started from a solved one -------------------------------------------------------------
# A candidate's program is the structure's program plus its own columns and rows, and the
# structure's program is that of its last part when it was a candidate. Started from that
# program's final basis (its columns and rows found again by what they are: the parts, stud bases
# and support points), HiGHS's primal simplex takes a few iterations where a start from nothing
# takes hundreds: on the 135 structures of objects 0 and 1 of the default config (seed 0), each
# started from the one before, 1,494 against 20,495 iterations and 1.31 s against 3.66 s
# (`solve_from`, its keys and start included, against a solve from nothing), objectives within
# 6.3e-15 (this repository's 2-core CPU, shared with another job).
WARM_START = True
"""Whether the reference starts a candidate's program from the structure's solved one (`check.py`);
off, every program starts from nothing (as tests compare)."""

WARM_COUNTS: dict[str, int] = {"started": 0, "cold": 0, "iterations": 0}
"""Programs of this process solved by `solve_from`: started from a basis, started from nothing, and
their simplex iterations."""

_ROUND = 1e4  # keys of stud bases and support points, to 1e-4 LDU


def _point_keys(parts: np.ndarray, *rest) -> list[tuple]:
    """One key per row: the part numbers as they are, the points rounded to `1 / _ROUND` LDU."""
    if not len(parts):
        return []
    cols = [np.asarray(parts, np.int64)[:, None]]
    for r in rest:
        r = np.asarray(r)
        cols.append(np.asarray(r, np.int64).reshape(len(parts), -1) if r.dtype.kind in "iu"
                    else np.round(r.reshape(len(parts), -1) * _ROUND).astype(np.int64))
    return [tuple(row) for row in np.concatenate(cols, axis=1).tolist()]


@dataclass(frozen=True, eq=False)
class ProgramKeys:
    """What names the columns and rows of a model's program (`to_lp`), by the caller's part
    numbers: each connection (its two parts and stud base), support point (its part and position)
    and link (its two parts and point), and each body's part."""

    conn: list
    ground: list
    link: list
    parts: list

    @classmethod
    def of(cls, model: LoadModel) -> "ProgramKeys":
        p = model.parts
        return cls(_point_keys(p[model.conn_a], p[model.conn_b], model.conn_pos),
                   _point_keys(p[model.ground_body], model.ground_pos),
                   _point_keys(p[model.link_a], p[model.link_b], model.link_pos), p.tolist())

    @cached_property
    def distinct(self) -> bool:
        """Whether no two connections, support points or links share a key (else no start maps)."""
        return all(len(set(k)) == len(k) for k in (self.conn, self.ground, self.link))

    @cached_property
    def index(self) -> tuple[dict, dict, dict, dict]:
        """Each connection's, support point's, link's and body's position by its key."""
        return tuple({k: i for i, k in enumerate(ks)} for ks in (self.conn, self.ground, self.link, self.parts))


@dataclass(frozen=True, eq=False)
class Solved:
    """A load program's final basis, with what names its columns and rows, so that a larger
    program can start from it (`start_basis`)."""

    basis: Basis
    keys: ProgramKeys

    @classmethod
    def of(cls, model: LoadModel, basis: Basis) -> "Solved":
        return cls(basis, ProgramKeys.of(model))


def start_basis(solved: Solved, model: LoadModel, cfg: LoadConfig = LoadConfig(),
                keys: ProgramKeys | None = None) -> Basis | None:
    """A basis of `model`'s program (`to_lp`; `keys` its `ProgramKeys` when known) from a solved
    smaller one whose every body, connection, support point and link `model` holds too: those
    keep their statuses, a new force is nonbasic (free ones at zero, the ground's at its bound 0)
    and a new row's slack basic, so the basic columns and slacks stay as many as the rows. None
    where `model` lacks one of `solved`'s things or two things of either share a key."""
    keys = keys or ProgramKeys.of(model)
    if BASIS_STATUS is None or not solved.keys.distinct or not keys.distinct:
        return None
    basic, zero, lower = BASIS_STATUS.kBasic, BASIS_STATUS.kZero, BASIS_STATUS.kLower
    conn, ground, link, body = solved.keys.index
    old_cols, old_rows = solved.basis.cols, solved.basis.rows
    conn_src = [conn.get(k) for k in keys.conn]
    ground_src = [ground.get(k) for k in keys.ground]
    link_src = [link.get(k) for k in keys.link]
    body_src = [body.get(k) for k in keys.parts]
    found = sum(o is not None for src in (conn_src, ground_src, link_src, body_src) for o in src)
    if found != len(conn) + len(ground) + len(link) + len(body):
        return None

    def columns(src, first: int, width: int, new) -> list:
        out = []
        for o in src:
            out += [new] * width if o is None else old_cols[first + width * o:first + width * (o + 1)]
        return out

    g0 = 1 + PER_CONNECTION * len(conn)
    cols = [old_cols[0], *columns(conn_src, 1, PER_CONNECTION, zero), *columns(ground_src, g0, PER_SUPPORT, lower),
            *columns(link_src, g0 + PER_SUPPORT * len(ground), PER_LINK, zero)]
    kinds = len(capacity_rows(cfg))
    rows = [basic if o is None else old_rows[j * len(conn) + o] for j in range(kinds) for o in conn_src]
    e0 = kinds * len(conn)
    for o in body_src:
        rows += [basic] * 6 if o is None else old_rows[e0 + 6 * o:e0 + 6 * (o + 1)]
    return Basis(cols, rows)


def solve_from(model: LoadModel, cfg: LoadConfig = LoadConfig(),
               start: Solved | None = None) -> tuple[LPResult, Solved | None]:
    """The model's load program with HiGHS, started from `start` (`start_basis`) where one maps,
    with its own final basis for the programs after it. The objective is HiGHS's optimum either
    way; a started solve may end at another optimal vertex of a degenerate program."""
    keys = ProgramKeys.of(model)
    basis = start_basis(start, model, cfg, keys) if start is not None and WARM_START else None
    result, final, iterations = solve_highs_from(to_lp(model, cfg), basis)
    WARM_COUNTS["started" if basis is not None else "cold"] += 1
    WARM_COUNTS["iterations"] += max(iterations, 0)
    return result, None if final is None else Solved(final, keys)


def judge_many(models: Sequence[LoadModel], cfg: LoadConfig = LoadConfig(),
               solve_loads: Callable[[list[LoadModel], LoadConfig], list[LPResult]] | None = None,
               explain: bool = True) -> list[LoadVerdict]:
    """`judge` for many models: the programs of those that do not tip are solved in one
    `solve_loads(models, cfg)` call (`lp_jax.solve_loads`: all at once on the JAX device), by
    default one by one with HiGHS; `explain` as in `verdict_of`."""
    tipping = [tips(m, cfg) for m in models]
    todo = [k for k, t in enumerate(tipping) if not t]
    results = (solve_loads or solve_loads_highs)([models[k] for k in todo], cfg)
    out: list[LPResult | None] = [None] * len(models)
    for k, r in zip(todo, results):
        out[k] = r
    return [verdict_of(m, r, cfg, explain) for m, r in zip(models, out)]


# -- the new part alone ----------------------------------------------------------------------------
def holds_alone(mass_kg: float, com: np.ndarray, conns: Sequence[tuple[bool, np.ndarray, np.ndarray]],
                ground: np.ndarray = np.zeros((0, 3)), cfg: LoadConfig = LoadConfig()) -> bool:
    """Whether a new part (or rigid unit) is held by its own connections with the rest fixed: the
    same model as `to_lp` for one body, so it never rejects what the whole-structure program
    accepts; the cheap rule that runs first. `conns`: (the part holds the stud, stud base, stud
    axis) per connection; `ground`: its support points on the ground.

    Where every connection is vertical (bricks and plates on and under each other), the program
    has a closed form: the upward force at each rim point j is bounded on one side (at least
    -C/4 where the part sits on the stud, at most C/4 where it hangs from it; at least 0 on the
    ground), so with all bounded below, shifting by the bounds leaves nonnegative forces whose
    resultant must pass through the part's "effective centre" (W c - sum lo_j x_j) / (W - sum lo_j):
    that point must lie in the hull of the rim and ground points; all bounded above is the mirror
    image. Mixed or sideways connections go to the program itself (6 rows)."""
    return holds_alone_many([(mass_kg, com, conns, ground)], cfg)[0]


_RIM_VERTICAL = np.array([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0]])


def holds_alone_many(cases: Sequence[tuple], cfg: LoadConfig = LoadConfig(),
                     solve: Callable[[list[LinearProgram]], list[LPResult]] | None = None) -> list[bool]:
    """`holds_alone` of each case (mass, com, conns, ground): the closed form where it applies, the
    programs of the rest solved together by `solve` (default: HiGHS one at a time; the batched
    checks pass `lp_jax.solve_batch`).

    The question does not depend on where the part is, so each case is asked about its centre of
    mass (positions relative to it, rounded to 1e-6 LDU) and its answer kept (`_ALONE`): the
    sampler's candidates of one part repeat configurations (2x4 bricks on a 30-brick wall: 819
    cases, 174 distinct), so most never reach a program."""
    keys = [(_alone_key(*case), cfg) for case in cases]
    answers = {key: _ALONE[key] for key in keys if key in _ALONE}
    programs: dict[tuple, LinearProgram] = {}
    for key in keys:
        if key in answers or key in programs:
            continue
        mass_kg, conns, ground = _alone_unkey(key[0])
        verdict = _closed_form(mass_kg, np.zeros(3), conns, ground, cfg)
        if verdict is None:
            programs[key] = _alone_program(mass_kg, np.zeros(3), conns, ground, cfg)
        else:
            answers[key] = verdict
    if programs:
        results = (solve or (lambda lps: [solve_highs(lp) for lp in lps]))(list(programs.values()))
        for key, res in zip(programs, results):
            answers[key] = res.status == "optimal" and res.objective <= 1.0 + cfg.tolerance
    if len(_ALONE) + len(answers) > ALONE_KEPT:
        _ALONE.clear()
    _ALONE.update(answers)
    return [bool(answers[key]) for key in keys]


ALONE_KEPT = 65536
"""Most `holds_alone` answers kept (`_ALONE`); past it they are dropped and found again."""
_ALONE: dict = {}
"""`holds_alone` answers by (case relative to its centre of mass, config) (`holds_alone_many`)."""


def _alone_key(mass_kg, com, conns, ground) -> tuple:
    com = np.asarray(com, float)
    rel = ()
    if conns:  # rounded as whole arrays: elementwise, so the same numbers as row by row
        pos = np.round(np.array([p for _, p, _ in conns], float).reshape(-1, 3) - com, 6).tolist()
        axes = np.round(np.array([n for _, _, n in conns], float).reshape(-1, 3), 9).tolist()
        rel = tuple((bool(h), tuple(p), tuple(n)) for (h, _, _), p, n in zip(conns, pos, axes))
    g = tuple(map(tuple, np.round(np.asarray(ground, float).reshape(-1, 3) - com, 6).tolist()))
    return float(mass_kg), rel, g


def _alone_unkey(key: tuple) -> tuple:
    mass_kg, rel, g = key
    conns = [(h, np.array(p), np.array(n)) for h, p, n in rel]
    return mass_kg, conns, np.array(g, float).reshape(-1, 3)


def _closed_form(mass_kg, com, conns, ground, cfg: LoadConfig) -> bool | None:
    """`holds_alone` where every connection is vertical and all rim bounds lie on one side, or
    where the part is held by the connections on one side alone; None where the program must
    decide."""
    weight = mass_kg * GRAVITY
    if not conns and not len(ground):
        return False
    axes = np.array([n for _, _, n in conns], float).reshape(-1, 3)
    if len(axes) and not (np.abs(axes[:, 1]) > 0.999).all():
        return None
    # Rim points connection by connection (+x, -x, +z, -z), then the ground's: the order of the sums.
    holds = np.array([h for h, _, _ in conns], bool)
    up = ((axes @ UP) > 0) != holds  # the stud pushes the part up when it sits on it
    ground = np.asarray(ground, float).reshape(-1, 3)
    if (up.any() and not up.all()) or (len(ground) and len(up) and not up[0]):
        # Bounds on both sides (sitting on studs or the ground, and hanging from studs): the
        # program decides, unless what it sits on or what it hangs from holds it alone. That is
        # exact: every force of a connection left out may be zero in the program, so a subset
        # that holds the part is a solution of the whole.
        below = [c for c, u in zip(conns, up) if u]
        if _closed_form(mass_kg, com, below, ground, cfg) or _closed_form(
                mass_kg, com, [c for c, u in zip(conns, up) if not u], np.zeros((0, 3)), cfg):
            return True
        return None
    pos = np.array([p for _, p, _ in conns], float).reshape(-1, 3)
    rims = (pos[:, None, :] + STUD_RADIUS * _RIM_VERTICAL[None]).reshape(-1, 3)
    pts = np.concatenate([rims, ground])
    bound = np.concatenate([np.repeat(np.where(up, -cfg.clutch_n / 4, cfg.clutch_n / 4), 4), np.zeros(len(ground))])
    xz = pts[:, [0, 2]]
    sgn = 1.0 if (up.all() if len(up) else True) else -1.0  # all bounded below, or all above (mirrored)
    total = sgn * weight - sgn * bound.sum()
    if total <= 0:
        return False
    centre = (sgn * weight * np.asarray(com)[[0, 2]] - sgn * (bound[:, None] * xz).sum(0)) / total
    return _inside(_hull_xz(np.unique(np.round(xz, 6), axis=0)), centre, cfg.tolerance)


def _alone_program(mass_kg, com, conns, ground, cfg: LoadConfig) -> LinearProgram:
    """The one-body program of `holds_alone` (body 1, the fixed rest of the structure, has no rows)."""
    axes = np.array([n for _, _, n in conns], float).reshape(-1, 3)
    model = LoadModel(
        parts=np.array([0, -1]), mass=np.array([mass_kg, 0.0]),
        com=np.stack([np.asarray(com, float), np.zeros(3)]),
        conn_a=np.array([0 if h else 1 for h, _, _ in conns], np.int64),
        conn_b=np.array([1 if h else 0 for h, _, _ in conns], np.int64),
        conn_pos=np.array([p for _, p, _ in conns], float).reshape(-1, 3), conn_axis=axes,
        ground_body=np.zeros(len(ground), np.int64), ground_pos=np.asarray(ground, float).reshape(-1, 3),
        link_a=np.zeros(0, np.int64), link_b=np.zeros(0, np.int64), link_pos=np.zeros((0, 3)),
    )
    lp = to_lp(model, cfg)
    return LinearProgram(lp.c, lp.a_eq[:6], lp.b_eq[:6], lp.a_ub, lp.b_ub, lp.lower, lp.upper)
