"""The batched LP solver's kernel (`lp_jax`): a primal-dual interior-point method (Mehrotra's
predictor-corrector) in float64 for one LP in the structured form below, jitted and vmapped over a
launch's members (`_SOLVE`) and called through its export (`_launch`, `jax_export`: this file's
digest names the export).

It is built around the load programs' structure. It replaced restarted Halpern PDHG, which was
accurate but needed thousands of iterations (4,160 median, 17,024 max at ~1,000 variables), and a
launch waits for its slowest member; the interior-point method takes 7-14 on the same kind of
programs (the iteration cap, `lp_jax.MAX_ITERATIONS`, is a bound, not a budget).

- Form: minimise c x subject to A x = b (the balance rows: 6 per body) and one-sided rows
  coef_r x[j_r] + link_r x[L] <= rhs_r, each on one variable and the link column L: every
  inequality of `load_program.to_lp` is one force against s (tension per rim point, shear and torsion
  both ways, capacities scaled by s), and bounds are such rows without the link. Other
  inequality rows become an equality row and a new variable; fixed variables are substituted
  (`lp_jax._parts`).
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
  objective. A member not done in `max_iterations`, or not finite, is "error";
  `lp_jax.solve_batch` then gives it to HiGHS (`lp_jax.FALLBACKS` counts them; none on the test
  programs).

Every program of the load form is feasible once it does not tip (s can grow until every
connection is rigid), so infeasibility is not detected: such a program would end at the cap.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from factory.physics import jax_export
from factory.physics.jax_cache import enable as enable_compile_cache

enable_compile_cache()  # before this module's first compile

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

_RUNNING, _OPTIMAL, _ERROR = 0, 1, 2


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
"""The kernel's arguments per member, in order (`lp_jax._empty` writes them)."""


def _launch(arrays: dict, tol: float, max_iterations: int):
    """`_SOLVE` of one launch's arrays, through its export (`jax_export`: a shape this process has
    not met is not traced again)."""
    return jax_export.call("lp", _SOLVE, *(arrays[k] for k in _ARRAYS), np.float64(tol), np.int32(max_iterations),
                           source=__file__)
