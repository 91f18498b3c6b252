"""Small dense linear programs solved with HiGHS directly (``highspy``).

The force problems here have a handful of variables and rows, so ``scipy.optimize.linprog``'s
input checking dominates its cost (about 1.4 ms a solve); one reused HiGHS instance solves the same
problem in about 0.2 ms, and a problem whose only change is its equality right-hand side (the
wrench, step after step) warm-starts in about 0.05 ms.

    minimise c x  subject to  A_eq x = b_eq,  A_ub x <= b_ub,  lower <= x <= upper
"""

from __future__ import annotations

import highspy
import numpy as np

from inhand_exp.quiet import c_output_silenced

INF = highspy.kHighsInf
_OPTIMAL = highspy.HighsModelStatus.kOptimal


def _new_solver() -> highspy.Highs:
    with c_output_silenced():  # its banner, in every process
        h = highspy.Highs()
    h.setOptionValue("output_flag", False)
    h.setOptionValue("presolve", "off")  # tiny dense problems: presolve only costs time
    return h


class SmallLP:
    """One LP whose equality right-hand side may change between solves (warm-started)."""

    def __init__(self, c: np.ndarray, A_eq: np.ndarray, A_ub: np.ndarray | None,
                 b_ub: np.ndarray | None, lower: np.ndarray, upper: np.ndarray,
                 solver: highspy.Highs | None = None):
        n = len(c)
        A_ub = np.zeros((0, n)) if A_ub is None else np.asarray(A_ub, float)
        b_ub = np.zeros(0) if b_ub is None else np.asarray(b_ub, float)
        A = np.vstack([np.asarray(A_eq, float), A_ub])
        self.n_eq = len(A_eq)
        self.eq_rows = np.arange(self.n_eq, dtype=np.int32)
        lp = highspy.HighsLp()
        lp.num_col_, lp.num_row_ = n, len(A)
        lp.col_cost_ = np.asarray(c, float)
        lp.col_lower_ = np.where(np.isfinite(lower), lower, -INF)
        lp.col_upper_ = np.where(np.isfinite(upper), upper, INF)
        lp.row_lower_ = np.concatenate([np.zeros(self.n_eq), np.full(len(b_ub), -INF)])
        lp.row_upper_ = np.concatenate([np.zeros(self.n_eq), b_ub])
        rows, cols = np.nonzero(A)
        lp.a_matrix_.format_ = highspy.MatrixFormat.kRowwise
        lp.a_matrix_.start_ = np.searchsorted(rows, np.arange(len(A) + 1)).astype(np.int32)
        lp.a_matrix_.index_ = cols.astype(np.int32)
        lp.a_matrix_.value_ = A[rows, cols]
        self.h = solver or _new_solver()
        self.h.passModel(lp)

    def solve(self, b_eq: np.ndarray) -> np.ndarray | None:
        """The optimum for this right-hand side, or None when the LP is infeasible."""
        b = np.asarray(b_eq, float)
        self.h.changeRowsBounds(self.n_eq, self.eq_rows, b, b)
        self.h.run()
        if self.h.getModelStatus() != _OPTIMAL:
            return None
        return np.array(self.h.getSolution().col_value)


def linprog(c: np.ndarray, A_eq: np.ndarray, b_eq: np.ndarray, A_ub: np.ndarray | None = None,
            b_ub: np.ndarray | None = None, lower: np.ndarray | None = None,
            upper: np.ndarray | None = None) -> np.ndarray | None:
    """Solve one LP; bounds default to free variables. None when infeasible or unbounded."""
    n = len(c)
    lower = np.full(n, -np.inf) if lower is None else np.asarray(lower, float)
    upper = np.full(n, np.inf) if upper is None else np.asarray(upper, float)
    return SmallLP(c, A_eq, A_ub, b_ub, lower, upper, _shared()).solve(b_eq)


_SHARED: list[highspy.Highs] = []


def _shared() -> highspy.Highs:
    """One solver per process for one-off problems (building a solver costs more than a solve)."""
    if not _SHARED:
        _SHARED.append(_new_solver())
    return _SHARED[0]
