"""Joint-velocity regularisation."""

from __future__ import annotations

from typing import Sequence

from ..robot import Robot
from .task import JointSpaceTask


class DampingTask(JointSpaceTask):
    """Regularisation ½ w ‖q̇‖² on its dofs: with a hard primary task it yields the
    minimum-norm J†v.

    Args:
        robot: the robot.
        weight: cost weight.
        joints: joints whose dofs are damped (default: every hinge and slide joint).
    """

    name = "damping task"

    def __init__(self, robot: Robot, weight=1e-3, joints: Sequence[str] | None = None):
        super().__init__(robot, joints, weight)

    def update(self) -> None:
        pass
