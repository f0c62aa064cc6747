r"""HierarchicalController: a strict task hierarchy solved as a sequence of QPs, in every world.

Level k (0 the highest priority) is solved after every level above it:

.. math::
    \dot q_k^* = \arg\min_{\dot q}\ \tfrac12 \sum_{i \in k,\ \text{soft}} w_i \|J_i \dot q - v_i\|^2
                 + \tfrac12 \epsilon \|\dot q\|^2
    \quad\text{s.t.}\quad
    J_j \dot q = J_j \dot q_{k-1}^* \ (j \text{ in the levels above}),\quad
    J_h \dot q = v_h \ (h \in k,\ \text{hard}),\quad lb \le \dot q \le ub,\quad G \dot q \le h

with every limit hard at every level (Kanoun, Lamiraux and Wieber 2011; Escande, Mansard
and Wieber 2014). :math:`\dot q^*_{k-1}` meets every equality, so only a level's own hard
tasks (or an empty box) can make it infeasible, and the error names that level; a level
without hard tasks that every solver fails on keeps :math:`\dot q^*_{k-1}`
(``kept_above``). Dependent rows above are replaced by a basis of their row space.

Each level is solved in two stages, as the QP is (docs/controllers.md):

1. in every world at once, by the QP's closed form with the bounds held at the last
   answer (:class:`~qpik.problem.HeldBounds`, in damped least-squares form: accurate
   when only ε makes the Hessian definite). An answer inside every limit is the level's
   minimiser.
2. the worlds left, one by one, by the chosen solver with its fallbacks
   (:class:`~qpik.controllers.worlds.WorldSolver`), a least-squares answer
   polished from the active set it found, and, where the solver fails with rows above, the
   same level again on an SVD basis of those rows. This stage is a loop over worlds: each
   world's solver call, active set and basis are its own.

A failing world of N is named in one :class:`~qpik.errors.WorldsFailed` after every level
of the other worlds is solved (its velocity zero); one robot's error is raised as it is.
"""

from __future__ import annotations

from functools import partial
from typing import Sequence

import numpy as np

from ..controllers.labels import task_label
from ..errors import InfeasibleProblem, InvalidInput, SolverError, WorldsFailed
from ..limits import Limit
from ..numerics import everywhere
from ..problem import Cost, HeldBounds, Problem, Stack, check_dt, group_levels
from ..tasks import Task
from ..tasks.inputs import positive_scalar
from .worlds import WorldQP, WorldSolver, check_finite_velocities, solve_each

# Singular values below this fraction of the largest are dropped when the rows above a
# level are replaced by a basis of their row space.
_RANK_TOLERANCE = 1e-10


def _level_regularization(nv: int, soft: Sequence[Task], regularization: float) -> float:
    """ε only breaks ties between a level's optima. Hard tasks alone: the minimum-norm
    solution (H = I, which any solver meets accurately). Joint-space tasks on every dof:
    H already positive definite, no ε."""
    covered = np.zeros(nv, dtype=bool)
    for task in soft:
        if task.joint_space:
            covered[task.dofs[task.weight > 0]] = True
    return 1.0 if not soft else 0.0 if covered.all() else regularization


class _Level:
    """One level: its rows in the hierarchy's stack, its cost, closed form and solvers.

    Its equalities are rows ``[0, rows)`` of the stack (the rows above, then its hard
    rows: hard tasks come first within a level), copied after its cost's rows, with the
    right-hand side ``b`` (N, rows):
    :math:`J_{above}\\dot q^*_{k-1}`, then the hard tasks' v.
    """

    def __init__(self, index: int, tasks: Sequence[Task], rows: slice, regularization: float, controller):
        robot, solver = controller.robot, controller.solver
        n, nv = robot.n, robot.nv
        self.index, self.tasks, self.level_rows = index, list(tasks), rows
        self.names = ", ".join(task_label(task) for task in self.tasks)
        self.above = rows.start  # equality rows frozen from the levels above
        self.hard_dim = sum(task.dim for task in self.tasks if task.hard)  # a hard task keeps all its rows
        self.rows = self.above + self.hard_dim
        self.hard_rows = slice(self.above, self.rows)
        soft = [task for task in self.tasks if not task.hard]
        epsilon = _level_regularization(nv, soft, regularization)
        self.cost = Cost(robot, soft, epsilon, spare_rows=self.rows)
        self.general = bool(self.cost.general)
        self.A, self.b = controller._J[:, : self.rows], self.cost.b  # the stack's rows, the cost's right side
        self.frozen = self.b[:, : self.above, None]  # (N, above, 1) view: J_above q̇*_{k-1}
        self.solver = WorldSolver(solver, nv, self.rows, controller.problem.rows, controller._native,
                                  **controller._solver_settings)
        self.reduced: dict[int, WorldSolver] = {}  # for rows replaced by a basis, by its rank
        self.held = HeldBounds(n, nv, self.cost.soft_rows, self.rows, hold=self.solver.exact)


class HierarchicalController:
    """A strict hierarchy of task levels, each a QP that keeps the optimum of those above,
    for one robot or N worlds.

    Args:
        robot: the robot the tasks and limits read (:class:`qpik.Robot` or
            :class:`qpik.batch.Robot`).
        tasks: tasks grouped into levels by their ``priority`` (0 the highest; equal
            priorities share a level and are weighed there by their weights).
        limits: joint position/velocity limits and general rows G q̇ ≤ h (collision
            avoidance), hard at every level.
        solver: a qpsolvers name (``daqp``, ``osqp``, ``proxqp``, ``quadprog``, ...).
        dt: control period in seconds (required: the limits bound the step q̇Δt).
        levels: explicit levels (lists of tasks, level 0 first) instead of ``tasks``.
        regularization: ε on the Hessian diagonal of a least-squares level whose cost
            alone does not fix every joint (it picks one optimum and biases the level's
            task velocities by about ε relative; 1e-10 keeps DAQP accurate, which at
            1e-12 loses digits on such a nearly singular Hessian).
        native: call DAQP/OSQP/ProxQP directly (True) or through qpsolvers.

    A task with ``hard=True`` is an equality at its own level (and kept below); the
    others are least squares at their level. Weights and constant limits are read once.
    After each step ``level_velocities`` holds each level's q̇*_k ((levels, nv), or
    (N, levels, nv)) and ``kept_above`` counts the level solves (world by world) that
    failed and kept the level above's velocity.

    Raises:
        InvalidInput: an empty level, a task listed twice, both or neither of
            ``tasks``/``levels``, a bad ``dt`` or ``regularization``, a model without
            degrees of freedom.
        UnknownName: an unknown solver.
    """

    kind = "hqp"

    def __init__(self, robot, tasks: Sequence[Task] | None = None, limits: Sequence[Limit] = (),
                 solver: str = "daqp", dt: float | None = None, *, levels: Sequence[Sequence[Task]] | None = None,
                 regularization: float = 1e-10, native: bool = True, **solver_settings):
        dt = check_dt(dt)
        regularization = positive_scalar(regularization, "regularization")  # a level may need it
        grouped = group_levels(robot, tasks, levels, "HierarchicalController")
        if robot.nv == 0:
            raise InvalidInput("a HierarchicalController needs a robot with at least one degree of freedom; "
                               "this model has none")
        # Hard tasks first within a level: the equalities of level k are then a prefix of
        # the stack of every level's rows (all rows above, then level k's hard rows).
        grouped = [[t for t in level if t.hard] + [t for t in level if not t.hard] for level in grouped]
        self.tasks = [t for level in grouped for t in level]
        self.updated_tasks = tuple(self.tasks)  # fresh after every step (rollouts read them)
        self.problem = problem = Problem(robot, self.tasks, limits, dt, "HierarchicalController")
        self.robot, self.solver, self.dt, self.limits = robot, solver, problem.dt, problem.limits
        self._native, self._solver_settings = native, solver_settings
        self._stack = Stack(robot, self.tasks)
        self._J, self._v = self._stack.J, self._stack.v  # (N, rows, nv), (N, rows): every level's rows
        rows = {id(task): task_rows for task, task_rows in self._stack.task_rows}
        self.levels, start = [], 0
        for k, level in enumerate(grouped):  # a level's rows end where its last task's do
            stop = rows[id(level[-1])].stop
            self.levels.append(_Level(k, level, slice(start, stop), regularization, self))
            start = stop
        n, nv = robot.n, robot.nv
        self.level_velocities_all = np.zeros((n, len(self.levels), nv))  # q̇*_k of each level, every world
        self.level_velocities = robot.present(self.level_velocities_all)
        self.qdots = self.level_velocities_all[:, -1]  # the last level's (a view)
        self.qdot = robot.present(self.qdots)
        self.kept_above = 0  # level solves that failed and kept the level above's velocity
        self._failures: dict[int, str] = {}

    lb = property(lambda self: self.robot.present(self.problem.lower), doc="The last step's lower bound on q̇.")
    ub = property(lambda self: self.robot.present(self.problem.upper), doc="The last step's upper bound on q̇.")
    G = property(lambda self: self.robot.present(self.problem.G), doc="The last step's general rows.")
    h = property(lambda self: self.robot.present(self.problem.h), doc="Their bounds.")

    @property
    def level_count(self) -> int:
        return len(self.levels)

    def compute_velocity(self) -> np.ndarray:
        """Fill the step's problem, then solve the levels in order, in every world: (nv,)
        for one robot, (N, nv) for N worlds.

        Raises:
            InfeasibleProblem, SolverError, InvalidInput: one robot's level has no answer
                (the message names the level and says why).
            WorldsFailed: some of N worlds have none; the others are solved.
        """
        self.problem.fill()
        self._stack.stack()
        failures = self._failures
        failures.clear()
        previous = None
        for level in self.levels:
            self._solve_level(level, previous, failures)
            previous = self.level_velocities_all[:, level.index]
        if failures:
            failed = list(failures)
            self.level_velocities_all[failed] = 0.0
            raise WorldsFailed(dict(failures), self.qdots, "HierarchicalController step")
        return self.qdot

    # -- stage 1: every world in closed form ------------------------------------------------
    def _solve_level(self, level: _Level, previous: np.ndarray | None, failures: dict) -> None:
        """Level ``level`` in every world into ``level_velocities_all``: the closed form, then
        the solver in the worlds it leaves (those failed above excluded)."""
        if level.above:
            np.matmul(self._J[:, : level.above], previous[:, :, None], level.frozen)
        if level.hard_dim:
            level.b[:, level.above:] = self._v[:, level.hard_rows]
        x, solved, worlds = self._closed_form(level)
        out = self.level_velocities_all[:, level.index]
        if worlds is None and not failures and (solved is everywhere(len(out)) or solved.all()):
            np.copyto(out, x)
            return
        settled = np.zeros(len(out), dtype=bool)
        ids = np.arange(len(out)) if worlds is None else worlds
        settled[ids[solved]] = True
        out[ids[solved]] = x[solved]
        settled[list(failures)] = True
        rest = np.flatnonzero(~settled)
        if not len(rest):
            return
        solve_each(rest, lambda w: self._solve_world(level, w, previous), out, self.robot.batched,
                   "HierarchicalController step", failures)
        level.held.remember(rest, out[rest], self.problem.lower[rest], self.problem.upper[rest])

    def _closed_form(self, level: _Level):
        """``(x, solved, worlds)``: the level's closed form in ``worlds`` (None: every world),
        ``solved`` where x is its minimiser inside every limit."""
        problem, cost = self.problem, level.cost
        cost.write()
        cost.A[...] = level.A
        uncapped = cost.uncapped()  # where a solver would see c capped, it decides
        worlds = None if uncapped is everywhere(len(uncapped)) else np.flatnonzero(uncapped)
        x, solved = level.held.solve(cost, problem.box, *problem.inequalities, worlds)
        return x, solved, worlds

    # -- stage 2: the worlds left, one by one ------------------------------------------------
    def _world_qp(self, level: _Level, w: int, A: np.ndarray, b: np.ndarray) -> WorldQP:
        p, cost = self.problem, level.cost
        return WorldQP(cost.world_hessian(w), cost.c[w], A, b, p.lower[w], p.upper[w], p.G[w], p.h[w],
                       partial(cost.world_rows, w))

    def _solve_world(self, level: _Level, w: int, previous: np.ndarray | None) -> np.ndarray:
        """World ``w``'s level by the solver (see the module's description)."""
        qp = self._world_qp(level, w, level.A[w], level.b[w])
        check_finite_velocities(self.tasks, qp.c, self._v[w], w)
        try:
            return self._polish(level, w, level.solver.solve(w, qp, hessian_changed=level.general))
        except (InfeasibleProblem, SolverError) as first:
            if not level.above:
                raise self._named(level, first) from None
        # The rows above are consistent (q̇*_{k-1} meets them) but may depend on each
        # other: constrain the same set through an orthonormal basis of their row space.
        basis = _row_basis(self._J[w, : level.above])
        rank = len(basis)
        if rank not in level.reduced:
            level.reduced[rank] = WorldSolver(self.solver, self.robot.nv, rank + level.hard_dim, self.problem.rows,
                                              self._native, **self._solver_settings)
        A = np.concatenate([basis, self._J[w, level.hard_rows]])
        b = np.concatenate([basis @ previous[w], self._v[w, level.hard_rows]])
        try:
            return self._polish(level, w, level.reduced[rank].solve(w, self._world_qp(level, w, A, b),
                                                                    hessian_changed=level.general))
        except (InfeasibleProblem, SolverError) as second:
            if level.hard_dim:  # the level above's velocity misses the level's own hard rows
                raise self._named(level, second) from None
        self.kept_above += 1  # it is a point of the level's set (see the module's docstring)
        return previous[w]

    def _polish(self, level: _Level, w: int, x: np.ndarray) -> np.ndarray:
        """The solver's answer polished by the held-bounds iteration from its bounds where the
        level weighs general tasks (a least-squares level whose Hessian only ε makes definite
        is met loosely by solvers): :meth:`~qpik.problem.HeldBounds.polish`."""
        if not level.general:
            return x
        return level.held.polish(level.cost, self.problem.box, *self.problem.inequalities, w, x)

    @staticmethod
    def _named(level: _Level, exc: Exception) -> Exception:
        if isinstance(exc, InfeasibleProblem) or level.hard_dim:
            what = ("its hard tasks and the limits cannot all be met" if level.hard_dim
                    else "the limits leave no velocity")
            return InfeasibleProblem(f"level {level.index} ({level.names}) is infeasible: {what} ({exc})")
        return SolverError(f"level {level.index} ({level.names}): {exc}")

    def report(self) -> dict[str, np.ndarray]:
        """Per-level residual ‖J q̇ − v‖ of the last step (velocity units of each level),
        over every task of the level: what each QP minimised (its soft part); (levels,),
        or (N, levels)."""
        out = np.zeros((self.robot.n, len(self.levels)))
        for k, level in enumerate(self.levels):
            rows = level.level_rows
            residual = np.einsum("nij,nj->ni", self._J[:, rows], self.qdots) - self._v[:, rows]
            out[:, k] = np.sqrt(np.einsum("ni,ni->n", residual, residual))
        return {"level_residual": self.robot.present(out)}


def _row_basis(rows: np.ndarray) -> np.ndarray:
    """An orthonormal basis (rank, nv) of the row space of ``rows`` (one world's): the SVD's
    right singular vectors above ``_RANK_TOLERANCE`` of the largest singular value."""
    _, singular, vt = np.linalg.svd(rows, full_matrices=False)
    rank = int(np.sum(singular > _RANK_TOLERANCE * singular[0])) if singular.size and singular[0] > 0 else 0
    return vt[:rank]
