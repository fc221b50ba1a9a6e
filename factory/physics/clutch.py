"""The clutch rule: whether a new part (or rigid unit) is held by its own connections with the
rest of the structure fixed (`holds_alone`), the load model of `load_model` and `load_program` for
one body; the cheap rule that runs before the sweep and the whole-structure loads (`statics`).
"""

from __future__ import annotations

from typing import Callable, Sequence

import numpy as np

from factory.connections import STUD_RADIUS
from factory.physics.check_state import current
from factory.physics.load_model import UP, LoadConfig, LoadModel, NO_LINKS, hull_xz, inside_polygon
from factory.physics.load_program import to_lp
from factory.physics.lp import LinearProgram, LPResult, solve_highs
from factory.physics.mass import GRAVITY


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
    mass (positions relative to it, rounded to 1e-6 LDU) and its answer kept (the checker's
    `CheckState.alone`): the
    sampler's candidates of one part repeat configurations (2x4 bricks on a 30-brick wall: 819
    cases, 174 distinct), so most never reach a program."""
    kept = current().alone
    keys = [(_alone_key(*case), cfg) for case in cases]
    answers = {key: kept[key] for key in keys if key in kept}
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
    if len(kept) + len(answers) > ALONE_KEPT:
        kept.clear()
    kept.update(answers)
    return [bool(answers[key]) for key in keys]


ALONE_KEPT = 65536
"""Most `holds_alone` answers a checker keeps (`CheckState.alone`, by case relative to its centre
of mass and config); past it they are dropped and found again."""


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
    return inside_polygon(hull_xz(np.unique(np.round(xz, 6), axis=0)), centre, cfg.tolerance)


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
        **NO_LINKS,
    )
    lp = to_lp(model, cfg)
    return LinearProgram(lp.c, lp.a_eq[:6], lp.b_eq[:6], lp.a_ub, lp.b_ub, lp.lower, lp.upper)
