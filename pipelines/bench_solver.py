"""The batched LP solver (`factory.physics.lp_jax`) alone against HiGHS, on load programs of the
form `load_program.to_lp` writes: `bench` solves a batch in one call (after a call that compiles) and
reports its rate, iterations, shapes and the answers' largest difference from HiGHS's;
`statics_like_lp` writes random such programs (tests/test_lp_jax.py uses them too). Run by
`pipelines.bench_physics --solver`; `--lp` there times the whole load check from the candidates'
poses instead (`bench_checks.measure_lp`).
"""

from __future__ import annotations

import time
from collections import Counter
from typing import Sequence

import jax
import numpy as np
import scipy.sparse as sp

from factory.physics.lp import LinearProgram, solve_highs
from factory.physics.lp_jax import MAX_ITERATIONS, _launches, _parts, _solve

_BRICKS = ((1, 1), (1, 2), (1, 4), (2, 2), (2, 3), (2, 4), (1, 6), (2, 6))


def statics_like_lp(rng: np.random.Generator, size: int) -> LinearProgram:
    """A load program of the form `load_program.to_lp` writes (LDraw frame, y down; N, kg, LDU; moment
    rows in newton-studs; per stud 4 rim forces with tension <= s C/4, 2 shears and a torsion with
    |.| <= s capacity; 4 friction-pyramid edges per ground support point; minimise s, variable 0)
    for a random structure: bricks stacked on a 6x8 base plate, grown until the program has at
    least `size` variables. The structure's centre of mass stays over the base, so the program is
    feasible."""
    clutch, shear, torsion, friction, radius, pitch = 1.0, 10.0, 6.0, 0.8, 6.0, 20.0
    up = np.array([0.0, -1.0, 0.0])
    # Parts: (x, z, width, depth, layer) in studs; the base is layer 0, 8 x 6 studs, 8 LDU thick.
    parts = [(0, 0, 8, 6, 0)]
    mass = [0.009]
    studs: list[tuple[int, int, int, int]] = []  # (lower part, upper part, stud x, stud z)

    def cells(p):
        x, z, w, d, _ = p
        return {(x + i, z + j) for i in range(w) for j in range(d)}

    def centre(p):
        x, z, w, d, layer = p
        y = 4.0 if layer == 0 else -24.0 * layer + 12.0
        return np.array([pitch * (x + w / 2), y, pitch * (z + d / 2)])

    n_vars = 1 + 4 * 8
    while n_vars < size:
        on = parts[rng.integers(len(parts))]
        w, d = _BRICKS[rng.integers(len(_BRICKS))][:: rng.choice([1, -1])]
        new = (on[0] + int(rng.integers(1 - w, on[2])), on[1] + int(rng.integers(1 - d, on[3])), w, d, on[4] + 1)
        taken = set().union(*(cells(p) for p in parts if p[4] == new[4]))
        m = 0.00035 * w * d + 0.0002
        com = (np.dot(mass, [centre(p) for p in parts]) + m * centre(new)) / (sum(mass) + m)
        if cells(new) & taken or not (0 < com[0] < 8 * pitch and 0 < com[2] < 6 * pitch):
            continue
        k = len(parts)
        for j, p in enumerate(parts):
            if abs(p[4] - new[4]) == 1:
                lower, upper = (j, k) if p[4] < new[4] else (k, j)
                for sx, sz in sorted(cells(p) & cells(new)):
                    studs.append((lower, upper, sx, sz))
                    n_vars += 7
        parts.append(new)
        mass.append(m)

    nb, ns = len(parts), len(studs)
    coms = np.array([centre(p) for p in parts])
    supports = np.array([[x, 8.0, z] for x in (0, 80, 160) for z in (0, 60, 120) if (x, z) != (80, 60)])
    n = 1 + 7 * ns + 4 * len(supports)
    rows, cols, vals = [], [], []

    def force(body, col, f, point, moment=np.zeros(3)):
        torque = (np.cross(point - coms[body], f) + moment) / pitch
        for r, v in enumerate(np.r_[f, torque]):
            if v:
                rows.append(6 * body + r), cols.append(col), vals.append(v)

    ub = []  # (column, coefficient, capacity): coefficient * x[column] - capacity * s <= 0
    ex, ez = np.eye(3)[0], np.eye(3)[2]
    for i, (a, b, sx, sz) in enumerate(studs):
        base = np.array([pitch * (sx + 0.5), -24.0 * parts[a][4], pitch * (sz + 0.5)])  # top of the lower part
        col = 1 + 7 * i
        kinds = [(up, base + radius * e, np.zeros(3)) for e in (ex, -ex, ez, -ez)]
        kinds += [(ex, base, np.zeros(3)), (ez, base, np.zeros(3)), (np.zeros(3), base, up)]
        for j, (f, point, moment) in enumerate(kinds):
            force(b, col + j, f, point, moment)
            force(a, col + j, -f, point, -moment)
        ub += [(col + j, -1.0, clutch / 4) for j in range(4)]
        ub += [(col + j, sign, shear) for j in (4, 5) for sign in (1.0, -1.0)]
        ub += [(col + 6, sign, torsion) for sign in (1.0, -1.0)]
    for i, point in enumerate(supports):
        for j, e in enumerate((ex, -ex, ez, -ez)):
            force(0, 1 + 7 * ns + 4 * i + j, up + friction * e, point)
    a_eq = sp.csr_matrix((vals, (rows, cols)), shape=(6 * nb, n))
    b_eq = np.zeros(6 * nb)
    b_eq[1::6] = -np.array(mass) * 9.81
    k = len(ub)
    column, coefficient, capacity = (np.array(v) for v in zip(*ub))
    rows_ub = np.r_[np.arange(k), np.arange(k)]
    a_ub = sp.csr_matrix((np.r_[coefficient, -capacity], (rows_ub, np.r_[column, np.zeros(k, int)])), shape=(k, n))
    lower = np.full(n, -np.inf)
    lower[0] = 0.0
    lower[1 + 7 * ns :] = 0.0
    c = np.zeros(n)
    c[0] = 1.0
    return LinearProgram(c, a_eq, b_eq, a_ub, np.zeros(k), lower, np.full(n, np.inf))


def bench(n_problems: int = 64, size: int = 960, seed: int = 0, tol: float = 1e-8,
          lps: Sequence[LinearProgram] | None = None, reference: int = 64) -> dict:
    """Solve `n_problems` load programs in one `solve_batch` call, after a first call that compiles;
    report the rate, iterations, shapes, and the objectives' largest difference from HiGHS,
    |s - s_HiGHS| / max(1, |s_HiGHS|), and the verdicts s <= 1 + 1e-6 that differ, over the first
    `reference` distinct programs (HiGHS one at a time, also timed). The programs: `lps`, repeated
    in turn to fill the batch, else random ones of at least `size` variables (`statics_like_lp`)."""
    if lps is None:
        rng = np.random.default_rng(seed)
        lps = [statics_like_lp(rng, size) for _ in range(min(n_problems, reference))]
    batch = [lps[i % len(lps)] for i in range(n_problems)]
    sample = list(lps[:reference])
    t = time.perf_counter()
    highs = [solve_highs(lp) for lp in sample]
    highs_s = time.perf_counter() - t
    t = time.perf_counter()
    _solve(batch, tol, MAX_ITERATIONS)
    first_s = time.perf_counter() - t
    t = time.perf_counter()
    results, iterations = _solve(batch, tol, MAX_ITERATIONS)
    solve_s = time.perf_counter() - t
    ours = results[: len(sample)]
    err = [abs(r.objective - h.objective) / max(1.0, abs(h.objective)) for r, h in zip(ours, highs) if r.status == "optimal"]
    flips = sum((r.objective <= 1 + 1e-6) != (h.objective <= 1 + 1e-6) for r, h in zip(ours, highs) if r.status == "optimal")
    return {
        "problems": n_problems,
        "distinct": len(lps),
        "variables": round(float(np.mean([lp.n for lp in batch]))),
        "equality_rows": round(float(np.mean([lp.a_eq.shape[0] for lp in batch]))),
        "shapes": sorted(Counter(shape for shape, _ in _launches([_parts(lp) for lp in batch])).items()),
        "lps_per_s": round(n_problems / solve_s, 1),
        "solve_s": round(solve_s, 3),
        "first_call_s": round(first_s, 2),
        "iterations_median": int(np.median(iterations)),
        "iterations_p90": int(np.percentile(iterations, 90)),
        "iterations_max": int(iterations.max()),
        "not_optimal": sum(r.status != "optimal" for r in results),
        "max_objective_error": max(err, default=float("nan")),
        "verdicts_differing": int(flips),
        "highs_ms_per_lp": round(1e3 * highs_s / len(sample), 2),
        "device": str(jax.devices()[0]),
    }
