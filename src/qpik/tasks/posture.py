"""Joint-space posture: pull toward a reference configuration."""

from __future__ import annotations

from typing import Sequence

import mujoco
import numpy as np

from ..robot import Robot
from .task import JointSpaceTask, ScalarGain, contiguous_rows, target_vector


class PostureTask(JointSpaceTask):
    """Joint-space task toward a reference configuration: v = K (q_ref ⊖ q) on its dofs.

    Args:
        robot: the robot.
        target: reference configuration (nq,), default the current one.
        gain: K (1/s), a number >= 0.
        weight: cost weight.
        joints: joints whose dofs the task covers (default: every hinge and slide joint,
            so a floating base is left free).

    Raises:
        InvalidInput: a gain that is not a finite number >= 0, a bad weight or target.
    """

    name = "posture task"
    gain = ScalarGain("posture gain")

    def __init__(self, robot: Robot, target=None, gain: float = 1.0, weight=1.0, joints: Sequence[str] | None = None):
        super().__init__(robot, joints, weight)
        self.gain = gain
        self.target = robot.q.copy() if target is None else target_vector(target, robot.nq, "posture target")
        self._difference = np.zeros(robot.nv)
        # Consecutive dofs (every hinge, with or without a floating base before them): the
        # error is a view of the difference, no copy per step.
        rows = contiguous_rows(self.dofs)
        if rows is not None:
            self.error = self._difference[rows]
        self._copy_error = rows is None
        self._model, self._qpos = robot.model, robot.data.qpos  # views, valid for the robot's life

    def set_target(self, target) -> None:
        self.target[:] = target_vector(target, self.robot.nq, "posture target")

    def feedback_gains(self) -> np.ndarray:
        return np.full(self.dim, self.gain)

    def update(self) -> None:
        mujoco.mj_differentiatePos(self._model, self._difference, 1.0, self._qpos, self.target)
        if self._copy_error:
            self._difference.take(self.dofs, None, self.error)
        np.multiply(self._k, self.error, self.target_velocity)
