"""Batched linear programs in JAX: thousands of `LinearProgram`s in one jitted, vmapped call.

Why: the whole-structure load check (`statics`) writes one LP per candidate structure (each part's
force and moment balance, stud and ground forces, minimise the largest utilisation s; the structure
holds when s <= 1), and the sampler judges thousands of candidates per call on a GPU. HiGHS
(`lp.solve_highs`) solves one LP at a time on the CPU; here all LPs of a call advance together on
the default JAX device, and their answers agree with HiGHS (tests/test_lp_jax.py).

Method: restarted Halpern PDHG with reflection (cuPDLPx: Lu, Peng & Yang 2025, after PDLP:
Applegate et al. 2021), with one change for these programs: the equality rows are not dualised but
kept exactly, the primal step projecting onto {A x = b}. PDLP's form (all rows dual, bounds
clipped) was tried first and was too slow on the load programs: their equilibrium rows are badly
conditioned (the whole structure's horizontal translation is resisted only by ground friction;
after scaling, the smallest singular value of the equality block was 7e-4 of the largest for a
30-brick structure), and it took 4k-38k iterations on 10-brick structures and did not converge in
100k on any of 16 30-brick ones. Projecting takes that block out of the iteration: 1.1k-2.5k and
2.2k-4.4k iterations on the same programs (`pipelines.bench_physics` structures). So:

- the LP is split into A x = b (the equality rows) and G x >= h (the inequality rows negated, and
  one row per finite bound), and preconditioned on [A; G]: 10 Ruiz iterations, then Pock-Chambolle
  (alpha = 1), then objective and right-hand side divided by (1 + their 2-norms);
- the projection x -> x - A^T (A A^T)^-1 (A x - b) uses the dense inverse of the Gram matrix,
  formed once per LP on the device by Cholesky (equality rows that depend on earlier ones, found
  by a first factorisation, are left out of it);
- PDHG on (x, y) with y >= 0 the duals of G: x <- P(x - tau (c - G^T y)), y <- max(0, y + sigma
  (h - G (2 x' - x))); each step reflected (2 T(z) - z) and pulled towards the epoch's anchor
  (Halpern); constant step eta = 0.998 / ||G on the null space of A|| (power iteration; the
  Pock-Chambolle bound ||G|| <= 1 makes eta = 0.998 always safe, and a member whose longer step
  proves too long, its PDHG metric turning out indefinite or its iterates not finite, starts over
  with that one);
- restarts on the fixed-point residual ||z - T(z)|| in the PDHG metric (decay to 0.2; to 0.8 with
  no progress since the last check; an epoch over 0.36 of all iterations); the primal weight starts
  at ||c|| / ||q|| and moves at each restart towards the ratio of the distances y and x moved
  (PDLP's smoothing, 0.5), or falls tenfold where y did not move;
- termination every 64 iterations, in the original units: relative primal residual (equalities,
  inequalities, bounds), dual residual (the reduced costs left after the equality multipliers'
  least-squares fit) and duality gap all below `tol` (PDLP's relative criteria, 2-norms). A member
  that reaches `max_iterations`, or stays non-finite, returns "error", never an unverified optimum.
  Infeasible and unbounded programs are not detected: they end in "error" at the cap (the load
  check never writes them).

Layout: A is stored by columns with a fixed number of entries per column (ELL: a load program's
column touches the balance rows of at most two parts, 6 of them for the studs of bricks), so A x is
one scatter and A^T u one gather; G is one COO, G x and G^T y two scatters (`segment_sum`, not
marked sorted: on the H200 the sorted lowering of the vmapped scatter was 5-8 times slower). Dense
storage loses at these sizes: for 64 programs of ~1,000 variables (G 2,048 x 1,024, A 512 x 1,024)
one G x, G^T y, A x and A^T u took 115 ms dense against 4.6 ms sparse on this repository's
two-core CPU (float64); the dense Gram inverse's product took 4.3 ms.

Shapes: each LP falls in a bucket (variables, inequality rows and their nonzeros: powers of two;
equality rows: quarter steps of powers of two, since the Gram matrix grows with their square;
entries per column: a power of two), the LPs of one bucket run together, their count padded to a
quarter step of a power of two (at most 4,096 per launch), so a run compiles once per (bucket,
count) pair met (`COMPILES`), never per call; tolerance and iteration cap are traced values. Memory
per LP is dominated by the Gram inverse, 8 (equality rows)^2 bytes: 1.2 MB at 384 rows (a 60-part
structure), 3.3 MB at 640.

Speed, measured on `statics_like_lp` programs of ~1,000 variables (63 parts on average): 4,096 of
them on an H200 (JAX 0.11.2, 7 shape groups) took 70 s, 59 LPs/s, at 4.7 ms per iteration of all
groups; iterations had median 4,160, 90th percentile 7,040, maximum 17,024 (a launch runs until its
slowest member is done); all optimal, objectives within 4.7e-7 of HiGHS, which took 35 ms per LP on
one core of that machine. On this repository's two-core CPU, 64 of them took 50 s (1.3 LPs/s;
HiGHS: 17 ms per LP). `bench` measures it.

Precision: float64, switched on only inside the call (`jax.enable_x64` as a context manager, so the
global flag stays float32 for the rest of the project). float32 cannot work here: the Gram matrices
of the load programs have condition numbers near 2e6 (30 bricks), so a float32 projection is off in
the first digits of its weakest direction; and the tolerance 1e-7 is float32's epsilon.
"""

from __future__ import annotations

import time
from collections import Counter
from typing import NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp
from jax import lax

from factory.physics.lp import LinearProgram, LPResult, solve_highs

CHECK_EVERY = 64
"""Iterations between termination and restart checks; iteration counts are multiples of it."""
RUIZ_ITERATIONS = 10
POWER_ITERATIONS = 50
STEP = 0.998
RESTART_SUFFICIENT, RESTART_NECESSARY, RESTART_ARTIFICIAL = 0.2, 0.8, 0.36
PRIMAL_WEIGHT_SMOOTHING = 0.5
STALLED_DUAL = 10.0
"""The primal weight is divided by this after an epoch in which x moved and y did not."""
GRAM_RIDGE = 1e-14
DEPENDENT_PIVOT = 1e-10
"""An equality row whose Cholesky pivot (of the unit-diagonal Gram matrix) is below this depends on
the rows before it and is left out of the projection."""
MIN_BUCKET = 16
MAX_BATCH = 4096
"""LPs of one shape per launch; more run in chunks of this many."""

COMPILES: list[tuple[int, ...]] = []
"""(batch, variables, equality rows, inequality rows, equality entries per column, inequality
nonzeros) of every bucket compiled in this process."""

_RUNNING, _OPTIMAL, _ERROR = 0, 1, 2


# --- Padding and stacking (numpy) -------------------------------------------------------------


class _Parts(NamedTuple):
    """One LP split the way the solver uses it: minimise c x with the equalities A x = b and
    everything else as G x >= h (the inequalities negated, then one row per finite bound)."""

    c: np.ndarray
    a: sp.csc_matrix
    b: np.ndarray
    g: sp.csr_matrix
    h: np.ndarray


def _parts(lp: LinearProgram) -> _Parts:
    lo, up = np.flatnonzero(np.isfinite(lp.lower)), np.flatnonzero(np.isfinite(lp.upper))
    eye = sp.identity(lp.n, format="csr")
    g = sp.vstack([-lp.a_ub, eye[lo], -eye[up]], format="csr")
    g.sum_duplicates()
    a = sp.csc_matrix(lp.a_eq)
    a.sum_duplicates()
    h = np.r_[-lp.b_ub, lp.lower[lo], -lp.upper[up]]
    return _Parts(np.asarray(lp.c, float), a, np.asarray(lp.b_eq, float), g, h)


def _pow2(v: int, minimum: int = MIN_BUCKET) -> int:
    return max(minimum, 1 << max(v - 1, 0).bit_length())


def _quarter(v: int, minimum: int = MIN_BUCKET) -> int:
    """The next of 8, 10, 12, 14, 16, 20, 24, ... (at least `minimum`; exact below 8): quarter
    steps of powers of two, so padding adds at most a quarter."""
    if v <= minimum:
        return minimum
    step = 1 << max((v - 1).bit_length() - 3, 0)
    return -(-v // step) * step


def _bucket(p: _Parts) -> tuple[int, int, int, int, int]:
    per_column = int(np.diff(p.a.indptr).max(initial=0))
    return _pow2(p.a.shape[1]), _quarter(p.a.shape[0]), _pow2(p.g.shape[0]), _pow2(per_column, 1), _pow2(p.g.nnz)


def bucket_of(lp: LinearProgram) -> tuple[int, int, int, int, int]:
    """(variables, equality rows, inequality rows, equality entries per column, inequality
    nonzeros) of the padded shape `lp` is solved in."""
    return _bucket(_parts(lp))


def pad_stack(
    lps: Sequence[LinearProgram], batch: int, n: int, e: int, mg: int, w: int, nnz: int
) -> dict[str, np.ndarray]:
    """Stack LPs (at most `batch`, each within the bucket (n, e, mg, w, nnz)) into the arrays the
    solver takes: A by columns, `w` entries per column (row 0, value 0 where a column has fewer),
    G as COO. Padded variables and rows are empty, padded nonzeros are zeros, padded members are
    empty LPs, which converge at the first check."""
    return _stack([_parts(lp) for lp in lps], batch, n, e, mg, w, nnz)


def _stack(parts: Sequence[_Parts], batch: int, n: int, e: int, mg: int, w: int, nnz: int) -> dict[str, np.ndarray]:
    out = {
        "c": np.zeros((batch, n)), "b": np.zeros((batch, e)), "h": np.zeros((batch, mg)),
        "a_rows": np.zeros((batch, n, w), np.int32), "a_vals": np.zeros((batch, n, w)),
        "g_rows": np.zeros((batch, nnz), np.int32), "g_cols": np.zeros((batch, nnz), np.int32),
        "g_vals": np.zeros((batch, nnz)),
    }
    for i, p in enumerate(parts):
        out["c"][i, : len(p.c)] = p.c
        out["b"][i, : len(p.b)] = p.b
        out["h"][i, : len(p.h)] = p.h
        counts = np.diff(p.a.indptr)
        slot = np.arange(p.a.nnz) - np.repeat(p.a.indptr[:-1], counts)
        col = np.repeat(np.arange(len(counts)), counts)
        out["a_rows"][i, col, slot], out["a_vals"][i, col, slot] = p.a.indices, p.a.data
        coo, k = p.g.tocoo(), p.g.nnz
        out["g_rows"][i, :k], out["g_cols"][i, :k], out["g_vals"][i, :k] = coo.row, coo.col, coo.data
    return out


# --- The solver (JAX; one LP, vmapped over the batch) -----------------------------------------


class _State(NamedTuple):
    x: jax.Array  # current iterate and its products G x, G^T y
    y: jax.Array
    gx: jax.Array
    gty: jax.Array
    x0: jax.Array  # the epoch's anchor
    y0: jax.Array
    gx0: jax.Array
    gty0: jax.Array
    xh: jax.Array  # the last PDHG output T(z): the point that is checked and returned
    yh: jax.Array
    gxh: jax.Array
    gtyh: jax.Array
    r: jax.Array  # fixed-point residual of the last step, of the epoch's first, at the last check
    r0: jax.Array
    r_prev: jax.Array
    k: jax.Array  # iterations in this epoch, in all
    t: jax.Array
    omega: jax.Array  # primal weight
    eta: jax.Array  # step size
    indefinite: jax.Array  # the PDHG metric was seen negative: the step is too long
    status: jax.Array


def _inv_sqrt(v):
    """1/sqrt(v), and 1 where v is 0 or -inf (empty rows and columns keep their scale)."""
    ok = v > 0
    return jnp.where(ok, 1 / jnp.sqrt(jnp.where(ok, v, 1)), 1.0)


def _solve_one(c, b, h, a_rows, a_vals, g_rows, g_cols, g_vals, tol, max_iterations):
    n, e, mg = c.shape[0], b.shape[0], h.shape[0]
    a_flat = a_rows.reshape(-1)

    # The sparse products, for the matrices' values at any scaling (av, gv).
    def a_mul(av, x):  # A x: columns scattered into rows
        return jax.ops.segment_sum((av * x[:, None]).reshape(-1), a_flat, e)

    def a_tmul(av, u):  # A^T u: each column gathers its rows
        return (av * u[a_rows]).sum(axis=1)

    # G x and G^T y are scatters of one COO; not marked sorted: on an H200 the sorted lowering of
    # the vmapped scatter took 1.6 ms for 4,096 LPs, the plain one 0.2 ms.
    def g_mul(gv, x):
        return jax.ops.segment_sum(gv * x[g_cols], g_rows, mg)

    def g_tmul(gv, y):
        return jax.ops.segment_sum(gv * y[g_rows], g_cols, n)

    def scaled(d):
        dra, drg, dc = d
        return a_vals * dra[a_rows] * dc[:, None], g_vals * drg[g_rows] * dc[g_cols]

    # Preconditioning of [A; G] (Ruiz, then Pock-Chambolle): A~ = Dra A Dc, G~ = Drg G Dc.
    def rescale(d, reduce_rows, reduce_cols, combine):
        av, gv = (jnp.abs(v) for v in scaled(d))
        row_a = reduce_rows(av.reshape(-1), a_flat, e)
        row_g = reduce_rows(gv, g_rows, mg)
        col = combine(reduce_cols(av, axis=1), reduce_rows(gv, g_cols, n))
        return d[0] * _inv_sqrt(row_a), d[1] * _inv_sqrt(row_g), d[2] * _inv_sqrt(col)

    d = (jnp.ones(e), jnp.ones(mg), jnp.ones(n))
    d = lax.fori_loop(0, RUIZ_ITERATIONS, lambda _, d: rescale(d, jax.ops.segment_max, jnp.max, jnp.maximum), d)
    d = rescale(d, jax.ops.segment_sum, jnp.sum, jnp.add)
    dra, drg, dc = d
    av, gv = scaled(d)
    beta_c = jnp.linalg.norm(c * dc) + 1
    beta_b = jnp.sqrt(jnp.sum((b * dra) ** 2) + jnp.sum((h * drg) ** 2)) + 1
    cs, bs, hs = c * dc / beta_c, b * dra / beta_b, h * drg / beta_b
    # PDLP's first primal weight, ||c|| / ||q||: in the load programs c is far smaller than q after
    # scaling (c is the column of s, which every inequality row holds), and a weight of 1 made the
    # primal steps so short that x crept for thousands of iterations with no constraint active.
    nc, nq = jnp.linalg.norm(cs), jnp.sqrt(bs @ bs + hs @ hs)
    omega_start = jnp.where((nc > 0) & (nq > 0), nc / jnp.where(nq > 0, nq, 1), 1.0)

    # The projection onto {A~ x = b~}: v - A~^T (A~ A~^T)^+ (A~ v - b~), the (pseudo-)inverse formed
    # once. Rows that depend on earlier ones (numerically) are dropped from it: a first Cholesky
    # factorisation of the unit-diagonal Gram matrix, with a ridge so that it completes, finds them
    # by their vanishing pivots; the inverse then comes from the rest, unridged (a ridge left in
    # costs accuracy in the weakest direction, and the load programs' Gram matrices have condition
    # numbers near 1e6). Empty rows (padding) are kept with a unit diagonal: they change nothing.
    pair = (a_rows[:, :, None] * e + a_rows[:, None, :]).reshape(-1)
    gram = jax.ops.segment_sum((av[:, :, None] * av[:, None, :]).reshape(-1), pair, e * e).reshape(e, e)
    gram = gram + jnp.diag(jnp.where(jnp.diag(gram) > 0, 0.0, 1.0))
    unit = 1 / jnp.sqrt(jnp.diag(gram))
    gram = gram * unit[:, None] * unit[None, :]
    eye = jnp.eye(e)
    pivots = jnp.diag(jnp.linalg.cholesky(gram + GRAM_RIDGE * eye)) ** 2
    keep = pivots > DEPENDENT_PIVOT
    both = keep[:, None] & keep[None, :]
    gram = jnp.where(both, gram, eye)
    gram_inv = jax.scipy.linalg.cho_solve(jax.scipy.linalg.cho_factor(gram, lower=True), eye)
    gram_inv = jnp.where(both, gram_inv, 0.0) * unit[:, None] * unit[None, :]

    def project(v, rhs):
        return v - a_tmul(av, gram_inv @ (a_mul(av, v) - rhs))

    # Step: Pock-Chambolle bounds ||G~|| by 1, so 0.998 is safe; power iteration finds the norm of
    # G~ on the null space of A~, a longer step.
    def power(_, p):
        w = project(g_tmul(gv, g_mul(gv, p)), 0.0)
        return w / jnp.maximum(jnp.linalg.norm(w), 1e-300)

    p = project(jnp.sin(jnp.arange(n) * 12.9898 + 1.0), 0.0)  # fixed, generic start
    p = lax.fori_loop(0, POWER_ITERATIONS, power, p / jnp.maximum(jnp.linalg.norm(p), 1e-300))
    norm_g = jnp.sqrt(jnp.linalg.norm(project(g_tmul(gv, g_mul(gv, p)), 0.0)))
    eta_long = jnp.where(norm_g > 0, STEP / norm_g, STEP)

    def start(eta, t):
        x = project(jnp.zeros(n), bs)
        y, gx = jnp.zeros(mg), g_mul(gv, x)
        zero = jnp.zeros(())
        return _State(
            x, y, gx, jnp.zeros(n), x, y, gx, jnp.zeros(n), x, y, gx, jnp.zeros(n),
            r=zero, r0=zero, r_prev=jnp.full((), jnp.inf), k=jnp.zeros((), jnp.int32), t=t,
            omega=omega_start, eta=eta, indefinite=jnp.zeros((), bool), status=jnp.full((), _RUNNING, jnp.int32),
        )

    # Termination, in the original units.
    q_norm = jnp.sqrt(jnp.sum(b**2) + jnp.sum(h**2))
    c_norm = jnp.linalg.norm(c)

    def converged(st):
        x = st.xh * dc * beta_b
        primal = jnp.concatenate([(a_mul(av, st.xh) - bs) / dra, jnp.minimum(st.gxh - hs, 0) / drg]) * beta_b
        # The equality multipliers: the least-squares fit of the reduced costs, as the projection.
        reduced = cs - st.gtyh
        mu = gram_inv @ a_mul(av, reduced)
        dual = (reduced - a_tmul(av, mu)) / dc * beta_c
        pobj = c @ x
        dobj = b @ (mu * dra * beta_c) + h @ (st.yh * drg * beta_c)
        return (
            (jnp.linalg.norm(primal) <= tol * (1 + q_norm))
            & (jnp.linalg.norm(dual) <= tol * (1 + c_norm))
            & (jnp.abs(pobj - dobj) <= tol * (1 + jnp.abs(pobj) + jnp.abs(dobj)))
        )

    def step(_, st):
        tau, sigma = st.eta / st.omega, st.eta * st.omega
        xh = project(st.x - tau * (cs - st.gty), bs)
        gxh = g_mul(gv, xh)
        yh = jnp.maximum(st.y + sigma * (hs - 2 * gxh + st.gx), 0)
        gtyh = g_tmul(gv, yh)
        # ||z - T(z)||^2 in the PDHG metric [[omega/eta, G^T], [G, 1/(eta omega)]].
        dx, dy = st.x - xh, st.y - yh
        square = st.omega / st.eta * (dx @ dx) + (dy @ dy) / (st.eta * st.omega)
        r2 = square + 2 * dy @ (st.gx - gxh)
        w = (st.k + 1) / (st.k + 2)

        def halpern(cur, hat, anchor):  # reflected step 2 T(z) - z, pulled towards the anchor
            return w * (2 * hat - cur) + (1 - w) * anchor

        r = jnp.sqrt(jnp.maximum(r2, 0))
        return st._replace(
            x=halpern(st.x, xh, st.x0), y=halpern(st.y, yh, st.y0),
            gx=halpern(st.gx, gxh, st.gx0), gty=halpern(st.gty, gtyh, st.gty0),
            xh=xh, yh=yh, gxh=gxh, gtyh=gtyh, r=r, r0=jnp.where(st.k == 0, r, st.r0), k=st.k + 1, t=st.t + 1,
            indefinite=st.indefinite | (r2 < -1e-9 * square),
        )

    def body(st):
        st = lax.fori_loop(0, CHECK_EVERY, step, st)
        finite = jnp.isfinite(st.r) & jnp.all(jnp.isfinite(st.xh)) & jnp.all(jnp.isfinite(st.yh))
        done = finite & converged(st)
        retry = ~done & (st.indefinite | ~finite) & (st.eta > STEP)
        failed = ~done & ~retry & (~finite | (st.t >= max_iterations))
        status = jnp.where(done, _OPTIMAL, jnp.where(failed, _ERROR, _RUNNING)).astype(jnp.int32)

        restart = (
            (st.r <= RESTART_SUFFICIENT * st.r0)
            | ((st.r <= RESTART_NECESSARY * st.r0) & (st.r > st.r_prev))
            | (st.k >= RESTART_ARTIFICIAL * st.t)
        )
        # Primal weight: balance the distances moved by x and y over the epoch. Where y did not move
        # (no constraint active) PDLP keeps the weight; there the primal step is too short, and
        # lengthening it tenfold per epoch reached the active constraints far sooner.
        dx, dy = jnp.linalg.norm(st.xh - st.x0), jnp.linalg.norm(st.yh - st.y0)
        moved = (dx > 1e-10) & (dy > 1e-10)
        log_ratio = jnp.log(jnp.where(moved, dy, 1)) - jnp.log(jnp.where(moved, dx, 1))
        smoothed = jnp.exp(PRIMAL_WEIGHT_SMOOTHING * log_ratio + (1 - PRIMAL_WEIGHT_SMOOTHING) * jnp.log(st.omega))
        omega = jnp.where(moved, smoothed, jnp.where(dx > 1e-10, st.omega / STALLED_DUAL, st.omega))

        def at_restart(new, old):
            return jnp.where(restart, new, old)

        st = st._replace(
            x=at_restart(st.xh, st.x), y=at_restart(st.yh, st.y),
            gx=at_restart(st.gxh, st.gx), gty=at_restart(st.gtyh, st.gty),
            x0=at_restart(st.xh, st.x0), y0=at_restart(st.yh, st.y0),
            gx0=at_restart(st.gxh, st.gx0), gty0=at_restart(st.gtyh, st.gty0),
            r_prev=at_restart(jnp.inf, st.r), k=at_restart(0, st.k).astype(jnp.int32),
            omega=at_restart(omega, st.omega), status=status,
        )
        # A step proven too long: start over with the step Pock-Chambolle guarantees.
        safe = start(jnp.full((), STEP), st.t)
        return jax.tree.map(lambda a, b: jnp.where(retry, a, b), safe, st)

    st = lax.while_loop(lambda s: s.status == _RUNNING, body, start(eta_long, jnp.zeros((), jnp.int32)))
    return st.xh * dc * beta_b, st.status, st.t


_SOLVE = jax.jit(jax.vmap(_solve_one, in_axes=(0,) * 8 + (None, None)))
_ARRAYS = ("c", "b", "h", "a_rows", "a_vals", "g_rows", "g_cols", "g_vals")


def solve_batch(lps: Sequence[LinearProgram], *, tol: float = 1e-7, max_iterations: int = 100_000) -> list[LPResult]:
    """Solve every LP on the default JAX device, the LPs of each shape bucket in one launch.
    Results come in the order given: "optimal" with x (clipped to its bounds) and c @ x, where the
    relative primal and dual residuals and the duality gap fell below `tol`; "error" (x None)
    where they did not within `max_iterations` (rounded up to a multiple of `CHECK_EVERY`)."""
    return _solve(lps, tol, max_iterations)[0]


def _solve(lps: Sequence[LinearProgram], tol: float, max_iterations: int) -> tuple[list[LPResult], np.ndarray]:
    """`solve_batch`, plus each LP's iteration count."""
    results: list[LPResult] = [LPResult("error", None, float("nan"))] * len(lps)
    iterations = np.zeros(len(lps), int)
    parts = [_parts(lp) for lp in lps]
    groups: dict[tuple[int, ...], list[int]] = {}
    for i, p in enumerate(parts):
        groups.setdefault(_bucket(p), []).append(i)
    with jax.enable_x64(True):
        for bucket, members in groups.items():
            for start in range(0, len(members), MAX_BATCH):
                chunk = members[start : start + MAX_BATCH]
                shape = (_quarter(len(chunk), 1), *bucket)
                if shape not in COMPILES:
                    COMPILES.append(shape)
                arrays = _stack([parts[i] for i in chunk], *shape)
                x, status, t = _SOLVE(*(arrays[k] for k in _ARRAYS), np.float64(tol), np.int32(max_iterations))
                x, status, t = np.asarray(x), np.asarray(status), np.asarray(t)
                for j, i in enumerate(chunk):
                    iterations[i] = t[j]
                    if status[j] == _OPTIMAL:
                        lp = lps[i]
                        xi = np.clip(x[j, : lp.n], lp.lower, lp.upper)  # bounds hold to tol; make them exact
                        results[i] = LPResult("optimal", xi, float(lp.c @ xi))
    return results, iterations


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


def bench(n_problems: int = 64, size: int = 960, seed: int = 0, tol: float = 1e-7) -> dict:
    """Solve `n_problems` random load programs of at least `size` variables (`statics_like_lp`)
    with HiGHS one at a time and with `solve_batch` in one call, after a first call that compiles
    (and runs 64 iterations); report the rates, iterations and the objectives' largest difference,
    |s - s_HiGHS| / max(1, |s_HiGHS|)."""
    rng = np.random.default_rng(seed)
    lps = [statics_like_lp(rng, size) for _ in range(n_problems)]
    t = time.perf_counter()
    reference = [solve_highs(lp) for lp in lps]
    highs_s = time.perf_counter() - t
    t = time.perf_counter()
    _solve(lps, tol, CHECK_EVERY)
    first_s = time.perf_counter() - t
    t = time.perf_counter()
    results, iterations = _solve(lps, tol, 100_000)
    solve_s = time.perf_counter() - t
    groups = Counter(bucket_of(lp) for lp in lps)
    solved = [(r.objective, h.objective) for r, h in zip(results, reference) if r.status == "optimal"]
    err = [abs(s - s_ref) / max(1.0, abs(s_ref)) for s, s_ref in solved]
    return {
        "problems": n_problems,
        "variables": round(float(np.mean([lp.n for lp in lps]))),
        "shapes": sorted((_quarter(min(k, MAX_BATCH), 1), *g) for g, k in groups.items()),
        "lps_per_s": round(n_problems / solve_s, 2),
        "solve_s": round(solve_s, 2),
        "first_call_s": round(first_s, 2),
        "iterations_median": int(np.median(iterations)),
        "iterations_p90": int(np.percentile(iterations, 90)),
        "iterations_max": int(iterations.max()),
        "not_optimal": sum(r.status != "optimal" for r in results),
        "max_objective_error": max(err, default=float("nan")),
        "highs_ms_per_lp": round(1e3 * highs_s / n_problems, 2),
    }
