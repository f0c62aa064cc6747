"""Joint-velocity regularisation."""

from __future__ import annotations

from typing import Sequence

from .task import JointSpaceTask


class DampingTask(JointSpaceTask):
    """Regularisation ½ w ‖q̇‖² on its dofs: with a hard primary task it yields the
    minimum-norm J†v.

    Args:
        robot: the robot (one world or N).
        weight: cost weight.
        joints: joints whose dofs are damped (default: every hinge and slide joint).
    """

    name = "damping task"

    def __init__(self, robot, weight=1e-3, joints: Sequence[str] | None = None):
        super().__init__(robot, joints, weight)

    def track(self) -> None:
        """v = 0: nothing to track."""
