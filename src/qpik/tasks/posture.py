"""Joint-space posture: pull toward a reference configuration."""

from __future__ import annotations

from typing import Sequence

import mujoco
import numpy as np

from ..robot import Robot
from .task import JointSpaceTask, finite_vector


class PostureTask(JointSpaceTask):
    """Joint-space task toward a reference configuration: v = K (q_ref ⊖ q) on its dofs.

    Args:
        robot: the robot.
        target: reference configuration (nq,), default the current one.
        gain: K (1/s).
        weight: cost weight.
        joints: joints whose dofs the task covers (default: every hinge and slide joint,
            so a floating base is left free).
    """

    name = "posture task"

    def __init__(self, robot: Robot, target=None, gain: float = 1.0, weight=1.0, joints: Sequence[str] | None = None):
        super().__init__(robot, joints, weight)
        self.gain = float(gain)
        self.target = robot.q.copy() if target is None else finite_vector(target, robot.nq, "posture target")
        self._difference = np.zeros(robot.nv)

    def set_target(self, target) -> None:
        self.target[:] = finite_vector(target, self.robot.nq, "posture target")

    def feedback_gains(self) -> np.ndarray:
        return np.full(self.dim, self.gain)

    def update(self) -> None:
        mujoco.mj_differentiatePos(self.robot.model, self._difference, 1.0, self.robot.q, self.target)
        np.take(self._difference, self.dofs, out=self.error)
        np.multiply(self.gain, self.error, out=self.target_velocity)
