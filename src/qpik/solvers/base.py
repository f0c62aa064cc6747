r"""The QP back-end interface, and the checks every back-end's answer goes through.

Every back-end solves

.. math::
    \min_x \tfrac12 x^T H x + c^T x \quad\text{s.t.}\quad A x = b,\quad G x \le h,
    \quad lb \le x \le ub

with fixed sizes (nv variables, meq equalities, mineq general inequalities) decided
once. The controller writes the problem straight into the back-end's own arrays ``A``,
``b``, ``G``, ``h``, ``lb``, ``ub`` (±inf for an absent bound), laid out as the solver
wants them, then calls :meth:`QPBackend.solve` with H and c.

:meth:`QPBackend.solve` keeps three promises whatever the solver does:

- its inputs are sane: a box with lb > ub is reported as infeasible (naming the
  variable) before any solver sees it; non-finite H, c, b, h are refused;
- its answer is checked: finite, within the box (a tolerance-based solver that lands a
  hair outside is projected back in; farther than ``bound_tolerance`` is a failure), the
  equalities met to ``equality_tolerance`` by :func:`equalities_met` (the one check every
  answer of a controller goes through, the closed form's too) at a size where rounding
  cannot decide that check (:func:`equalities_checkable`), and the inequalities to
  ``constraint_tolerance`` (relative to the data's scale), so a stale or wrong answer
  never passes as a solution, whatever the solver;
- every failure is a typed qpik error: :class:`~qpik.errors.InfeasibleProblem` or
  :class:`~qpik.errors.SolverError`, naming the solver and the cause; iteration and time
  limits are set on every solver, so a solve cannot hang.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import InfeasibleProblem, SolverError

BIG = 1e30  # the stand-in for an absent bound in solvers that take no inf (OSQP: >= 1e30 is inf)
# Iteration caps keep every solve bounded and deterministic; the time limit, given to the
# solvers that take one, is only a guard against a hang: a solve that normally takes
# microseconds never nears it, so a busy machine cannot change a result.
TIME_LIMIT = 1.0
ITERATION_LIMIT = 10000  # DAQP's active-set iterations on a phase-1 problem (H = I: no cycling)
# Iterative solvers: enough to converge on a well-posed step (OSQP needs up to 4,000 on the
# bundled robots' binding steps, ProxQP up to 919 inner iterations), few enough that a
# step that will not converge fails within milliseconds and falls back to an exact solver.
OSQP_ITERATIONS = 4000
PROXQP_ITERATIONS = 200  # outer iterations, of up to a tenth as many inner ones each
# On a large model the caps also shrink with one iteration's work, nv (2 nv + m) for nv
# variables and m rows (a pass over the KKT matrix: about 1 ns per unit for OSQP and DAQP,
# 40 for a ProxQP outer iteration): a solve that does not converge then stops after about
# 20 ms on any model (an 85-dof dog ran OSQP's 4,000 iterations for 95 ms), while the
# bundled robots (24 dofs at most) keep the caps above.
ITERATION_WORK = 2e7


def iteration_cap(cap: int, nv: int, rows: int, cost: float = 1.0) -> int:
    """``cap``, or fewer iterations where ``cap`` of them cost more than
    :data:`ITERATION_WORK` (``cost`` per unit of nv (2 nv + rows)); at least 100."""
    return max(100, min(cap, int(ITERATION_WORK / (cost * nv * (2 * nv + rows)))))


def active_set_iterations(nv: int, rows: int) -> int:
    """DAQP's iteration cap on a QP of nv variables and ``rows`` general rows. Its active
    set holds at most nv rows, and a solve that does not cycle adds or drops each a few
    times (the any-robot fuzz's solves: 2.1 nv at the 99th percentile); one past 10 nv +
    100 is cycling on a nearly singular Hessian (1e-12 curvature), which the guard's
    damped retry then solves in tens of iterations. A fixed 10,000 cost 100 ms a step on
    53 dofs."""
    return iteration_cap(10 * nv + 100, nv, rows)


# Equality residual an exact answer may leave, relative to 1 + |b| (the hard rows'
# promise): an active-set solver or the closed form meets it unless the rows are
# ill-conditioned or contradictory, and then the answer is not one.
EXACT_EQUALITY_TOLERANCE = 1e-9
ROUNDOFF = 0.5 * float(np.finfo(float).eps)  # the unit roundoff u


def equalities_met(A: np.ndarray, x: np.ndarray, b: np.ndarray, tolerance: float) -> bool:
    """Whether |Ax − b| <= tolerance (1 + |b|) (Euclidean norms) and every row at its own
    scale, |A_i x − b_i| <= tolerance (1 + |b_i| + |A_i||x|): the check every solver's
    answer that promises to meet hard rows goes through (:func:`misses_met` of one world)."""
    return bool(misses_met((A.dot(x) - b)[None], A[None], x[None], b[None], tolerance)[0])


def misses_met(miss: np.ndarray, A: np.ndarray, x: np.ndarray, b: np.ndarray, tolerance: float) -> np.ndarray:
    """(N,) the rule of :func:`equalities_met` in every world, from the miss A x − b (N, m),
    A (N, m, nv), x (N, nv) and b (N, m). Row by row too, or a far row's scale excuses a
    near row's miss (any-robot case 4966: a hierarchy's level below a position target 6e7
    away met the pose rows above it 6e-4 off)."""
    normwise = np.einsum("ni,ni->n", miss, miss) <= tolerance * tolerance * (1.0 + np.einsum("ni,ni->n", b, b))
    scale = np.einsum("nij,nj->ni", np.abs(A), np.abs(x)) + np.abs(b) + 1.0
    return normwise & (np.abs(miss) <= tolerance * scale).all(axis=1)


def equalities_checkable(A: np.ndarray, x: np.ndarray, b: np.ndarray, tolerance: float) -> bool:
    """Whether x is small enough for :func:`equalities_met` to tell an answer that meets
    the rows from one that misses them: the rounding its entries leave in A x, u ‖A∘x‖
    (u the unit roundoff, each x_j within u |x_j| of the value it stands for; the
    Frobenius norm of the products A_ij x_j, as independent errors add up), at most
    ``tolerance`` (1 + |b|). Past that the check of a correct answer is decided by its
    last bits: under 1e-15 moves of b, one passed 30 to 36 times in 40 at 1.2 times the
    tolerance (any-robot case 3516) and 10 in 40 at 3.5 (case 8160's cap 1e3, which one
    run passed and the other failed), against 40 in 40 at 0.25 to 0.93 (cases 7488, 7477,
    6711). The answer's size is fixed by the data, so this decision is not."""
    products = A * x
    return ROUNDOFF * ROUNDOFF * np.vdot(products, products) <= tolerance * tolerance * (1.0 + b.dot(b))


class QPBackend:
    """Base class: one solver instance per controller, sized at construction.

    Subclasses implement :meth:`_solve` and may lay ``A``, ``b``, ``G``, ``h``, ``lb``,
    ``ub`` out as views into their own storage.

    Attributes:
        exact: an active-set solver: its equalities (always in the active set) and
            active bounds hold to machine precision on a well-posed problem.
        bound_tolerance: how far outside the box an answer may land and still be
            projected back in (beyond it the solve failed).
        equality_tolerance: allowed residual of the equalities, relative to 1 + |b|
            (:data:`EXACT_EQUALITY_TOLERANCE` for an exact solver: a larger one means
            contradictory or ill-conditioned rows).
        constraint_tolerance: allowed excess of the general inequalities, relative to
            1 + the largest right-hand side.
    """

    name = "qp"
    exact = False
    bound_tolerance = 1e-6
    equality_tolerance = 1e-6
    constraint_tolerance = 1e-6

    def __init__(self, nv: int, meq: int, mineq: int = 0):
        self.nv, self.meq, self.mineq = nv, meq, mineq
        self.A, self.b = np.zeros((meq, nv)), np.zeros(meq)
        self.G, self.h = np.zeros((mineq, nv)), np.zeros(mineq)
        self.lb, self.ub = np.full(nv, -np.inf), np.full(nv, np.inf)

    def solve(self, H: np.ndarray, c: np.ndarray, hessian_changed: bool = True) -> np.ndarray:
        """Solve with the arrays as written and return the checked minimiser.

        ``hessian_changed=False`` lets a workspace keep its factorised H from the
        previous step.

        Raises:
            InfeasibleProblem: the box is empty for some variable, or the solver
                certified the constraints infeasible.
            SolverError: non-finite data, a solver failure (iteration or time limit,
                numerical trouble, a rejected update) or an answer that fails the checks.
        """
        self._check_inputs(H, c)
        x = self._solve(H, c, hessian_changed)
        return self._check_result(x)

    def _solve(self, H: np.ndarray, c: np.ndarray, hessian_changed: bool) -> np.ndarray:
        raise NotImplementedError

    # Checks ----------------------------------------------------------------------
    # Small problems are checked in Python floats: a NumPy reduction costs ~1 µs, a
    # conversion to a list 0.1 µs.
    def _check_inputs(self, H: np.ndarray, c: np.ndarray) -> None:
        lbs, ubs = self.lb.tolist(), self.ub.tolist()
        for i, (low, high) in enumerate(zip(lbs, ubs)):
            if low > high:
                raise InfeasibleProblem(f"QP infeasible ({self.name}): variable {i} must lie in the empty "
                                        f"interval [{low:.6g}, {high:.6g}]", variable=i)
        total = sum(c.tolist()) + sum(self.b.tolist()) + float(H.sum())
        if not math.isfinite(total):
            what = [name for name, arr in (("H", H), ("c", c), ("b", self.b)) if not np.all(np.isfinite(arr))]
            raise SolverError(f"QP solver {self.name}: the problem data {', '.join(what) or '(overflow)'} "
                              "contains NaN or inf (a task velocity or weight overflowed)")
        if self.mineq:  # h = +inf is an inactive row
            if np.isnan(self.h).any() or not math.isfinite(float(self.G.sum())):
                raise SolverError(f"QP solver {self.name}: an inequality row contains NaN or inf")
            if (self.h == -np.inf).any():
                raise InfeasibleProblem(f"QP infeasible ({self.name}): an inequality row has h = -inf")

    def _check_result(self, x) -> np.ndarray:
        if x is None:
            raise SolverError(f"QP solver {self.name} returned no solution")
        x = np.asarray(x, dtype=float)
        if x.shape != (self.nv,):
            raise SolverError(f"QP solver {self.name} returned a solution of shape {x.shape}")
        xs = x.tolist()
        if not math.isfinite(sum(xs)):
            raise SolverError(f"QP solver {self.name} returned a non-finite solution")
        # A tolerance's worth outside the box is projected back in; farther is a failure.
        outside = 0.0
        for i, (value, low, high) in enumerate(zip(xs, self.lb.tolist(), self.ub.tolist())):
            if value < low:
                outside = max(outside, low - value)
                x[i] = low
            elif value > high:
                outside = max(outside, value - high)
                x[i] = high
        if outside > self.bound_tolerance:
            raise SolverError(f"QP solver {self.name} returned a point {outside:.3g} outside its bounds")
        if self.meq:  # the size first: no refinement can make a point too large checkable
            if not equalities_checkable(self.A, x, self.b, self.equality_tolerance):
                rounding = ROUNDOFF * float(np.linalg.norm(self.A * x))
                raise SolverError(f"QP solver {self.name} returned a point too large to check against the "
                                  f"equality constraints: at |x| = {float(np.linalg.norm(x)):.3g} its rounding "
                                  f"leaves {rounding:.2g} in A x, past their tolerance "
                                  f"{self.equality_tolerance:.0e} (1 + |b|)")
            if not equalities_met(self.A, x, self.b, self.equality_tolerance):
                x = self._refined(x)
        if self.mineq:
            finite = self.h < BIG
            if finite.any():
                excess = float(np.max((self.G @ x - self.h)[finite]))
                scale = 1.0 + float(np.max(np.abs(self.h[finite])))
                if not excess <= self.constraint_tolerance * scale:
                    raise SolverError(f"QP solver {self.name} returned a point that exceeds an inequality "
                                      f"by {excess:.3g}")
        return x

    def _refined(self, x: np.ndarray, rounds: int = 4) -> np.ndarray:
        """``x`` moved onto A x = b by least-squares corrections of the dofs not at a bound
        (an ill-conditioned KKT system loses the equalities' last digits: far targets give
        |b| ~ 1e8 with cond(A) ~ 1e6), a dof the correction pushes out held at its bound
        and left out of the next round; kept only if it then meets them (the inequalities
        are checked after, as for any answer). Else SolverError."""
        lb, ub = self.lb, self.ub
        x = x.copy()
        for _ in range(rounds):
            free = (x > lb) & (x < ub)
            if not free.any():
                break
            x[free] += np.linalg.lstsq(self.A[:, free], self.b - self.A @ x, rcond=None)[0]
            np.clip(x, lb, ub, out=x)
            if not np.all(np.isfinite(x)):
                break
            if equalities_met(self.A, x, self.b, self.equality_tolerance):
                return x
        miss = float(np.abs(self.A @ x - self.b).max())
        raise SolverError(f"QP solver {self.name} returned a point that misses the equality "
                          f"constraints by {miss:.3g}")

    def _fail(self, status: str, infeasible: bool) -> None:
        if infeasible:
            raise InfeasibleProblem(f"QP infeasible ({self.name}: {status})")
        raise SolverError(f"QP solver {self.name} failed: {status}")

