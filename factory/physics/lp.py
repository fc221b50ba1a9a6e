"""Linear programs as plain arrays, and the CPU reference solver (HiGHS through scipy).

The whole-structure load check (`statics.py`; `load_program.to_lp`) writes each structure's equilibrium as one
`LinearProgram`; the CPU path solves it here with HiGHS, and a batched solver on the GPU takes the
same arrays. Form:

    minimise    c @ x
    subject to  a_eq @ x == b_eq
                a_ub @ x <= b_ub
                lower <= x <= upper      (entries may be -inf / +inf)
"""

from __future__ import annotations

from dataclasses import dataclass

import warnings

import numpy as np
import scipy.sparse as sp
from scipy.optimize import OptimizeWarning, linprog

try:  # scipy's private HiGHS binding: a scipy laid out otherwise solves through `linprog` only
    import scipy.optimize._highspy._core as _CORE
except ImportError:
    _CORE = None

STATUSES = ("optimal", "infeasible", "unbounded", "error")


@dataclass(frozen=True, eq=False)
class LinearProgram:
    """One LP in the module's form; matrices are scipy CSR."""

    c: np.ndarray
    a_eq: sp.csr_matrix
    b_eq: np.ndarray
    a_ub: sp.csr_matrix
    b_ub: np.ndarray
    lower: np.ndarray
    upper: np.ndarray

    @property
    def n(self) -> int:
        return len(self.c)

    def residuals(self, x: np.ndarray) -> tuple[float, float, float]:
        """Largest violation of the equalities, the inequalities and the bounds at x."""
        eq = float(np.abs(self.a_eq @ x - self.b_eq).max(initial=0.0))
        ub = float(np.maximum(self.a_ub @ x - self.b_ub, 0).max(initial=0.0))
        bd = float(np.maximum(np.maximum(self.lower - x, x - self.upper), 0).max(initial=0.0))
        return eq, ub, bd


@dataclass(frozen=True)
class LPResult:
    status: str
    """One of `STATUSES`."""
    x: np.ndarray | None
    objective: float


HIGHS_OPTIONS = {"simplex_strategy": 4}
"""HiGHS's primal simplex (after presolve): on the 77 load programs of one 70-step sampled object
(17 to 2,100 variables) it took 2.14 s against 2.59 s for HiGHS's default dual simplex, 13,439
iterations against 15,784, objectives the same to 4e-15 (this repository's 2-core CPU)."""


def solve_highs(lp: LinearProgram) -> LPResult:
    """Solve with HiGHS (`HIGHS_OPTIONS`): the reference the batched solver is measured against."""
    with warnings.catch_warnings():  # scipy passes options it does not list through, warning each time
        warnings.filterwarnings("ignore", "Unrecognized options detected", OptimizeWarning)
        res = _linprog(lp)
    status = {0: "optimal", 2: "infeasible", 3: "unbounded"}.get(res.status, "error")
    if status != "optimal":
        return LPResult(status, None, float("nan"))
    return LPResult(status, np.asarray(res.x), float(res.fun))


@dataclass(frozen=True, eq=False)
class Basis:
    """A simplex basis of one program: HiGHS's status of each column and of each row (the rows of
    `a_ub`, then those of `a_eq`), as lists of `HighsBasisStatus`."""

    cols: list
    rows: list


RESIDUAL_TOL = 1e-7
"""Largest violation of a constraint or bound in a solution `solve_highs_from` keeps; one further
off is solved again by `solve_highs` (scipy checks its answers alike, and reports such a solution
as a failure)."""


HIGHS = _CORE if hasattr(_CORE, "_Highs") and hasattr(_CORE, "HighsBasis") else None
"""scipy's own HiGHS binding (the one `linprog` runs), None where this scipy lacks it."""

BASIS_STATUS = getattr(HIGHS, "HighsBasisStatus", None)
"""HiGHS's basis statuses (kBasic, kLower, kUpper, kZero, kNonbasic); None without the binding."""


def solve_highs_from(lp: LinearProgram, start: Basis | None = None) -> tuple[LPResult, Basis | None, int]:
    """`solve_highs`, started from `start` (a basis of this program's columns and rows) when given,
    and returning the final basis and the simplex iterations. The same HiGHS and options as
    `solve_highs`: without a start its solution is that of `solve_highs`, bit for bit. Without the
    binding, a start HiGHS refuses, a non-optimal status or a solution off its constraints by more
    than `RESIDUAL_TOL`, it is `solve_highs`'s answer with no basis (-1 iterations)."""
    solved = _run_highs(lp, start) if HIGHS is not None else None
    return solved if solved is not None else (solve_highs(lp), None, -1)


def _run_highs(lp: LinearProgram, start: Basis | None) -> tuple[LPResult, Basis, int] | None:
    a = (sp.vstack([lp.a_ub, lp.a_eq]) if lp.a_ub.shape[0] else lp.a_eq).tocsc()
    m, n = a.shape
    highs = HIGHS._Highs()
    highs.setOptionValue("output_flag", False)
    for key, value in HIGHS_OPTIONS.items():
        highs.setOptionValue(key, value)
    error = HIGHS.HighsStatus.kError  # (a warning, such as infinite bounds noted, is not one: as in scipy)
    # The model as arrays (every column continuous): HiGHS reads them in place, where a `HighsLp`'s
    # fields are filled element by element (3.7 of 9.6 ms of a 2,105-column program's solve).
    if highs.passModel(n, m, a.nnz, int(HIGHS.MatrixFormat.kColwise), int(HIGHS.ObjSense.kMinimize), 0.0,
                       lp.c, lp.lower, lp.upper, np.concatenate([np.full(lp.a_ub.shape[0], -np.inf), lp.b_eq]),
                       np.concatenate([lp.b_ub, lp.b_eq]), a.indptr[:-1].astype(np.int32),
                       a.indices.astype(np.int32), a.data, np.zeros(n, np.int32)) == error:
        return None
    if start is not None:
        basis = HIGHS.HighsBasis()
        basis.col_status, basis.row_status, basis.valid = start.cols, start.rows, True
        if highs.setBasis(basis) == error:
            return None
    highs.run()
    if highs.getModelStatus() != HIGHS.HighsModelStatus.kOptimal:
        return None
    x = np.array(highs.getSolution().col_value)
    if max(lp.residuals(x)) > RESIDUAL_TOL:
        return None
    final = highs.getBasis()
    return (LPResult("optimal", x, float(highs.getInfo().objective_function_value)),
            Basis(final.col_status, final.row_status), int(highs.getInfo().simplex_iteration_count))


def _linprog(lp: LinearProgram):
    return linprog(
        lp.c,
        A_ub=lp.a_ub if lp.a_ub.shape[0] else None,
        b_ub=lp.b_ub if lp.a_ub.shape[0] else None,
        A_eq=lp.a_eq if lp.a_eq.shape[0] else None,
        b_eq=lp.b_eq if lp.a_eq.shape[0] else None,
        bounds=np.column_stack([lp.lower, lp.upper]),
        method="highs",
        options=HIGHS_OPTIONS,
    )


def empty_rows(n: int) -> sp.csr_matrix:
    return sp.csr_matrix((0, n))
