r"""SNSController: Saturation in the Null Space (Flacco, De Luca and Khatib, ICRA 2012,
IROS 2012; IEEE T-RO 31(3), 2015), the pseudoinverse law made to respect joint bounds.

Level by level (priority 0 first), in the null space of the levels above: the
prioritised pseudoinverse law; a joint that would leave its velocity bounds is held at
its bound and the task solved again by the others, until the answer stays in the box; a
task that cannot be met inside it is executed along its own direction, scaled by the
largest s ∈ [0, 1] a pass allows (:math:`\dot q(s) = s\,a + b`). The null space is
carried as an orthonormal basis Z or as the projector P itself (:class:`_NullSpace`).
A saturation pass whose rows keep a singular value below 1e-2 ‖J‖ counts as having cost
the task that direction: the task is scaled on the passes before it (near a
singularity such a pass would move the saturated joints at full speed for a tiny share
of the task). The derivation, with the bounds (including the braking bound
:math:`\sqrt{2 A_{max} d}`), is in docs/controllers.md.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from .. import linalg
from ..errors import DivergenceError, InvalidInput
from ..problem import Problem, Stack, check_dt, group_levels
from ..robot import Robot
from ..tasks import Task

# Products below use ndarray.dot: `@` costs twice as much at these sizes.
_RANK_TOLERANCE = 1e-10  # singular values below this fraction of the largest count as zero
_BOUND_TOLERANCE = 1e-12  # rad/s (m/s): rounding, not a violation
# A saturation pass whose rows keep a singular value below this fraction of ‖J‖ (a
# condition above 100) counts as having cost the task that direction: the task is scaled
# instead (docs/controllers.md, "Near a singularity").
_PASS_RANK_TOLERANCE = 1e-2


def _solve(X: np.ndarray, scale: float | None, closed: bool,
           tolerance: float = _RANK_TOLERANCE) -> tuple[np.ndarray, int, np.ndarray | None]:
    """(X⁺, X's rank, the Vᵀ of its SVD or None when none was made). Singular values below
    ``tolerance · scale`` count as zero (``scale`` the size of J itself, X being J Z or
    J P: a direction the levels above nearly took is kept; None: X's largest). One row:
    xᵀ/‖x‖²; two rows when ``closed``: X⁺ = Xᵀ G⁻¹ (G = X Xᵀ) by a Gram-Schmidt step,
    unless they are nearly dependent or conditioned worse than 1e2; else one SVD from
    LAPACK directly (NumPy's wrapper costs more than the decomposition at these sizes)."""
    m = X.shape[0]
    if m == 1:  # one row x: x^# = xᵀ/‖x‖²
        row = X[0]
        norm_sq = float(row.dot(row))
        if not math.isfinite(norm_sq):
            raise DivergenceError("SNS: a task Jacobian is not finite")
        rank = 1 if norm_sq > (tolerance * (math.sqrt(norm_sq) if scale is None else scale)) ** 2 else 0
        return (X.T / norm_sq if rank else 0.0 * X.T), rank, None
    if m == 2 and closed:
        (n1, g12), (_, g22) = X.dot(X.T).tolist()
        if n1 > 0.0:
            c = g12 / n1
            nr = g22 - c * g12  # ‖r‖², from G where that loses at most two digits
            if not nr >= 0.01 * g22:
                r = X[1] - c * X[0]
                nr = float(r.dot(r))
            det, trace = n1 * nr, n1 + g22  # σ1² ≤ trace, so σ2² ≥ det/trace, σ2²/σ1² ≥ det/trace²
            if det > 1e-4 * trace * trace and (scale is None or det > 4.0 * (tolerance * scale) ** 2 * trace):
                inverse = np.empty((2, 2))  # G⁻¹
                inverse[1, 1] = i22 = 1.0 / nr
                inverse[0, 1] = inverse[1, 0] = i12 = -c * i22
                inverse[0, 0] = 1.0 / n1 - c * i12
                return X.T.dot(inverse), 2, None
    u, s, vt, info = linalg.dgesvd(X)
    largest = float(s[0])
    if info != 0 or not math.isfinite(largest):
        raise DivergenceError("SNS: the singular value decomposition failed (non-finite Jacobian)")
    threshold = tolerance * (largest if scale is None else scale)
    rank = len(s) if s[-1] > threshold else int(np.count_nonzero(s > threshold))
    if rank == len(s) == m:  # full row rank, the usual case
        return vt[:rank].T.dot(u.T / s[:, None]), rank, vt
    return vt[:rank].T.dot(u[:, :rank].T / s[:rank, None]), rank, vt


class _NullSpace:
    """The null space of the levels done, of dimension ``free``: all of joint space
    (``F`` None), an orthonormal basis Z (``F``), or, ``projector``, P = Z Zᵀ itself."""

    def __init__(self, nv: int):
        self.F, self.projector, self.free = None, False, nv

    @property
    def closed(self) -> bool:
        """Whether one or two rows are solved in closed form here (joint space, or a projector's)."""
        return self.F is None or self.projector

    def mapped(self, pinv: np.ndarray) -> np.ndarray:
        """(J Z)^# mapped back to joint space (Z (J Z)^#); as it is in joint space or a projector's."""
        return pinv if self.closed else self.F.dot(pinv)

    def hold(self, critical: int, target: float, shifted: np.ndarray, rows: np.ndarray, held: list):
        """Joint ``critical`` held at ``target`` (``held``: the directions held before, appended
        to): (q̇ shifted, the task's rows less that direction), or None where it cannot be."""
        F = self.F
        if self.projector:  # along d = P̄ e_i, P̄ = P less the joints already held
            d = F[critical]
            for e, norm in held:
                d = d - e * (e[critical] / norm)
            norm_sq = float(d[critical])  # ‖P̄ e_i‖²
            if norm_sq <= _RANK_TOLERANCE**2:
                return None
            shifted = shifted + d.dot((target - shifted.item(critical)) / norm_sq)  # dot: a faster *
            held.append((d, norm_sq))
            # J P̄: the task without d
            return shifted, rows - (d.dot(rows.dot(d).item() / norm_sq) if len(rows) == 1 else
                                    (rows.dot(d) / norm_sq)[:, None] * d)
        # Within the basis, as close as it allows: along h, the joint's row of Z less its
        # part along the joints already held.
        h = F[critical]
        for u in held:
            h = h - u.dot(h) * u
        norm_sq = float(h.dot(h))
        if norm_sq <= _RANK_TOLERANCE**2:
            return None
        shifted = shifted + F.dot(h * ((target - shifted[critical]) / norm_sq))
        u = h / math.sqrt(norm_sq)
        held.append(u)
        return shifted, rows - rows.dot(u)[:, None] * u  # J Z (I − u uᵀ): the task without u

    def reduce(self, rank: int, pinv: np.ndarray, X: np.ndarray, vt: np.ndarray | None, eye: np.ndarray) -> None:
        """The null space left after a level of this ``rank`` (X = J F its rows, ``pinv``
        their pseudoinverse, ``vt`` their SVD's Vᵀ or None)."""
        self.free -= rank
        if self.closed and vt is None:  # closed form: P_k = P_{k-1} − X⁺X, X = J P_{k-1}
            self.F, self.projector = (eye if self.F is None else self.F) - pinv.dot(X), True
            return
        if self.projector:
            self.F = self.F - pinv.dot(X)
            return
        if vt is None:  # one row: decompose now
            vt = linalg.dgesvd(X)[2]
        null = vt[rank:].T
        self.F = null if self.F is None else self.F.dot(null)


class SNSController:
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
        self.levels = [Stack(robot.nv, level, weighted=True) for level in grouped]
        self.updated_tasks = tuple(self.tasks)  # fresh after every step (rollouts read them)
        self._braking = self._braking_terms(max_acceleration)
        self._zero = np.zeros(robot.nv)
        self._eye = np.eye(robot.nv)
        self._lower, self._upper = [], []  # the step's box as lists of floats (the loops read it joint by joint)
        self.task_scale = np.ones(len(self.levels))
        self.saturated = np.zeros(len(self.levels), dtype=int)  # joints saturated per level
        self.qdot = np.zeros(robot.nv)

    def _braking_terms(self, max_acceleration):
        if max_acceleration is None:
            return []
        nv = self.robot.nv
        amax = np.full(nv, float(max_acceleration)) if np.ndim(max_acceleration) == 0 else \
            np.asarray(max_acceleration, dtype=float)
        if amax.shape != (nv,) or np.any(np.isnan(amax)) or np.any(amax <= 0):
            raise InvalidInput(f"max_acceleration must be positive (inf for none), one number or shape ({nv},)")
        ranges = [lim.ranges for lim in self.limits if lim.ranges is not None]
        if not ranges:
            raise InvalidInput("max_acceleration needs a joint position limit among the limits "
                               "(the ranges to brake before)")
        return [(r.qpos_index, r.dof_index, r.lower, r.upper, amax[r.dof_index]) for r in ranges]

    @property
    def level_count(self) -> int:
        return len(self.levels)

    lb = property(lambda self: np.array(self._lower), doc="Lower bounds of the last step's velocity box (a copy).")
    ub = property(lambda self: np.array(self._upper), doc="Upper bounds of the last step's velocity box (a copy).")

    def _bounds(self) -> None:
        """The step's box as lists, with the braking bounds."""
        inequalities = self.problem.inequalities
        if not self._braking:
            self._lower, self._upper = inequalities.box()
            return
        lb, ub, q = inequalities.lb, inequalities.ub, self.robot.q
        for qpos, dofs, low, high, amax in self._braking:
            up = np.sqrt(2.0 * amax * np.maximum(high - q[qpos], 0.0))
            down = -np.sqrt(2.0 * amax * np.maximum(q[qpos] - low, 0.0))
            ub[dofs] = np.minimum(ub[dofs], np.maximum(up, lb[dofs]))  # outside the range: return
            lb[dofs] = np.maximum(lb[dofs], np.minimum(down, ub[dofs]))
        self._lower, self._upper = lb.tolist(), ub.tolist()

    def compute_velocity(self) -> np.ndarray:
        """Fill the step's problem (tasks, bounds), then run SNS level by level."""
        self.problem.fill()
        for level in self.levels:
            level.stack()
        self._bounds()
        lower, upper = self._lower, self._upper
        # Start from the box's point nearest zero (zero unless a joint is outside its range).
        zero = max(lower) <= 0.0 <= min(upper)
        qdot = self._zero if zero else np.array([min(max(0.0, lo), hi) for lo, hi in zip(lower, upper)])
        space = _NullSpace(self.robot.nv)
        last = len(self.levels) - 1
        for k, level in enumerate(self.levels):
            qdot, self.task_scale[k], self.saturated[k] = self._level(level, qdot, zero, space, k < last)
            zero = False
        # Clipped to the box (rounding only: every pass ends inside it), on floats.
        clipped = [hi if x > hi else lo if x < lo else x for x, lo, hi in zip(qdot.tolist(), lower, upper)]
        if not math.isfinite(sum(clipped)):
            raise DivergenceError("SNS produced a non-finite joint velocity (singular Jacobian)")
        self.qdot[:] = clipped
        return self.qdot

    def _level(self, level: Stack, above: np.ndarray, above_zero: bool, space: _NullSpace, more: bool):
        """SNS for one level in the null space of the levels above, whose velocity is
        ``above``. Returns (q̇, scale, saturated joints); ``space`` is left as the null
        space for the levels below (computed only when ``more`` levels follow)."""
        J, v = level.J, level.v
        if space.free == 0 or J.shape[0] == 0:
            return above, 0.0, 0
        if level.identity:  # J = I: no decomposition needed; (J F)^# mapped back: F Fᵀ, or P itself
            F = space.F
            X = vt = size = None
            pinv, rank = (self._eye if F is None else F if space.projector else F.dot(F.T)), space.free
        else:
            # The task's rows J F; ‖J‖ for the rank decisions (None: J itself, its largest
            # singular value). Two rows in joint space or in a projector's: closed form.
            X = J if space.F is None else J.dot(space.F)
            size = None if space.F is None else math.sqrt(float(np.vdot(J, J)))
            pinv, rank, vt = _solve(X, size, space.closed)
            if rank == 0:  # the levels above took every direction this task moves
                return above, 0.0, 0
            pinv = space.mapped(pinv)
        # The unsaturated pass: the prioritised pseudoinverse law.
        qdot = pinv.dot(v) if above_zero else above + pinv.dot(v - (above if level.identity else J.dot(above)))
        qdot, scale, saturated = self._saturate(level, above, qdot, pinv, rank, size, space, X, above_zero)
        if qdot is None:  # no scale in [0, 1] fits: not executed
            return above, 0.0, saturated
        if not more or level.identity:
            space.free -= rank
        else:
            space.reduce(rank, pinv, X, vt, self._eye)
        return qdot, scale, saturated

    def _saturate(self, level: Stack, above: np.ndarray, qdot: np.ndarray, pinv: np.ndarray, rank: int,
                  size: float | None, space: _NullSpace, X: np.ndarray | None, above_zero: bool):
        """The saturation passes from the unsaturated q̇ (``X``: the task's rows J F):
        (q̇, scale, saturated joints), q̇ None when no scale fits."""
        J, v = level.J, level.v
        lower, upper = self._lower, self._upper
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
            pinv, pass_rank, _ = _solve(rows, size, space.closed, _PASS_RANK_TOLERANCE)
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
        lower, upper = self._lower, self._upper
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

    def report(self) -> dict[str, np.ndarray]:
        """The last step's task scale of each level (1: met in full)."""
        return {"task_scale": self.task_scale.copy()}


def _inside(q: list[float], lower: list[float], upper: list[float]) -> bool:
    """Whether q̇ is in the box, up to rounding (``_BOUND_TOLERANCE``)."""
    for x, lo, hi in zip(q, lower, upper):
        if x < lo - _BOUND_TOLERANCE or x > hi + _BOUND_TOLERANCE:
            return False
    return True
