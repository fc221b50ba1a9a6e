"""The minimax load program of a `LoadModel` (`to_lp`, a `LinearProgram`): its columns (`s`, then
each connection's 4 rim forces, 2 shears and torsion, each support point's friction pyramid, each
link's force and moment along and across its axis: `layout`), the balance rows of every body and
the capacity rows scaled by `s` (the connections', then the links' finite ones: `link_rows`).

Minimising `s`, the largest share of any capacity used (all tension, shear and torsion limits
scaled by `s`), gives the structure's load: it stands when `s <= 1`, and the connections at `s`
are the ones that fail first.

`statics` judges by it, `loads_jax` writes the same program for the batched solver from these columns.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from factory.connections import STUD_RADIUS
from factory.physics.load_model import UP, LoadConfig, LoadModel
from factory.physics.lp import LinearProgram
from factory.physics.mass import GRAVITY

LEVER_LDU = 20.0
"""Moment rows are written in newton-studs (lever arms in units of 20 LDU), so that force and
moment coefficients are of one size for the solver."""


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


def link_columns(pos: np.ndarray, axis: np.ndarray) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """The 6 columns of each link: a force along its axis and across it (two), then a moment
    about its axis and across it (two), in the order of `JointCapacity.as_row`."""
    z = np.zeros_like(pos)
    e1, e2 = _basis(axis) if len(axis) else (axis, axis)
    axes = [axis, e1, e2]
    return [(v, pos, z) for v in axes] + [(z, pos, v) for v in axes]


def link_rows(cap: np.ndarray) -> list[tuple[np.ndarray, int, float]]:
    """The links' capacity rows, as (links, column of the link, sign) groups: each row
    sign * x[column] <= s * cap[link, column], for every finite capacity, column by column."""
    out = []
    for j in range(PER_LINK):
        finite = np.flatnonzero(np.isfinite(cap[:, j])) if len(cap) else np.zeros(0, np.int64)
        if len(finite):
            out += [(finite, j, 1.0), (finite, j, -1.0)]
    return out


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
    for j, (f, p, m) in enumerate(link_columns(model.link_pos, model.link_axis) if nl else []):
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
    for links, j, s in link_rows(model.link_cap):
        ub_cols.append(cols["link"].start + PER_LINK * links + j)
        ub_vals.append(np.full(len(links), s))
        ub_cap.append(model.link_cap[links, j])
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
