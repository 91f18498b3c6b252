"""Contact-force distribution (paper eq. 2-4): balance the object wrench inside the friction cones.

``lam`` stacks ``(f_n, f_t)`` per contact (N), as in ``grasp.grasp_matrix``. Two solvers:

- ``solve_lp``: the exact linear program ``G lam = w``, ``f_n >= f_min``, ``|f_t| <= mu f_n``,
  ``f_n <= f_max``, least total squeeze; ``None`` when infeasible (HiGHS, about 0.2 ms): used
  for feasibility checks and as the reference in tests.
- ``Squeeze``: for one contact configuration (``G`` constant in the object frame), the internal
  force ``lam0`` in the null space of ``G`` that lies deepest inside all cones, found once by an
  LP. Each control step then takes ``lam = pinv(G) w + alpha lam0`` with the least ``alpha`` that
  satisfies every constraint: a one-dimensional LP with a closed-form answer, cheap enough for
  the torque loop. Where no strict squeeze exists (e.g. two fingers on one side and a third
  that only slides), each step solves the full LP for its wrench instead, which may still be
  feasible thanks to gravity; infeasible when that LP is. A plan may also ask for the LP at
  every step with its own cost (a sliding finger that should press as lightly as it can: its
  kinetic friction grows with its normal force, so it must not join the squeeze).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from inhand_exp.control.lp import SmallLP, VertexLP, linprog

MARGIN = 1e-9  # least slack (N per N of total squeeze) of a strict squeeze


def _cone_rows(k: int, mu: float) -> np.ndarray:
    """Rows ``A`` with ``A lam <= 0`` meaning ``|f_t| <= mu f_n`` for each of ``k`` contacts."""
    A = np.zeros((2 * k, 2 * k))
    for i in range(k):
        A[2 * i, 2 * i], A[2 * i, 2 * i + 1] = -mu, 1.0
        A[2 * i + 1, 2 * i], A[2 * i + 1, 2 * i + 1] = -mu, -1.0
    return A


def solve_lp(G: np.ndarray, w: np.ndarray, mu: float, f_min: float,
             f_max: float = np.inf) -> np.ndarray | None:
    """Contact forces with ``G lam = w`` inside the cones and bounds, least total normal force."""
    k = G.shape[1] // 2
    return linprog(np.tile([1.0, 0.0], k), G, w, _cone_rows(k, mu), np.zeros(2 * k),
                   np.tile([f_min, -np.inf], k), np.tile([f_max, np.inf], k),
                   pointed=f_min >= 0)  # normal forces bounded below, friction in the cones


def _deepest_squeeze(Gr: np.ndarray, fn: np.ndarray, fric: np.ndarray, mu: float
                     ) -> tuple[np.ndarray, float]:
    """The internal force (``Gr lam0 = 0``, sum f_n = 1) deepest inside the cones, and its
    least slack: maximise s with f_n >= s and mu f_n -+ f_t >= s (one LP)."""
    m = Gr.shape[1]
    rows = []
    for a, b in fric:
        for sign in (1.0, -1.0):
            r = np.zeros(m + 1)
            r[a], r[b], r[m] = -mu, sign, 1.0
            rows.append(r)
    for a in fn:
        r = np.zeros(m + 1)
        r[a], r[m] = -1.0, 1.0
        rows.append(r)
    A_eq = np.zeros((4, m + 1))
    A_eq[:3, :m] = Gr
    A_eq[3, fn] = 1.0
    cost = np.zeros(m + 1)
    cost[m] = -1.0
    upper = np.full(m + 1, np.inf)
    upper[m] = 1.0
    # pointed: every force has a row bounding it by s, and s <= 1 bounds the cost -s
    x = linprog(cost, A_eq, np.array([0.0, 0.0, 0.0, 1.0]), np.array(rows),
                np.zeros(len(rows)), np.full(m + 1, -np.inf), upper, pointed=True)
    return (x[:m], float(x[m])) if x is not None else (np.zeros(m), 0.0)


def squeeze_margin(G: np.ndarray, mu: float) -> float:
    """The least slack, per newton of total squeeze, of the internal force deepest inside the
    cones (``Squeeze.margin`` of a grasp whose every contact may squeeze; 0 when none is
    strictly inside)."""
    k = G.shape[1] // 2
    return _deepest_squeeze(G, np.arange(0, 2 * k, 2), np.arange(2 * k).reshape(-1, 2), mu)[1]


def has_strict_squeeze(G: np.ndarray, mu: float, least: float = MARGIN) -> bool:
    """True when an internal force lies strictly inside every friction cone (what
    ``Squeeze.build(G, mu, ...).usable`` says, without building the rest of the plan), with a
    slack of more than ``least`` (its ``margin``)."""
    return squeeze_margin(G, mu) > max(least, MARGIN)


def strict_span(G0: np.ndarray, col: int, k: float, mu: float, bound: float,
                least: float = 0.0) -> tuple[float, float] | None:
    """Where along its face one contact may sit for a strict squeeze to be possible.

    The contact whose normal force is column ``col`` of ``G0`` moves along a straight face: at
    coordinate ``c`` the grasp matrix is ``G0`` with ``c k`` added to that column's moment entry
    (``k``: the face direction crossed with the normal). A strict squeeze at ``c`` scales to
    forces inside the closed cones with that normal force 1 and ``G(c) lam = 0``, so
    ``c = -(G0 lam)_tau / k``, linear in ``lam``: two LPs bound it. Outside ``(lo, hi)`` (both
    clipped to +-``bound``) no strict squeeze exists; None: none anywhere.

    ``least``: bound instead the places where the deepest squeeze has a slack of at least
    ``least`` per newton of total squeeze (``has_strict_squeeze``'s ``margin``): every slack
    ``f_n``, ``mu f_n -+ f_t`` at least ``least`` times the sum of the normal forces, which is
    linear in ``lam`` too.
    """
    m = G0.shape[1]
    coord = -G0[2] / k  # c as a function of the forces
    A_eq = np.vstack([G0[:2], np.eye(m)[col]])
    b_eq = np.array([0.0, 0.0, 1.0])
    cones = _cone_rows(m // 2, mu)
    if least > 0:
        total = np.tile([least, 0.0], m // 2)  # least times the sum of the normal forces
        cones = np.vstack([cones + total, -np.eye(m)[0::2] + total])
    A_ub = np.vstack([cones, coord, -coord])
    b_ub = np.concatenate([np.zeros(len(cones)), [bound, bound]])
    lower, upper = np.tile([0.0, -np.inf], m // 2), np.full(m, np.inf)
    ends = []
    for sign in (1.0, -1.0):
        lam = linprog(sign * coord, A_eq, b_eq, A_ub, b_ub, lower, upper,
                      pointed=True)  # f_n >= 0, friction in the cones, |coord| <= bound
        if lam is None:
            return None
        ends.append(float(coord @ lam))
    return ends[0], ends[1]


@dataclass(frozen=True)
class Squeeze:
    """Precomputed distribution for one contact configuration (see module docstring).

    Contacts in ``coupled`` (sliding fingers) have one free variable, ``f_n``, and a tangential
    force tied to it, ``f_t = coupled[i] * f_n``: zero for a push without friction, ``+-mu``
    for kinetic friction on a contact that slides.
    """

    pinv: np.ndarray | None  # (m, 3): minimum-norm particular solution (closed form only)
    lam0: np.ndarray  # (m,): internal force with sum f_n = 1, strictly inside the cones
    margin: float  # least slack of lam0 in its constraints (> 0 when usable)
    cols: np.ndarray  # (m,): column of each free variable in the full ``lam`` (2k,)
    tied: np.ndarray  # (c, 3): (free variable, column of f_t, coefficient) of coupled contacts
    G: np.ndarray  # (3, m): grasp matrix over the free variables
    fn: np.ndarray  # positions of the normal forces among the free variables
    fric: np.ndarray  # (j, 2): positions of (f_n, f_t) of the contacts with friction
    size: int  # 2k
    mu: float
    f_min: float
    f_max: float
    cost: np.ndarray | None = None  # per free variable: always solve the LP with this cost
    fast: tuple | None = None  # the closed form's constants as plain floats (see _closed_form)
    lp: SmallLP | None = field(default=None, compare=False)  # the per-step LP, once needed

    @classmethod
    def build(cls, G: np.ndarray, mu: float, f_min: float, f_max: float = np.inf,
              coupled: dict[int, float] | None = None,
              light: tuple[int, ...] = ()) -> Squeeze:
        """Find the internal force deepest inside the cones (LP), normalised to sum f_n = 1.

        Contacts in ``light`` switch the plan to a per-step LP whose cost weighs their normal
        force ten times (and no internal squeeze is looked for: ``usable`` is False).
        """
        k = G.shape[1] // 2
        coupled = coupled or {}
        cols = [c for i in range(k) for c in ((2 * i,) if i in coupled else (2 * i, 2 * i + 1))]
        pos = {c: j for j, c in enumerate(cols)}
        fn = np.array([pos[2 * i] for i in range(k)])
        fric = np.array([(pos[2 * i], pos[2 * i + 1]) for i in range(k) if i not in coupled],
                        dtype=int).reshape(-1, 2)
        tied = np.array([(pos[2 * i], 2 * i + 1, c) for i, c in coupled.items()]).reshape(-1, 3)
        Gr = G[:, cols].copy()
        for i, c in coupled.items():
            Gr[:, pos[2 * i]] += c * G[:, 2 * i + 1]
        m = len(cols)
        # a plan with its own cost solves the LP at every step: no squeeze to find
        lam0, margin = _deepest_squeeze(Gr, fn, fric, mu) if not light else (np.zeros(m), 0.0)
        cost = None
        if light:
            cost = np.zeros(m)
            cost[fn] = 1.0
            cost[[pos[2 * i] for i in light]] = 10.0
        pinv, fast = None, None
        if margin > MARGIN:  # the closed form (a plan without a squeeze solves its LP)
            pinv = np.linalg.pinv(Gr)
            # constraints g(lam) >= bound, g linear: f_n >= f_min and mu f_n -+ f_t >= 0, so
            # alpha >= (bound - g(lam_p)) / g(lam0) for each; every g(lam0) >= margin > 0
            rows = [(f_min, (1.0, fn_i, 0.0, fn_i), lam0[fn_i]) for fn_i in fn]
            for a, b in fric:
                rows.append((0.0, (mu, a, -1.0, b), mu * lam0[a] - lam0[b]))
                rows.append((0.0, (mu, a, 1.0, b), mu * lam0[a] + lam0[b]))
            fast = (tuple(tuple(map(float, r)) for r in pinv), tuple(map(float, lam0)), rows,
                    tuple(int(i) for i in fn))
        return cls(pinv, lam0, margin, np.array(cols), tied, Gr, fn, fric, 2 * k,
                   mu, f_min, f_max, cost, fast)

    @property
    def usable(self) -> bool:
        """True when a strict internal squeeze exists: every wrench is then a closed form."""
        return self.margin > MARGIN

    def solve(self, w: np.ndarray) -> np.ndarray | None:
        """Forces ``lam`` (2k,) balancing wrench ``w`` (same frame as ``G``), or None."""
        red = self._closed_form(w) if self.usable and self.cost is None else self._lp(w)
        if red is None:
            return None
        if not len(self.tied):  # no coupled contact: the free variables are lam, in order
            return np.array(red)
        lam = np.zeros(self.size)
        lam[self.cols] = red
        for var, col, coef in self.tied:
            lam[int(col)] = coef * red[int(var)]
        return lam

    def _lp(self, w: np.ndarray) -> np.ndarray | None:
        if self.lp is None:  # built at first use, then warm-started step after step
            m = len(self.cols)
            rows = []
            for a, b in self.fric:
                for sign in (1.0, -1.0):
                    r = np.zeros(m)
                    r[a], r[b] = -self.mu, sign
                    rows.append(r)
            if self.cost is None:
                cost = np.zeros(m)
                cost[self.fn] = 1.0
            else:
                cost = self.cost
            lower, upper = np.full(m, -np.inf), np.full(m, np.inf)
            lower[self.fn], upper[self.fn] = self.f_min, self.f_max
            args = (cost, self.G, np.array(rows) if rows else None,
                    np.zeros(len(rows)) if rows else None, lower, upper)
            # normal forces bounded below, friction inside the cones, a cost on the normal
            # forces: bounded and pointed, so the vertex solver applies where it fits
            lp = VertexLP(*args) if VertexLP.fits(self.G) else None
            object.__setattr__(self, "lp", lp if lp is not None and lp.ok else SmallLP(*args))
        return self.lp.solve(w)

    def _closed_form(self, w: np.ndarray) -> list[float] | None:
        """``pinv(G) w + alpha lam0`` with the least feasible ``alpha`` (plain floats)."""
        pinv, lam0, rows, fn = self.fast
        w0, w1, w2 = float(w[0]), float(w[1]), float(w[2])
        lp = [p0 * w0 + p1 * w1 + p2 * w2 for p0, p1, p2 in pinv]
        alpha = 0.0
        for bound, (c1, i1, c2, i2), den in rows:
            alpha = max(alpha, (bound - c1 * lp[i1] - c2 * lp[i2]) / den)
        red = [x + alpha * y for x, y in zip(lp, lam0, strict=True)]
        if max(red[i] for i in fn) > self.f_max:
            return None
        return red
