"""Joint position limits with a velocity damper near the bounds."""

from __future__ import annotations

import math

import mujoco
import numpy as np

from ..errors import InvalidInput
from ..robot import JointLimits, Robot
from ..tasks.task import positive_scalar
from .limit import Limit, as_slice

# From this many limited joints a box is kept, while q stays clear of the bounds, without a
# pass over the joints: below it the pass costs less than the check.
WATCH_MIN_JOINTS = 8


class JointPositionLimit(Limit):
    """Keep limited joints inside their range at the end of the step.

    Args:
        robot: the robot.
        limits: the ranges to enforce (default: the model's ``range`` attributes).
        gain: fraction in (0, 1] of the remaining distance that one step may cover.
        influence: distance to a bound below which the velocity damper acts
            (0 disables the damper).
        damper_rate: ξ (joint units/s): once the distance d to a bound is below
            ``influence``, the speed toward it is at most ξ d / influence, so the joint
            slows down exponentially as it arrives.
        margin: the bounds are pulled in by this much (joint units), so that rounding in
            q + q̇Δt never lands a hair outside the range.

    Raises:
        InvalidInput: a parameter that is not a single finite number in its range, or a
            range narrower than twice the margin.
    """

    constant = False  # depends on q: recomputed every step
    takes_lists = True  # the box of a robot of a few dofs, in floats

    def __init__(self, robot: Robot, limits: JointLimits | None = None, gain: float = 1.0,
                 influence: float = 0.0, damper_rate: float = 20.0, margin: float = 1e-10):
        self.limits = self.ranges = robot.joint_limits if limits is None else limits
        gain = positive_scalar(gain, "position-limit gain")
        if gain > 1.0:
            raise InvalidInput(f"position-limit gain must lie in (0, 1], got {gain}")
        margin = positive_scalar(margin, "position-limit margin", allow_zero=True)
        influence = positive_scalar(influence, "position-limit influence (of the damper)", allow_zero=True)
        damper_rate = positive_scalar(damper_rate, "position-limit damper rate")
        if not np.all(self.limits.upper - self.limits.lower > 2.0 * margin):
            bad = [f"{n} [{lo:g}, {hi:g}]" for n, lo, hi in zip(self.limits.names, self.limits.lower,
                                                              self.limits.upper) if not hi - lo > 2.0 * margin]
            raise InvalidInput(f"joint range narrower than twice the limit margin ({margin:g}) or empty: "
                               f"{', '.join(bad)}")
        self.robot, self.gain, self.influence, self.damper_rate, self.margin = robot, gain, influence, damper_rate, \
            float(margin)
        # Rows: lower then upper bound, pulled in by the margin.
        self._bounds = np.stack([self.limits.lower + margin, self.limits.upper - margin])
        self._q = robot.data.qpos  # a view, valid for the robot's life (MuJoCo's getter makes a new one)
        qpos = as_slice(self.limits.qpos_index)
        # The limited joints' positions: a view of it when they are consecutive.
        self._positions = self._q[qpos] if isinstance(qpos, slice) else None
        self._qpos = qpos
        self._dofs = as_slice(self.limits.dof_index)
        self._steps = np.empty_like(self._bounds)
        self._low, self._high = self._steps  # row views, made once
        self._rate = damper_rate / influence if influence > 0 else 0.0
        self._factor = np.empty_like(self._bounds)
        self._near = np.empty(self._bounds.shape, dtype=bool)
        self._joints = [(int(qi), int(di), float(lo), float(hi)) for qi, di, lo, hi in
                        zip(self.limits.qpos_index, self.limits.dof_index, *self._bounds)]
        # Where every bound was looser than the incoming box: (step rate, that box, the
        # limited joints' positions, the squared distance they may move and stay so).
        self._loose = None
        self._width = float(np.max(self._bounds[1] - self._bounds[0])) if len(self._joints) else 0.0
        self._drift = np.empty(len(self._joints))
        self._watched = len(self._joints) >= WATCH_MIN_JOINTS

    def apply(self, dt: float, lb, ub, G=None, h=None) -> None:
        """Tighten the velocity box [lb, ub] (nv,) in place (lists of floats: joint by joint)."""
        if type(lb) is not list:
            self._apply_to_arrays(dt, lb, ub)
            return
        watched = self._watched
        if watched:
            if self._still_loose(dt, lb, ub):
                return
            incoming = (lb.copy(), ub.copy())
        q = self._q.tolist()
        step_rate = self.gain / dt
        influence = self.influence
        damped = self._rate if self._rate < step_rate else step_rate
        for qi, di, lo, hi in self._joints:
            x = q[qi]
            low, high = lo - x, hi - x
            if influence > 0.0:
                low *= damped if abs(low) < influence else step_rate
                high *= damped if abs(high) < influence else step_rate
            else:
                low *= step_rate
                high *= step_rate
            # Into the velocity box (recovery from outside the range never asks for more than
            # it; an empty incoming box stays as it is): most joints need one comparison a side.
            v_lo, v_hi = lb[di], ub[di]
            if low > v_lo:
                lb[di] = low if low <= v_hi else (v_hi if v_hi > v_lo else v_lo)
            if high < v_hi:
                ub[di] = high if high >= v_lo else (v_lo if v_lo < v_hi else v_hi)
        if not math.isfinite(sum(q)):  # NaN or inf somewhere in q: name the limited joint
            self._non_finite()
        if watched:
            self._remember(q, step_rate, incoming, lb == incoming[0] and ub == incoming[1])

    def _still_loose(self, dt: float, lb: list, ub: list) -> bool:
        """Whether q is within the distance found at the last pass that left the incoming
        box as it was (the same box and rate, no damper): each bound moves by at most
        rate x |Δq|, so none is tighter than the box now either."""
        loose = self._loose
        if loose is None or self.gain / dt != loose[0] or lb != loose[1] or ub != loose[2] or self.influence:
            return False
        positions = self._positions if self._positions is not None else self._q[self._qpos]
        drift = self._drift
        np.subtract(positions, loose[3], drift)
        return drift.dot(drift) <= loose[4]  # NaN in q fails: the pass names the joint

    def _remember(self, q: list, step_rate: float, incoming: tuple, unchanged: bool) -> None:
        """After a pass that left the box as it was: the least gap between a bound and the
        box, in q (half of it: far above the rounding in (bound − q) x rate), is how far q
        may move before the next pass."""
        self._loose = None
        if not unchanged or self.influence:
            return
        lower, upper = incoming
        gap = min(min([lower[di] - (lo - q[qi]) * step_rate for qi, di, lo, _ in self._joints]),
                  min([(hi - q[qi]) * step_rate - upper[di] for qi, di, _, hi in self._joints]))
        if 1e-9 * (1.0 + step_rate * self._width) < gap < math.inf:
            positions = self._positions if self._positions is not None else self._q[self._qpos]
            reach = 0.5 * gap / step_rate
            self._loose = (step_rate, lower, upper, positions.copy(), reach * reach)

    def _apply_to_arrays(self, dt: float, lb: np.ndarray, ub: np.ndarray) -> None:
        steps = self._steps  # distance to each bound: row 0 <= 0, row 1 >= 0 inside the range
        positions = self._positions if self._positions is not None else self._q[self._qpos]
        np.subtract(self._bounds, positions, out=steps)
        if not math.isfinite(mujoco.mju_sum(self._low)):  # NaN or inf in q: name the joint
            self._non_finite()
        if self.influence > 0.0:
            # Within the influence distance of a bound the speed toward it is rate x
            # distance, but never more than the step limit (a damper faster than gain/Δt
            # would step past the bound); elsewhere the step limit q + q̇Δt in range applies.
            np.less(np.abs(steps, out=self._factor), self.influence, out=self._near)
            self._factor.fill(self.gain / dt)
            np.copyto(self._factor, min(self._rate, self.gain / dt), where=self._near)
            steps *= self._factor
        else:
            steps *= self.gain / dt
        low, high = self._low, self._high
        vel_lo, vel_hi = lb[self._dofs], ub[self._dofs]  # views when the dofs are contiguous
        # Recovery from outside the range never asks for more than the velocity box.
        np.minimum(low, vel_hi, out=low)
        np.maximum(high, vel_lo, out=high)
        np.maximum(vel_lo, low, out=vel_lo)
        np.minimum(vel_hi, high, out=vel_hi)
        if not isinstance(self._dofs, slice):
            lb[self._dofs] = vel_lo
            ub[self._dofs] = vel_hi

    def _non_finite(self) -> None:
        q = self.robot.data.qpos
        for qpos, dof in zip(self.limits.qpos_index, self.limits.dof_index):
            if not math.isfinite(q[qpos]):
                raise InvalidInput(f"joint {self.robot.dof_name(dof)} has a non-finite position {q[qpos]}")
