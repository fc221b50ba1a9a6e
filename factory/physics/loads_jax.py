"""The load programs `load_program.to_lp` writes, solved on the JAX device by the batched solver
(`lp_jax`, backend 'jax') and written straight into its arrays from the load models, with no
`LinearProgram` in between:

- `solve_loads`: the programs of any load models (`load_model.LoadModel`), the arrays of a whole
  launch built at once (`_load_arrays`: array operations over every connection of the launch);
- `solve_on_base`, `solve_on_bases`: one-part candidates on a connected structure
  (`load_model.LoadBase.shared`), the structure's columns written once (`_base_block`) and each
  candidate's own joined to them on the host; the programs of every structure of a lockstep
  round in shared launches.

Results are `lp_jax.solve_batch`'s for `to_lp`'s programs (x in `load_program.layout`'s columns,
objective s); a member that does not converge goes to HiGHS with `fallback` (`lp_jax.FALLBACKS`
counts them). Tested against HiGHS in tests/test_lp_jax.py.
"""

from __future__ import annotations

from typing import Sequence

import jax
import numpy as np

from factory.physics.interior_point_jax import _OPTIMAL
from factory.physics.load_model import NO_LINKS, LoadBase, LoadConfig, LoadModel, connection_arrays, support_points
from factory.physics.load_program import (LEVER_LDU, PER_CONNECTION, PER_LINK, PER_SUPPORT, capacity_rows,
                                          connection_columns, layout, link_columns, link_rows, support_columns, to_lp)
from factory.physics.lp import LPResult
from factory.physics.lp_jax import COMPILES, MAX_ITERATIONS, _cols, _empty, _fallback, _group, _quarter, _rows, _run
from factory.physics.mass import GRAVITY, part_mass_properties


def _n_vars(model: LoadModel) -> int:
    return layout(model)["link"].stop


def _load_bucket(model: LoadModel) -> tuple[int, int, int, int]:
    w = 12 if len(model.conn_a) or len(model.link_a) else 6  # entries per column: two bodies or one
    return _cols(_n_vars(model)), _rows(6 * model.n_bodies), _quarter(w, 1), 2


def _load_arrays(models: Sequence[LoadModel], cfg: LoadConfig, batch: int, n: int, m: int, w: int,
                 k: int) -> dict[str, np.ndarray]:
    """`lp_jax._stack` of the load programs `load_program.to_lp` writes, built from the models directly
    and for all of them at once (array operations over every connection of the launch, no program
    per model), from the same columns (`load_program.connection_columns`, ...): the same rows and
    columns as `to_lp` then `lp_jax._parts` give, except that zero entries are kept (they change
    nothing). Members past the models copy the first (padding that converges with it)."""
    out = _empty(batch, n, m, w, k)
    rows_flat, vals_flat = out["a_rows"].reshape(-1), out["a_vals"].reshape(-1)
    B = len(models)
    nb = np.array([md.n_bodies for md in models])
    nc = np.array([len(md.conn_a) for md in models])
    ng = np.array([len(md.ground_body) for md in models])
    nl = np.array([len(md.link_a) for md in models])
    body_off = np.r_[0, np.cumsum(nb)[:-1]]
    com = np.concatenate([md.com for md in models])
    # The objective is s (column 0, the link column), s >= 0.
    out["c"][:B, 0] = 1.0
    out["coef"][:B, 0, 0], out["rhs"][:B, 0, 0], out["mask"][:B, 0, 0] = -1.0, 0.0, 1.0
    mi = np.repeat(np.arange(B), nb)
    local = np.arange(len(mi)) - np.repeat(body_off, nb)
    out["b"][mi, 6 * local + 1] = -np.concatenate([md.mass for md in models]) * GRAVITY

    def each(counts):
        """Model and index within it of every item of the concatenation."""
        owner = np.repeat(np.arange(B), counts)
        return owner, np.arange(len(owner)) - np.repeat(np.r_[0, np.cumsum(counts)[:-1]], counts)

    def cat(name):
        return np.concatenate([getattr(md, name) for md in models])

    def put(owner, cols, bodies, sign, f, p, mom, first_slot):
        """Six entries of each column (force, then moment in newton-studs) on one body."""
        torque = (_cross(p - com[body_off[owner] + bodies], f) + mom) / LEVER_LDU
        at = ((owner * n + cols) * w + first_slot)[:, None] + np.arange(6)
        rows_flat[at] = 6 * bodies[:, None] + np.arange(6)
        vals_flat[at] = np.concatenate([f, torque], axis=1) * sign

    if nc.sum():
        owner, idx = each(nc)
        a, b = cat("conn_a"), cat("conn_b")
        base = 1 + PER_CONNECTION * idx
        for j, (f, p, mom) in enumerate(connection_columns(cat("conn_pos"), cat("conn_axis"))):
            put(owner, base + j, b, 1.0, f, p, mom, 0)
            put(owner, base + j, a, -1.0, f, p, mom, 6)
        slots = np.zeros(PER_CONNECTION, int)
        for j, sign, cap in capacity_rows(cfg):  # sign * x_j <= s * cap, one slot per row
            col, slot = base + j, slots[j]
            out["coef"][owner, col, slot], out["link"][owner, col, slot] = sign, -cap
            out["rhs"][owner, col, slot], out["mask"][owner, col, slot] = 0.0, 1.0
            slots[j] += 1
    if ng.sum():
        owner, idx = each(ng)
        gb = cat("ground_body")
        base = 1 + PER_CONNECTION * nc[owner] + PER_SUPPORT * idx
        for j, (f, p, mom) in enumerate(support_columns(cat("ground_pos"), cfg)):
            put(owner, base + j, gb, 1.0, f, p, mom, 0)
            # The ground only pushes: -x <= 0.
            out["coef"][owner, base + j, 0], out["rhs"][owner, base + j, 0], out["mask"][owner, base + j, 0] = -1.0, 0.0, 1.0
    if nl.sum():
        owner, idx = each(nl)
        la, lb = cat("link_a"), cat("link_b")
        base = 1 + PER_CONNECTION * nc[owner] + PER_SUPPORT * ng[owner] + PER_LINK * idx
        for j, (f, p, mom) in enumerate(link_columns(cat("link_pos"), cat("link_axis"))):
            put(owner, base + j, lb, 1.0, f, p, mom, 0)
            put(owner, base + j, la, -1.0, f, p, mom, 6)
        cap = cat("link_cap")
        for links, j, sign in link_rows(cap):  # sign * x_j <= s * cap: slot 0 for +, 1 for -
            col, slot = base[links] + j, int(sign < 0)
            out["coef"][owner[links], col, slot], out["link"][owner[links], col, slot] = sign, -cap[links, j]
            out["rhs"][owner[links], col, slot], out["mask"][owner[links], col, slot] = 0.0, 1.0
    for v in out.values():
        v[B:] = v[0]
    return out


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise `np.cross` of two (n, 3) arrays, the same products and differences in the same
    order (so the same bits), without its axis handling: a launch's arrays take thousands of small
    crosses, and `np.cross` was 1.3 s of 29 s of host work growing 16 objects of 30 parts."""
    a0, a1, a2 = a[:, 0], a[:, 1], a[:, 2]
    b0, b1, b2 = b[:, 0], b[:, 1], b[:, 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=1)


def _optimal(xi: np.ndarray, ground: slice) -> LPResult:
    """A load program's result from its x in `layout` order (`ground`: the supports' columns);
    s and the ground forces are >= 0 to tol: made exact."""
    xi = xi.copy()
    xi[0] = max(xi[0], 0.0)
    xi[ground] = np.maximum(xi[ground], 0.0)
    return LPResult("optimal", xi, float(xi[0]))


def solve_loads(models: Sequence[LoadModel], cfg: LoadConfig | None = None, *, tol: float = 1e-8,
                max_iterations: int = MAX_ITERATIONS, fallback: bool = True) -> list[LPResult]:
    """The load program of each `load_model.LoadModel` (as `load_program.to_lp` writes it), all at once on
    the default JAX device, written straight into the solver's arrays (`_load_arrays`); results as
    `lp_jax.solve_batch` gives them for `to_lp`'s programs (x in `load_program.layout`'s columns,
    objective s). A member that does not converge goes to HiGHS with `fallback`
    (`lp_jax.FALLBACKS` counts them)."""
    cfg = cfg or LoadConfig()
    results: list[LPResult] = [LPResult("error", None, float("nan"))] * len(models)
    with jax.enable_x64(True):
        for shape, chunk in _group([_load_bucket(md) for md in models]):
            if shape not in COMPILES:
                COMPILES.append(shape)
            x, status = _run(_load_arrays([models[i] for i in chunk], cfg, *shape), tol, max_iterations)
            for j, i in enumerate(chunk):
                if status[j] == _OPTIMAL:
                    results[i] = _optimal(x[j, :_n_vars(models[i])], layout(models[i])["ground"])
    return _fallback(results, lambda i: to_lp(models[i], cfg), fallback)


def _base_block(base: LoadBase, cfg: LoadConfig) -> dict:
    """The structure's own columns (connections, supports, links: the same in every candidate's
    program, without s), kept on `base` for its load constants."""
    hit = getattr(base, "_loads_jax_block", None)
    if hit is None or hit[0] != cfg:
        alone = base.alone()
        arrays = _load_arrays([alone], cfg, 1, _n_vars(alone), 6 * (base.n + 1), 12, 2)
        hit = (cfg, {key: arrays[key][0, 1:] for key in _ASSEMBLED})
        base._loads_jax_block = hit
    return hit[1]


_ASSEMBLED = ("a_rows", "a_vals", "coef", "link", "rhs", "mask")


def _own_model(base: LoadBase, unit, conns, cfg: LoadConfig) -> LoadModel:
    """The model of a one-part unit's own columns on `base`: its connections and ground supports
    alone, the structure's bodies kept (for their rows and centres of mass)."""
    m, c, _ = part_mass_properties(unit[0].part)
    pts = support_points(unit[0], base.floor_y, cfg)
    ca, cb, cp, cx = connection_arrays(conns)
    return LoadModel(parts=None, mass=np.r_[base.mass, m], com=np.concatenate([base.com, unit[0].pose.apply(c)[None]]),
                     conn_a=ca, conn_b=cb, conn_pos=cp, conn_axis=cx,
                     ground_body=np.full(len(pts), base.n, np.int64), ground_pos=pts,
                     **NO_LINKS)


def solve_on_base(base: LoadBase, units: Sequence, conns: Sequence, cfg: LoadConfig | None = None, *,
                  tol: float = 1e-8, max_iterations: int = MAX_ITERATIONS, fallback: bool = True) -> list[LPResult]:
    """The load program of each one-part unit on a `load_model.LoadBase` whose parts form one
    component (`base.shared()`), as `solve_loads` of `base.model(unit, conns)` gives it (x in
    `load_program.layout` order of that model): `solve_on_bases` of one base."""
    return solve_on_bases([(base, units, conns)], cfg, tol=tol, max_iterations=max_iterations, fallback=fallback)[0]


def solve_on_bases(groups: Sequence[tuple], cfg: LoadConfig | None = None, *, tol: float = 1e-8,
                   max_iterations: int = MAX_ITERATIONS, fallback: bool = True) -> list[list[LPResult]]:
    """`solve_on_base(base, units, conns)` of every group (each its own structure: objects grown in
    lockstep), in shared launches. Each structure's columns are written once (`_base_block`),
    each candidate's own columns (its connections and ground supports) per candidate, and the two
    are joined on the host; programs of every structure with the same equality rows' bucket run in
    one launch, padded to the largest of their variables (`lp_jax._group`)."""
    cfg = cfg or LoadConfig()
    out: list[list[LPResult]] = [[LPResult("error", None, float("nan"))] * len(g[1]) for g in groups]
    # Per group: the candidates' own models, the structure's layout and block, and each program's
    # bucket (variables: the structure's columns, s and the widest candidate's own).
    members, buckets, info = [], [], []
    for gi, (base, units, conns) in enumerate(groups):
        if not len(units):
            info.append(None)
            continue
        own = [_own_model(base, u, c, cfg) for u, c in zip(units, conns)]
        shared = layout(base.alone())
        n_block = shared["link"].stop - 1
        width = max(_n_vars(md) for md in own)
        info.append((own, shared, n_block, width, _base_block(base, cfg)))
        for i in range(len(own)):
            members.append((gi, i))
            buckets.append((_cols(n_block + width), _rows(6 * (base.n + 1)), 12, 2))
    with jax.enable_x64(True):
        for shape, chunk in _group(buckets):
            if shape not in COMPILES:
                COMPILES.append(shape)
            m = shape[2]
            arrays = _empty(*shape)
            arrays["c"][:, 0] = 1.0
            # Every candidate's own columns in one go (row r of `new` is the chunk's row r, in the
            # widest group's columns), then each group's rows joined to its structure's block.
            rows_of: dict[int, list[int]] = {}
            for row, e in enumerate(chunk):
                rows_of.setdefault(members[e][0], []).append(row)
            widest = max(info[gi][3] for gi in rows_of)
            own_models = [info[gi][0][i] for gi, i in (members[e] for e in chunk)]
            new = _load_arrays(own_models, cfg, len(chunk), widest, m, 12, 2)
            for gi, rows in rows_of.items():
                _, _, n_block, width, block = info[gi]
                rows = np.array(rows)
                # Columns: s, the structure's (connections, supports, links), the candidate's own.
                for key in _ASSEMBLED:
                    arrays[key][rows, :1] = new[key][rows, :1]
                    arrays[key][rows, 1:1 + n_block] = block[key]
                    arrays[key][rows, 1 + n_block:n_block + width] = new[key][rows, 1:width]
            arrays["b"][:len(chunk)] = new["b"]
            arrays["link_col"][:len(chunk)] = new["link_col"]
            for key, v in arrays.items():  # padding members copy the first (they converge with it)
                v[len(chunk):] = v[0]
            x, status = _run(arrays, tol, max_iterations)
            for row, e in enumerate(chunk):
                if status[row] != _OPTIMAL:
                    continue
                gi, i = members[e]
                own, shared, n_block, _, _ = info[gi]
                # `layout` wants s, connections (the structure's, the unit's), supports (the same),
                # links.
                mine, xj = layout(own[i]), x[row]
                own_conn, own_ground = (xj[n_block + c.start:n_block + c.stop] for c in (mine["conn"], mine["ground"]))
                xi = np.concatenate([xj[:1], xj[shared["conn"]], own_conn, xj[shared["ground"]], own_ground,
                                     xj[shared["link"]]])
                start = shared["conn"].stop + len(own_conn)
                out[gi][i] = _optimal(xi, slice(start, start + len(own_ground) + shared["ground"].stop - shared["ground"].start))
    for gi, (base, units, conns) in enumerate(groups):
        out[gi] = _fallback(out[gi], lambda i: to_lp(base.model(units[i], conns[i]), cfg), fallback)
    return out
