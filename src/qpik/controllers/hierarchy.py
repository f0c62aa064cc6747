r"""HierarchicalController: a strict task hierarchy solved as a sequence of QPs.

Level k (0 the highest priority) is solved after every level above it:

.. math::
    \dot q_k^* = \arg\min_{\dot q}\ \tfrac12 \sum_{i \in k,\ \text{soft}} w_i \|J_i \dot q - v_i\|^2
                 + \tfrac12 \epsilon \|\dot q\|^2
    \quad\text{s.t.}\quad
    J_j \dot q = J_j \dot q_{k-1}^* \ (j \text{ in the levels above}),\quad
    J_h \dot q = v_h \ (h \in k,\ \text{hard}),\quad lb \le \dot q \le ub

with every limit hard at every level (Kanoun, Lamiraux and Wieber 2011; Escande, Mansard
and Wieber 2014). :math:`\dot q^*_{k-1}` meets every equality, so only a level's own hard
tasks (or an empty box) can make it infeasible, and the error names that level; a level
without hard tasks that every solver fails on keeps :math:`\dot q^*_{k-1}`
(``kept_above``). Dependent rows above are replaced by a basis of their row space. Why,
and how each level is solved in closed form first: docs/controllers.md.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ..errors import InfeasibleProblem, InvalidInput, SolverError
from ..problem import (
    ClosedForm,
    Cost,
    Problem,
    Stack,
    check_dt,
    closed_form_step,
    damped_least_squares_step,
    group_levels,
)
from ..robot import Robot
from ..solvers import make_backend
from ..tasks import Task
from .fallbacks import GuardedSolve, check_finite_velocities
from .labels import task_label

# Singular values below this fraction of the largest are dropped when the rows above a
# level are replaced by a basis of their row space.
_RANK_TOLERANCE = 1e-10


class _Level:
    """One level: its rows in the hierarchy's stack, its cost, closed form and solver."""

    def __init__(self, index: int, stack: Stack, offset: int, regularization: float, problem: Problem):
        nv = problem.robot.nv
        self.index = index
        self.tasks = stack.tasks
        self.names = ", ".join(task_label(task) for task in self.tasks)
        self.above = offset  # equality rows frozen from the levels above
        self.hard_dim = sum(task.dim for task in self.tasks if task.hard)  # hard tasks come first
        self.hard_rows = slice(offset, offset + self.hard_dim)
        soft = [task for task in self.tasks if not task.hard]
        self.cost = Cost(nv, soft, _level_regularization(nv, soft, regularization))
        self.rows = offset + self.hard_dim  # the level's equalities: the rows above, then its hard rows
        # The closed form (qpik.problem.closed_form) on those equalities: with a constant
        # Hessian through H⁻¹; with soft tasks of their own Jacobian in damped
        # least-squares form (accurate when only ε makes H definite) on R = [√w J_soft; A].
        self.diagonal0 = np.diag(self.cost.H0).copy()
        self.dinv = np.zeros(nv)
        if self.cost.general:
            self.soft_rows = m = Stack(nv, self.cost.general, weighted=True).dim
            self.R, self.rhs = np.zeros((m + self.rows, nv)), np.zeros(m + self.rows)
            self.soft = Stack(nv, self.cost.general, weighted=True, out=(self.R[:m], self.rhs[:m]))  # √W J, √W v
        else:
            self.Ac = np.zeros((self.rows + 1, nv))  # [A; cᵀ]
            self.b = np.zeros(self.rows)
            self.step = closed_form_step(nv, self.rows, self.cost.H0)
        self.closed_form = ClosedForm(problem.inequalities.admits)
        self.guard = None  # the back-end with taming and fallbacks (qpik.controllers.fallbacks)
        self.reduced: dict[int, GuardedSolve] = {}  # for rows replaced by a basis, by count


def _level_regularization(nv: int, soft: Sequence[Task], regularization: float) -> float:
    """ε only breaks ties between a level's optima. Hard tasks alone: the minimum-norm
    solution (H = I, which any solver meets accurately). Joint-space tasks on every dof:
    H already positive definite, no ε."""
    covered = np.zeros(nv, dtype=bool)
    for task in soft:
        if task.joint_space:
            covered[task.dofs[task.weight > 0]] = True
    return 1.0 if not soft else 0.0 if covered.all() else regularization


class HierarchicalController:
    """A strict hierarchy of task levels, each a QP that keeps the optimum of those above.

    Args:
        robot: the robot the tasks and limits read.
        tasks: tasks grouped into levels by their ``priority`` (0 the highest; equal
            priorities share a level and are weighed there by their weights).
        limits: joint position/velocity limits, hard at every level.
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

    Raises:
        InvalidInput: an empty level, a task listed twice, both or neither of
            ``tasks``/``levels``, a bad ``dt``.
        UnknownName: an unknown solver.
    """

    kind = "hqp"

    def __init__(self, robot: Robot, tasks: Sequence[Task] | None = None, limits: Sequence = (),
                 solver: str = "daqp", dt: float | None = None, *, levels: Sequence[Sequence[Task]] | None = None,
                 regularization: float = 1e-10, native: bool = True, **solver_settings):
        dt = check_dt(dt)
        if not (np.isfinite(regularization) and regularization > 0):  # a level may need it
            raise InvalidInput(f"regularization must be positive, got {regularization}")
        grouped = group_levels(robot, tasks, levels, "HierarchicalController")
        self.tasks = [t for level in grouped for t in level]
        self.updated_tasks = tuple(self.tasks)  # fresh after every step (rollouts read them)
        self.problem = problem = Problem(robot, self.tasks, limits, dt, "HierarchicalController")
        self.robot, self.solver, self.dt, self.limits = robot, solver, problem.dt, problem.limits
        # Hard tasks first within a level: the equalities of level k are then a prefix of
        # the stack of every level's rows (all rows above, then level k's hard rows).
        grouped = [[t for t in level if t.hard] + [t for t in level if not t.hard] for level in grouped]
        self._native, self._solver_settings = native, solver_settings
        nv, mineq = robot.nv, problem.inequalities.rows
        sizes = [Stack(nv, level).dim for level in grouped]
        self._J, self._v = np.zeros((sum(sizes), nv)), np.zeros(sum(sizes))
        self._stacks, self.levels = [], []
        for k, (level, offset) in enumerate(zip(grouped, np.cumsum([0] + sizes[:-1]))):
            rows = slice(int(offset), int(offset) + sizes[k])
            stack = Stack(nv, level, out=(self._J[rows], self._v[rows]))
            self._stacks.append(stack)
            self.levels.append(_Level(k, stack, int(offset), float(regularization), problem))
        for level in self.levels:
            level.guard = GuardedSolve(make_backend(solver, nv, level.rows, mineq, native=native, **solver_settings),
                                       solver)
        self.level_velocities = np.zeros((len(self.levels), nv))  # q̇*_k of each level
        self.qdot = np.zeros(nv)
        self.kept_above = 0  # level solves that failed and kept the level above's velocity

    lb = property(lambda self: self.problem.inequalities.lb, doc="The last step's lower bound on q̇ (nv,).")
    ub = property(lambda self: self.problem.inequalities.ub, doc="The last step's upper bound on q̇ (nv,).")
    G = property(lambda self: self.problem.inequalities.G, doc="The last step's general rows (mineq x nv).")
    h = property(lambda self: self.problem.inequalities.h, doc="Their bounds (mineq,).")

    @property
    def level_count(self) -> int:
        return len(self.levels)

    def compute_velocity(self) -> np.ndarray:
        """Fill the step's problem, then solve the levels in order."""
        self.problem.fill()
        for stack in self._stacks:
            stack.stack()
        previous = None
        for level in self.levels:
            x = self._solve_level(level, previous)
            self.level_velocities[level.index] = x
            previous = x
        self.qdot = previous
        return previous

    def _write(self, backend, level: _Level, above_rows, above_values) -> None:
        m = len(above_values)
        backend.A[:m] = above_rows
        backend.b[:m] = above_values
        if level.hard_dim:
            backend.A[m:] = self._J[level.hard_rows]
            backend.b[m:] = self._v[level.hard_rows]
        backend.lb[:] = self.lb
        backend.ub[:] = self.ub
        if backend.mineq:
            backend.G[:] = self.G
            backend.h[:] = self.h

    def _solve_level(self, level: _Level, previous: np.ndarray | None) -> np.ndarray:
        above = self._J[: level.above]
        frozen = above @ previous if level.above else self._v[:0]
        x = self._closed_form(level, frozen)
        if x is not None:
            return x
        level.cost.write()
        check_finite_velocities(self.tasks, level.cost.c, self._v)
        try:
            return self._guarded(level.guard, level, above, frozen, frozen)
        except (InfeasibleProblem, SolverError) as first:
            if not level.above:
                raise self._named(level, first) from None
        # The rows above are consistent (q̇*_{k-1} meets them) but may depend on each
        # other: constrain the same set through an orthonormal basis of their row space.
        _, singular, vt = np.linalg.svd(above, full_matrices=False)
        rank = int(np.sum(singular > _RANK_TOLERANCE * singular[0])) if singular.size and singular[0] > 0 else 0
        basis = vt[:rank]
        if rank not in level.reduced:
            level.reduced[rank] = GuardedSolve(make_backend(self.solver, self.robot.nv, rank + level.hard_dim,
                                                            self.problem.inequalities.rows, native=self._native,
                                                            **self._solver_settings), self.solver)
        try:
            return self._guarded(level.reduced[rank], level, basis, basis @ previous, frozen)
        except (InfeasibleProblem, SolverError) as second:
            if level.hard_dim:  # previous misses the level's own hard rows
                raise self._named(level, second) from None
        self.kept_above += 1  # previous is a point of the level's set (see the module's docstring)
        return previous

    def _guarded(self, guard: GuardedSolve, level: _Level, rows, values, frozen: np.ndarray) -> np.ndarray:
        """The level solved by ``guard`` with ``rows`` q̇ = ``values`` for the rows above.
        The back-end checks the answer (finite, projected into the box, rows met); the
        guard tames a far target's cost and falls back as QPController does."""
        self._write(guard.backend, level, rows, values)
        x = guard.solve(level.cost.H, level.cost.c, hessian_changed=bool(level.cost.general))
        return self._polish(level, x, frozen)

    def _least_squares(self, level: _Level, frozen: np.ndarray) -> None:
        """Fill R = [√w J_soft; A], its right-hand side, D⁻¹ and c of a level with soft
        general rows (the form :func:`damped_least_squares_step` takes)."""
        level.soft.stack()
        R, rhs, start = level.R, level.rhs, level.soft_rows
        if level.rows:
            R[start:] = self._J[: level.rows]
            rhs[start:start + level.above] = frozen
            rhs[start + level.above:] = self._v[level.hard_rows]
        np.divide(1.0, level.diagonal0 + level.cost.levenberg_marquardt(), out=level.dinv)

    def _closed_form(self, level: _Level, frozen: np.ndarray) -> np.ndarray | None:
        """The level's equality-constrained minimiser when it meets every limit (then it is
        the level's QP solution), else None."""
        return level.closed_form.attempt(self._closed_form_solve, level, frozen)

    def _closed_form_solve(self, level: _Level, frozen: np.ndarray) -> np.ndarray | None:
        level.cost.write_diagonal()
        if level.cost.general:
            self._least_squares(level, frozen)
            return damped_least_squares_step(level.dinv, level.R, level.soft_rows, level.rhs,
                                             level.cost.c if level.cost.diagonal else None)
        level.Ac[: level.rows] = self._J[: level.rows]
        level.Ac[level.rows] = level.cost.c
        level.b[: level.above] = frozen
        level.b[level.above:] = self._v[level.hard_rows]
        return level.step.solve(level.cost.H0, level.Ac, level.b)

    def _polish(self, level: _Level, x: np.ndarray, frozen: np.ndarray) -> np.ndarray:
        """The solver's answer made exact on its active set (a least-squares level whose
        Hessian only ε makes definite is met loosely by solvers): with the bounds it found
        active fixed, the rest in closed form, kept if it meets every limit and costs no more."""
        mineq = self.problem.inequalities.rows
        if not level.cost.general or (mineq and not (self.G @ x < self.h).all()):
            return x  # a general row on its bound: left to the solver
        lb, ub = self.lb, self.ub
        # An absent bound (±inf) is never "reached" (|x − inf| <= inf would say it is).
        at_lower = np.isfinite(lb) & (np.abs(x - lb) <= 1e-9 * (1.0 + np.abs(lb)))
        at_upper = np.isfinite(ub) & ~at_lower & (np.abs(x - ub) <= 1e-9 * (1.0 + np.abs(ub)))
        fixed = at_lower | at_upper
        free = ~fixed
        if not free.any():
            return x
        level.cost.write_diagonal()
        self._least_squares(level, frozen)
        R, rhs, dinv, c = level.R, level.rhs, level.dinv, level.cost.c
        bound = np.where(at_lower, lb, ub)[fixed]
        polished = x.copy()
        polished[fixed] = bound
        step = damped_least_squares_step(dinv[free], R[:, free], level.soft_rows, rhs - R[:, fixed] @ bound,
                                         c[free] if level.cost.diagonal else None)
        if step is None:
            return x
        polished[free] = step
        if not self.problem.inequalities.admits(polished):
            return x
        return polished if self._level_cost(level, polished) <= self._level_cost(level, x) else x

    @staticmethod
    def _level_cost(level: _Level, x: np.ndarray) -> float:
        m = level.soft_rows
        residual = level.R[:m] @ x - level.rhs[:m]
        return 0.5 * float(residual @ residual) + 0.5 * float(x @ (x / level.dinv)) + float(level.cost.c @ x)

    def _named(self, level: _Level, exc: Exception) -> Exception:
        if isinstance(exc, InfeasibleProblem) or level.hard_dim:
            what = ("its hard tasks and the limits cannot all be met" if level.hard_dim
                    else "the limits leave no velocity")
            return InfeasibleProblem(f"level {level.index} ({level.names}) is infeasible: {what} ({exc})")
        return SolverError(f"level {level.index} ({level.names}): {exc}")

    def report(self) -> dict[str, np.ndarray]:
        """Per-level residual ‖J q̇ − v‖ of the last step (velocity units of each level),
        over every task of the level: what each QP minimised (its soft part)."""
        out = np.zeros(len(self.levels))
        for k, (level, stack) in enumerate(zip(self.levels, self._stacks)):
            rows = slice(level.above, level.above + stack.dim)
            out[k] = float(np.linalg.norm(self._J[rows] @ self.qdot - self._v[rows]))
        return {"level_residual": out}
