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


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross products of (k, 3) arrays (``np.cross`` costs twice as much here)."""
    (a0, a1, a2), (b0, b1, b2) = a.T, b.T
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=1)


class VertexLP:
    """``SmallLP``'s problem solved by enumerating vertices, for a changing ``b_eq``.

    With ``A_eq`` of full row rank ``r``, ``x = P b + N z`` (``N``: an orthonormal basis of its
    null space, of dimension ``d`` <= 3) turns the problem into one over ``z`` with ``p``
    inequalities ``C N z <= e - C P b``. The optimum of a pointed polyhedron is at a vertex,
    where ``d`` of them hold with equality: each choice of ``d`` rows is a ``d x d`` system,
    inverted once in closed form (cross products), so a vertex is a weighted sum of its rows'
    right-hand sides. A solve computes every vertex, keeps those that satisfy all rows and
    takes the cheapest: a few elementwise operations (about 30 us against 150 us for a
    HiGHS solve), and building one costs about as much (no solver to set up).

    Only for problems whose feasible set has no line and whose cost is bounded below on it
    (the caller's guarantee; e.g. contact forces: normal forces bounded below, friction inside
    the cones, a cost that sums normal forces). ``VertexLP.fits`` says whether the sizes allow
    it; ``ok`` is False when ``A_eq`` has not full row rank. Where the optimum is a whole face,
    the answer is the mean of its vertices (optimal as well, and inside the face rather than at
    an end, where some constraint is tight), so a solve depends on ``b_eq`` alone, not on the
    solves before it.
    """

    TOL = 1e-7  # feasibility tolerance, HiGHS's default primal one
    MAX_DIM = 3
    _COMBOS: dict[tuple[int, int], np.ndarray] = {}
    _BOUNDS: dict[tuple[int, bytes, bytes], np.ndarray] = {}  # the bounds' rows of C, by pattern
    _PAIRS: dict[int, tuple] = {}  # by row count: pairs of rows, where each choice finds them

    def __init__(self, c: np.ndarray, A_eq: np.ndarray, A_ub: np.ndarray | None,
                 b_ub: np.ndarray | None, lower: np.ndarray, upper: np.ndarray):
        A_eq = np.asarray(A_eq, float)
        r, n = A_eq.shape
        self.ok = 1 <= n - r <= self.MAX_DIM  # ``fits``
        if not self.ok:
            return
        u, sv, vt = np.linalg.svd(A_eq)
        self.ok = bool(sv[-1] > 1e-10 * max(1.0, sv[0]))
        if not self.ok:
            return
        d = n - r
        lower, upper = np.asarray(lower, float), np.asarray(upper, float)
        lo, hi = np.isfinite(lower), np.isfinite(upper)
        C = self._bound_rows(n, lo, hi)  # -x <= -lower, x <= upper
        self.e = np.concatenate([np.zeros(0) if b_ub is None else np.asarray(b_ub, float),
                                 -lower[lo], upper[hi]])
        if A_ub is not None:
            C = np.vstack([np.asarray(A_ub, float), C])
        self.P = (vt[:r].T / sv) @ u.T  # the pseudo-inverse: A_eq P = I
        self.N = vt[r:].T
        self.CP, self.CN = C @ self.P, C @ self.N
        self.cN = np.asarray(c, float) @ self.N
        key = (len(C), d)
        if key not in self._COMBOS:
            self._COMBOS[key] = np.array(list(itertools.combinations(range(len(C)), d)),
                                         dtype=np.intp).reshape(-1, d)
        combos = self._COMBOS[key]
        X = self.CN[combos]  # (k, d, d): the rows of each choice
        if d == 1:
            det, cof = X[:, 0, 0], np.ones((len(combos), 1, 1))
        elif d == 2:
            # the inverse's columns: (d2, -c2) and (-b, a) of the rows (a, b), (c2, d2)
            det = X[:, 0, 0] * X[:, 1, 1] - X[:, 0, 1] * X[:, 1, 0]
            cof = X[:, ::-1, ::-1] * _SIGNS2
        else:
            cof = self._cofactors3(self.CN, combos)
            det = np.einsum("ij,ij->i", np.ascontiguousarray(X[:, 0]), cof[:, 0])
        S = np.abs(X).sum(axis=2)  # (k, d): each row's 1-norm
        scale = S[:, 0]
        for t in range(1, d):
            scale = scale * S[:, t]
        keep = np.abs(det) > 1e-9 * scale
        self.combos = combos[keep]
        # vertex of a choice = sum over its rows t of rhs[row t] * weights[:, t]
        self.weights = cof[keep] / det[keep, None, None]  # (k, d, d)
        self.ok = bool(keep.any())

    @classmethod
    def _bound_rows(cls, n: int, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """``-I[lo]`` over ``I[hi]`` (read-only, shared by the LPs of one bounds pattern)."""
        key = (n, lo.tobytes(), hi.tobytes())
        rows = cls._BOUNDS.get(key)
        if rows is None:
            eye = np.eye(n)
            rows = cls._BOUNDS[key] = np.vstack([-eye[lo], eye[hi]])
            rows.flags.writeable = False
        return rows

    @classmethod
    def _cofactors3(cls, rows: np.ndarray, combos: np.ndarray) -> np.ndarray:
        """``[r1 x r2, r2 x r0, r0 x r1]`` (k, 3, 3) for each choice ``(r0, r1, r2)`` of
        ``rows`` (``combos``: every choice of three, in order, as ``_COMBOS`` holds them, so
        the row count says which they are): the cross product of each pair of rows is
        computed once and shared by the choices holding it (a reversed pair is the same
        product negated, exactly)."""
        p = len(rows)
        index = cls._PAIRS.get(p)
        if index is None:
            a, b = np.triu_indices(p, 1)
            slot = np.zeros((p, p), dtype=np.intp)
            slot[a, b] = np.arange(len(a))
            c0, c1, c2 = combos.T  # increasing within a choice
            # the products r1 x r2 and r0 x r1 are pairs in order; r2 x r0 is -(r0 x r2)
            index = cls._PAIRS[p] = (a, b, np.stack([slot[c1, c2], slot[c0, c2],
                                                       slot[c0, c1]], axis=1))
        a, b, pick = index
        pairs = _cross(rows[a], rows[b])
        cof = pairs[pick]
        cof[:, 1] *= -1.0
        return cof

    @classmethod
    def fits(cls, A_eq: np.ndarray) -> bool:
        """Whether the dimension left after the equalities (1 to 3) allows vertex enumeration."""
        r, n = np.shape(A_eq)
        return 1 <= n - r <= cls.MAX_DIM

    def solve(self, b_eq: np.ndarray) -> np.ndarray | None:
        """The optimum for this right-hand side, or None when the LP is infeasible."""
        b = np.asarray(b_eq, float)
        rhs = self.e - self.CP @ b  # C N z <= rhs
        picked = rhs[self.combos]  # (k, d)
        W = self.weights
        z = picked[:, 0, None] * W[:, 0]
        for t in range(1, W.shape[1]):
            z = z + picked[:, t, None] * W[:, t]
        feasible = np.all(self.CN @ z.T - rhs[:, None] <= self.TOL, axis=0)
        if not feasible.any():
            return None
        cost = np.where(feasible, z @ self.cN, np.inf)
        low = cost.min()
        tied = np.flatnonzero(cost <= low + 1e-9 * (1.0 + abs(low)))
        # the optimum may be a whole face (here often: which holding finger takes the
        # friction); its vertices' mean is optimal too and keeps off the cones' edges
        best = z[tied[0]] if len(tied) == 1 else z[tied].mean(axis=0)
        return self.P @ b + self.N @ best


_SIGNS2 = np.array([[1.0, -1.0], [-1.0, 1.0]])  # signs of the 2 x 2 inverse's entries


def linprog(c: np.ndarray, A_eq: np.ndarray, b_eq: np.ndarray, A_ub: np.ndarray | None = None,
            b_ub: np.ndarray | None = None, lower: np.ndarray | None = None,
            upper: np.ndarray | None = None, pointed: bool = False) -> np.ndarray | None:
    """Solve one LP; bounds default to free variables. None when infeasible or unbounded.

    ``pointed``: the caller guarantees that the feasible set holds no line and that the cost is
    bounded below on it; the LP is then solved by ``VertexLP`` where its size allows.
    """
    n = len(c)
    lower = np.full(n, -np.inf) if lower is None else np.asarray(lower, float)
    upper = np.full(n, np.inf) if upper is None else np.asarray(upper, float)
    if pointed and VertexLP.fits(A_eq):
        lp = VertexLP(c, A_eq, A_ub, b_ub, lower, upper)
        if lp.ok:
            return lp.solve(b_eq)
    return SmallLP(c, A_eq, A_ub, b_ub, lower, upper, _shared()).solve(b_eq)


_SHARED: list[highspy.Highs] = []
_POOL: list[highspy.Highs] = []  # solvers of LPs that are gone, for the next ``SmallLP``
_POOL_SIZE = 64


def _shared() -> highspy.Highs:
    """One solver per process for one-off problems (building a solver costs more than a solve)."""
    if not _SHARED:
        _SHARED.append(_new_solver())
    return _SHARED[0]
