"""References: drive a tracking task along a trajectory and measure how well it is tracked."""

from __future__ import annotations

import numpy as np

from ..errors import InvalidInput
from ..robot import Robot
from ..tasks import ComTask, PositionTask


class PositionReference:
    """Feeds a trajectory to a position task (or a CoM task); measures what the task tracks
    (its frame's position, the CoM) on any robot: the controller's, or the physics plant of
    the same model."""

    def __init__(self, task: PositionTask | ComTask, trajectory):
        if trajectory.dim != task.target_dim:
            raise InvalidInput(f"trajectory has {trajectory.dim} coordinates, the task's target {task.target_dim}")
        self.task = task
        self.trajectory = trajectory

    def apply(self, t: float) -> None:
        position, velocity = self.trajectory.sample(t)
        self.task.set_target(position, velocity)

    def desired(self) -> np.ndarray:
        return self.task.target

    def measure(self, robot: Robot) -> dict:
        return {"x": self.task.measured(robot)}
