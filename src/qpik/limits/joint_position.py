"""Joint position limits with a velocity damper near the bounds."""

from __future__ import annotations

import math

import numpy as np

from ..errors import InvalidInput
from ..robot import JointLimits, Robot
from ..tasks.task import positive_scalar
from .limit import Limit, as_slice

SCALAR_JOINTS_MAX = 8  # measured crossover: 4 joints 2.1 vs 5.3 µs, 18 joints 5.4 vs 3.7


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

    def __init__(self, robot: Robot, limits: JointLimits | None = None, gain: float = 1.0,
                 influence: float = 0.0, damper_rate: float = 20.0, margin: float = 1e-10):
        self.limits = robot.joint_limits if limits is None else limits
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
        self.robot = robot
        self._q = robot.data.qpos  # a view, valid for the robot's life (MuJoCo's getter costs ~0.5 µs)
        self.gain = gain
        self.influence = influence
        self.damper_rate = damper_rate
        self.margin = float(margin)
        # Rows: lower then upper bound, pulled in by the margin.
        self._bounds = np.stack([self.limits.lower + margin, self.limits.upper - margin])
        self._qpos = as_slice(self.limits.qpos_index)
        self._dofs = as_slice(self.limits.dof_index)
        self._steps = np.empty_like(self._bounds)
        self._low, self._high = self._steps  # row views, made once
        self._rate = damper_rate / influence if influence > 0 else 0.0
        self._factor = np.empty_like(self._bounds)
        self._near = np.empty(self._bounds.shape, dtype=bool)
        # A few joints: plain floats beat a dozen NumPy calls (each ~0.4 µs) per step.
        self._scalar_joints = [(int(qi), int(di), float(lo), float(hi)) for qi, di, lo, hi in
                               zip(self.limits.qpos_index, self.limits.dof_index, *self._bounds)] \
            if len(self.limits.names) <= SCALAR_JOINTS_MAX else None

    @property
    def in_floats(self) -> bool:
        """Whether the box is computed joint by joint in floats (a few joints): then
        :meth:`apply_from` and :meth:`apply_to_lists` are the cheap calls."""
        return self._scalar_joints is not None

    def apply(self, dt: float, lb: np.ndarray, ub: np.ndarray) -> None:
        """Tighten the velocity box [lb, ub] (nv,) in place."""
        if self._scalar_joints is not None:
            self._apply_scalars(dt, lb, ub)
            return
        steps = self._steps  # distance to each bound: row 0 <= 0, row 1 >= 0 inside the range
        np.subtract(self._bounds, self._q[self._qpos], out=steps)
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

    def apply_from(self, dt: float, lower: list[float], upper: list[float], lb: np.ndarray, ub: np.ndarray) -> None:
        """:meth:`apply` to the box [lower, upper] (lists of nv floats: a controller's
        constant bounds), writing all of ``lb`` and ``ub``: the same result as copying the
        box into them and applying, one NumPy copy per side fewer."""
        if self._scalar_joints is not None:
            lbs, ubs = list(lower), list(upper)
            self.apply_to_lists(dt, lbs, ubs)
            lb[:] = lbs
            ub[:] = ubs
            return
        lb[:] = lower
        ub[:] = upper
        self.apply(dt, lb, ub)

    def _apply_scalars(self, dt: float, lb: np.ndarray, ub: np.ndarray) -> None:
        """:meth:`apply` joint by joint in floats: the same operations in the same order."""
        lbs, ubs = lb.tolist(), ub.tolist()
        self.apply_to_lists(dt, lbs, ubs)
        lb[:] = lbs
        ub[:] = ubs

    def apply_to_lists(self, dt: float, lbs: list, ubs: list) -> None:
        """:meth:`apply` on the box as lists of floats: the joint-by-joint loop itself."""
        if self._scalar_joints is None:
            super().apply_to_lists(dt, lbs, ubs)
            return
        q = self._q.tolist()
        step_rate = self.gain / dt
        influence = self.influence
        damped = self._rate if self._rate < step_rate else step_rate
        total = 0.0  # one finiteness test for all the joints, after the loop
        for qi, di, lo, hi in self._scalar_joints:
            x = q[qi]
            total += x
            low, high = lo - x, hi - x
            if influence > 0.0:
                low *= damped if abs(low) < influence else step_rate
                high *= damped if abs(high) < influence else step_rate
            else:
                low *= step_rate
                high *= step_rate
            v_lo, v_hi = lbs[di], ubs[di]
            # Recovery from outside the range never asks for more than the velocity box.
            if low > v_hi:
                low = v_hi
            if high < v_lo:
                high = v_lo
            if low > v_lo:
                lbs[di] = low
            if high < v_hi:
                ubs[di] = high
        if not math.isfinite(total):
            for qi, di, _, _ in self._scalar_joints:
                if not math.isfinite(q[qi]):
                    raise InvalidInput(f"joint {self.robot.dof_name(di)} has a non-finite position {q[qi]}")
