"""References: drive a tracking task along a trajectory and measure how well it is tracked."""

from __future__ import annotations

import numpy as np

from ..errors import InvalidInput
from ..robot import Robot
from ..tasks import PositionTask


class PositionReference:
    """Feeds a trajectory to a position task; measures the tracked site on any robot."""

    def __init__(self, task: PositionTask, trajectory):
        if trajectory.dim != task.dim:
            raise InvalidInput(f"trajectory has {trajectory.dim} coordinates, the task {task.dim}")
        self.task = task
        self.trajectory = trajectory

    def apply(self, t: float) -> None:
        position, velocity = self.trajectory.sample(t)
        self.task.set_target(position, velocity)

    def desired(self) -> np.ndarray:
        return self.task.target

    def measure(self, robot: Robot) -> dict:
        return {"x": robot.site_position(self.task.site_id)[self.task.rows].copy()}
