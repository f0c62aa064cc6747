"""SNS as it was at commit a61460b (before the saturation loop was made cheaper), kept
verbatim apart from this docstring, its imports, its class name and the rank rule of
the saturation passes (marked "pass rank": ‖J‖ and a tolerance of 1e-2, as the package
decides since a pass's rank no longer follows the task scale) and the engine's world
axis (a level's rows are world 0 of the package's Stack, a limit writes a (1, nv) view of
the box: marked "world axis"), for
tests/core/test_sns_equivalence.py only: the package's SNSController must give the same
joint velocities, task scales and saturation counts, step by step. Not part of the
package; see qpik.controllers.sns for the algorithm."""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np
from scipy.linalg import lapack

from qpik.errors import DivergenceError, InvalidInput
from qpik.limits import order_limits
from qpik.problem import Stack, check_dt, group_levels
from qpik.robot import JointLimits, Robot
from qpik.tasks import Task


def StackedLevel(robot: Robot, tasks, weighted: bool) -> Stack:  # the package's stack, as it was named
    return Stack(robot, tasks, weighted)


_gesvd = lapack.dgesvd
_RANK_TOLERANCE = 1e-10  # singular values below this fraction of the largest count as zero
_BOUND_TOLERANCE = 1e-12  # rad/s (m/s): rounding, not a violation


class _Solve:
    """The minimum-norm solution of J F y = r mapped back, x = F y (F: an orthonormal
    basis, or None for the identity): ``pinv`` (n x m) applied to r; and ``null``, a basis
    of the null space of J F mapped back (computed when asked for). Singular values below
    ``_RANK_TOLERANCE · scale`` count as zero, ``scale`` being the size of J itself (not of
    J F: a task direction the levels above nearly took is kept, as the law would keep
    it; only rounding is cut; None: the matrix is J, its largest singular value). One
    SVD, from LAPACK directly (NumPy's wrapper costs more than the decomposition at these
    sizes), or none for one row."""

    __slots__ = ("pinv", "rank", "_basis", "_matrix", "_vt", "_null")

    def __init__(self, matrix: np.ndarray | None, basis: np.ndarray | None, nv: int, scale: float | None = 1.0,
                 tolerance: float = _RANK_TOLERANCE):
        self._basis, self._matrix, self._vt, self._null = basis, matrix, None, None
        if matrix is None:  # J = I: x = F (I F)^# r = F Fᵀ r, and nothing of F is left
            self.rank = nv if basis is None else basis.shape[1]
            self.pinv = np.eye(nv) if basis is None else basis @ basis.T
            self._null = np.zeros((nv, 0))
            return
        m, n = matrix.shape
        if m == 0 or n == 0:
            self.rank, self.pinv = 0, np.zeros((nv, m))
            self._null = np.eye(nv) if basis is None else basis
            return
        if m == 1:  # one row x: x^# = xᵀ/‖x‖²
            row = matrix[0]
            norm_sq = float(row @ row)
            if not math.isfinite(norm_sq):
                raise DivergenceError("SNS: a task Jacobian is not finite")
            self.rank = 1 if norm_sq > (tolerance * (math.sqrt(norm_sq) if scale is None else scale)) ** 2 else 0
            pinv = (row / norm_sq if self.rank else 0.0 * row)[:, None]
            self.pinv = pinv if basis is None else basis @ pinv
            return
        u, s, vt, info = _gesvd(matrix)
        largest = float(s[0])
        if info != 0 or not math.isfinite(largest):
            raise DivergenceError("SNS: the singular value decomposition failed (non-finite Jacobian)")
        threshold = tolerance * (largest if scale is None else scale)
        rank = len(s) if s[-1] > threshold else int(np.count_nonzero(s > threshold))
        self.rank, self._vt = rank, vt
        if rank == len(s) == m:  # full row rank, the usual case
            pinv = vt[:rank].T @ (u.T / s[:, None])
        else:
            pinv = vt[:rank].T @ (u[:, :rank].T / s[:rank, None])
        self.pinv = pinv if basis is None else basis @ pinv

    @property
    def null(self) -> np.ndarray:
        if self._null is None:
            if self._vt is None:  # the one-row case: decompose now
                self._vt = _gesvd(self._matrix)[2]
            null = self._vt[self.rank:].T
            self._null = null if self._basis is None else self._basis @ null
        return self._null


class ReferenceSNSController:
    """Saturation in the Null Space: the prioritised pseudoinverse law inside joint bounds.

    Args:
        robot: the robot the tasks and limits read.
        tasks: tasks grouped into levels by their ``priority`` (0 the highest).
        limits: joint position/velocity limits: the box of joint velocities.
        dt: control period T in seconds (required: the limits bound the step q̇T).
        levels: explicit levels (lists of tasks, level 0 first) instead of ``tasks``.
        max_acceleration: :math:`A_{max}` per dof (nv,) or one number, for the braking
            bound :math:`\\sqrt{2 A_{max} d}` near the ranges of the position limits
            (default: none).

    After each step ``task_scale`` holds each level's scale factor s (1: met at full
    speed; below 1: slowed down to fit the bounds; 0: not executed).

    Raises:
        InvalidInput: an empty level, a task listed twice, a bad ``dt`` or acceleration.
    """

    kind = "sns"
    solver = "none"

    def __init__(self, robot: Robot, tasks: Sequence[Task] | None = None, limits: Sequence = (),
                 dt: float | None = None, *, levels: Sequence[Sequence[Task]] | None = None,
                 max_acceleration=None):
        dt = check_dt(dt)
        grouped = group_levels(robot, tasks, levels, "SNSController")
        self.robot = robot
        self.dt = float(dt)
        self.levels = [StackedLevel(robot, level, weighted=True) for level in grouped]
        self.tasks = [t for level in grouped for t in level]
        for task in self.tasks:
            task.attach(self.dt)
        self.limits = order_limits(limits)
        rows = [type(lim).__name__ for lim in self.limits if lim.inequality_rows]
        if rows:
            raise InvalidInput(f"SNS saturates joints inside a velocity box; it cannot keep general rows "
                               f"({', '.join(rows)}): use the QP or the hierarchy for those")
        nv = robot.nv
        self._lb0, self._ub0 = np.full(nv, -np.inf), np.full(nv, np.inf)
        for limit in self.limits:
            if limit.constant:
                limit.apply(self.dt, self._lb0[None], self._ub0[None])  # world axis
        self._dynamic_limits = [lim for lim in self.limits if not lim.constant]
        self._braking = self._braking_terms(max_acceleration)
        self.lb, self.ub = np.zeros(nv), np.zeros(nv)
        self._identity = np.eye(nv)
        self._zero = np.zeros(nv)
        self._lower, self._upper = [], []  # the box as lists, for the scaling loop
        self.task_scale = np.ones(len(self.levels))
        self.saturated = np.zeros(len(self.levels), dtype=int)  # joints saturated per level
        self.qdot = np.zeros(nv)

    def _braking_terms(self, max_acceleration):
        if max_acceleration is None:
            return []
        nv = self.robot.nv
        amax = np.full(nv, float(max_acceleration)) if np.ndim(max_acceleration) == 0 else \
            np.asarray(max_acceleration, dtype=float)
        if amax.shape != (nv,) or np.any(np.isnan(amax)) or np.any(amax <= 0):
            raise InvalidInput(f"max_acceleration must be positive (inf for none), one number or shape ({nv},)")
        ranges = [lim.limits for lim in self.limits if isinstance(getattr(lim, "limits", None), JointLimits)]
        if not ranges:
            raise InvalidInput("max_acceleration needs a joint position limit among the limits "
                               "(the ranges to brake before)")
        return [(r.qpos_index, r.dof_index, r.lower, r.upper, amax[r.dof_index]) for r in ranges]

    @property
    def level_count(self) -> int:
        return len(self.levels)

    def _bounds(self) -> None:
        lb, ub = self.lb, self.ub
        lb[:] = self._lb0
        ub[:] = self._ub0
        for limit in self._dynamic_limits:
            limit.apply(self.dt, lb[None], ub[None])  # world axis
        q = self.robot.q
        for qpos, dofs, lower, upper, amax in self._braking:
            up = np.sqrt(2.0 * amax * np.maximum(upper - q[qpos], 0.0))
            down = -np.sqrt(2.0 * amax * np.maximum(q[qpos] - lower, 0.0))
            ub[dofs] = np.minimum(ub[dofs], np.maximum(up, lb[dofs]))  # outside the range: return
            lb[dofs] = np.maximum(lb[dofs], np.minimum(down, ub[dofs]))

    def compute_velocity(self) -> np.ndarray:
        """Update every task and bound, then run SNS level by level."""
        self.robot.ensure_kinematics()
        for task in self.tasks:
            task.update()
        for level in self.levels:
            level.stack()
        self._bounds()
        lb, ub = self.lb, self.ub
        self._lower, self._upper = lb.tolist(), ub.tolist()
        # Start from the box's point nearest zero (zero unless a joint is outside its range).
        zero = all(lo <= 0.0 <= hi for lo, hi in zip(self._lower, self._upper))
        qdot = self._zero if zero else np.minimum(np.maximum(0.0, lb), ub)
        basis = None  # orthonormal basis of the null space of the levels done (None: all)
        for k, level in enumerate(self.levels):
            qdot, self.task_scale[k], self.saturated[k], basis = self._level(level, qdot, zero, basis)
            zero = False
        if qdot is self._zero:
            qdot = qdot.copy()
        np.minimum(qdot, ub, out=qdot)  # rounding only: every pass ends inside the box
        np.maximum(qdot, lb, out=qdot)
        if not math.isfinite(qdot.sum()):
            raise DivergenceError("SNS produced a non-finite joint velocity (singular Jacobian)")
        self.qdot = qdot
        return qdot

    def _level(self, level: StackedLevel, above: np.ndarray, above_zero: bool, basis: np.ndarray | None):
        """SNS for one level in the null space ``basis`` (None: all of joint space) of the
        levels above, whose velocity is ``above``. Returns (q̇, scale, saturated joints,
        the basis left for the levels below)."""
        nv = self.robot.nv
        free_count = nv if basis is None else basis.shape[1]
        J, v = level.J[0], level.v[0]  # world axis: one robot
        if free_count == 0 or J.shape[0] == 0:
            return above, 0.0, 0, basis
        identity = level.identity  # J = I: no decomposition needed
        # ‖J‖ for the rank decisions (None: J itself is decomposed, its largest singular value)
        scale = None if identity or basis is None else math.sqrt(float(np.vdot(J, J)))
        task = _Solve(None if identity else (J if basis is None else J @ basis), basis, nv, scale)
        if task.rank == 0:  # the levels above took every direction this task moves
            return above, 0.0, 0, basis
        # The unsaturated pass: the prioritised pseudoinverse law.
        if above_zero:
            qdot = task.pinv @ v
        else:
            qdot = above + task.pinv @ (v - (above if identity else J @ above))
        if self._inside(qdot):
            return qdot, 1.0, 0, task.null
        solve, shifted = task, above
        saturated: list[int] = []
        targets: list[float] = []
        best_scale, best = -1.0, None
        while True:
            # q̇(s) = s a + b: a the task's share, b the saturated joints' and the levels above'
            a = solve.pinv @ v
            b = qdot - a
            scale, critical = self._scaling(a, b, saturated)
            if scale > best_scale:
                best_scale, best = scale, (a, b)
            # One more saturated joint leaves free_count − len(saturated) − 1 directions: if
            # that is fewer than the task needs, it would cost the task one: scale it now.
            if critical < 0 or free_count - len(saturated) - 1 < task.rank:
                break
            # Hold the critical joint at the bound it crossed; the task gets what is left.
            saturated.append(critical)
            targets.append(self._upper[critical] if qdot[critical] > self._upper[critical] else self._lower[critical])
            if basis is None:  # in joint space: the saturated joints are simply set
                shifted = above.copy()
                shifted[saturated] = targets
                free = np.delete(self._identity, saturated, axis=1)
            else:  # within the null space of the levels above, as close as it allows
                hold = _Solve(basis[saturated], basis, nv)
                if hold.rank < len(saturated):  # that null space cannot hold these joints
                    break
                shifted = above + hold.pinv @ (np.array(targets) - above[saturated])
                free = hold.null
            pass_size = math.sqrt(float(np.vdot(J, J)))  # pass rank
            solve = _Solve(None if identity else J @ free, free, nv, pass_size, 1e-2)
            if solve.rank < task.rank:  # the saturations cost the task a direction: scale it
                break
            qdot = shifted + solve.pinv @ (v - J @ shifted)
            if self._inside(qdot):
                return qdot, 1.0, len(saturated), task.null
        if best is None or best_scale < 0.0:  # no scale in [0, 1] fits: not executed
            return above, 0.0, len(saturated), basis
        a, b = best
        return best_scale * a + b, best_scale, len(saturated), task.null

    def _inside(self, qdot: np.ndarray) -> bool:
        return all(lo - _BOUND_TOLERANCE <= x <= hi + _BOUND_TOLERANCE
                   for x, lo, hi in zip(qdot.tolist(), self._lower, self._upper))

    def _scaling(self, a: np.ndarray, b: np.ndarray, saturated: list[int]) -> tuple[float, int]:
        """For a + b outside the box: the largest s in [0, 1] with s·a + b inside on the
        free joints (−1: none) and the most critical joint (the next to saturate; −1: none
        left). A plain loop: nv is small, and NumPy's per-call cost would dominate."""
        lower, upper = self._lower, self._upper
        a_list, b_list = a.tolist(), b.tolist()
        tiny = 1e-14 * (1.0 + max(abs(x) for x in a_list))
        s_max, s_min, first_out, last_in = math.inf, -math.inf, -1, -1
        for i, (ai, bi) in enumerate(zip(a_list, b_list)):
            if i in saturated:
                continue
            if -tiny <= ai <= tiny:  # the task does not move this joint
                if bi < lower[i] - _BOUND_TOLERANCE or bi > upper[i] + _BOUND_TOLERANCE:
                    return -1.0, i  # out of bounds whatever the scale
                continue
            low, high = (lower[i] - bi) / ai, (upper[i] - bi) / ai
            if ai < 0.0:
                low, high = high, low
            if high < s_max:
                s_max, first_out = high, i
            if low > s_min:
                s_min, last_in = low, i
        if first_out < 0 and last_in < 0:
            return -1.0, -1
        critical = first_out if s_max < 1.0 else last_in
        if s_min > s_max or s_max < 0.0 or s_min > 1.0:
            return -1.0, critical
        return min(s_max, 1.0), critical

    def report(self) -> dict[str, np.ndarray]:
        """The last step's task scale of each level (1: met in full)."""
        return {"task_scale": self.task_scale.copy()}
