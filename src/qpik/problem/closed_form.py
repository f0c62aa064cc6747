r"""The equality-constrained QP in closed form: the fast path of a control step.

When no limit binds, the QP's minimiser is that of :math:`\min \tfrac12 x^THx + c^Tx`
s.t. :math:`Ax = b`: :math:`x = H^{-1}A^TS^{-1}r - H^{-1}c` with :math:`S = AH^{-1}A^T`,
:math:`r = b + AH^{-1}c`; the QP being strictly convex, an x that also meets every
inequality *is* its solution. :func:`closed_form_step` chooses once how to compute it,
:class:`ClosedForm` tries it before the solver, :class:`HeldBounds` (the QP's) with the
bounds a solver found active held. Every answer is checked against the hard rows
(``EQUALITY_TOLERANCE``); one that fails any check goes to the solver.
"""

from __future__ import annotations

from typing import Callable

import mujoco
import numpy as np

from .. import linalg
from ..solvers.base import equalities_met, equalities_met_in_floats
from .backoff import PAUSE, Backoff
from .cost import UNCAPPED_NORM2, uncapped

# S is treated as singular (dependent hard rows) when its Cholesky factor's diagonal spans
# more than this ratio (the condition number of S is the square of it: 1e12).
SINGULAR_RATIO = 1e6
# Equality residual (relative to 1 + |b|) a closed-form step may leave, checked on every
# answer as the solvers' are: a nearly singular H or S loses digits no cheaper test foresees.
EQUALITY_TOLERANCE = 1e-10
# Closed forms a step may try with held bounds (HeldBounds) before the solver takes it.
HELD_TRIES = 3


def closed_form_step(nv: int, meq: int, H0: np.ndarray | None) -> "KKTStep":
    """The closed-form solve for ``nv`` dofs and ``meq`` equality rows, chosen once: A⁻¹b
    when the rows are as many as the dofs; else through H⁻¹, kept when ``H0`` (the Hessian
    when the same every step, else None) is a positive diagonal, else factorised every step
    (by MuJoCo's Cholesky when there are no rows: a cost alone)."""
    if meq and meq == nv:
        return SquareRows(meq)
    if H0 is not None:
        diagonal = np.diag(H0)
        if np.count_nonzero(H0 - np.diag(diagonal)) == 0 and np.all(diagonal > 0):
            return DiagonalHessian(meq, 1.0 / diagonal)
    return FactorisedHessian(meq) if meq else CostOnly(nv)


class KKTStep:
    """Solves min ½xᵀHx + cᵀx s.t. Ax = b (``Ac``: A, meq x nv, and cᵀ as its last row);
    :meth:`solve` returns None where the solvers would see c capped (:func:`uncapped`: they
    answer a far target), H is not positive definite, S is singular or x misses the
    equalities (the solver then decides). A subclass gives ``scaled(H, Ac)``, [A H⁻¹;
    cᵀH⁻¹] or None; with ``uniform`` (H = I/d) [A; cᵀ] is its own: d goes to the scalars.
    ``norm_factor`` (where H is a constant diagonal): c·c is at most it times cᵀH⁻¹c (over d
    when uniform), which the step computes anyway; None: c·c is computed. ``capped`` says
    whether the last None was the cap's (no failure of the closed form's)."""

    capped = False

    def __init__(self, meq: int, d: float = 1.0, uniform: bool = False, norm_factor: float | None = None):
        self.meq, self.d, self.uniform = meq, d, uniform
        self._norm_factor = norm_factor if meq else None
        self._Ac = self._transposed = None
        self._tail = np.array([0.0] * meq + [-d])  # [d y; −d], the coefficients of x in [A H⁻¹; cᵀH⁻¹]
        self._y = self._tail[:meq]  # solved in place where LAPACK allows
        self._M = np.empty((meq + 1, meq + 1))  # [A H⁻¹; cᵀH⁻¹] [A; cᵀ]ᵀ, written in place
        self._S, self._Ahc, self._d = self._M[:meq, :meq], self._M[:meq, meq], np.array(d)  # (views; d as an array)

    def solve(self, H: np.ndarray, Ac: np.ndarray, b: np.ndarray) -> np.ndarray | None:
        """x, or None."""
        meq, d, norm_factor = self.meq, self.d, self._norm_factor
        self.capped = norm_factor is None and not uncapped(Ac[meq], H)
        if self.capped:
            return None
        scaled = Ac if self.uniform else self.scaled(H, Ac)
        if scaled is None:
            return None
        if not meq:
            return -d * scaled[0]
        if Ac is not self._Ac:  # Aᵀ (a view), kept while Ac is the same array
            self._Ac, self._transposed = Ac, Ac.T
        M = scaled.dot(self._transposed, self._M)  # [[S, A H⁻¹ c], [·, ·]] (over d when H = I/d)
        rows = M.tolist() if meq <= 2 else None
        if norm_factor is not None and not (norm_factor * (rows[meq][meq] if rows else M[meq, meq]) <= UNCAPPED_NORM2
                                            or uncapped(Ac[meq], H)):
            self.capped = True
            return None
        rhs = b.tolist()
        if not (self._small_rows(rows, rhs, d) if rows else self._rows(b)):
            return None
        x = self._tail.dot(scaled)  # checked as the solvers' answers are (a few rows: in floats)
        if meq > 8:
            return x if equalities_met(Ac[:meq], x, b, EQUALITY_TOLERANCE) else None
        return x if equalities_met_in_floats(Ac.dot(x).tolist(), rhs, EQUALITY_TOLERANCE) else None

    def _rows(self, b: np.ndarray) -> bool:
        """d y = d S⁻¹r into the tail: (S/d) z = r by LAPACK's Cholesky (z is d y); False where S is singular."""
        rhs = self._y
        np.multiply(self._Ahc, self._d, rhs)
        rhs += b
        factor, z, info = linalg.dposv(self._S, rhs, 0, 0, 1)  # overwrite_b (positional: cheaper)
        if info != 0:
            return False
        pivots = factor.diagonal().tolist()
        if max(pivots) > SINGULAR_RATIO * min(pivots):
            return False
        if z is not rhs:
            rhs[:] = z
        return True

    def _small_rows(self, rows: list, rhs: list, d: float) -> bool:
        """:meth:`_rows` for one or two rows, in floats (``rows``: M as lists)."""
        tail = self._tail
        if self.meq == 1:
            s = d * rows[0][0]
            if not s > 0.0:
                return False
            tail[0] = d * (d * rows[0][1] + rhs[0]) / s
            return True
        (a, b_, r0), (_, d_, r1) = rows[0], rows[1]
        a, b_, d_ = d * a, d * b_, d * d_
        det = a * d_ - b_ * b_
        if not det * SINGULAR_RATIO ** 2 > a * d_:  # cond(S) > 1e12, or not positive
            return False
        r0 = d * r0 + rhs[0]
        r1 = d * r1 + rhs[1]
        tail[0] = d * (d_ * r0 - b_ * r1) / det
        tail[1] = d * (a * r1 - b_ * r0) / det
        return True


class SquareRows(KKTStep):
    """As many independent hard rows as dofs: the feasible set is the point x = A⁻¹b (one LU)."""

    def solve(self, H: np.ndarray, Ac: np.ndarray, b: np.ndarray) -> np.ndarray | None:
        A = Ac[: self.meq]
        lu, _, x, info = linalg.dgesv(A, b)
        pivots = np.abs(lu.diagonal()).tolist()
        well_posed = info == 0 and max(pivots) <= SINGULAR_RATIO ** 2 * min(pivots)
        return x if well_posed and equalities_met(A, x, b, EQUALITY_TOLERANCE) else None


class DiagonalHessian(KKTStep):
    """H a constant positive diagonal: H⁻¹ is the vector ``inverse`` (uniform: H = I/d)."""

    def __init__(self, meq: int, inverse: np.ndarray):
        uniform = bool(np.all(inverse == inverse[0]))
        super().__init__(meq, float(inverse[0]) if uniform else 1.0, uniform,
                         norm_factor=1.0 if uniform else float(1.0 / inverse.min()))
        self.inverse = inverse

    def scaled(self, H: np.ndarray, Ac: np.ndarray) -> np.ndarray:
        return Ac * self.inverse


class FactorisedHessian(KKTStep):
    """H changes every step (or is dense): H⁻¹[Aᵀ c] by one Cholesky solve."""

    def scaled(self, H: np.ndarray, Ac: np.ndarray) -> np.ndarray | None:
        factor, scaled_t, info = linalg.dposv(H, Ac.T)
        return None if info != 0 else scaled_t.T


class CostOnly(KKTStep):
    """No hard rows, H changes every step: x = −H⁻¹c by MuJoCo's dense Cholesky (on the
    small systems of a control step its call costs less than LAPACK's through SciPy)."""

    def __init__(self, nv: int):
        super().__init__(0)
        self._factor = np.empty((nv, nv))
        self._c = None  # the last Ac's row c (a view, kept while Ac is the same array)

    def solve(self, H: np.ndarray, Ac: np.ndarray, b: np.ndarray) -> np.ndarray | None:
        if Ac is not self._Ac:
            self._Ac, self._c = Ac, Ac[0]
        c, factor = self._c, self._factor
        self.capped = not (c.dot(c) <= UNCAPPED_NORM2 or uncapped(c, H))
        if self.capped:
            return None
        np.copyto(factor, H)  # H stays as it is for the solver
        if mujoco.mju_cholFactor(factor, 0.0) < len(factor):  # not positive definite
            return None
        x = np.empty(len(factor))
        mujoco.mju_cholSolve(x, factor, c)
        return np.negative(x, x)


class ClosedForm(Backoff):
    """The closed form tried before the solver: its answer is kept when it meets every
    limit (then it is the QP's solution). ``admits``: the limits' check (None: none).

    A limit that binds usually still binds next step, where the closed form is wasted
    work: after a miss the next few steps go to the solver directly (the same answer),
    twice as many after each miss again; a success brings the pause back to its start.
    """

    def __init__(self, admits: Callable[[np.ndarray], bool] | None):
        super().__init__()
        self.admits = admits

    def attempt(self, solve: Callable[..., np.ndarray | None], *arguments) -> np.ndarray | None:
        """``solve(*arguments)`` when it is tried this step and meets the limits, else None
        (one step of the pause used up, or a miss that starts the next pause)."""
        if not self.ready():
            return None
        x = solve(*arguments)
        return self.kept(x if x is None or self.admits is None or self.admits(x) else None)

    def kept(self, x: np.ndarray | None) -> np.ndarray | None:
        """x, the pause back at its start; or None (a miss), the next pause begun."""
        if x is None:
            self.failed()
        else:
            self.succeeded()
        return x


class HeldBounds(ClosedForm):
    r"""The QP's closed form (:class:`ClosedForm` of ``plain``), the bounds the last solver step
    found active held for an active-set solver (``hold``; a tolerance-based one's stay its own).

    The held dofs are equality rows :math:`x_i = v_i` (this step's bound values) beside
    the hard rows; the KKT system :math:`[H\ C^T; C\ 0][x; \mu] = [-c; v]` is solved by LU
    (accurate however small ε is). The answer is the QP's unique minimiser when it is in
    every limit, meets the hard rows and each held bound's multiplier :math:`r_i = -\mu_i`
    has the sign of an active bound (≥ 0 at a lower bound, ≤ 0 at an upper one). Else a
    wrong-signed bound is released, a crossed bound held, and the system solved again
    (``HELD_TRIES`` at most); then None: the solver decides (docs/controllers.md).
    """

    def __init__(self, nv: int, meq: int, plain: KKTStep, inequalities, hold: bool = True):
        super().__init__(inequalities.admits)
        self.nv, self.meq, self.plain, self.inequalities, self.hold = nv, meq, plain, inequalities, hold
        self.lower, self.upper = [], []  # the dofs held at their lower and upper bounds
        self._kkt = None  # ((lower, upper), its KKT matrix)

    def attempt(self, H: np.ndarray, Ac: np.ndarray, b: np.ndarray) -> np.ndarray | None:
        """:meth:`ClosedForm.attempt` of :meth:`solve` (of the plain closed form alone
        without ``hold``); most steps (nothing held, no limit crossed) end here."""
        if self.skip:  # Backoff.ready, inline (every step)
            self.skip -= 1
            return None
        if self.lower or self.upper:
            x = None
            if not uncapped(Ac[self.meq], H):  # the solver's capped cost answers: no miss
                return None
        else:
            x = self.plain.solve(H, Ac, b)
            if x is not None and self.admits(x):
                self.next = PAUSE  # Backoff.succeeded, inline
                return x
            if self.plain.capped:
                return None
        return self.kept(self.solve(H, Ac, b, x) if self.hold else None)

    def remember(self, x: np.ndarray) -> None:
        """The bounds active at a solver's answer x (to 1e-9 relative), held next time."""
        lb, ub = self.inequalities.lb, self.inequalities.ub
        at_lower = np.isfinite(lb) & (np.abs(x - lb) <= 1e-9 * (1.0 + np.abs(lb)))
        at_upper = np.isfinite(ub) & ~at_lower & (np.abs(x - ub) <= 1e-9 * (1.0 + np.abs(ub)))
        self.lower, self.upper = np.flatnonzero(at_lower).tolist(), np.flatnonzero(at_upper).tolist()

    def solve(self, H: np.ndarray, Ac: np.ndarray, b: np.ndarray, plain: np.ndarray | None = None) -> np.ndarray | None:
        """The QP's minimiser by closed forms with bounds held, checked (None: the solver decides);
        ``plain``: the plain closed form's answer, where the caller has it."""
        lower, upper = self.lower, self.upper
        if not (lower or upper):  # the plain closed form, kept when it meets the limits
            x = self.plain.solve(H, Ac, b) if plain is None else plain
            if x is None or self.admits(x):
                return x
            r = np.zeros(0)
        else:
            x, r = self._held_solve(H, Ac, b, lower, upper)
        for _ in range(HELD_TRIES):
            if x is None:
                return None
            wrong = {i for i, ri in zip(lower, r[: len(lower)].tolist()) if ri < 0.0} | \
                {i for i, ri in zip(upper, r[len(lower):].tolist()) if ri > 0.0}
            if not wrong and self.admits(x):
                self.lower, self.upper = lower, upper  # the working set, held again next step
                return x
            lb, ub = self.inequalities.box()
            values = x.tolist()
            below = [i for i, value in enumerate(values) if value < lb[i]]
            above = [i for i, value in enumerate(values) if value > ub[i]]
            if not (wrong or below or above):  # a general row, not a bound, is in the way
                return None
            lower = [i for i in lower if i not in wrong] + below
            upper = [i for i in upper if i not in wrong] + above
            x, r = self._held_solve(H, Ac, b, lower, upper) if lower or upper else (self.plain.solve(H, Ac, b), r[:0])
        return None

    def _bordered(self, lower: list, upper: list) -> np.ndarray:
        """The KKT matrix with its held dofs' unit rows and columns in place (kept while
        the same bounds are held)."""
        if self._kkt is None or self._kkt[0] != (lower, upper):
            nv, meq, held = self.nv, self.meq, lower + upper
            kkt = np.zeros((nv + meq + len(held),) * 2)
            rows = np.arange(nv + meq, nv + meq + len(held))
            kkt[rows, held] = kkt[held, rows] = 1.0
            self._kkt = ((list(lower), list(upper)), kkt)
        return self._kkt[1]

    def _held_solve(self, H: np.ndarray, Ac: np.ndarray, b: np.ndarray, lower: list, upper: list):
        """(x, the held bounds' multipliers r) with ``lower`` and ``upper`` held, or (None, None)."""
        nv, meq, held = self.nv, self.meq, len(lower)  # (more rows than dofs: a singular system, refused below)
        kkt = self._bordered(lower, upper)
        kkt[:nv, :nv] = H
        kkt[nv:nv + meq, :nv] = Ac[:meq]
        kkt[:nv, nv:nv + meq] = Ac[:meq].T
        lb, ub = self.inequalities.lb, self.inequalities.ub
        right = np.concatenate([-Ac[meq], b, lb[lower], ub[upper]])
        lu, _, solution, info = linalg.dgesv(kkt, right)
        pivots = np.abs(lu.diagonal()).tolist()
        if info != 0 or max(pivots) > SINGULAR_RATIO ** 2 * min(pivots):
            return None, None
        x = solution[:nv]
        x[lower], x[upper] = right[nv + meq:nv + meq + held], right[nv + meq + held:]  # on the bounds exactly
        if not equalities_met(Ac[:meq], x, b, EQUALITY_TOLERANCE):  # the hard rows, once x is on them
            return None, None
        return x, -solution[nv + meq:]


def damped_least_squares_step(dinv: np.ndarray, R: np.ndarray, soft_rows: int, rhs: np.ndarray,
                              c: np.ndarray | None) -> np.ndarray | None:
    r"""min ½‖R₁x − r₁‖² + ½xᵀDx + cᵀx s.t. R₂x = r₂ (R₁ the first ``soft_rows`` rows of R,
    D diagonal positive, ``dinv`` = D⁻¹, c None for zero), or None where singular.

    x = D⁻¹(Rᵀz − c) with (R D⁻¹ Rᵀ + diag(I, 0)) z = r + R D⁻¹ c: the damped
    least-squares form, which keeps its digits where H⁻¹ (of order 1/ε) would not; an x
    that misses R₂x = r₂ by more than ``EQUALITY_TOLERANCE`` relative is None. Up to
    ``SMALL_SYSTEM`` rows in floats.
    """
    m = R.shape[0]
    scaled = R * dinv
    K = scaled.dot(R.T)
    right = rhs if c is None else rhs + scaled.dot(c)
    if m <= SMALL_SYSTEM:
        z = _small_spd_solve(K.tolist(), right.tolist(), soft_rows)
        if z is None:
            return None
        x = np.dot(z, R)
    else:
        K.reshape(-1)[:: m + 1][:soft_rows] += 1.0
        factor, z, info = linalg.dposv(K, right, overwrite_a=1, overwrite_b=right is not rhs)
        if info != 0:
            return None
        pivots = factor.diagonal().tolist()
        if max(pivots) > SINGULAR_RATIO * min(pivots):
            return None
        x = np.dot(z, R)
    if c is not None:
        x -= c
    x *= dinv
    if soft_rows < m and not equalities_met(R[soft_rows:], x, rhs[soft_rows:], EQUALITY_TOLERANCE):
        return None
    return x


# Up to this many rows, damped_least_squares_step solves in Python floats.
SMALL_SYSTEM = 2


def _small_spd_solve(K: list, r: list, soft_rows: int) -> list | None:
    """z of (K + diag(I, 0)) z = r for one or two rows, in floats (K symmetric, as lists),
    or None where it is not positive definite or its condition number passes
    SINGULAR_RATIO² (as the LAPACK path's pivot test)."""
    if len(r) == 1:
        a = K[0][0] + (1.0 if soft_rows else 0.0)
        return [r[0] / a] if a > 0.0 else None
    (a, b), (_, d) = K
    if soft_rows:
        a += 1.0
        if soft_rows > 1:
            d += 1.0
    det = a * d - b * b
    if not (a > 0.0 and det * SINGULAR_RATIO ** 2 > a * d):
        return None
    return [(d * r[0] - b * r[1]) / det, (a * r[1] - b * r[0]) / det]
