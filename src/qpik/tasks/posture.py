"""Joint-space posture: pull toward a reference configuration."""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ..numerics import ConfigurationDifference
from .inputs import as_index, positive_scalar, world_values
from .task import JointSpaceTask, ScalarGain


class PostureTask(ScalarGain, JointSpaceTask):
    """Joint-space task toward a reference configuration: v = K (q_ref ⊖ q) on its dofs.

    Args:
        robot: the robot (one world or N).
        target: reference configuration (nq,) (or (N, nq), one per world); default the
            current one.
        gain: K (1/s), a number >= 0.
        weight: cost weight.
        joints: joints whose dofs the task covers (default: every hinge and slide joint,
            so a floating base is left free).

    Raises:
        InvalidInput: a gain that is not a finite number >= 0, a bad weight or target.
    """

    name = "posture task"
    gain_label = "posture gain"

    def __init__(self, robot, target=None, gain: float = 1.0, weight=1.0, joints: Sequence[str] | None = None):
        super().__init__(robot, joints, weight)
        self.set_gain(np.full(self.dim, positive_scalar(gain, self.gain_label, allow_zero=True)))
        self.targets = np.array(robot.qpos) if target is None else \
            np.array(world_values(robot, target, (robot.nq,), "posture target"))
        self.target = robot.present(self.targets)
        self._difference = ConfigurationDifference(robot.model, robot.n)
        self._velocity = np.zeros((robot.n, robot.nv))
        self._dofs = as_index(self.dofs)
        if isinstance(self._dofs, slice):  # the error is a view of the difference: no copy per step
            self.errors = self._velocity[:, self._dofs]
            self.error = robot.present(self.errors)

    def set_target(self, target) -> None:
        """The reference configuration (nq,), or (N, nq) one per world."""
        self.targets[...] = world_values(self.robot, target, (self.robot.nq,), "posture target")

    def measure_rows(self) -> None:
        self._difference(self.robot.qpos, self.targets, self._velocity)
        if not isinstance(self._dofs, slice):
            np.take(self._velocity, self._dofs, 1, self.errors)
