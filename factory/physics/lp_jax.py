"""Batched linear programs in JAX: thousands of `LinearProgram`s in one jitted, vmapped call.

Why: the whole-structure load check (`statics`) writes one LP per candidate structure (each part's
force and moment balance, stud and ground forces, minimise the largest utilisation s; the structure
holds when s <= 1), and the sampler judges thousands of candidates per call on a GPU. HiGHS
(`lp.solve_highs`) solves one LP at a time on the CPU; here all LPs of a call advance together on
the default JAX device, and their answers agree with HiGHS (tests/test_lp_jax.py).

Method: a primal-dual interior-point method (Mehrotra's predictor-corrector) in float64, built
around the load programs' structure. It replaced restarted Halpern PDHG, which was accurate but
needed thousands of iterations (4,160 median, 17,024 max at ~1,000 variables), and a launch waits
for its slowest member; the interior-point method takes 7-14 on the same kind of programs (the
iteration cap, `MAX_ITERATIONS`, is a bound, not a budget).

- Form: minimise c x subject to A x = b (the balance rows: 6 per body) and one-sided rows
  coef_r x[j_r] + link_r x[L] <= rhs_r, each on one variable and the link column L: every
  inequality of `statics.to_lp` is one force against s (tension per rim point, shear and torsion
  both ways, capacities scaled by s), and bounds are such rows without the link. Other
  inequality rows become an equality row and a new variable; fixed variables are substituted.
- Newton system: with D = Z / W on the one-sided rows, the primal block H = G^T D G + rho I is an
  arrow (a diagonal, plus the row and column of s), so H^-1 is a diagonal plus one rank-one term
  through s's Schur complement (computed per variable by the Lagrange identity, without the
  cancellation of large D). The equality multipliers solve the normal equations
  (A diag(1/d) A^T + q q^T / sigma) dy = r: a dense m x m matrix (m = 6 x bodies) formed by one
  scatter of A's columns' outer products, a batched Cholesky factorisation per iteration and the
  factor's inverse (one triangular solve with m right-hand sides), the rank-one part by
  Sherman-Morrison. Predictor and corrector share the factorisation; each of the iteration's five
  solves is two matrix-vector products with the inverse factor (on one H100, 64 programs of a
  60-brick structure a launch: 1,223 per s, against 801 with two substitutions per solve), and
  each is refined once against the full system.
- Regularisation: rho = 1e-4 (scaled) on H, a proximal term: a free variable (a rigid link's
  force) has an invertible block, and no variable strictly inside its rows weighs more than
  1 / rho in the normal matrix (`REG_PRIMAL` says what smaller values did). Equality rows that
  depend on earlier ones (a rotation no force resists) are found once, by the pivots of a
  Cholesky factorisation of A A^T, and left out.
- Scaling: Ruiz equilibration of [A; G], objective and right-hand side divided by 1 + their
  largest entry. Start: Mehrotra's heuristic (x the least-squares fit of the one-sided rows
  subject to A x = b; slacks and multipliers shifted positive). Steps: 0.995 of the way to the
  boundary, primal and dual separately.
- Termination, in the original units: equality and inequality residuals, dual residual and
  duality gap within `tol` (1e-8 by default) relative to 1 + the largest entry of b, c and the
  objective. A member not done in `max_iterations`, or not finite, is "error"; `solve_batch`
  then gives it to HiGHS (`FALLBACKS` counts them; none on the test programs).

Every program of the load form is feasible once it does not tip (s can grow until every
connection is rigid), so infeasibility is not detected: such a program would end at the cap.

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
import time
from collections import Counter
from typing import NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp
from jax import lax

from factory.physics import jax_export
from factory.physics.jax_cache import enable as enable_compile_cache
from factory.physics.lp import LinearProgram, LPResult, solve_highs
from factory.physics.mass import GRAVITY, part_mass_properties
from factory.physics.statics import (LEVER_LDU, PER_CONNECTION, PER_LINK, PER_SUPPORT, LoadBase, LoadConfig, LoadModel,
                                     _connection_arrays, capacity_rows, connection_columns, layout, link_columns,
                                     support_columns, support_points, to_lp)

enable_compile_cache()  # before this module's first compile

MAX_ITERATIONS = 80
"""Iterations after which a member that has not converged is "error" (or goes to HiGHS)."""
RUIZ_ITERATIONS = 8
STEP_TO_BOUNDARY = 0.995
"""Fraction of the longest step that keeps the slacks and their duals positive."""
REG_PRIMAL = 1e-4
"""Added to the diagonal of the (scaled) primal Hessian, a proximal term on each step: a variable
no row bounds (a rigid link's force) still has an invertible block, and a variable strictly
inside its rows weighs at most 1 / REG_PRIMAL in the normal matrix. At 1e-9 the normal matrix of
some real load programs (rows active to 1e-16 against free ones at 1e9) lost all accuracy near
the optimum: 29 of 3,334 programs of an 8-brick structure stalled; at 1e-7, 2; at 1e-6 none, but
5 of 64 of a 60-brick structure's did; at 1e-5 and 1e-4 none, in 12 and 10 iterations at most."""
REG_DUAL = 1e-12
"""The normal matrix's diagonal is multiplied by (1 + this), so that its Cholesky factorisation
completes where rounding makes it semidefinite; relative to each row, since rows differ by 10
orders of magnitude (a fixed variable's row against a force's)."""
REFINEMENTS = 1
"""Passes of iterative refinement of each Newton step (see `newton`). One keeps the test programs
(1,000+ real load programs near the limit, rigid links included) within 1e-7 of HiGHS, as two
did; each pass costs two solves with the normal matrix per iteration (on one H200, 90-brick
candidates: 710-753 per s with one, 679-700 with two)."""
DEPENDENT_PIVOT = 1e-10
"""An equality row whose Cholesky pivot (of the unit-diagonal Gram matrix) is below this depends on
the rows before it and is left out."""
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

_RUNNING, _OPTIMAL, _ERROR = 0, 1, 2


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
    # times heavier than the rest. Its x comes back from the bounds (`_solve` clips).
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


# --- The solver (JAX; one LP, vmapped over the batch) --------------------------------------------


class _State(NamedTuple):
    x: jax.Array
    y: jax.Array  # equality multipliers
    w: jax.Array  # slacks of the one-sided rows (n, k)
    z: jax.Array  # their multipliers
    k: jax.Array
    status: jax.Array


def _inv_sqrt(v):
    """1/sqrt(v), and 1 where v is 0 or -inf (empty rows and columns keep their scale)."""
    ok = v > 0
    return jnp.where(ok, 1 / jnp.sqrt(jnp.where(ok, v, 1)), 1.0)


def _solve_one(c, b, a_rows, a_vals, coef, link, rhs, mask, link_col, tol, max_iterations):
    n, m, slots = c.shape[0], b.shape[0], coef.shape[1]

    # Scatter targets of A's entries and of their pairwise products. Zero entries (padding slots
    # and columns, rows left out) are sent out of range, which segment sums drop: they add
    # nothing, and as row 0 they were most of each scatter (at 90 bricks 14,537 of a Gram matrix's
    # 294,912 adds went to entry (0, 0) alone, one atomic after another on a GPU).
    def targets(vals):
        live = vals != 0
        flat = jnp.where(live, a_rows, m).reshape(-1)
        both = live[:, :, None] & live[:, None, :]
        pair = jnp.where(both, a_rows[:, :, None] * m + a_rows[:, None, :], m * m).reshape(-1)
        return flat, pair

    a_flat, _ = targets(a_vals)
    is_link = jnp.arange(n) == link_col
    count = jnp.maximum(mask.sum(), 1.0)

    # Ruiz equilibration of [A; G] (G: the one-sided rows), then objective and right-hand side
    # divided by (1 + their largest entry): A~ = Dr A Dc, G~ = Dg G Dc.
    def scaled(dr, dg, dc):
        av = a_vals * dr[a_rows] * dc[:, None]
        return av, coef * dg * dc[:, None], link * dg * dc[link_col]

    def ruiz(_, d):
        dr, dg, dc = d
        av, gc, gl = (jnp.abs(v) for v in scaled(dr, dg, dc))
        row_a = jax.ops.segment_max(av.reshape(-1), a_flat, m)
        row_g = jnp.maximum(gc, gl)
        col = jnp.maximum(av.max(axis=1), gc.max(axis=1))
        col = col.at[link_col].max(gl.max())
        return dr * _inv_sqrt(row_a), dg * _inv_sqrt(row_g), dc * _inv_sqrt(col)

    dr, dg, dc = lax.fori_loop(0, RUIZ_ITERATIONS, ruiz, (jnp.ones(m), jnp.ones((n, slots)), jnp.ones(n)))
    av, gc, gl = scaled(dr, dg, dc)
    beta_c = 1 + jnp.abs(c * dc).max()
    beta_b = 1 + jnp.maximum(jnp.abs(b * dr).max(), jnp.abs(rhs * dg * mask).max())
    cs, bs, hs = c * dc / beta_c, b * dr / beta_b, jnp.where(mask > 0, rhs * dg / beta_b, 1.0)

    # Equality rows that depend on earlier ones are left out (consistent: the same equilibrium
    # written twice, or a rotation no force resists about a line of ground points): a Cholesky
    # factorisation of the unit-diagonal Gram matrix, with a ridge so that it completes, finds them
    # by their vanishing pivots. Empty rows (padding) get a unit diagonal: they change nothing.
    _, pair = targets(av)

    def gram(weight):  # A~ diag(weight) A~^T
        outer = weight[:, None, None] * av[:, :, None] * av[:, None, :]
        return jax.ops.segment_sum(outer.reshape(-1), pair, m * m).reshape(m, m)

    g0 = gram(jnp.ones(n))
    empty = jnp.diag(g0) <= 0
    unit = jnp.where(empty, 1.0, 1 / jnp.sqrt(jnp.where(empty, 1.0, jnp.diag(g0))))
    g0 = g0 * unit[:, None] * unit[None, :] + jnp.diag(jnp.where(empty, 1.0, 0.0))
    pivots = jnp.diag(jnp.linalg.cholesky(g0 + 1e-14 * jnp.eye(m))) ** 2
    keep = (pivots > DEPENDENT_PIVOT) & ~empty
    av = jnp.where(keep[a_rows], av, 0.0)
    bs = jnp.where(keep, bs, 0.0)
    a_flat, pair = targets(av)

    def a_mul(x):
        return jax.ops.segment_sum((av * x[:, None]).reshape(-1), a_flat, m)

    def a_tmul(u):
        return (av * u[a_rows]).sum(axis=1)

    def g_mul(x):  # (n, slots)
        return gc * x[:, None] + gl * x[link_col]

    def g_tmul(v):  # v (n, slots), zero on empty slots
        return (gc * v).sum(axis=1).at[link_col].add((gl * v).sum())

    # The Newton system. With D = Z / W on the one-sided rows, the primal block is
    # H = G~^T D G~ + rho I: each row touches one variable and the link, so H is an arrow: a
    # diagonal d plus the link's row and column u. H^-1 = diag(1/d, 0) + p p^T / sigma with
    # p = e_L - u / d and sigma = H_LL - sum u_j^2 / d_j, the link's Schur complement, summed per
    # variable as (rho sum D k^2 + sum_{r<t} D_r D_t (k_r a_t - k_t a_r)^2) / d_j (the Lagrange
    # identity: no cancellation where D is large). The equality multipliers then solve the normal
    # equations (A H^-1 A^T) dy = r, a dense m x m matrix: the sparse part A diag(1/d) A^T plus
    # the rank-one q q^T / sigma, q = A p; one Cholesky factorisation per iteration.
    def factor(dd):
        da2 = (dd * gc**2).sum(axis=1)
        dak = (dd * gc * gl).sum(axis=1)
        dk2 = (dd * gl**2).sum(axis=1)
        d = REG_PRIMAL + da2
        cross = jnp.zeros(n)
        for r in range(slots):
            for t in range(r + 1, slots):
                cross = cross + dd[:, r] * dd[:, t] * (gl[:, r] * gc[:, t] - gl[:, t] * gc[:, r]) ** 2
        sigma = d[link_col] + jnp.where(is_link, 0.0, (REG_PRIMAL * dk2 + cross) / d).sum()
        dinv = jnp.where(is_link, 0.0, 1 / d)
        p = jnp.where(is_link, 1.0, -dinv * dak)
        q = a_mul(p)
        normal = gram(dinv)
        normal = normal + jnp.diag(jnp.where(keep, REG_DUAL * jnp.diag(normal), 1.0))
        # The factor's inverse, once per iteration (one triangular solve with m right-hand sides):
        # the iteration's five solves with the normal matrix are then two matrix-vector products
        # each, not two sequential substitutions of m steps each (on a GPU a substitution's steps
        # are launches that wait on each other).
        chol = jnp.linalg.cholesky(normal)
        linv = jax.scipy.linalg.solve_triangular(chol, jnp.eye(m), lower=True)
        mq = linv.T @ (linv @ q)
        return dinv, p, sigma, linv, q, mq, sigma + q @ mq

    def h_inv(fac, v):
        dinv, p, sigma = fac[:3]
        return dinv * v + p * (p @ v) / sigma

    def normal_solve(fac, r):  # (M0 + q q^T / sigma)^-1 r, Sherman-Morrison
        _, _, _, linv, q, mq, denom = fac
        v = linv.T @ (linv @ r)
        return v - mq * (q @ v) / denom

    def newton_once(fac, f, rp):
        hf = h_inv(fac, f)
        dy = normal_solve(fac, rp - a_mul(hf))
        return h_inv(fac, f + a_tmul(dy)), dy

    def newton(fac, dd, f, rp):
        # [H, -A^T; A, 0] (dx, dy) = (f, rp), refined: the normal matrix weighs a free column
        # (a rigid link's force) 1 / REG_PRIMAL times more than a bounded one, and its Cholesky
        # factor is off by as much in the other directions; each pass divides that error by as much.
        def refine(_, d):  # pass 0 from zero: the plain solve
            dx, dy = d
            hx = g_tmul(dd * g_mul(dx)) + REG_PRIMAL * dx
            ex, ey = newton_once(fac, f - hx + a_tmul(dy), rp - a_mul(dx))
            return dx + ex, dy + ey

        return lax.fori_loop(0, 1 + REFINEMENTS, refine, (jnp.zeros(n), jnp.zeros(m)))

    def direction(fac, dd, w, z, rp, rg, rd, rc):
        f = -rd - g_tmul(mask * (rc / w - dd * rg))
        dx, dy = newton(fac, dd, f, rp)
        dz = mask * (dd * (g_mul(dx) - rg) + rc / w)
        dw = mask * (rc - w * dz) / z
        return dx, dy, dw, dz

    def longest(v, dv):
        ratio = jnp.where((dv < 0) & (mask > 0), -v / jnp.where(dv < 0, dv, -1.0), jnp.inf)
        return jnp.minimum(1.0, ratio.min())

    def residuals(st):
        rp = bs - a_mul(st.x)
        rg = mask * (hs - g_mul(st.x) - st.w)
        rd = cs - a_tmul(st.y) + g_tmul(mask * st.z)
        return rp, rg, rd

    def converged(st):  # in the original units (x = beta_b Dc x~, y = beta_c Dr y~, z = beta_c Dg z~)
        rp, _, rd = residuals(st)
        primal = jnp.maximum(jnp.abs(rp / dr).max(), (mask * jnp.maximum(g_mul(st.x) - hs, 0) / dg).max()) * beta_b
        dual = jnp.abs(rd / dc).max() * beta_c
        pobj = cs @ st.x
        dobj = bs @ st.y - (mask * hs * st.z).sum()
        gap = jnp.abs(pobj - dobj) * beta_b * beta_c
        return (
            (primal <= tol * (1 + jnp.abs(b).max()))
            & (dual <= tol * (1 + jnp.abs(c).max()))
            & (gap <= tol * (1 + jnp.abs(pobj * beta_b * beta_c)))
        )

    def step(st):
        dd = mask * st.z / st.w
        fac = factor(dd)
        rp, rg, rd = residuals(st)
        wz = mask * st.w * st.z
        mu = wz.sum() / count

        # Pass 0, the predictor: the affine-scaling direction (complementarity driven to zero).
        # Pass 1, the corrector: centred towards (mu_aff / mu)^3 mu, with the predictor's
        # second-order term. One loop, so that the solve is compiled once.
        def predict_correct(i, d):
            _, _, dwa, dza = d
            ap, ad = longest(st.w, dwa), longest(st.z, dza)
            mu_aff = (mask * (st.w + ap * dwa) * (st.z + ad * dza)).sum() / count
            rc = jnp.where(i == 0, -wz, mask * ((mu_aff / mu) ** 3 * mu - wz - dwa * dza))
            return direction(fac, dd, st.w, st.z, rp, rg, rd, rc)

        zero = (jnp.zeros(n), jnp.zeros(m), jnp.zeros_like(st.w), jnp.zeros_like(st.w))
        dx, dy, dw, dz = lax.fori_loop(0, 2, predict_correct, zero)
        ap = STEP_TO_BOUNDARY * longest(st.w, dw)
        ad = STEP_TO_BOUNDARY * longest(st.z, dz)
        new = _State(st.x + ap * dx, st.y + ad * dy, jnp.where(mask > 0, st.w + ap * dw, 1.0),
                     jnp.where(mask > 0, st.z + ad * dz, 1.0), st.k + 1, st.status)
        finite = jnp.all(jnp.isfinite(new.x)) & jnp.all(jnp.isfinite(new.y)) & jnp.all(jnp.isfinite(new.z))
        done = finite & converged(new)
        status = jnp.where(done, _OPTIMAL, jnp.where(~finite | (new.k >= max_iterations), _ERROR, _RUNNING))
        new = new._replace(status=status.astype(jnp.int32))
        return jax.tree.map(lambda a, b: jnp.where(finite, a, b), new, st._replace(status=new.status))

    # Start (Mehrotra's heuristic): x the least-squares fit of the one-sided rows subject to the
    # equalities (the Newton system with D = 1), slacks and multipliers shifted positive.
    fac = factor(mask)
    x0, _ = newton(fac, mask, g_tmul(mask * hs), bs)
    w0 = jnp.where(mask > 0, hs - g_mul(x0), jnp.inf)
    z0 = jnp.where(mask > 0, 1.0, jnp.inf)
    w0 = w0 + jnp.maximum(-1.5 * w0.min(), 0.0)
    w0, z0 = jnp.where(mask > 0, w0, 0.0), jnp.where(mask > 0, z0, 0.0)
    wz = (w0 * z0).sum()
    w0 = w0 + 0.5 * wz / jnp.maximum(z0.sum(), 1e-300)
    z0 = z0 + 0.5 * wz / jnp.maximum(w0.sum(), 1e-300)
    w0 = jnp.where(mask > 0, jnp.maximum(w0, 1e-8), 1.0)
    z0 = jnp.where(mask > 0, jnp.maximum(z0, 1e-8), 1.0)
    st = _State(x0, jnp.zeros(m), w0, z0, jnp.zeros((), jnp.int32), jnp.full((), _RUNNING, jnp.int32))
    st = st._replace(status=jnp.where(converged(st), _OPTIMAL, _RUNNING).astype(jnp.int32))
    st = lax.while_loop(lambda s: s.status == _RUNNING, step, st)
    return st.x * dc * beta_b, st.status, st.k


_SOLVE = jax.jit(jax.vmap(_solve_one, in_axes=(0,) * 9 + (None, None)))
_ARRAYS = ("c", "b", "a_rows", "a_vals", "coef", "link", "rhs", "mask", "link_col")


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


# --- Load programs written straight into the solver's arrays -------------------------------------


def _n_vars(model: LoadModel) -> int:
    return layout(model)["link"].stop


def _load_bucket(model: LoadModel) -> tuple[int, int, int, int]:
    w = 12 if len(model.conn_a) or len(model.link_a) else 6  # entries per column: two bodies or one
    return _cols(_n_vars(model)), _rows(6 * model.n_bodies), _quarter(w, 1), 2


def _load_arrays(models: Sequence[LoadModel], cfg: LoadConfig, batch: int, n: int, m: int, w: int,
                 k: int) -> dict[str, np.ndarray]:
    """`_stack` of the load programs `statics.to_lp` writes, built from the models directly and
    for all of them at once (array operations over every connection of the launch, no program
    per model), from the same columns (`statics.connection_columns`, ...): the same rows and
    columns as `to_lp` then `_parts` give, except that zero entries are kept (they change
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
        for j, (f, p, mom) in enumerate(link_columns(cat("link_pos"))):  # free: no rows
            put(owner, base + j, lb, 1.0, f, p, mom, 0)
            put(owner, base + j, la, -1.0, f, p, mom, 6)
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


def _run(arrays: dict, tol: float, max_iterations: int) -> tuple[np.ndarray, np.ndarray]:
    """(x, status) of one launch."""
    x, status, _ = _launch(arrays, tol, max_iterations)
    return np.asarray(x), np.asarray(status)


def _launch(arrays: dict, tol: float, max_iterations: int):
    """`_SOLVE` of one launch's arrays, through its export (`jax_export`: a shape this process has
    not met is not traced again)."""
    return jax_export.call("lp", _SOLVE, *(arrays[k] for k in _ARRAYS), np.float64(tol), np.int32(max_iterations),
                           source=__file__)


def _optimal(xi: np.ndarray, ground: slice) -> LPResult:
    """A load program's result from its x in `layout` order (`ground`: the supports' columns);
    s and the ground forces are >= 0 to tol: made exact."""
    xi = xi.copy()
    xi[0] = max(xi[0], 0.0)
    xi[ground] = np.maximum(xi[ground], 0.0)
    return LPResult("optimal", xi, float(xi[0]))


def _fallback(results: list[LPResult], program, fallback: bool) -> list[LPResult]:
    """Members that did not converge, solved by HiGHS (`program(i)`: the i-th `LinearProgram`)."""
    if fallback:
        for i, r in enumerate(results):
            if r.status != "optimal":
                FALLBACKS[0] += 1
                results[i] = solve_highs(program(i))
    return results


def solve_loads(models: Sequence[LoadModel], cfg: LoadConfig | None = None, *, tol: float = 1e-8,
                max_iterations: int = MAX_ITERATIONS, fallback: bool = True) -> list[LPResult]:
    """The load program of each `statics.LoadModel` (as `statics.to_lp` writes it), all at once on
    the default JAX device, written straight into the solver's arrays (`_load_arrays`); results as
    `solve_batch` gives them for `to_lp`'s programs (x in `statics.layout`'s columns, objective s).
    A member that does not converge goes to HiGHS with `fallback` (`FALLBACKS` counts them)."""
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
    hit = getattr(base, "_lp_jax_block", None)
    if hit is None or hit[0] != cfg:
        alone = base.alone()
        arrays = _load_arrays([alone], cfg, 1, _n_vars(alone), 6 * (base.n + 1), 12, 2)
        hit = (cfg, {key: arrays[key][0, 1:] for key in _ASSEMBLED})
        base._lp_jax_block = hit
    return hit[1]


_ASSEMBLED = ("a_rows", "a_vals", "coef", "link", "rhs", "mask")


def _own_model(base: LoadBase, unit, conns, cfg: LoadConfig) -> LoadModel:
    """The model of a one-part unit's own columns on `base`: its connections and ground supports
    alone, the structure's bodies kept (for their rows and centres of mass)."""
    m, c, _ = part_mass_properties(unit[0].part)
    pts = support_points(unit[0], base.floor_y, cfg)
    ca, cb, cp, cx = _connection_arrays(conns)
    return LoadModel(parts=None, mass=np.r_[base.mass, m], com=np.concatenate([base.com, unit[0].pose.apply(c)[None]]),
                     conn_a=ca, conn_b=cb, conn_pos=cp, conn_axis=cx,
                     ground_body=np.full(len(pts), base.n, np.int64), ground_pos=pts,
                     link_a=np.zeros(0, np.int64), link_b=np.zeros(0, np.int64), link_pos=np.zeros((0, 3)))


def solve_on_base(base: LoadBase, units: Sequence, conns: Sequence, cfg: LoadConfig | None = None, *,
                  tol: float = 1e-8, max_iterations: int = MAX_ITERATIONS, fallback: bool = True) -> list[LPResult]:
    """The load program of each one-part unit on a `statics.LoadBase` whose parts form one
    component (`base.shared()`), as `solve_loads` of `base.model(unit, conns)` gives it (x in
    `statics.layout` order of that model): `solve_on_bases` of one base."""
    return solve_on_bases([(base, units, conns)], cfg, tol=tol, max_iterations=max_iterations, fallback=fallback)[0]


def solve_on_bases(groups: Sequence[tuple], cfg: LoadConfig | None = None, *, tol: float = 1e-8,
                   max_iterations: int = MAX_ITERATIONS, fallback: bool = True) -> list[list[LPResult]]:
    """`solve_on_base(base, units, conns)` of every group (each its own structure: objects grown in
    lockstep), in shared launches. Each structure's columns are written once (`_base_block`),
    each candidate's own columns (its connections and ground supports) per candidate, and the two
    are joined on the host; programs of every structure with the same equality rows' bucket run in
    one launch, padded to the largest of their variables (`_group`)."""
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


# --- Test problems and the benchmark ----------------------------------------------------------

_BRICKS = ((1, 1), (1, 2), (1, 4), (2, 2), (2, 3), (2, 4), (1, 6), (2, 6))


def statics_like_lp(rng: np.random.Generator, size: int) -> LinearProgram:
    """A load program of the form `statics.to_lp` writes (LDraw frame, y down; N, kg, LDU; moment
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
    in turn to fill the batch (`pipelines.bench_physics --lp`: real load models), else random ones
    of at least `size` variables (`statics_like_lp`)."""
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
