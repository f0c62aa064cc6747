r"""QPController: a stack of tasks and limits turned into one QP per control step.

.. math::
    \min_{\dot q}\ \tfrac12 \sum_{i\,\text{soft}} w_i \|J_i \dot q - v_i\|^2
                  + \tfrac12 \epsilon \|\dot q\|^2
    \quad\text{s.t.}\quad J_h \dot q = v_h \ (\text{hard tasks}),\quad
    G \dot q \le h,\quad lb \le \dot q \le ub \ (\text{limits})

With a hard position task and the manipulability task
(:math:`\tfrac12\|\dot q - k_0\nabla\sigma\|^2`) the solution is exactly the
null-space law :math:`J^\dagger v + (I - J^\dagger J) k_0 \nabla\sigma` whenever no
limit is active (Lagrange conditions of the equality-constrained least squares).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ..errors import InfeasibleProblem, InvalidInput
from ..limits import Limit, order_limits
from ..limits.limit import as_slice
from ..robot import Robot, check_same_robot
from ..solvers import make_backend
from ..tasks import Task
from .closed_form import ClosedFormPause, ClosedFormStep, inside_box, inside_limits
from .diagnostics import explain_infeasibility
from .fallbacks import GuardedSolve, check_finite_velocities

# Beyond this the Levenberg–Marquardt term dominates the cost: H and c are scaled down
# together (same minimiser) so no solver sees huge numbers from a far-away target.
LM_RESCALE = 1e6
# Up to this many dofs (and with no general rows) a closed-form step keeps the box as
# lists of floats: on the arm (4 dofs) the box and its check cost 1.8 µs so, 3.4 with
# the box written to arrays. (The position limit's float loop stops paying at ~8 joints.)
BOX_AS_LISTS_MAX_DOFS = 8

def check_dt(dt) -> float:
    """The control period as a positive finite float, or InvalidInput."""
    if dt is None:
        raise InvalidInput("dt is required: the control period in seconds (e.g. dt=0.002), "
                           "which the limits use to bound the next step")
    try:
        value = float(dt)
    except (TypeError, ValueError):
        raise InvalidInput(f"dt must be a number of seconds, got {dt!r}") from None
    if not (np.isfinite(value) and value > 0):
        raise InvalidInput(f"dt must be positive and finite, got {dt}")
    return value


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

    :meth:`compute_velocity` updates the robot's kinematics itself when its configuration
    changed since the last update. Task weights and constant limits (velocity bounds) are
    read once, when the controller is built: their share of the QP is precomputed, the
    hot path only adds what changes.
    """

    kind = "qp"

    def __init__(self, robot: Robot, tasks: Sequence[Task], limits: Sequence[Limit] = (), solver: str = "daqp",
                 dt: float | None = None, regularization: float = 1e-12, native: bool = True,
                 fast_path: bool = True, **solver_settings):
        if not tasks:
            raise InvalidInput("a QPController needs at least one task")
        self.dt = check_dt(dt)
        check_same_robot(robot, tasks, limits, "QPController")
        self.robot = robot
        self.tasks = list(tasks)
        for task in self.tasks:
            task.attach(self.dt)
        self.limits = order_limits(limits)
        self.solver = solver
        nv = robot.nv
        self._hard = [t for t in self.tasks if t.hard]
        soft = [t for t in self.tasks if not t.hard]
        # Joint-space tasks (J = I[dofs], as each task itself says) go on H's diagonal.
        self._soft_diagonal = [t for t in soft if t.joint_space]
        self._soft_general = [t for t in soft if not t.joint_space]
        meq = sum(t.dim for t in self._hard)
        self._rows = _row_slices(self._hard, lambda t: t.dim)
        self._row_limits = [lim for lim in self.limits if lim.inequality_rows]
        mineq = sum(lim.inequality_rows for lim in self._row_limits)
        self._inequality_slices = _row_slices(self._row_limits, lambda lim: lim.inequality_rows)
        self._backend = make_backend(solver, nv, meq, mineq, native=native, **solver_settings)
        # The equality rows and the cost vector share one array, [A; cᵀ], which the
        # closed-form step reads in one product; the solver gets a copy on the (rare) steps
        # that need it. Limits write straight into the back-end's box and rows.
        self._Ac = np.zeros((meq + 1, nv))
        self.A, self.c = self._Ac[:meq], self._Ac[meq]
        self.b = np.zeros(meq)
        self.G, self.h = self._backend.G, self._backend.h
        self._lb, self._ub = self._backend.lb, self._backend.ub
        # Parts that do not change between steps are computed once: the regulariser and
        # the joint-space tasks' weights on H's diagonal, and the constant bounds.
        self._H0 = np.eye(nv) * float(regularization)
        self._diagonal_dofs = [as_slice(task.dofs) for task in self._soft_diagonal]
        for task, dofs in zip(self._soft_diagonal, self._diagonal_dofs):
            self._H0.reshape(-1)[:: nv + 1][dofs] += task.weight
        self._lb0, self._ub0 = np.full(nv, -np.inf), np.full(nv, np.inf)
        for limit in self.limits:
            if limit.constant and limit.box:
                limit.apply(self.dt, self._lb0, self._ub0)
        self._dynamic_limits = [lim for lim in self.limits if lim.box and not lim.constant]
        self._neg_weights = [-task.weight for task in self._soft_diagonal]
        self.H = self._H0.copy()
        self._diag = self.H.reshape(-1)[:: nv + 1]
        self._scratch = np.zeros(nv)
        self.qdot = np.zeros(nv)
        self._closed_form = ClosedFormStep(None if self._soft_general else self._H0, meq) if fast_path else None
        # No general rows and a box of a few joints: the closed-form steps keep the box in
        # floats (each NumPy call on an array this small costs more than the arithmetic).
        self._box_as_lists = self._closed_form is not None and not mineq and nv <= BOX_AS_LISTS_MAX_DOFS
        self._pending_box = None
        # The step's work as flat lists, read once here (a Python loop over them is the
        # hot path's overhead).
        self._task_updates = [task.update for task in self.tasks]
        self.updated_tasks = tuple(self.tasks)  # fresh after every step (rollouts read them)
        self._diagonal_plan = list(zip(self._soft_diagonal, self._neg_weights, self._diagonal_dofs))
        # A first joint-space task on every dof writes c itself (no zeroing, no scratch).
        c_written_by_first = bool(self._soft_diagonal) and isinstance(self._diagonal_dofs[0], slice) \
            and self._diagonal_dofs[0] == slice(0, nv)
        self._c_first = self._diagonal_plan.pop(0)[:2] if c_written_by_first else None
        self._hard_plan = [(self.A[rows], self.b[rows], task) for task, rows in zip(self._hard, self._rows)]
        self._box_updates = [limit.apply for limit in self._dynamic_limits]
        self._box_from = None
        # Starting from the constant box as lists pays only for a limit that works in floats
        # (30 joints: 5.8 µs against 4.1 from arrays).
        if self._dynamic_limits and getattr(self._dynamic_limits[0], "in_floats", False):
            self._box_from = self._dynamic_limits[0].apply_from
            self._box_updates.pop(0)
        self._lb0_list, self._ub0_list = self._lb0.tolist(), self._ub0.tolist()
        self._row_plan = list(zip(self._row_limits, self._inequality_slices))
        self._pause = ClosedFormPause()
        self.solver_calls = 0  # steps that needed the solver (a limit would bind)
        self._guard = GuardedSolve(self._backend, solver)  # taming, fallbacks, infeasibility confirmed

    def compute_velocity(self) -> np.ndarray:
        """Update every task and limit from the current kinematics and solve the QP."""
        self.robot.ensure_kinematics()
        for update in self._task_updates:
            update()
        H, c = self.H, self.c
        # The cost: joint-space tasks on c's entries (H's diagonal is constant), then the
        # soft tasks with their own Jacobian (H changes).
        if self._c_first is not None:
            task, neg_weight = self._c_first
            np.multiply(neg_weight, task.target_velocity, c)
        else:
            c.fill(0.0)
        for task, neg_weight, dofs in self._diagonal_plan:
            scratch = self._scratch[: task.dim]
            np.multiply(neg_weight, task.target_velocity, scratch)
            c[dofs] += scratch
        if self._soft_general:
            self._add_general_tasks(H, c)
        for jacobian_rows, velocity_rows, task in self._hard_plan:
            jacobian_rows[...] = task.jacobian
            velocity_rows[...] = task.target_velocity
        try_closed_form = self._closed_form is not None and self._pause.ready()
        lbs = None
        if try_closed_form and self._box_as_lists:
            # A small box, in floats from start to finish: written to the solver's arrays
            # only on a step that needs the solver (or when lb/ub are read).
            lbs, ubs = self._lb0_list.copy(), self._ub0_list.copy()
            for limit in self._dynamic_limits:
                limit.apply_to_lists(self.dt, lbs, ubs)
            self._pending_box = lbs, ubs
        else:
            self._pending_box = None
            lb, ub = self._lb, self._ub
            if self._box_from is not None:  # the first box limit writes the whole box
                self._box_from(self.dt, self._lb0_list, self._ub0_list, lb, ub)
            else:
                lb[:] = self._lb0
                ub[:] = self._ub0
            for apply in self._box_updates:
                apply(self.dt, lb, ub)
            for limit, rows in self._row_plan:
                limit.fill_inequalities(self.dt, self.G[rows], self.h[rows])
        if try_closed_form:
            x = self._closed_form.solve(H, self._Ac, self.b)
            if x is not None and (inside_box(x.tolist(), lbs, ubs) if lbs is not None
                                  else inside_limits(x, self._lb, self._ub, self.G, self.h)):
                self._pause.succeeded()
                self.qdot = x
                return x
            self._pause.failed()  # a limit binds: the solver takes the next few steps
            self._write_pending_box()
        self.solver_calls += 1
        check_finite_velocities(self.tasks, self.c, self.b)
        self._backend.A[:] = self.A
        self._backend.b[:] = self.b
        try:
            self.qdot = self._guard.solve(H, c, hessian_changed=bool(self._soft_general))
        except InfeasibleProblem as exc:
            raise InfeasibleProblem(f"QP infeasible ({self.solver}): {explain_infeasibility(self, exc.variable)}",
                                    exc.variable) from None
        return self.qdot

    @property
    def lb(self) -> np.ndarray:
        """The lower bound on q̇ of the last step (nv,)."""
        self._write_pending_box()
        return self._lb

    @property
    def ub(self) -> np.ndarray:
        """The upper bound on q̇ of the last step (nv,)."""
        self._write_pending_box()
        return self._ub

    def _write_pending_box(self) -> None:
        if self._pending_box is not None:
            self._lb[:], self._ub[:] = self._pending_box
            self._pending_box = None

    def _add_general_tasks(self, H: np.ndarray, c: np.ndarray) -> None:
        """H = H0 + Σ JᵀWJ (+ the Levenberg–Marquardt terms), c −= Σ JᵀWv."""
        H[:] = self._H0
        lm_total = 0.0
        for task in self._soft_general:
            weighted = task.weight[:, None] * task.jacobian
            H += np.dot(task.jacobian.T, weighted)  # np.dot: less overhead than @ on small arrays
            c -= np.dot(task.target_velocity, weighted)
            if task.lm_damping:
                error = task.error
                lm = task.lm_damping * float(np.dot(error, task.weight * error))
                self._diag += lm
                lm_total += lm
        if lm_total > LM_RESCALE:
            if not np.isfinite(lm_total):
                raise InvalidInput("a soft task's error is too large to weigh (its squared norm overflows): "
                                   "check its target")
            scale = 1.0 / (1.0 + lm_total)
            H *= scale
            c *= scale

    @property
    def fallbacks(self) -> int:
        """Steps the solver failed on and a fallback solver solved."""
        return self._guard.fallbacks

def _row_slices(items, size) -> list[slice]:
    """Consecutive row blocks, one per item, of ``size(item)`` rows each."""
    slices, start = [], 0
    for item in items:
        slices.append(slice(start, start + size(item)))
        start += size(item)
    return slices
