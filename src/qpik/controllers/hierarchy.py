r"""HierarchicalController: a strict task hierarchy solved as a sequence of QPs.

Level k (0 the highest priority) is solved after every level above it:

.. math::
    \dot q_k^* = \arg\min_{\dot q}\ \tfrac12 \sum_{i \in k,\ \text{soft}} w_i \|J_i \dot q - v_i\|^2
                 + \tfrac12 \epsilon \|\dot q\|^2
    \quad\text{s.t.}\quad
    J_j \dot q = J_j \dot q_{k-1}^* \ (j \text{ in the levels above}),\quad
    J_h \dot q = v_h \ (h \in k,\ \text{hard}),\quad lb \le \dot q \le ub

with every limit hard at every level (Kanoun, Lamiraux and Wieber 2011; Escande, Mansard
and Wieber 2014). The equalities keep the optimum of each level above: the residual
:math:`J_j \dot q - v_j` of a level that could not be met exactly is frozen at its
optimal value (the "optimal slack" :math:`w_j^* = J_j \dot q^*_{k-1} - v_j`), and since a
level's cost is strictly convex in its task velocities :math:`J_j \dot q`, these are
unique: the set the equalities leave is exactly the set of optima of the level above.
:math:`\dot q^*_{k-1}` satisfies all of them, so a level below can never be infeasible;
only a level's own hard tasks (or an empty box) can make it so, and the error then names
that level. In floating point a lower level's set can be too thin for a solver (level 0
at a vertex of the box, velocities of 1e13 rad/s from a target far out of reach): when
every solver and the fallbacks fail on a level without hard tasks of its own, the level
keeps :math:`\dot q^*_{k-1}`, a point of its set (every limit and every level above
kept; only its own cost is not improved on that step), and ``kept_above`` counts it. The regulariser ε (and a task's Levenberg–Marquardt term) only picks one
optimum within a level; what the levels below keep is each task's velocity.

Each level owns a back-end of the solver asked for (:func:`qpik.solvers.make_backend`:
persistent workspaces and warm starts per level). Equality rows that depend on each other
(more rows above than joints, or a singular configuration) are consistent by
construction but some solvers refuse them; such a level is solved again with the rows
replaced by an orthonormal basis of their row space (an SVD), which constrains the same
set.

With a hard position task at level 0 and a joint-space task at level 1 this is exactly
the hard QP (and, with no limit active, the null-space law).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ..errors import InfeasibleProblem, InvalidInput, SolverError
from ..limits import order_limits
from ..robot import Robot, check_same_robot
from ..solvers import make_backend
from ..tasks import Task
from .closed_form import ClosedFormPause, ClosedFormStep, damped_least_squares_step, inside_limits
from .fallbacks import GuardedSolve, check_finite_velocities
from .levels import StackedLevel, check_dt, group_levels

# Singular values below this fraction of the largest are dropped when the rows above a
# level are replaced by a basis of their row space.
_RANK_TOLERANCE = 1e-10


class _Level:
    """One level: its soft tasks (the cost), its hard rows, and its solver back-end."""

    def __init__(self, index: int, tasks: Sequence[Task], above: int, stack: StackedLevel, nv: int,
                 regularization: float):
        self.index = index
        self.tasks = list(tasks)
        self.names = stack.names
        self.above = above  # equality rows frozen from the levels above
        self.hard_rows = slice(stack.offset, stack.offset + stack.hard_dim)  # hard tasks come first
        self.hard_dim = stack.hard_dim
        soft = [t for t in self.tasks if not t.hard]
        self.soft_diagonal = [t for t in soft if t.joint_space]
        self.soft_general = [t for t in soft if not t.joint_space]
        # ε only breaks ties between a level's optima. A level of hard tasks alone has no
        # cost of its own: its minimum-norm solution (H = I, which any solver meets
        # accurately; with H = εI a tolerance-based solver would leave the null space
        # loose). Joint-space tasks on every dof already make H positive definite: no ε.
        covered = np.zeros(nv, dtype=bool)
        for task in soft:
            if task.joint_space:
                covered[task.dofs[task.weight > 0]] = True
        self.H0 = np.eye(nv) * (1.0 if not soft else 0.0 if covered.all() else regularization)
        for task in self.soft_diagonal:
            self.H0.reshape(-1)[:: nv + 1][task.dofs] += task.weight
        self.hessian_changes = bool(self.soft_general)
        self.H = self.H0.copy()
        self.c = np.zeros(nv)
        rows = above + self.hard_dim
        # The closed-form step (qpik.controllers.closed_form) on the level's equalities (the
        # rows above, then its hard rows): with a constant diagonal Hessian, through H⁻¹;
        # with soft general rows, in damped least-squares form (accurate when only ε
        # makes H definite) on R = [√w J_soft; A].
        self.soft_rows = sum(t.dim for t in self.soft_general)
        self.roots = [np.sqrt(t.weight) for t in self.soft_general]  # weights are read once
        self.root_columns = [root[:, None] for root in self.roots]
        self.diagonal0 = np.diag(self.H0).copy()
        self.dinv = np.zeros(nv)
        self.dinv_fixed = False  # dinv holds 1/diagonal0 (no LM damping at the last fill)
        if self.soft_general:
            self.R = np.zeros((self.soft_rows + rows, nv))
            self.rhs = np.zeros(self.soft_rows + rows)
        else:
            self.Ac = np.zeros((rows + 1, nv))  # [A; cᵀ]
            self.b = np.zeros(rows)
            self.closed_form = ClosedFormStep(self.H0, rows)
        self.pause = ClosedFormPause()
        self.backend = None
        self.guard = None  # the back-end with taming and fallbacks (qpik.controllers.fallbacks)
        self.reduced: dict[int, GuardedSolve] = {}  # for rows replaced by a basis, by count


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
        check_same_robot(robot, (), limits, "HierarchicalController")  # tasks: group_levels checks them
        self.robot = robot
        self.solver = solver
        self.dt = float(dt)
        self.limits = order_limits(limits)
        # General rows G q̇ ≤ h (collision avoidance) are filled once per step and hold at
        # every level, as the box does.
        self._row_limits = [lim for lim in self.limits if lim.inequality_rows]
        self._mineq = sum(lim.inequality_rows for lim in self._row_limits)
        self.G, self.h = np.zeros((self._mineq, robot.nv)), np.zeros(self._mineq)
        self._row_slices = []
        start = 0
        for lim in self._row_limits:
            self._row_slices.append(slice(start, start + lim.inequality_rows))
            start += lim.inequality_rows
        self._native = native
        self._solver_settings = solver_settings
        nv = robot.nv
        # One stack of every level's rows (unweighted, zero-weight rows left out), level
        # by level and hard tasks first within a level: the equalities of level k are
        # then a prefix of it (all rows above, then level k's hard rows).
        ordered = [[t for t in level if t.hard] + [t for t in level if not t.hard] for level in grouped]
        sizes = [StackedLevel(robot, level, weighted=False).dim for level in ordered]
        self._J = np.zeros((sum(sizes), nv))
        self._v = np.zeros(sum(sizes))
        self._stacks = []
        offset = 0
        for level_tasks, size in zip(ordered, sizes):
            rows = slice(offset, offset + size)
            stack = StackedLevel(robot, level_tasks, weighted=False, out=(self._J[rows], self._v[rows]))
            stack.offset = offset
            stack.hard_dim = sum(t.dim for t in level_tasks if t.hard)
            self._stacks.append(stack)
            offset += size
        self.levels: list[_Level] = []
        for k, (level_tasks, stack) in enumerate(zip(grouped, self._stacks)):
            level = _Level(k, level_tasks, stack.offset, stack, nv, float(regularization))
            level.backend = make_backend(solver, nv, level.above + level.hard_dim, self._mineq, native=native,
                                         **solver_settings)
            level.guard = GuardedSolve(level.backend, solver)
            self.levels.append(level)
        self.tasks = [t for level in grouped for t in level]
        self.updated_tasks = tuple(self.tasks)  # fresh after every step (rollouts read them)
        for task in self.tasks:
            task.attach(self.dt)
        self._lb0, self._ub0 = np.full(nv, -np.inf), np.full(nv, np.inf)
        for limit in self.limits:
            if limit.constant and limit.box:
                limit.apply(self.dt, self._lb0, self._ub0)
        self._dynamic_limits = [lim for lim in self.limits if lim.box and not lim.constant]
        self.lb, self.ub = np.zeros(nv), np.zeros(nv)
        self.level_velocities = np.zeros((len(self.levels), nv))  # q̇*_k of each level
        self.qdot = np.zeros(nv)
        self.kept_above = 0  # level solves that failed and kept the level above's velocity

    @property
    def level_count(self) -> int:
        return len(self.levels)

    def compute_velocity(self) -> np.ndarray:
        """Update every task and limit, then solve the levels in order."""
        self.robot.ensure_kinematics()
        for task in self.tasks:
            task.update()
        for stack in self._stacks:
            stack.stack()
        self.lb[:] = self._lb0
        self.ub[:] = self._ub0
        for limit in self._dynamic_limits:
            limit.apply(self.dt, self.lb, self.ub)
        for limit, rows in zip(self._row_limits, self._row_slices):
            limit.fill_inequalities(self.dt, self.G[rows], self.h[rows])
        previous = None
        for level in self.levels:
            x = self._solve_level(level, previous)
            self.level_velocities[level.index] = x
            previous = x
        self.qdot = previous
        return previous

    def _cost(self, level: _Level) -> None:
        H, c = level.H, level.c
        H[:] = level.H0
        self._joint_space_cost(level)
        diagonal = H.reshape(-1)[:: H.shape[0] + 1]
        for task in level.soft_general:
            weighted = task.weight[:, None] * task.jacobian
            H += task.jacobian.T @ weighted
            c -= weighted.T @ task.target_velocity
            if task.lm_damping:
                error = task.error
                diagonal += task.lm_damping * float(error @ (task.weight * error))

    def _write(self, backend, level: _Level, above_rows, above_values) -> None:
        m = len(above_values)
        backend.A[:m] = above_rows
        backend.b[:m] = above_values
        if level.hard_dim:
            backend.A[m:] = self._J[level.hard_rows]
            backend.b[m:] = self._v[level.hard_rows]
        backend.lb[:] = self.lb
        backend.ub[:] = self.ub
        if self._mineq:
            backend.G[:] = self.G
            backend.h[:] = self.h

    def _run(self, guard: GuardedSolve, level: _Level) -> np.ndarray:
        # The back-end checks the answer (finite, projected into the box, rows met); the
        # guard tames a far target's cost and falls back as QPController does.
        return guard.solve(level.H, level.c, hessian_changed=level.hessian_changes)

    def _solve_level(self, level: _Level, previous: np.ndarray | None) -> np.ndarray:
        above = self._J[: level.above]
        frozen = above @ previous if level.above else self._v[:0]
        x = self._closed_form(level, frozen)
        if x is not None:
            return x
        self._cost(level)
        check_finite_velocities(self.tasks, level.c, self._v)
        try:
            self._write(level.backend, level, above, frozen)
            return self._polish(level, self._run(level.guard, level), frozen)
        except (InfeasibleProblem, SolverError) as first:
            if not level.above:
                raise self._named(level, first) from None
        # The rows above are consistent (q̇*_{k-1} meets them) but may depend on each
        # other: constrain the same set through an orthonormal basis of their row space.
        _, singular, vt = np.linalg.svd(above, full_matrices=False)
        rank = int(np.sum(singular > _RANK_TOLERANCE * singular[0])) if singular.size and singular[0] > 0 else 0
        basis = vt[:rank]
        guard = level.reduced.get(rank)
        if guard is None:
            guard = GuardedSolve(make_backend(self.solver, self.robot.nv, rank + level.hard_dim, self._mineq,
                                              native=self._native, **self._solver_settings), self.solver)
            level.reduced[rank] = guard
        try:
            self._write(guard.backend, level, basis, basis @ previous)
            return self._polish(level, self._run(guard, level), frozen)
        except (InfeasibleProblem, SolverError) as second:
            if level.hard_dim:  # previous misses the level's own hard rows
                raise self._named(level, second) from None
        self.kept_above += 1  # previous is a point of the level's set (see the module's docstring)
        return previous

    def _least_squares(self, level: _Level, frozen: np.ndarray) -> None:
        """Fill R = [√w J_soft; A], its right-hand side, D⁻¹ and c of a level with soft
        general rows (the form :func:`damped_least_squares_step` takes)."""
        rows = level.above + level.hard_dim
        R, rhs, start = level.R, level.rhs, 0
        damping = 0.0
        for task, root, column in zip(level.soft_general, level.roots, level.root_columns):
            stop = start + task.dim
            np.multiply(column, task.jacobian, out=R[start:stop])
            np.multiply(root, task.target_velocity, out=rhs[start:stop])
            if task.lm_damping:
                error = task.error
                damping += task.lm_damping * float(error @ (task.weight * error))
            start = stop
        if rows:
            R[start:] = self._J[:rows]
            if level.above:
                rhs[start:start + level.above] = frozen
            if level.hard_dim:
                rhs[start + level.above:] = self._v[level.hard_rows]
        if damping or not level.dinv_fixed:
            np.divide(1.0, level.diagonal0 + damping, out=level.dinv)
            level.dinv_fixed = not damping

    @staticmethod
    def _joint_space_cost(level: _Level) -> None:
        """c of the level's joint-space tasks alone (the soft general rows add theirs in
        :meth:`_cost`, or stay in R for the closed form)."""
        c = level.c
        c.fill(0.0)
        for task in level.soft_diagonal:
            c[task.dofs] -= task.weight * task.target_velocity

    def _closed_form(self, level: _Level, frozen: np.ndarray) -> np.ndarray | None:
        """The level's equality-constrained minimiser when it meets every limit (then it is
        the level's QP solution, as for :class:`~qpik.controllers.qp.QPController`), else
        None; after a step where a limit bound, the next few go to the solver directly
        (:class:`~qpik.controllers.closed_form.ClosedFormPause`)."""
        if not level.pause.ready():
            return None
        above, rows = level.above, level.above + level.hard_dim
        self._joint_space_cost(level)
        if level.soft_general:
            self._least_squares(level, frozen)
            x = damped_least_squares_step(level.dinv, level.R, level.soft_rows, level.rhs,
                                          level.c if level.soft_diagonal else None)
        else:
            level.Ac[:rows] = self._J[:rows]
            level.Ac[rows] = level.c
            level.b[:above] = frozen
            level.b[above:] = self._v[level.hard_rows]
            x = level.closed_form.solve(level.H0, level.Ac, level.b)
        if x is not None and inside_limits(x, self.lb, self.ub, self.G, self.h):
            level.pause.succeeded()
            return x
        level.pause.failed()
        return None

    def _polish(self, level: _Level, x: np.ndarray, frozen: np.ndarray) -> np.ndarray:
        """The solver's answer made exact on its active set. A least-squares level whose
        Hessian only ε makes definite is one a tolerance-based solver meets loosely (DAQP:
        a path residual of 4e-7 m/s where 0 was possible): with the bounds it found active
        fixed, the rest is an equality-constrained least squares solved in closed form.
        The polished point is kept only if it meets every limit and costs no more."""
        if not level.soft_general or (self._mineq and not (self.G @ x < self.h).all()):
            return x  # a general row on its bound: left to the solver
        lb, ub = self.lb, self.ub
        # An absent bound (±inf) is never "reached" (|x − inf| <= inf would say it is).
        at_lower = np.isfinite(lb) & (np.abs(x - lb) <= 1e-9 * (1.0 + np.abs(lb)))
        at_upper = np.isfinite(ub) & ~at_lower & (np.abs(x - ub) <= 1e-9 * (1.0 + np.abs(ub)))
        fixed = at_lower | at_upper
        free = ~fixed
        if not free.any():
            return x
        self._joint_space_cost(level)
        self._least_squares(level, frozen)
        R, rhs, dinv, c = level.R, level.rhs, level.dinv, level.c
        bound = np.where(at_lower, lb, ub)[fixed]
        polished = x.copy()
        polished[fixed] = bound
        step = damped_least_squares_step(dinv[free], R[:, free], level.soft_rows, rhs - R[:, fixed] @ bound,
                                         c[free] if level.soft_diagonal else None)
        if step is None:
            return x
        polished[free] = step
        if not inside_limits(polished, lb, ub, self.G, self.h):
            return x
        return polished if self._level_cost(level, polished) <= self._level_cost(level, x) else x

    @staticmethod
    def _level_cost(level: _Level, x: np.ndarray) -> float:
        m = level.soft_rows
        residual = level.R[:m] @ x - level.rhs[:m]
        return 0.5 * float(residual @ residual) + 0.5 * float(x @ (x / level.dinv)) + float(level.c @ x)

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
        for k, stack in enumerate(self._stacks):
            rows = slice(stack.offset, stack.offset + stack.dim)
            out[k] = float(np.linalg.norm(self._J[rows] @ self.qdot - self._v[rows]))
        return {"level_residual": out}
