"""Manipulability measures and the task that climbs their gradient in the null space."""

from __future__ import annotations

from typing import Protocol, Sequence

import mujoco
import numpy as np

from ..errors import InvalidInput
from ..robot import Robot
from .task import JointSpaceTask, axis_rows


class ManipulabilityMeasure(Protocol):
    """A scalar measure m(q) of dexterity and its gradient over the dofs."""

    label: str

    def value(self, robot: Robot | None = None) -> float:
        """m(q) of the bound robot, or of another robot on the same model."""
        ...

    def gradient(self, out: np.ndarray) -> None: ...


class SigmaProxy:
    """The source's proxy σ(q) = ½ Σ_j sin² q_j over chosen joints (maximum at ±π/2).

    On the arm, with joints θ2 and θ3, σ = ½(sin²θ2 + sin²θ3);
    ∂σ/∂q_j = sin q_j cos q_j.
    """

    label = "sigma"

    def __init__(self, robot: Robot, joints: Sequence[str] = ("theta2", "theta3")):
        self.robot = robot
        self.qpos_index = np.array([robot.joint_qpos_index(j) for j in joints], dtype=int)
        self.dof_index = np.array([robot.joint_dof_index(j) for j in joints], dtype=int)

    def value(self, robot: Robot | None = None) -> float:
        s = np.sin((robot or self.robot).q[self.qpos_index])
        return 0.5 * float(s @ s)

    def gradient(self, out: np.ndarray) -> None:
        angles = self.robot.q[self.qpos_index]
        out[:] = 0.0
        out[self.dof_index] = 0.5 * np.sin(2.0 * angles)


class Yoshikawa:
    """Yoshikawa's measure w = √det(J Jᵀ) of a site's position Jacobian on masked rows.

    Masking matters on planar robots: the z row of the arm's Jacobian is zero, so
    det over all three rows would be 0. The gradient is a central difference over
    each dof, on a scratch MjData so the robot's own kinematics stay untouched
    (2 nv extra kinematics evaluations, documented cost).
    """

    label = "yoshikawa"

    def __init__(self, robot: Robot, site: str, axes: str = "xyz", step: float = 1e-6):
        self.robot = robot
        self.site_id = robot.site_id(site)
        self.rows = axis_rows(axes)
        self.step = step
        self._scratch = mujoco.MjData(robot.model)
        self._jacp = np.zeros((3, robot.nv))
        self._dq = np.zeros(robot.nv)

    def _measure(self, data: mujoco.MjData) -> float:
        mujoco.mj_jacSite(self.robot.model, data, self._jacp, None, self.site_id)
        jac = self._jacp[self.rows]
        return float(np.sqrt(max(np.linalg.det(jac @ jac.T), 0.0)))

    def value(self, robot: Robot | None = None) -> float:
        return self._measure((robot or self.robot).data)

    def gradient(self, out: np.ndarray) -> None:
        model, scratch = self.robot.model, self._scratch
        for k in range(self.robot.nv):
            values = []
            for sign in (1.0, -1.0):
                scratch.qpos[:] = self.robot.q
                self._dq[:] = 0.0
                self._dq[k] = sign * self.step
                mujoco.mj_integratePos(model, scratch.qpos, self._dq, 1.0)
                mujoco.mj_kinematics(model, scratch)
                mujoco.mj_comPos(model, scratch)
                values.append(self._measure(scratch))
            out[k] = (values[0] - values[1]) / (2.0 * self.step)


class ManipulabilityTask(JointSpaceTask):
    """Posture task toward the manipulability gradient: cost ½ w ‖q̇ − k0 ∇m(q)‖².

    Written as a quadratic in q̇ with J = I (not as a bare linear term -w k0 ∇mᵀq̇,
    which with a tiny regulariser drives the null-space velocity to its bounds).
    With a hard primary task this is exactly the null-space law
    q̇ = J†v + (I − J†J) k0 ∇m.

    Args:
        robot: the robot.
        measure: the measure m whose gradient (over every dof) the task follows.
        gain: k0.
        weight: cost weight.
        joints: joints whose dofs the task covers (default: every hinge and slide joint).
    """

    name = "manipulability task"

    def __init__(self, robot: Robot, measure: ManipulabilityMeasure, gain: float = 5.0, weight=1.0,
                 joints: Sequence[str] | None = None):
        super().__init__(robot, joints, weight)
        if not np.isfinite(gain) or gain < 0:
            raise InvalidInput(f"manipulability gain must be finite and >= 0, got {gain}")
        self.measure = measure
        self.gain = float(gain)
        self._grad = np.zeros(robot.nv)

    def update(self) -> None:
        self.measure.gradient(self._grad)
        np.multiply(self.gain, self._grad[self.dofs], out=self.target_velocity)
