"""A QP step solved so that it fails only where the problem is infeasible.

:class:`GuardedSolve` wraps one solver back-end, shared by
:class:`~qpik.controllers.qp.QPController` and each level of
:class:`~qpik.controllers.hierarchy.HierarchicalController`:

- the cost vector is *tamed* (:func:`tame`): a soft task with a target absurdly far away
  puts ~1e29 in c against ~1 in H, leaving no digit for a solver to find the vertex of
  the limits it points at; c scaled down to ``COST_SCALE_CAP`` times H's scale keeps its
  direction, and the minimiser stays the same vertex up to 1e-9 relative;
- an exact solver's failure is solved again on the same QP in its row form
  (:meth:`GuardedSolve._row_form`), then with a little damping, then by DAQP, quadprog
  and DAQP in the hard rows' null space (:class:`~qpik.solvers.nullspace.NullSpaceBackend`:
  hard rows whose entries span 1e-2 to 1e6 are beyond the dual solvers);
- a solver's "infeasible", and any failure that no fallback overcomes, is checked by a
  phase-1 problem that has no cost to misjudge (:func:`has_feasible_point`): only a
  problem with no feasible point raises :class:`~qpik.errors.InfeasibleProblem`; a
  feasible one is solved again with the cost capped harder (at last, no cost), down to
  the first cap whose minimiser is small enough for its hard rows to be checked, or ends
  in a :class:`~qpik.errors.SolverError` that says so.
"""

from __future__ import annotations

from ctypes import c_int

import numpy as np

from ..errors import InfeasibleProblem, SolverError
from ..solvers import available_solvers, make_backend
from ..solvers.base import EXACT_EQUALITY_TOLERANCE, ITERATION_LIMIT, TIME_LIMIT
from ..solvers.nullspace import NullSpaceBackend
from ..problem.cost import COST_SCALE_CAP, tame

# Exact solvers a failing step falls back to, in this order (the last: DAQP on the problem
# reduced to the hard rows' null space, for steps with hard rows).
NULL_SPACE = "daqp in the null space"
FALLBACK_SOLVERS = ("daqp", "quadprog", NULL_SPACE)
# has_feasible_point: how far (relative to 1 + |b|) a point may miss an equality and
# still count as meeting it; the LP that decided before had the same tolerance (HiGHS's).
FEASIBILITY_TOLERANCE = 1e-7


# The capped solves' caps on c, relative to H's scale (tame); 0: no cost.
CAPS = (COST_SCALE_CAP, 1e6, 1e3, 1.0, 1e-3, 0.0)

# Steps skipped after a failure, doubled while failures follow, up to the maximum.
PAUSE = 8
PAUSE_MAX = 32


class Backoff:
    """Skips ``PAUSE`` steps after a failure, doubled while failures follow (at most
    ``PAUSE_MAX``); a hot loop may test ``skip`` itself, as :meth:`ready` does."""

    def __init__(self) -> None:
        self.skip = 0  # steps left before the next attempt
        self.next = PAUSE  # the pause after the next failure

    def ready(self) -> bool:
        """Whether to try this step (if not, one step of the pause is used up)."""
        if self.skip:
            self.skip -= 1
            return False
        return True

    def succeeded(self) -> None:
        self.next = PAUSE

    def failed(self) -> None:
        self.skip = self.next
        self.next = min(2 * self.next, PAUSE_MAX)


def has_feasible_point(backend) -> bool:
    """Whether the back-end's constraints (A x = b, G x <= h, lb <= x <= ub, as written)
    admit a point, decided by the phase-1 problem min ½‖x‖² under them, solved by DAQP.

    The problem has no cost vector and an identity Hessian: nothing of the badly scaled
    cost that can make a solver misjudge the step, and a dual active-set method proves
    infeasibility (an unbounded dual ray) rather than running out of iterations. The
    equalities enter as rows b ± ``FEASIBILITY_TOLERANCE`` (1 + |b|): dependent hard rows
    (more rows than dofs, two tasks on one frame) are then rows like any other for the
    active set, not an overdetermined set DAQP refuses to start from. Only DAQP's
    "primal infeasible" says no; a numerical failure is not a proof of it. With hard rows,
    that "no" is checked once more in their null space (:func:`feasible_in_null_space`):
    DAQP's dual squares the rows' conditioning and can call a feasible set empty.
    """
    import daqp

    lb, ub = backend.lb, backend.ub
    if (lb > ub).any():
        return False
    nv, meq = backend.nv, backend.meq
    margin = FEASIBILITY_TOLERANCE * (1.0 + np.abs(backend.b))
    rows = np.vstack([backend.A, backend.G]) if meq else np.array(backend.G, dtype=float)
    upper = np.concatenate([ub, backend.b + margin, backend.h])
    lower = np.concatenate([lb, backend.b - margin, np.full(len(backend.h), -np.inf)])
    _, _, exitflag, _ = daqp.solve(np.eye(nv), np.zeros(nv), np.ascontiguousarray(rows, dtype=float),
                                   upper, lower, np.zeros(len(upper), dtype=c_int),
                                   iter_limit=ITERATION_LIMIT, time_limit=TIME_LIMIT)
    return exitflag != -1 or (meq > 0 and feasible_in_null_space(backend))  # -1: primal infeasible


def feasible_in_null_space(backend) -> bool:
    """Whether the phase-1 problem, solved with the hard rows eliminated
    (:class:`~qpik.solvers.nullspace.NullSpaceBackend`), finds a point that meets them to
    ``FEASIBILITY_TOLERANCE`` and the limits; a failure to find one keeps the verdict
    "infeasible"."""
    phase1 = NullSpaceBackend(backend.nv, backend.meq, backend.mineq)
    phase1.equality_tolerance = FEASIBILITY_TOLERANCE
    copy_constraints(backend, phase1)
    try:
        phase1.solve(np.eye(backend.nv), np.zeros(backend.nv))
    except (InfeasibleProblem, SolverError):
        return False
    return True


def _hard_rows_unmet(backend) -> str:
    """Why no exact answer exists when the hard rows alone cannot be met to their promise
    (their least-squares fit misses them by more than 1e-9 relative: dependent hard tasks
    that disagree, by less than phase 1's 1e-7), else ""."""
    if not backend.meq:
        return ""
    fit = np.linalg.lstsq(backend.A, backend.b, rcond=None)[0]
    miss = float(np.linalg.norm(backend.A @ fit - backend.b)) / (1.0 + float(np.linalg.norm(backend.b)))
    if not miss > EXACT_EQUALITY_TOLERANCE:
        return ""
    return (f"the hard rows alone can be met to {miss:.2g} (relative) at best, not the promised "
            f"{EXACT_EQUALITY_TOLERANCE:.0e}: hard tasks that constrain the same motion disagree; make one of them "
            "soft or give it a lower priority")


def copy_constraints(source, target) -> None:
    """A, b, G, h, lb, ub of ``source`` (a back-end, a :class:`~qpik.controllers.worlds.WorldQP`) into ``target``'s."""
    target.A[:], target.b[:] = source.A, source.b
    target.G[:], target.h[:] = source.G, source.h
    target.lb[:], target.ub[:] = source.lb, source.ub


class GuardedSolve:
    """``backend.solve`` with taming, fallbacks and a confirmed infeasibility.

    Args:
        backend: the step's back-end; the caller writes the constraints into its arrays.
        solver: the back-end's solver name (for the messages, and not retried as a fallback).
    """

    def __init__(self, backend, solver: str):
        self.backend = backend
        self.solver = solver
        self.fallbacks = 0  # steps a retry or a fallback solved (the solver failed, or sat out)
        self._spares = {}  # by solver name; the row form's by its number of soft rows
        # A solver that failed on a step most likely fails on the next (the problem changes
        # little): it sits out the next few steps, which go to the fallbacks directly, as
        # the closed form does after a limit binds (8 steps, doubled while it keeps
        # failing, up to 32). A failing solver then costs its iteration cap once, not
        # every step (ProxQP: 35 ms a step on a 48-dof tree).
        self._pause = Backoff()

    def solve(self, H: np.ndarray, c: np.ndarray, hessian_changed: bool = True, rows=None) -> np.ndarray:
        """The checked minimiser; ``rows``: None or a function giving the cost as (R₁, r₁, D, c₀).

        Raises:
            InfeasibleProblem: no point meets the constraints (the phase-1 problem agrees), or the box
                is empty (``variable`` set).
            SolverError: a feasible problem that no solver could solve.
        """
        if not self._pause.ready():
            return self._retry(SolverError(f"QP solver {self.solver} sat out this step (it failed on a recent one)"),
                               H, c, rows)
        try:
            x = self.backend.solve(H, tame(c, _scale(H)), hessian_changed=hessian_changed)
        except InfeasibleProblem as exc:
            if exc.variable is None:  # an empty box is no failure of the solver's
                self._pause.failed()
            return self._confirm_infeasible(exc, H, c, self.solver)
        except SolverError as exc:
            self._pause.failed()
            return self._retry(exc, H, c, rows)
        self._pause.succeeded()
        return x

    def _retry(self, failure: SolverError, H: np.ndarray, c: np.ndarray, rows) -> np.ndarray:
        """An exact active-set solver (DAQP, quadprog: cycling) tries the same QP in its row
        form where c is untamed, then with a little damping on every dof; an iterative one
        out of iterations (OSQP, ProxQP) would run out again: the exact solvers take it."""
        x = self._row_form(*rows()) if self.backend.exact and rows is not None and tame(c, _scale(H)) is c else None
        if x is not None:
            self.fallbacks += 1
            return x
        nv = H.shape[0]
        damping = 1e-9 * max(1.0, float(np.trace(H)) / nv)
        H = H.copy()  # the caller's Hessian must not keep the damping
        H.reshape(-1)[:: nv + 1] += damping
        c = tame(c, _scale(H))
        tried = []
        if self.backend.exact:
            tried.append(f"{damping:.1g} of damping on every dof")
            try:
                x, self.fallbacks = self.backend.solve(H, c, hessian_changed=True), self.fallbacks + 1
                return x
            except InfeasibleProblem as exc:
                return self._confirm_infeasible(exc, H, c, self.solver)
            except SolverError:
                pass
        for name in FALLBACK_SOLVERS:
            spare = None if name == self.solver else self._spare(name)
            if spare is None:
                continue
            tried.append(name)
            try:
                x = spare.solve(H, c)
            except InfeasibleProblem as exc:
                return self._confirm_infeasible(exc, H, c, f"{self.solver}, then {name}")
            except SolverError:
                continue
            self.fallbacks += 1
            return x
        also = f" (also with {', and with '.join(tried)})" if tried else ""
        x = self._solve_capped(H, c)  # fails on an infeasible step, then decided below
        if x is not None:
            return x
        if not has_feasible_point(self.backend):
            raise InfeasibleProblem(f"{failure}{also}, and no point meets the constraints (a phase-1 problem proves it)") from None
        raise SolverError(f"{failure}{also}: " + (_hard_rows_unmet(self.backend) or (
            "the cost is nearly singular or badly scaled; add a DampingTask (weight 1e-6 or more), lower the "
            "task gains or try another solver"))) from None

    def _row_form(self, R1: np.ndarray, r1: np.ndarray, D: np.ndarray, c0: np.ndarray) -> np.ndarray | None:
        """The step's QP with its soft rows as equalities on slack s = R₁x − r₁ (min ½sᵀs +
        ½xᵀDx + c₀ᵀx), solved by the solver; None if that fails. Its Hessian is diagonal,
        where D + R₁ᵀR₁ squares the condition: past 1/ε it is indefinite in floats (any-robot
        case 3870, DAQP: "unbounded"; see docs/controllers.md)."""
        backend, (m, nv) = self.backend, R1.shape
        if not m:  # the QP as solved: H = D
            return None
        if m not in self._spares:
            lifted = self._spares[m] = make_backend(self.solver, nv + m, m + backend.meq, backend.mineq)
            lifted.A[:m, nv:] = -np.eye(m)
            lifted.lb[nv:], lifted.ub[nv:] = -np.inf, np.inf
        lifted = self._spares[m]
        lifted.A[:m, :nv], lifted.A[m:, :nv], lifted.b[:m], lifted.b[m:] = R1, backend.A, r1, backend.b
        lifted.G[:, :nv], lifted.h[:], lifted.lb[:nv], lifted.ub[:nv] = backend.G, backend.h, backend.lb, backend.ub
        try:
            return lifted.solve(np.diag(np.concatenate([D, np.ones(m)])), np.concatenate([c0, np.zeros(m)]))[:nv]
        except (InfeasibleProblem, SolverError):
            return None

    def _confirm_infeasible(self, report: InfeasibleProblem, H: np.ndarray, c: np.ndarray,
                            solvers: str) -> np.ndarray:
        """A solver's "infeasible" checked before the step fails: with a soft task's target
        far away the cost dwarfs the constraints and DAQP can declare a feasible problem
        infeasible (9 of 2,000 fuzzed hexapod cases). An empty box stands; a feasible
        problem is solved again by the exact solvers with the cost capped harder (the
        minimiser is then a vertex of the limits in the cost's direction, which a 1e3 cap
        still finds to about 1e-3 relative)."""
        if report.variable is not None or not has_feasible_point(self.backend):
            raise report
        x = self._solve_capped(H, c)
        if x is not None:
            return x
        raise SolverError(f"QP solver {solvers} reported infeasibility, but the constraints have a feasible "
                          "point (a phase-1 problem finds one) and no exact solver found the minimiser: " + (
                              _hard_rows_unmet(self.backend) or "the cost is badly scaled (a soft task with a target "
                              "far out of reach?); add LM damping (lm_damping) or a DampingTask"))

    def _spare(self, name: str):
        """Solver ``name`` sized like the problem, with the back-end's constraints (a
        workspace of its own, even for the solver itself), or None if not installed (or,
        for the null-space reduction, without hard rows to reduce)."""
        backend = self.backend
        if name == NULL_SPACE:
            if not backend.meq:
                return None
        elif name not in available_solvers():
            return None
        if name not in self._spares:
            self._spares[name] = NullSpaceBackend(backend.nv, backend.meq, backend.mineq) if name == NULL_SPACE \
                else make_backend(name, backend.nv, backend.meq, backend.mineq)
        spare = self._spares[name]
        copy_constraints(backend, spare)
        return spare

    def _solve_capped(self, H: np.ndarray, c: np.ndarray) -> np.ndarray | None:
        """A step the solvers failed on, solved by the exact solvers with the cost capped
        harder and harder (``CAPS`` times H's scale, then no cost at all): a soft cost 1e9
        times H's scale makes |q̇| ~ 1e8, where A q̇ cannot even be computed to the hard
        rows' 1e-9 (any-robot fuzz); the minimiser keeps the cost's direction. The answer is
        the minimiser at the first cap where it is small enough for its hard rows to be
        checked (every back-end refuses a larger one:
        :func:`~qpik.solvers.base.equalities_checkable`), a size the data fixes: two runs
        whose data differ by a rounding stop at the same cap (case 8160 stopped at 1e3 in
        one run and at 1 in the other, 1.0 apart, when a pass at 1e3 was the rounding's).
        The last, no cost, is the smallest step in H's metric that meets the hard rows and
        the limits. None if every try fails."""
        previous = None
        for cap in CAPS:
            capped = tame(c, _scale(H), cap)
            if capped is previous:  # c as the last cap left it: the same problem
                continue
            previous = capped
            for name in FALLBACK_SOLVERS:
                spare = self._spare(name)
                if spare is None:
                    continue
                try:
                    x = spare.solve(H, capped)
                except (InfeasibleProblem, SolverError):
                    continue
                self.fallbacks += 1
                return x
        return None


def _scale(H: np.ndarray) -> float:
    """H's scale for :func:`tame`: its largest diagonal entry."""
    return float(H.diagonal().max())
