r"""QPController: a stack of tasks and limits turned into one QP per control step.

.. math::
    \min_{\dot q}\ \tfrac12 \sum_{i\,\text{soft}} w_i \|J_i \dot q - v_i\|^2
                  + \tfrac12 \epsilon \|\dot q\|^2
    \quad\text{s.t.}\quad J_h \dot q = v_h \ (\text{hard tasks}),\quad
    G \dot q \le h,\quad lb \le \dot q \le ub \ (\text{limits})

With a hard task and a joint-space one it is the null-space law while no limit binds (docs/clik.md).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ..errors import InfeasibleProblem, InvalidInput
from ..limits import Limit
from ..problem import Cost, HeldBounds, Problem, Stack, check_dt, closed_form_step
from ..robot import Robot
from ..solvers import make_backend
from ..tasks import Task
from .diagnostics import explain_infeasibility
from .fallbacks import GuardedSolve, check_finite_velocities


class QPController:
    """Differential IK by quadratic programming.

    Args:
        robot: the robot the tasks and limits read.
        tasks: tasks; each one's ``hard`` flag chooses equality or weighted cost.
        limits: limits: boxes on q̇ (joint position and velocity) and general rows
            G q̇ ≤ h (collision avoidance).
        solver: a qpsolvers name (``daqp``, ``osqp``, ``quadprog``, ``proxqp``, ...).
        dt: control period in seconds (required: the limits bound the step q̇Δt).
        regularization: ε added to the Hessian's diagonal so it is positive definite.
        native: call DAQP/OSQP/ProxQP directly (True) or always go through qpsolvers.
        fast_path: solve the equality-constrained QP in closed form and call the solver
            only when that solution would cross a limit (the same minimiser: the QP is
            strictly convex); False calls the solver every step.

    :meth:`compute_velocity` fills the step's problem (:class:`qpik.problem.Problem`:
    the kinematics if q changed, the tasks, the limits) and solves it. Task weights and
    constant limits are read once, when the controller is built.
    """

    kind = "qp"

    def __init__(self, robot: Robot, tasks: Sequence[Task], limits: Sequence[Limit] = (), solver: str = "daqp",
                 dt: float | None = None, regularization: float = 1e-12, native: bool = True,
                 fast_path: bool = True, **solver_settings):
        if not tasks:
            raise InvalidInput("a QPController needs at least one task")
        check_dt(dt)
        meq = sum(task.dim for task in tasks if task.hard)
        mineq = sum(limit.inequality_rows for limit in limits)
        self._backend = backend = make_backend(solver, robot.nv, meq, mineq, native=native, **solver_settings)
        self.problem = Problem(robot, tasks, limits, dt, "QPController", (backend.lb, backend.ub, backend.G, backend.h))
        self.robot, self.dt, self.tasks, self.limits = robot, self.problem.dt, self.problem.tasks, self.problem.limits
        self.solver = solver
        # The equality rows and the cost vector share one array, [A; cᵀ], which the
        # closed-form step reads in one product; the solver gets a copy on the (rare) steps
        # that need it. Limits write straight into the back-end's box and rows.
        self._Ac = np.zeros((meq + 1, robot.nv))
        self.hard_rows = Stack(robot.nv, self.problem.hard, out=(self._Ac[:meq], np.zeros(meq)))
        self.cost = Cost(robot.nv, self.problem.soft, float(regularization), c=self._Ac[meq])
        self._step = closed_form_step(robot.nv, meq, None if self.cost.general else self.cost.H0)
        # With an active-set solver the closed form also holds the bounds that bind; a
        # tolerance-based solver's answers stay its own (its runs unchanged).
        self._closed_form = HeldBounds(robot.nv, meq, self._step, self.problem.inequalities, hold=backend.exact) \
            if fast_path else None
        self.updated_tasks = tuple(self.tasks)  # fresh after every step (rollouts read them)
        self.qdot = np.zeros(robot.nv)
        self.solver_calls = 0  # steps that needed the solver (a limit would bind)
        self._guard = GuardedSolve(backend, solver)  # taming, fallbacks, infeasibility confirmed

    # The step's problem, as the solver sees it.
    A = property(lambda self: self.hard_rows.J, doc="The hard rows' Jacobian (meq x nv) of the last step.")
    b = property(lambda self: self.hard_rows.v, doc="The hard rows' target velocities (meq,) of the last step.")
    H = property(lambda self: self.cost.H, doc="The Hessian (nv x nv) of the last step.")
    c = property(lambda self: self.cost.c, doc="The cost vector (nv,) of the last step.")
    lb = property(lambda self: self.problem.inequalities.lb, doc="The lower bound on q̇ (nv,) of the last step.")
    ub = property(lambda self: self.problem.inequalities.ub, doc="The upper bound on q̇ (nv,) of the last step.")
    G = property(lambda self: self._backend.G, doc="The general rows (mineq x nv) of the last step.")
    h = property(lambda self: self._backend.h, doc="Their bounds (mineq,) of the last step.")

    def compute_velocity(self) -> np.ndarray:
        """Fill the step's problem (kinematics, tasks, limits) and solve the QP."""
        self.problem.fill()
        self.cost.write()
        self.hard_rows.stack()
        if self._closed_form is not None:
            x = self._closed_form.attempt(self.cost.H, self._Ac, self.hard_rows.v)  # None where c is capped, too
            if x is not None:
                self.qdot = x
                return x
        return self._solve()

    def _solve(self) -> np.ndarray:
        """The step through the solver (a limit binds, or no closed form)."""
        self.solver_calls += 1
        check_finite_velocities(self.tasks, self.c, self.b)
        backend = self._backend
        backend.A[:] = self.A
        backend.b[:] = self.b
        self.problem.inequalities.sync()  # the box into the back-end's arrays, where it was kept in floats
        try:
            self.qdot = self._guard.solve(self.H, self.c, hessian_changed=bool(self.cost.general))
        except InfeasibleProblem as exc:
            raise InfeasibleProblem(f"QP infeasible ({self.solver}): {explain_infeasibility(self, exc.variable)}",
                                    exc.variable) from None
        if self._closed_form is not None and self._closed_form.hold and not self._closed_form.skip:
            self._closed_form.remember(self.qdot)  # its active bounds, held when the closed form is next tried
        return self.qdot

    @property
    def fallbacks(self) -> int:
        """Steps the solver failed on and a fallback solver solved."""
        return self._guard.fallbacks
