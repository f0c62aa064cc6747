r"""QPController: a stack of tasks and limits turned into one QP per control step, in every world.

.. math::
    \min_{\dot q}\ \tfrac12 \sum_{i\,\text{soft}} w_i \|J_i \dot q - v_i\|^2
                  + \tfrac12 \epsilon \|\dot q\|^2
    \quad\text{s.t.}\quad J_h \dot q = v_h \ (\text{hard tasks}),\quad
    G \dot q \le h,\quad lb \le \dot q \le ub \ (\text{limits})

Solved in three stages, each over the worlds that reach it: the closed form with the
bounds held at the last answer (:mod:`qpik.problem.closed_form`: most steps end there),
then the chosen solver world by world (:mod:`qpik.controllers.worlds`). With a hard task
and a joint-space one it is the null-space law while no limit binds (docs/clik.md).

General rows :math:`G\dot q \le h` (collision avoidance): the closed form's answer is
kept only where it meets them (:func:`~qpik.problem.inside`); a world whose
rows bind goes to the solver. The closed form holds bounds, not rows: a world whose last
solver answer had a row active (to ``ACTIVE_TOLERANCE``) goes straight to the solver
next step, until an answer leaves every row inactive.
"""

from __future__ import annotations

from functools import partial
from typing import Sequence

import numpy as np

from ..errors import InfeasibleProblem, InvalidInput
from ..limits import Limit
from ..numerics import everywhere
from ..problem import Cost, HeldBounds, Problem, check_dt
from ..problem.closed_form import ACTIVE_TOLERANCE
from ..tasks import Task
from .diagnostics import explain_infeasibility
from .worlds import WorldQP, WorldSolver, check_finite_velocities, solve_each


class QPController:
    """Differential IK by quadratic programming, for one robot or N worlds.

    Args:
        robot: the robot the tasks and limits read (:class:`qpik.Robot` or
            :class:`qpik.batch.Robot`).
        tasks: tasks; each one's ``hard`` flag chooses equality or weighted cost.
        limits: boxes on q̇ (joint position and velocity) and general rows G q̇ ≤ h
            (collision avoidance).
        solver: a qpsolvers name (``daqp``, ``osqp``, ``quadprog``, ``proxqp``, ...): the
            solver of the steps no closed form settles.
        dt: control period in seconds (required: the limits bound the step q̇Δt).
        regularization: ε added to the Hessian's diagonal so it is positive definite.
        native: call DAQP/OSQP/ProxQP directly (True) or always go through qpsolvers.

    :meth:`compute_velocity` fills the step's problem (:class:`qpik.problem.Problem`:
    the kinematics if q changed, the tasks, the limits) and solves it. Task weights and
    constant limits are read once, when the controller is built.
    """

    kind = "qp"

    def __init__(self, robot, tasks: Sequence[Task], limits: Sequence[Limit] = (), solver: str = "daqp",
                 dt: float | None = None, regularization: float = 1e-12, native: bool = True, **solver_settings):
        if not tasks:
            raise InvalidInput("a QPController needs at least one task")
        check_dt(dt)
        if robot.nv == 0:
            raise InvalidInput("a QPController needs a robot with at least one degree of freedom; this model has none")
        self.problem = Problem(robot, tasks, limits, dt, "QPController")
        self.robot, self.dt, self.tasks, self.limits = robot, self.problem.dt, self.problem.tasks, self.problem.limits
        self.solver = solver
        self.cost = cost = Cost(robot, self.problem.soft, float(regularization), hard=self.problem.hard)
        self._solver = WorldSolver(solver, robot.nv, cost.A.shape[1], self.problem.rows, native, **solver_settings)
        # An active-set solver's bounds are held by the closed form next step; a
        # tolerance-based solver's answers stay its own.
        self.held = HeldBounds(robot.n, robot.nv, cost.soft_rows, cost.A.shape[1], hold=self._solver.exact)
        self.updated_tasks = tuple(self.tasks)  # fresh after every step (rollouts read them)
        # The worlds whose last solver answer had a general row active (see the module).
        self.rows_held = np.zeros(robot.n, dtype=bool)
        self._holding_rows = False
        self.qdots = np.zeros((robot.n, robot.nv))
        self._everywhere = everywhere(robot.n)
        self.qdot = robot.present(self.qdots)
        self.solver_calls = 0  # world-steps that needed the solver

    # The step's problem, as the solver sees it (world 0 for one robot).
    A = property(lambda self: self.robot.present(self.cost.A), doc="The hard rows' Jacobian of the last step.")
    b = property(lambda self: self.robot.present(self.cost.b), doc="The hard rows' target velocities.")
    H = property(lambda self: self.robot.present(np.stack([self.cost.world_hessian(w) for w in range(self.robot.n)])),
                 doc="The Hessian of the last step.")
    c = property(lambda self: self.robot.present(self.cost.c), doc="The cost vector of the last step.")
    lb = property(lambda self: self.robot.present(self.problem.lower), doc="The lower bound on q̇ of the last step.")
    ub = property(lambda self: self.robot.present(self.problem.upper), doc="The upper bound on q̇ of the last step.")
    G = property(lambda self: self.robot.present(self.problem.G), doc="The general rows of the last step.")
    h = property(lambda self: self.robot.present(self.problem.h), doc="Their bounds of the last step.")

    def compute_velocity(self) -> np.ndarray:
        """Fill the step's problem (kinematics, tasks, limits) and solve the QP in every
        world: (nv,) for one robot, (N, nv) for N worlds.

        Raises:
            InfeasibleProblem, SolverError, InvalidInput: one robot's step has no answer
                (the message says why).
            WorldsFailed: some of N worlds have none; the others are solved.
        """
        problem = self.problem
        problem.fill()
        self.cost.write()
        closed = self.cost.uncapped()  # the worlds a closed form may answer
        if self._holding_rows:
            closed = closed & ~self.rows_held
        worlds = None if closed is self._everywhere else np.flatnonzero(closed)
        if worlds is not None and not len(worlds):
            x, solved = self.qdots[:0], np.zeros(0, dtype=bool)
        else:
            x, solved = self.held.solve(self.cost, problem.box, *problem.inequalities, worlds)
        if worlds is None and (solved is self._everywhere or solved.all()):
            self.qdots[...] = x
            return self.qdot
        self._finish(x, solved, worlds)
        return self.qdot

    def _finish(self, x: np.ndarray, solved: np.ndarray, worlds: np.ndarray | None) -> None:
        """The closed forms' answers kept, the other worlds solved by the solver."""
        settled = np.zeros(self.robot.n, dtype=bool)
        ids = np.arange(self.robot.n) if worlds is None else worlds
        settled[ids[solved]] = True
        self.qdots[ids[solved]] = x[solved]
        rest = np.flatnonzero(~settled)
        self.solver_calls += len(rest)
        solve_each(rest, self._solve_world, self.qdots, self.robot.batched, "QPController step")
        self.held.remember(rest, self.qdots[rest], self.problem.lower[rest], self.problem.upper[rest])
        if self.problem.rows:
            self._remember_rows(rest)

    def _remember_rows(self, worlds: np.ndarray) -> None:
        """Whether a general row is active at the solver's answers of ``worlds`` (an
        inactive row, 0 ≤ +inf, never is)."""
        p = self.problem
        h = p.h[worlds]
        slack = h - np.matmul(p.G[worlds], self.qdots[worlds, :, None])[:, :, 0]
        self.rows_held[worlds] = (slack <= ACTIVE_TOLERANCE * (1.0 + np.abs(h))).any(axis=1)
        self._holding_rows = bool(self.rows_held.any())

    def world_qp(self, w: int) -> WorldQP:
        """World ``w``'s QP (views)."""
        p = self.problem
        return WorldQP(self.cost.world_hessian(w), self.cost.c[w], self.cost.A[w], self.cost.b[w],
                       p.lower[w], p.upper[w], p.G[w], p.h[w], partial(self.cost.world_rows, w))

    def _solve_world(self, w: int) -> np.ndarray:
        qp = self.world_qp(w)
        check_finite_velocities(self.tasks, qp.c, qp.b, w)
        try:
            x = self._solver.solve(w, qp, hessian_changed=bool(self.cost.general))
        except InfeasibleProblem as exc:
            raise InfeasibleProblem(f"QP infeasible ({self.solver}): {explain_infeasibility(self, w, exc.variable)}",
                                    exc.variable) from None
        if self._solver.exact:
            return x
        p = self.problem
        return self.held.polish(self.cost, p.box, *p.inequalities, w, x)

    @property
    def fallbacks(self) -> int:
        """World-steps the solver failed on or sat out, answered by a retry or a fallback."""
        return self._solver.fallbacks
