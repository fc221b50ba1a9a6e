"""Batched linear programs in JAX: thousands of `LinearProgram`s in one jitted, vmapped call.

Why: the whole-structure load check (`statics`) writes one LP per candidate structure (each part's
force and moment balance, stud and ground forces, minimise the largest utilisation s; the structure
holds when s <= 1), and the sampler judges thousands of candidates per call on a GPU. HiGHS
(`lp.solve_highs`) solves one LP at a time on the CPU; here all LPs of a call advance together on
the default JAX device, and their answers agree with HiGHS (tests/test_lp_jax.py).

Method: each LP is put in the kernel's structured form (`_parts`), padded to its shape bucket and
stacked with the others of its launch (`_stack`); the kernel (`interior_point_jax`: a primal-dual
interior-point method in float64, one LP vmapped over the launch) solves them, and x comes back in
the LP's own columns. The load programs are written straight into these arrays from load models
(`loads_jax`).

Shapes: each LP falls in a bucket (variables and entries per column of A: quarter steps of powers
of two; equality rows: eighth steps; one-sided rows per variable: exact, 2 for the load programs);
a launch holds the LPs with the same equality rows and rows per variable, padded to the largest
variables and entries among them, their count padded to a quarter step (at most `MAX_BATCH` per
launch, fewer where the rows are many, `MAX_LAUNCH_ENTRIES`; in equal chunks), so a run compiles
once per shape met (`COMPILES`), never per call; tolerance and iteration cap are traced values.
Memory per LP is dominated by the normal matrix, 8 m^2 bytes for m padded rows: 1.2 MB at 384 (60
bricks: 366 rows), 2.7 MB at 576 (90 bricks: 546 rows); 4,096 of them, 11 GB.

Measured (CPU and one H200, `pipelines.bench_physics --lp`): docs/results.md.

Precision: float64, switched on only inside the call (`jax.enable_x64` as a context manager, so the
global flag stays float32 for the rest of the project): the normal matrices' diagonals span 20
orders of magnitude near the optimum.
"""

from __future__ import annotations

import functools
from typing import NamedTuple, Sequence

import jax
import numpy as np
import scipy.sparse as sp

from factory.physics.interior_point_jax import _OPTIMAL, _launch
from factory.physics.lp import LinearProgram, LPResult, solve_highs

MAX_ITERATIONS = 80
"""Iterations after which a member that has not converged is "error" (or goes to HiGHS)."""
MIN_BUCKET = 16
MAX_BATCH = 4096
"""LPs of one shape per launch; more run in chunks of this many."""
MAX_LAUNCH_ENTRIES = 2**29
"""Members x equality rows squared of one launch, at most (`_launch_cap`): a launch holds each
member's normal matrix and its factor, so its device memory grows with the rows squared. At 90
bricks (576 rows) a launch of 4,096 took 106 GB of an H200 and asked an H100 for one block of
32 GiB more than it had (2026-11-26); at this bound such programs launch 1,024 at a time (on one
H200, 1,024 and 16,384 candidates ran 1,272 and 1,179 per s: nothing is gained above 1,024)."""
MIN_LAUNCH = {"gpu": 64, "cpu": 8}
"""Fewest members of a launch by JAX backend (powers of two above; `min_launch`): on a GPU a few
programs cost a launch of 64 as much as one of 2, and every batch size met is a compile; on a CPU
each member costs its own."""
ROWS_FINE = 128
"""Equality rows up to which their bucket is a power of two (`_rows`)."""

COMPILES: list[tuple[int, ...]] = []
"""(batch, variables, equality rows, equality entries per column, one-sided rows per variable) of
every bucket compiled in this process."""


# --- The structured form (numpy) -----------------------------------------------------------------


class _Parts(NamedTuple):
    """One LP in the form the solver takes: minimise c x subject to A x = b and one-sided rows
    coef_r x[var_r] + link_r x[L] <= rhs_r, each on one variable and the link column L (the load
    programs' s). Inequality rows of another shape become an equality row and a new variable."""

    c: np.ndarray
    a: sp.csc_matrix
    b: np.ndarray
    var: np.ndarray
    coef: np.ndarray
    link: np.ndarray
    rhs: np.ndarray
    link_col: int
    n_orig: int


def _parts(lp: LinearProgram) -> _Parts:
    n0 = lp.n
    # A fixed variable is substituted (its column emptied, its value moved to the right-hand
    # sides): as a row of its own it would be a free column in the normal matrix, 1 / REG_PRIMAL
    # (`interior_point_jax`) times heavier than the rest. Its x comes back from the bounds
    # (`_solve` clips).
    fixed = np.flatnonzero(lp.lower == lp.upper)
    value = np.zeros(n0)
    value[fixed] = lp.lower[fixed]
    keep = sp.diags((lp.lower != lp.upper).astype(float))
    a_eq, ub = sp.csr_matrix(lp.a_eq @ keep), sp.csr_matrix(lp.a_ub @ keep)
    b_eq, b_ub = lp.b_eq - lp.a_eq @ value, lp.b_ub - lp.a_ub @ value
    ub.sum_duplicates()
    ub.eliminate_zeros()
    nnz = np.diff(ub.indptr)
    row_of = np.repeat(np.arange(ub.shape[0]), nnz)
    # The link column: the one most rows of two entries share (column 0, s, in a load program).
    two = np.isin(row_of, np.flatnonzero(nnz == 2))
    link_col = int(np.bincount(ub.indices[two], minlength=n0).argmax()) if two.any() else 0
    on_link = ub.indices == link_col
    link_of = np.zeros(ub.shape[0])
    link_of[row_of[on_link]] = ub.data[on_link]
    others = nnz - np.bincount(row_of[on_link], minlength=ub.shape[0])
    # Rows of one variable and the link: their own entry (the link's, where the row has no other).
    own = np.flatnonzero(others == 1)
    own_entry = np.flatnonzero(~on_link & np.isin(row_of, own))
    only_link = np.flatnonzero((others == 0) & (nnz > 0))
    var = np.r_[ub.indices[own_entry], np.full(len(only_link), link_col)]
    coef = np.r_[ub.data[own_entry], link_of[only_link]]
    link = np.r_[link_of[own], np.zeros(len(only_link))]
    rhs = np.r_[b_ub[own], b_ub[only_link]]
    # Any other row: a new variable v = row x (an equality row) with the row's bound on it.
    general = np.flatnonzero(others > 1)
    extra = ub[general]
    k = len(general)
    # Bounds: one row each.
    lo = np.flatnonzero(np.isfinite(lp.lower) & (lp.lower != lp.upper))
    up = np.flatnonzero(np.isfinite(lp.upper) & (lp.lower != lp.upper))
    var = np.r_[var, n0 + np.arange(k), lo, up].astype(np.int64)
    coef = np.r_[coef, np.ones(k), -np.ones(len(lo)), np.ones(len(up))]
    link = np.r_[link, np.zeros(k + len(lo) + len(up))]
    rhs = np.r_[rhs, b_ub[general], -lp.lower[lo], lp.upper[up]]
    a = sp.vstack([sp.hstack([a_eq, sp.csr_matrix((a_eq.shape[0], k))]), sp.hstack([extra, -sp.identity(k)])], format="csc")
    a.sum_duplicates()
    a.eliminate_zeros()
    b = np.r_[b_eq, np.zeros(k)]
    c = np.r_[np.where(lp.lower == lp.upper, 0.0, lp.c), np.zeros(k)]
    order = np.argsort(var, kind="stable")
    return _Parts(c, a, b, var[order], coef[order], link[order], rhs[order], link_col, n0)


def _pow2(v: int, minimum: int = MIN_BUCKET) -> int:
    return max(minimum, 1 << max(v - 1, 0).bit_length())


def _quarter(v: int, minimum: int = MIN_BUCKET) -> int:
    """The next of 8, 10, 12, 14, 16, 20, 24, ... (at least `minimum`; exact below 8): quarter
    steps of powers of two, so padding adds at most a quarter."""
    if v <= minimum:
        return minimum
    step = 1 << max((v - 1).bit_length() - 3, 0)
    return -(-v // step) * step


def _eighth(v: int, minimum: int = MIN_BUCKET) -> int:
    """As `_quarter`, in eighth steps (16, 18, 20, ..., 32, 36, ...): the equality rows' bucket,
    whose cost grows with its cube (546 rows, 90 bricks, pad to 576, not 640)."""
    if v <= minimum:
        return minimum
    step = 1 << max((v - 1).bit_length() - 4, 0)
    return -(-v // step) * step


def _rows(v: int) -> int:
    """The equality rows' bucket: powers of two up to `ROWS_FINE` (small programs cost little, so
    padding them costs little), eighth steps above (`_eighth`: the cost grows with the rows' cube).
    A growing object meets each bucket once: a bounded number of compiles per run."""
    return _pow2(v) if v <= ROWS_FINE else _eighth(v)


@functools.cache
def min_launch() -> int:
    """`MIN_LAUNCH` of the default JAX backend (asked at the first launch, not at import: that
    starts the backend)."""
    return MIN_LAUNCH.get(jax.default_backend(), MIN_LAUNCH["cpu"])


def _cols(v: int) -> int:
    """The variables' bucket: powers of two and the midpoints between them (16, 24, 32, 48, ...):
    the cost grows about linearly with them."""
    if v <= MIN_BUCKET:
        return MIN_BUCKET
    p = _pow2(v)
    return p * 3 // 4 if v <= p * 3 // 4 else p


def _bucket(p: _Parts) -> tuple[int, int, int, int]:
    per_column = int(np.diff(p.a.indptr).max(initial=1))
    per_var = int(np.bincount(p.var, minlength=1).max(initial=1))
    return _quarter(p.a.shape[1]), _eighth(p.a.shape[0]), _quarter(per_column, 1), max(per_var, 1)


def bucket_of(lp: LinearProgram) -> tuple[int, int, int, int]:
    """(variables, equality rows, equality entries per column, one-sided rows per variable) of the
    padded shape `lp` is solved in (after its general inequality rows and fixed variables became
    equality rows)."""
    return _bucket(_parts(lp))


def _empty(batch: int, n: int, m: int, w: int, k: int) -> dict[str, np.ndarray]:
    """The solver's arrays of a launch, every column padding (no entries, no rows in force)."""
    return {
        "c": np.zeros((batch, n)), "b": np.zeros((batch, m)),
        "a_rows": np.zeros((batch, n, w), np.int32), "a_vals": np.zeros((batch, n, w)),
        "coef": np.zeros((batch, n, k)), "link": np.zeros((batch, n, k)), "rhs": np.ones((batch, n, k)),
        "mask": np.zeros((batch, n, k)), "link_col": np.zeros(batch, np.int32),
    }


def _stack(parts: Sequence[_Parts], batch: int, n: int, m: int, w: int, k: int) -> dict[str, np.ndarray]:
    out = _empty(batch, n, m, w, k)
    for i, p in enumerate(parts):
        out["c"][i, : len(p.c)] = p.c
        out["b"][i, : len(p.b)] = p.b
        counts = np.diff(p.a.indptr)
        slot = np.arange(p.a.nnz) - np.repeat(p.a.indptr[:-1], counts)
        col = np.repeat(np.arange(len(counts)), counts)
        out["a_rows"][i, col, slot], out["a_vals"][i, col, slot] = p.a.indices, p.a.data
        first = np.searchsorted(p.var, p.var)  # rows are sorted by variable
        slot = np.arange(len(p.var)) - first
        for key, v in (("coef", p.coef), ("link", p.link), ("rhs", p.rhs), ("mask", 1.0)):
            out[key][i, p.var, slot] = v
        out["link_col"][i] = p.link_col
    return out


# --- Launches ------------------------------------------------------------------------------------


def solve_batch(lps: Sequence[LinearProgram], *, tol: float = 1e-8, max_iterations: int = MAX_ITERATIONS,
                fallback: bool = True) -> list[LPResult]:
    """Solve every LP on the default JAX device, the LPs of each shape bucket in one launch.
    Results come in the order given: "optimal" with x (clipped to its bounds) and c @ x, where the
    relative primal and dual residuals and the duality gap fell below `tol`; a member that did not
    within `max_iterations` is solved by HiGHS with `fallback` (`FALLBACKS` counts them), else
    "error" (x None)."""
    results, _ = _solve(lps, tol, max_iterations)
    if fallback:
        for i, r in enumerate(results):
            if r.status != "optimal":
                FALLBACKS[0] += 1
                results[i] = solve_highs(lps[i])
    return results


FALLBACKS = [0]
"""Programs this process handed to HiGHS because the batched solver did not converge."""


def _solve(lps: Sequence[LinearProgram], tol: float, max_iterations: int) -> tuple[list[LPResult], np.ndarray]:
    """`solve_batch` without the fallback, plus each LP's iteration count."""
    results: list[LPResult] = [LPResult("error", None, float("nan"))] * len(lps)
    iterations = np.zeros(len(lps), int)
    parts = [_parts(lp) for lp in lps]
    with jax.enable_x64(True):
        for shape, chunk in _launches(parts):
            if shape not in COMPILES:
                COMPILES.append(shape)
            arrays = _stack([parts[i] for i in chunk], *shape)
            x, status, t = _launch(arrays, tol, max_iterations)
            x, status, t = np.asarray(x), np.asarray(status), np.asarray(t)
            for j, i in enumerate(chunk):
                iterations[i] = t[j]
                if status[j] == _OPTIMAL:
                    lp = lps[i]
                    xi = np.clip(x[j, : lp.n], lp.lower, lp.upper)  # bounds hold to tol; make them exact
                    results[i] = LPResult("optimal", xi, float(lp.c @ xi))
    return results, iterations


def _launches(parts: Sequence[_Parts]) -> list[tuple[tuple[int, ...], list[int]]]:
    """(shape, members) of each launch (see `_group`)."""
    return _group([_bucket(p) for p in parts])


def _group(buckets: Sequence[tuple[int, int, int, int]]) -> list[tuple[tuple[int, ...], list[int]]]:
    """(shape, members) of each launch, from each program's bucket. Programs with the same
    equality rows' and slots' buckets run together, in the largest of their variables' and
    entries' buckets: the cost is the normal matrix (its rows squared and cubed), and one launch
    is cheaper than two. At most `MAX_BATCH` per launch, in equal chunks (one batch size, one
    compile)."""
    groups: dict[tuple[int, int], list[int]] = {}
    size: dict[tuple[int, int], tuple[int, int]] = {}
    for i, (n, m, w, k) in enumerate(buckets):
        groups.setdefault((m, k), []).append(i)
        size[(m, k)] = tuple(max(a, b) for a, b in zip(size.get((m, k), (0, 0)), (n, w)))
    out = []
    for (m, k), members in groups.items():
        launches = -(-len(members) // _launch_cap(m))
        per = -(-len(members) // launches)
        n, w = size[(m, k)]
        for start in range(0, len(members), per):
            chunk = members[start : start + per]
            out.append(((_pow2(len(chunk), min_launch()), n, m, w, k), chunk))
    return out


def _launch_cap(m: int) -> int:
    """Most members of one launch of programs with `m` equality rows (their bucket): `MAX_BATCH`,
    or the largest power of two within `MAX_LAUNCH_ENTRIES` (at least `min_launch`)."""
    fit = MAX_LAUNCH_ENTRIES // max(m * m, 1)
    return max(min(MAX_BATCH, 1 << (fit.bit_length() - 1) if fit else 0), min_launch())


def _run(arrays: dict, tol: float, max_iterations: int) -> tuple[np.ndarray, np.ndarray]:
    """(x, status) of one launch."""
    x, status, _ = _launch(arrays, tol, max_iterations)
    return np.asarray(x), np.asarray(status)


def _fallback(results: list[LPResult], program, fallback: bool) -> list[LPResult]:
    """Members that did not converge, solved by HiGHS (`program(i)`: the i-th `LinearProgram`)."""
    if fallback:
        for i, r in enumerate(results):
            if r.status != "optimal":
                FALLBACKS[0] += 1
                results[i] = solve_highs(program(i))
    return results
