"""Small dense linear programs solved with HiGHS directly (``highspy``).

The force problems here have a handful of variables and rows, so ``scipy.optimize.linprog``'s
input checking dominates its cost (about 1.4 ms a solve); one reused HiGHS instance solves the same
problem in about 0.2 ms, and a problem whose only change is its equality right-hand side (the
wrench, step after step) warm-starts in about 0.05 ms. Building a HiGHS instance costs about
0.3 ms, so the solvers of LPs that are gone are kept in a pool and given to new ones (passing
a model clears a solver's basis: a pooled solver answers exactly as a new one).

    minimise c x  subject to  A_eq x = b_eq,  A_ub x <= b_ub,  lower <= x <= upper
"""

from __future__ import annotations

import itertools

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
        self._pooled = solver is None
        self.h = solver or (_POOL.pop() if _POOL else _new_solver())
        self.h.passModel(lp)  # also clears the solver's basis: a pooled one starts afresh

    def __del__(self) -> None:
        # building a HiGHS instance costs more than a solve (~0.3 ms): hand it to the next LP
        if getattr(self, "_pooled", False) and len(_POOL) < _POOL_SIZE:
            _POOL.append(self.h)

    def solve(self, b_eq: np.ndarray) -> np.ndarray | None:
        """The optimum for this right-hand side, or None when the LP is infeasible."""
        b = np.asarray(b_eq, float)
        self.h.changeRowsBounds(self.n_eq, self.eq_rows, b, b)
        self.h.run()
        if self.h.getModelStatus() != _OPTIMAL:
            return None
        return np.array(self.h.getSolution().col_value)


class VertexLP:
    """``SmallLP``'s problem solved by enumerating vertices, for a changing ``b_eq``.

    With ``A_eq`` of full row rank ``r``, ``x = P b + N z`` (``N``: an orthonormal basis of its
    null space, of dimension ``d`` = 1 or 2) turns the problem into one over ``z`` with ``p``
    inequalities ``C N z <= e - C P b``. The optimum of a pointed polyhedron is at a vertex,
    where ``d`` of them hold with equality: a solve finds every such point (``d`` = 2: each
    pair of rows, a 2 x 2 system in closed form), keeps those that satisfy all rows, and takes
    the cheapest; a few elementwise operations, about 30 us against 150 us for HiGHS, and
    building one costs about as much as a solve (no solver to set up).

    Only for problems whose feasible set has no line and whose cost is bounded below on it
    (the caller's guarantee; e.g. contact forces: normal forces bounded below, friction inside
    the cones, a cost that sums normal forces). ``VertexLP.fits`` says whether the sizes allow
    it; ``ok`` is False when ``A_eq`` has not full row rank. Where the optimum is a whole face,
    the answer is the mean of its vertices (optimal as well, and inside the face rather than at
    an end, where some constraint is tight), so a solve depends on ``b_eq`` alone, not on the
    solves before it.
    """

    TOL = 1e-7  # feasibility tolerance, HiGHS's default primal one
    _PAIRS: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def __init__(self, c: np.ndarray, A_eq: np.ndarray, A_ub: np.ndarray | None,
                 b_ub: np.ndarray | None, lower: np.ndarray, upper: np.ndarray):
        A_eq = np.asarray(A_eq, float)
        r, n = A_eq.shape
        u, sv, vt = np.linalg.svd(A_eq)
        self.d = n - r
        self.ok = self.fits(A_eq) and bool(sv[-1] > 1e-10 * max(1.0, sv[0]))
        if not self.ok:
            return
        lower, upper = np.asarray(lower, float), np.asarray(upper, float)
        lo, hi = np.isfinite(lower), np.isfinite(upper)
        eye = np.eye(n)
        C = np.vstack([np.zeros((0, n)) if A_ub is None else np.asarray(A_ub, float),
                       -eye[lo], eye[hi]])
        self.e = np.concatenate([np.zeros(0) if b_ub is None else np.asarray(b_ub, float),
                                 -lower[lo], upper[hi]])
        self.P = (vt[:r].T / sv) @ u.T  # the pseudo-inverse: A_eq P = I
        self.N = vt[r:].T
        self.CP, CN = C @ self.P, C @ self.N
        self.cN = np.asarray(c, float) @ self.N
        p = len(C)
        if self.d == 1:
            self.rows = np.flatnonzero(np.abs(CN[:, 0]) > 1e-12)
            self.den = CN[self.rows, 0]
        else:
            if p not in self._PAIRS:
                pairs = np.array(list(itertools.combinations(range(p), 2)), dtype=np.intp)
                self._PAIRS[p] = (pairs[:, 0], pairs[:, 1]) if len(pairs) else (pairs, pairs)
            i, j = self._PAIRS[p]
            a, b, c2, d2 = CN[i, 0], CN[i, 1], CN[j, 0], CN[j, 1]
            det = a * d2 - b * c2
            keep = np.abs(det) > 1e-9 * (np.abs(a) + np.abs(b)) * (np.abs(c2) + np.abs(d2))
            self.i, self.j, self.det = i[keep], j[keep], det[keep]
            self.a, self.b, self.c2, self.d2 = a[keep], b[keep], c2[keep], d2[keep]
        self.CN0, self.CN1 = CN[:, :1], CN[:, 1:] if self.d == 2 else None
        self.ok = bool(len(self.rows) if self.d == 1 else len(self.i))

    @staticmethod
    def fits(A_eq: np.ndarray) -> bool:
        """Whether the dimension left after the equalities (1 or 2) allows vertex enumeration."""
        r, n = np.shape(A_eq)
        return 1 <= n - r <= 2

    def solve(self, b_eq: np.ndarray) -> np.ndarray | None:
        """The optimum for this right-hand side, or None when the LP is infeasible."""
        b = np.asarray(b_eq, float)
        rhs = self.e - self.CP @ b  # C N z <= rhs
        if self.d == 1:
            z = (rhs[self.rows] / self.den)[None, :]
            slack = rhs[:, None] - self.CN0 * z
        else:
            ri, rj = rhs[self.i], rhs[self.j]
            z = np.array([(self.d2 * ri - self.b * rj) / self.det,
                          (self.a * rj - self.c2 * ri) / self.det])
            slack = rhs[:, None] - self.CN0 * z[0] - self.CN1 * z[1]
        feasible = np.all(slack >= -self.TOL, axis=0)
        if not feasible.any():
            return None
        cost = np.where(feasible, self.cN @ z, np.inf)
        low = cost.min()
        tied = cost <= low + 1e-9 * (1.0 + abs(low))
        # the optimum may be a whole face (here often: which holding finger takes the
        # friction); its vertices' mean is optimal too and keeps off the cones' edges
        return self.P @ b + self.N @ z[:, tied].mean(axis=1)


def linprog(c: np.ndarray, A_eq: np.ndarray, b_eq: np.ndarray, A_ub: np.ndarray | None = None,
            b_ub: np.ndarray | None = None, lower: np.ndarray | None = None,
            upper: np.ndarray | None = None) -> np.ndarray | None:
    """Solve one LP; bounds default to free variables. None when infeasible or unbounded."""
    n = len(c)
    lower = np.full(n, -np.inf) if lower is None else np.asarray(lower, float)
    upper = np.full(n, np.inf) if upper is None else np.asarray(upper, float)
    return SmallLP(c, A_eq, A_ub, b_ub, lower, upper, _shared()).solve(b_eq)


_SHARED: list[highspy.Highs] = []
_POOL: list[highspy.Highs] = []  # solvers of LPs that are gone, for the next ``SmallLP``
_POOL_SIZE = 64


def _shared() -> highspy.Highs:
    """One solver per process for one-off problems (building a solver costs more than a solve)."""
    if not _SHARED:
        _SHARED.append(_new_solver())
    return _SHARED[0]
