"""Whole-structure statics: can every part's weight be carried to the ground with every stud
connection within its capacity?

A merged rigid body on flat ground stands exactly when its centre of mass lies over its support
polygon, so a rollout of the merged object adds nothing a point-in-polygon test does not give, and
it never asks what the connections inside the structure must carry. This module asks it, as a
linear program per structure (StableLego's formulation, as BrickGPT uses it, with our constants;
docs/concepts/physics.md says why): the model is
`load_model`'s (`LoadBase`, `LoadModel`), its program `load_program`'s (`to_lp`).

Minimising `s`, the largest share of any capacity used (all tension, shear and torsion limits
scaled by `s`), gives the structure's load: it stands when `s <= 1`, and the connections at `s`
are the ones that fail first. Before the program, the cheap rule: the candidate's component must
have its centre of mass over its support polygon (else it tips, whatever the connections hold);
that also makes every program feasible (with `s` large enough the connections are rigid), which a
batched first-order solver needs.

Only the component of the connection graph that holds the candidate is judged: loads elsewhere
did not change when it was added.

A program started from a smaller solved one is `started_loads`'s (`solve_from`); the same model for
the new part alone, the clutch rule, is `clutch`'s (`holds_alone`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
import scipy.sparse as sp

from factory.physics.load_model import (LoadBase, LoadConfig, LoadModel, hull_xz, inside_polygon, inside_polygon_many,
                                        support_points)
from factory.physics.load_program import capacity_rows, link_rows, to_lp
from factory.physics.lp import LinearProgram, LPResult, solve_highs
from factory.physics.mass import part_mass_properties
from factory.physics.structure import Placed


@dataclass(frozen=True)
class Failure:
    """A connection at the model's largest load: the stud's part, the socket's part (caller's
    numbering) and the stud's base (LDU); for a joint (`joint` set: its kind), its two parts and
    where it holds."""

    stud_part: int
    socket_part: int
    stud: tuple[float, float, float]
    load: float
    joint: str | None = None

    def to_json(self) -> dict:
        out = {"stud_part": self.stud_part, "socket_part": self.socket_part,
               "stud": [round(v, 3) for v in self.stud], "load": round(self.load, 4)}
        return out if self.joint is None else {**out, "joint": self.joint}


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


def _rigid(kinds: np.ndarray) -> int:
    """How many links are held rigid (not joints with capacities: `Link.kind` 'rigid')."""
    return int(np.count_nonzero(kinds == "rigid"))


def tips(model: LoadModel, cfg: LoadConfig = LoadConfig()) -> bool:
    """Whether the component's centre of mass lies outside its support polygon (or it has none)."""
    if not len(model.ground_pos):
        return True
    c = (model.mass @ model.com / model.mass.sum())[[0, 2]]
    xz = hull_xz(np.unique(np.round(model.ground_pos[:, [0, 2]], 6), axis=0))
    return not inside_polygon(xz, c, cfg.tolerance)


def judge(model: LoadModel, cfg: LoadConfig = LoadConfig(),
          solve: Callable[[LinearProgram], LPResult] = solve_highs) -> LoadVerdict:
    """The load verdict of one model: tips, overloaded (with the connections that fail) or stands."""
    return verdict_of(model, None if tips(model, cfg) else solve(to_lp(model, cfg)), cfg)


def verdict_of(model: LoadModel, result: LPResult | None, cfg: LoadConfig = LoadConfig(),
               explain: bool = True) -> LoadVerdict:
    """A verdict from a solved program (None: the model tips and was not solved); `explain=False`
    leaves `failing` empty (finding the failing connections costs a second program)."""
    links = _rigid(model.link_kind)
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
    nc, nl = len(model.conn_a), len(model.link_a)
    coo = lp.a_ub.tocoo()
    # Capacity rows come in blocks of one per connection, then the links' (`load_program.link_rows`).
    n_conn_rows = len(capacity_rows(cfg)) * nc
    holder = np.concatenate([np.arange(n_conn_rows) % max(nc, 1)] +
                            [nc + links for links, _, _ in link_rows(model.link_cap)]).astype(np.int64)
    nh = nc + nl
    col = np.where(coo.col == 0, lp.n + holder[coo.row], coo.col)
    a_ub = sp.csr_matrix((coo.data, (coo.row, col)), shape=(lp.a_ub.shape[0], lp.n + nh))
    a_eq = sp.hstack([lp.a_eq, sp.csr_matrix((lp.a_eq.shape[0], nh))]).tocsr()
    c = np.concatenate([np.zeros(lp.n), np.ones(nh)])
    lower = np.concatenate([lp.lower, np.zeros(nh)])
    upper = np.concatenate([lp.upper, np.full(nh, s * (1 + 1e-9) + 1e-12)])
    lower[0] = upper[0] = 0.0
    res = solve_highs(LinearProgram(c, a_eq, lp.b_eq, a_ub, lp.b_ub, lower, upper))
    if res.status != "optimal":
        loads = np.full(nh, s)  # cannot happen for a solved minimax; keep every connection
    else:
        loads = res.x[lp.n:]
    # A rigid link has no capacity row: its load variable stays at 0, never among the worst.
    worst = np.flatnonzero(loads >= s * (1 - 1e-6))
    out = []
    for k in worst:
        if k < nc:
            out.append(Failure(int(model.parts[model.conn_a[k]]), int(model.parts[model.conn_b[k]]),
                               tuple(float(v) for v in model.conn_pos[k]), float(loads[k])))
        else:
            link = k - nc
            out.append(Failure(int(model.parts[model.link_a[link]]), int(model.parts[model.link_b[link]]),
                               tuple(float(v) for v in model.link_pos[link]), float(loads[k]),
                               joint=str(model.link_kind[link])))
    return tuple(out)


def solve_loads_highs(models: Sequence[LoadModel], cfg: LoadConfig = LoadConfig()) -> list[LPResult]:
    """The load program of each model, one at a time with HiGHS (the CPU reference)."""
    return [solve_highs(to_lp(m, cfg)) for m in models]


def judge_many(models: Sequence[LoadModel], cfg: LoadConfig = LoadConfig(),
               solve_loads: Callable[[list[LoadModel], LoadConfig], list[LPResult]] | None = None,
               explain: bool = True) -> list[LoadVerdict]:
    """`judge` for many models: the programs of those that do not tip are solved in one
    `solve_loads(models, cfg)` call (`loads_jax.solve_loads`: all at once on the JAX device), by
    default one by one with HiGHS; `explain` as in `verdict_of`."""
    tipping = [tips(m, cfg) for m in models]
    todo = [k for k, t in enumerate(tipping) if not t]
    results = (solve_loads or solve_loads_highs)([models[k] for k in todo], cfg)
    out: list[LPResult | None] = [None] * len(models)
    for k, r in zip(todo, results):
        out[k] = r
    return [verdict_of(m, r, cfg, explain) for m, r in zip(models, out)]


def judge_on_base(base: LoadBase, units: Sequence[Sequence[Placed]], conns: Sequence, cfg: LoadConfig,
                  solve_on_base: Callable, explain: bool = True) -> list[LoadVerdict]:
    """`judge_many` of `base.model(unit, conns)` for one-part units on a `base.shared()` structure,
    without a model per candidate: the tipping rule at once for those that do not touch the ground
    (the structure's support polygon, kept), then `solve_on_base(base, units, conns, cfg)` for those
    that stand (`loads_jax.solve_on_base`). Models are built only for parts on the ground and for the
    failing connections of an overload (`explain`)."""
    return judge_on_bases([(base, units, conns)], cfg,
                          lambda groups, c: [solve_on_base(*g, c) for g in groups], explain)[0]


def judge_on_bases(groups: Sequence[tuple], cfg: LoadConfig, solve_on_bases: Callable,
                   explain: bool = True) -> list[list[LoadVerdict]]:
    """`judge_on_base` of every (base, units, conns) group, the programs of all groups solved in one
    `solve_on_bases(groups, cfg)` call (`loads_jax.solve_on_bases`: objects grown in lockstep)."""
    todo_all, tipping_all = [], []
    for base, units, conns in groups:
        props = [part_mass_properties(u[0].part) for u in units]
        masses = np.array([m for m, _, _ in props])
        coms = np.array([u[0].pose.apply(c) for u, (_, c, _) in zip(units, props)]).reshape(-1, 3)
        centre = (base.mass @ base.com + masses[:, None] * coms) / (base.mass.sum() + masses)[:, None]
        grounded = np.array([len(support_points(u[0], base.floor_y, cfg)) > 0 for u in units], bool)
        hull = base.hull()
        tipping = (~inside_polygon_many(hull, centre[:, [0, 2]], cfg.tolerance) if len(hull)
                   else np.ones(len(units), bool))
        for i in np.flatnonzero(grounded):  # its own supports widen the polygon
            tipping[i] = tips(base.model(units[i], conns[i]), cfg)
        todo_all.append(np.flatnonzero(~tipping))
        tipping_all.append(tipping)
    solved = solve_on_bases([(base, [units[i] for i in todo], [conns[i] for i in todo])
                             for (base, units, conns), todo in zip(groups, todo_all)], cfg)
    out_all = []
    for (base, units, conns), todo, results in zip(groups, todo_all, solved):
        links = _rigid(base.link_kind)
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
