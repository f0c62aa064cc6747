r"""SNSController: Saturation in the Null Space (Flacco, De Luca and Khatib, ICRA 2012,
IROS 2012; IEEE T-RO 31(3), 2015), the pseudoinverse law made to respect joint bounds,
for one robot or N worlds.

Level by level (priority 0 first), in the null space of the levels above: the
prioritised pseudoinverse law; a joint that would leave its velocity bounds is held at
its bound and the task solved again by the others, until the answer stays in the box; a
task that cannot be met inside it is executed along its own direction, scaled by the
largest s ∈ [0, 1] a pass allows (:math:`\dot q(s) = s\,a + b`). The null space is
carried as an orthonormal basis Z or as the projector P itself
(:class:`~qpik.controllers.sns_null_space.NullSpace`). A saturation pass whose
rows keep a singular value below 1e-2 ‖J‖ counts as having cost the task that
direction: the task is scaled on the passes before it (near a singularity such a pass
would move the saturated joints at full speed for a tiny share of the task). The
derivation, with the bounds (including the braking bound :math:`\sqrt{2 A_{max} d}`), is
in docs/controllers.md.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from ..errors import DivergenceError, InvalidInput
from ..limits import Limit
from ..limits.limit import bound_values
from ..problem import Problem, Stack, check_dt, group_levels
from ..tasks import Task
from .sns_null_space import NullSpace, pseudoinverse
from .worlds import solve_each

_BOUND_TOLERANCE = 1e-12  # rad/s (m/s): rounding, not a violation
# A saturation pass whose rows keep a singular value below this fraction of ‖J‖ (a
# condition above 100) counts as having cost the task that direction: the task is scaled
# instead (docs/controllers.md, "Near a singularity").
_PASS_RANK_TOLERANCE = 1e-2


def _level_stack(robot, tasks: Sequence[Task]) -> Stack:
    """A level's rows weighted by √w; one task of one weight is its own stack (a uniform
    weight changes no pseudoinverse solution; J = I is then seen as such)."""
    single = len(tasks) == 1 and bool(np.all(tasks[0].weight == tasks[0].weight[0]))
    return Stack(robot, tasks, weighted=not single)


class BrakingBounds:
    r"""The braking bound near the ranges of the position limits, in every world:
    :math:`-\sqrt{2 A_{max} (q - q_{min})} \le \dot q \le \sqrt{2 A_{max} (q_{max} - q)}`
    (a joint can still stop inside its range at deceleration :math:`A_{max}`), kept inside
    the box (outside the range: the box's way back).

    Args:
        robot: the robot.
        limits: the controller's limits (their ``ranges``: the joints to brake).
        max_acceleration: :math:`A_{max}` per dof (nv,) or one number; ``inf`` on a dof:
            no braking there.

    Raises:
        InvalidInput: an acceleration that is NaN, not positive or (finite) above 1e12, a
            wrong shape, or no position limit among the limits.
    """

    def __init__(self, robot, limits: Sequence[Limit], max_acceleration):
        amax = bound_values(max_acceleration, robot.nv, "max_acceleration", " (one per dof)")
        finite = np.isfinite(amax)
        ranges = [lim.ranges for lim in limits if lim.ranges is not None]
        if not ranges:
            raise InvalidInput("max_acceleration needs a joint position limit among the limits "
                               "(the ranges to brake before)")
        self.terms = []  # (qpos, dofs, lower, upper, A_max) of the braked joints of each range
        for r in ranges:
            braked = finite[r.dof_index]
            self.terms.append((np.asarray(r.qpos_index)[braked], np.asarray(r.dof_index)[braked],
                               np.asarray(r.lower)[braked], np.asarray(r.upper)[braked],
                               amax[r.dof_index][braked]))

    def apply(self, q: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> None:
        """Tighten the box [lower, upper] (N, nv) in place at the configurations q (N, nq)."""
        for qpos, dofs, low, high, amax in self.terms:
            position = q[:, qpos]
            up = np.sqrt(2.0 * amax * np.maximum(high - position, 0.0))
            down = -np.sqrt(2.0 * amax * np.maximum(position - low, 0.0))
            upper[:, dofs] = np.minimum(upper[:, dofs], np.maximum(up, lower[:, dofs]))  # outside the range: return
            lower[:, dofs] = np.maximum(lower[:, dofs], np.minimum(down, upper[:, dofs]))


class SNSController:
    """Saturation in the Null Space: the prioritised pseudoinverse law inside joint bounds,
    for one robot or N worlds.

    Args:
        robot: the robot the tasks and limits read (:class:`qpik.Robot` or
            :class:`qpik.batch.Robot`).
        tasks: tasks grouped into levels by their ``priority`` (0 the highest).
        limits: joint position/velocity limits: the box of joint velocities (general rows
            are refused).
        dt: control period T in seconds (required: the limits bound the step q̇T).
        levels: explicit levels (lists of tasks, level 0 first) instead of ``tasks``.
        max_acceleration: :math:`A_{max}` per dof (nv,) or one number, for the braking
            bound :math:`\\sqrt{2 A_{max} d}` near the ranges of the position limits
            (default: none; :class:`BrakingBounds`).

    After each step ``task_scale`` holds each level's scale factor s (1: met at full
    speed; below 1: slowed down to fit the bounds; 0: not executed) and ``saturated``
    the joints saturated per level: (levels,) for one robot, (N, levels) for N worlds.

    How it runs over worlds: the tasks, the box and the braking bounds are filled for
    every world at once; the saturation passes then run world by world, each on views of
    its world's rows and bounds (as lists of floats: the passes read them joint by
    joint). The passes are data-dependent per world (which joint saturates, in what order,
    how many passes, a basis or a projector for the null space), so they are a loop over
    worlds, written once for all of them.

    Raises:
        InvalidInput: an empty level, a task listed twice, a bad ``dt`` or acceleration,
            general rows among the limits, a model without degrees of freedom.
    """

    kind = "sns"
    solver = "none"

    def __init__(self, robot, tasks: Sequence[Task] | None = None, limits: Sequence[Limit] = (),
                 dt: float | None = None, *, levels: Sequence[Sequence[Task]] | None = None,
                 max_acceleration=None):
        dt = check_dt(dt)
        if robot.nv == 0:  # as the QP: nothing to solve for is a malformed problem, not a step
            raise InvalidInput("SNSController needs a robot with at least one degree of freedom; "
                               "this model has none")
        grouped = group_levels(robot, tasks, levels, "SNSController")
        rows = [type(lim).__name__ for lim in limits if lim.inequality_rows]
        if rows:
            raise InvalidInput(f"SNS saturates joints inside a velocity box; it cannot keep general rows "
                               f"({', '.join(rows)}): use the QP or the hierarchy for those")
        self.tasks = [t for level in grouped for t in level]
        self.problem = Problem(robot, self.tasks, limits, dt, "SNSController")
        self.robot, self.dt, self.limits = robot, self.problem.dt, self.problem.limits
        self.levels = [_level_stack(robot, level) for level in grouped]
        self.updated_tasks = tuple(self.tasks)  # fresh after every step (rollouts read them)
        self._braking = None if max_acceleration is None else BrakingBounds(robot, self.limits, max_acceleration)
        n, count = robot.n, len(self.levels)
        self.task_scales = np.ones((n, count))
        self.saturations = np.zeros((n, count), dtype=int)  # joints saturated per level
        self.task_scale, self.saturated = robot.present(self.task_scales), robot.present(self.saturations)
        self.qdots = np.zeros((n, robot.nv))
        self.qdot = robot.present(self.qdots)
        self._passes = _Passes(robot.nv)

    @property
    def level_count(self) -> int:
        return len(self.levels)

    lb = property(lambda self: self.robot.present(self.problem.lower).copy(),
                  doc="Lower bounds of the last step's velocity box (a copy).")
    ub = property(lambda self: self.robot.present(self.problem.upper).copy(),
                  doc="Upper bounds of the last step's velocity box (a copy).")

    def compute_velocity(self) -> np.ndarray:
        """Fill the step's problem (tasks, bounds) in every world, then run SNS level by
        level in each: (nv,) for one robot, (N, nv) for N worlds.

        Raises:
            DivergenceError: one robot's step is not finite (a singular Jacobian).
            WorldsFailed: some of N worlds' are not; the others are solved.
        """
        problem = self.problem
        problem.fill()
        for level in self.levels:
            level.stack()
        if self._braking is not None:
            self._braking.apply(self.robot.qpos, problem.lower, problem.upper)
        # A Jacobian whose square overflows makes the passes' answer inf or NaN, which they
        # report as a DivergenceError of that world: no RuntimeWarning on the way.
        with np.errstate(over="ignore", invalid="ignore"):
            solve_each(range(self.robot.n), self._world, self.qdots, self.robot.batched, "SNSController step")
        return self.qdot

    def _world(self, w: int) -> list[float]:
        """SNS in world ``w`` (its rows and bounds as views and lists)."""
        passes = self._passes
        passes.lower, passes.upper = self.problem.lower[w].tolist(), self.problem.upper[w].tolist()
        rows = [(level.J[w], level.v[w], level.identity) for level in self.levels]
        return passes.run(rows, self.task_scales[w], self.saturations[w])

    def report(self) -> dict[str, np.ndarray]:
        """The last step's task scale of each level (1: met in full)."""
        return {"task_scale": self.task_scale.copy()}


class _Passes:
    """SNS on one world: its box ``lower``, ``upper`` (lists of floats) and its levels'
    rows (J, v, whether J = I), views of the controller's arrays."""

    def __init__(self, nv: int):
        self.nv = nv
        self.lower: list[float] = []
        self.upper: list[float] = []
        self._zero = np.zeros(nv)
        self._eye = np.eye(nv)

    def run(self, levels: list, scales: np.ndarray, saturated: np.ndarray) -> list[float]:
        """q̇ of every level in turn, clipped to the box; each level's scale and saturated
        joint count into ``scales`` and ``saturated``.

        Raises:
            DivergenceError: the answer is not finite (a singular Jacobian).
        """
        lower, upper = self.lower, self.upper
        # Start from the box's point nearest zero (zero unless a joint is outside its range).
        zero = max(lower) <= 0.0 <= min(upper)
        qdot = self._zero if zero else np.array([min(max(0.0, lo), hi) for lo, hi in zip(lower, upper)])
        space = NullSpace(self.nv)
        last = len(levels) - 1
        for k, level in enumerate(levels):
            qdot, scales[k], saturated[k] = self._level(level, qdot, zero, space, k < last)
            zero = False
        # Clipped to the box (rounding only: every pass ends inside it), on floats.
        clipped = [hi if x > hi else lo if x < lo else x for x, lo, hi in zip(qdot.tolist(), lower, upper)]
        if not math.isfinite(sum(clipped)):
            raise DivergenceError("SNS produced a non-finite joint velocity (singular Jacobian)")
        return clipped

    def _level(self, level: tuple, above: np.ndarray, above_zero: bool, space: NullSpace, more: bool):
        """SNS for one level in the null space of the levels above, whose velocity is
        ``above``. Returns (q̇, scale, saturated joints); ``space`` is left as the null
        space for the levels below (computed only when ``more`` levels follow)."""
        J, v, identity = level
        if space.free == 0 or J.shape[0] == 0:
            return above, 0.0, 0
        if identity:  # J = I: no decomposition needed; (J F)^# mapped back: F Fᵀ, or P itself
            F = space.F
            X = vt = size = None
            pinv, rank = (self._eye if F is None else F if space.projector else F.dot(F.T)), space.free
        else:
            # The task's rows J F; ‖J‖ for the rank decisions (None: J itself, its largest
            # singular value).
            X = J if space.F is None else J.dot(space.F)
            size = None if space.F is None else math.sqrt(float(np.vdot(J, J)))
            pinv, rank, vt = pseudoinverse(X, size)
            if rank == 0:  # the levels above took every direction this task moves
                return above, 0.0, 0
            pinv = space.mapped(pinv)
        # The unsaturated pass: the prioritised pseudoinverse law.
        qdot = pinv.dot(v) if above_zero else above + pinv.dot(v - (above if identity else J.dot(above)))
        qdot, scale, saturated = self._saturate(level, above, qdot, pinv, rank, size, space, X, above_zero)
        if qdot is None:  # no scale in [0, 1] fits: not executed
            return above, 0.0, saturated
        if not more or identity:
            space.free -= rank
        else:
            space.reduce(rank, pinv, X, vt, self._eye)
        return qdot, scale, saturated

    def _saturate(self, level: tuple, above: np.ndarray, qdot: np.ndarray, pinv: np.ndarray, rank: int,
                  size: float | None, space: NullSpace, X: np.ndarray | None, above_zero: bool):
        """The saturation passes from the unsaturated q̇ (``X``: the task's rows J F):
        (q̇, scale, saturated joints), q̇ None when no scale fits."""
        J, v, _ = level
        lower, upper = self.lower, self.upper
        saturated: list[int] = []
        held: list = []  # joints held within F: unit directions u (basis) or (d, ‖d‖²) (projector)
        shifted, rows = above, X
        best_scale, best = -1.0, None
        first = qdot if above_zero else None  # with nothing above, the first pass's a is q̇
        while True:
            q_list = qdot.tolist()
            if _inside(q_list, lower, upper):
                return qdot, 1.0, len(saturated)
            # q̇(s) = s a + b: a the task's share, b = q̇ − a the saturated joints' and the
            # levels above' (taken joint by joint where needed; None: b = 0)
            if first is None:
                a, whole = pinv.dot(v), qdot
                s, critical = self._scaling(a.tolist(), q_list, saturated)
            else:  # a = q̇, b = 0
                a, whole, first = first, None, None
                s, critical = self._scaling(q_list, None, saturated)
            if s > best_scale:
                best_scale, best = s, (a, whole)
            # One more saturated joint leaves free − len(saturated) − 1 directions: if that
            # is fewer than the task needs, it would cost the task one: scale it now.
            if critical < 0 or space.free - len(saturated) - 1 < rank:
                break
            # Hold the critical joint at the bound it crossed; the task gets what is left.
            saturated.append(critical)
            target = upper[critical] if q_list[critical] > upper[critical] else lower[critical]
            if space.F is None:  # in joint space: the saturated joints are simply set, and the
                # task keeps the other columns (zeroed columns: the same singular values as
                # J without them, and a pseudoinverse with zero rows there)
                if shifted is above:
                    shifted, rows = above.copy(), J.copy()
                shifted[critical] = target
                rows[:, critical] = 0.0
            else:
                moved = space.hold(critical, target, shifted, rows, held)
                if moved is None:  # that null space cannot hold this joint
                    break
                shifted, rows = moved
            # The rank tolerance of these passes scales with ‖J‖, never with the task scale s
            # (which is −1 when no scale fits: a negative threshold counted zero singular
            # values as a rank and divided by them).
            if size is None:
                size = math.sqrt(float(np.vdot(J, J)))
            pinv, pass_rank, _ = pseudoinverse(rows, size, _PASS_RANK_TOLERANCE)
            if pass_rank < rank:  # the saturations cost the task a direction: scale it
                break
            pinv = space.mapped(pinv)
            qdot = shifted + pinv.dot(v - J.dot(shifted))
        if best is None or best_scale < 0.0:
            return None, 0.0, len(saturated)
        a, b = best[0], self._zero if best[1] is None else best[1] - best[0]
        return (b if best_scale == 0.0 else best_scale * a + b), best_scale, len(saturated)

    def _scaling(self, a_list: list[float], q_list: list[float] | None, saturated: list[int]) -> tuple[float, int]:
        """For q̇ = a + b outside the box (``q_list``: q̇; None: b = 0): the largest s in
        [0, 1] with s·a + b inside on the free joints (−1: none) and the most critical
        joint (the next to saturate; −1: none left). A plain loop: nv is small, and NumPy's
        per-call cost would dominate."""
        lower, upper = self.lower, self.upper
        tiny = 1e-14 * (1.0 + max(map(abs, a_list)))
        s_max, s_min, first_out, last_in = math.inf, -math.inf, -1, -1
        for i, ai in enumerate(a_list):
            if i in saturated:
                continue
            bi = 0.0 if q_list is None else q_list[i] - ai
            if -tiny <= ai <= tiny:  # the task does not move this joint
                if bi < lower[i] - _BOUND_TOLERANCE or bi > upper[i] + _BOUND_TOLERANCE:
                    return -1.0, i  # out of bounds whatever the scale
                continue
            if ai > 0.0:
                low, high = (lower[i] - bi) / ai, (upper[i] - bi) / ai
            else:
                low, high = (upper[i] - bi) / ai, (lower[i] - bi) / ai
            if high < s_max:
                s_max, first_out = high, i
            if low > s_min:
                s_min, last_in = low, i
        if first_out < 0 and last_in < 0:
            return -1.0, -1
        critical = first_out if s_max < 1.0 else last_in
        if s_min > s_max or s_max < 0.0 or s_min > 1.0:
            return -1.0, critical
        return max(0.0, min(s_max, 1.0)), critical  # 0.0, never the −0.0 of (0 − 0)/−a


def _inside(q: list[float], lower: list[float], upper: list[float]) -> bool:
    """Whether q̇ is in the box, up to rounding (``_BOUND_TOLERANCE``)."""
    for x, lo, hi in zip(q, lower, upper):
        if x < lo - _BOUND_TOLERANCE or x > hi + _BOUND_TOLERANCE:
            return False
    return True
