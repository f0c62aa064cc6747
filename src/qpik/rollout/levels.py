"""Per-level errors of a task hierarchy, measured the same way whatever the controller.

A hierarchy's levels are compared across controllers that do not all see them (the
pseudoinverse law stacks some tasks and ignores priorities, a soft QP weighs them): each
level's error is therefore measured from its own tasks after the controller's step,
not taken from the controller.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..errors import InvalidInput
from ..tasks import Task

MEASURES = ("error", "residual")


@dataclass(frozen=True)
class Level:
    """How one level is measured.

    Args:
        name: a label (``"path"``, ``"phi"``, ...).
        tasks: the level's tasks.
        unit: the unit of the measure.
        measure: ``"error"``: the norm of the tasks' stacked ``error`` (a tracking task's
            distance to its target); ``"residual"``: the norm of :math:`J\\dot q - v`, the
            part of the asked velocity that was not delivered (for a task without a
            target, such as a gradient-following manipulability task).
    """

    name: str
    tasks: tuple[Task, ...]
    unit: str
    measure: str = "error"

    def __post_init__(self) -> None:
        if self.measure not in MEASURES:
            raise InvalidInput(f"level {self.name!r}: measure must be one of {MEASURES}, got {self.measure!r}")
        if not self.tasks:
            raise InvalidInput(f"level {self.name!r} has no task")


class LevelErrors:
    """Measures every level after a control step (on the controller's robot, whose
    kinematics the tasks read; call before the configuration is integrated)."""

    def __init__(self, levels: Sequence[Level]):
        if not levels:
            raise InvalidInput("LevelErrors needs at least one level")
        self.levels = list(levels)
        self.names = tuple(level.name for level in self.levels)
        self.units = tuple(level.unit for level in self.levels)
        self._tasks = list({id(t): t for level in self.levels for t in level.tasks}.values())
        self._stale = list(self._tasks)
        self._out = np.zeros(len(self.levels))

    def skip_updates_of(self, tasks: Sequence[Task]) -> None:
        """Tasks the controller updates itself every step (before :meth:`measure`): they
        are fresh, so measuring does not update them a second time."""
        fresh = {id(task) for task in tasks}
        self._stale = [task for task in self._tasks if id(task) not in fresh]

    def measure(self, qdot: np.ndarray) -> np.ndarray:
        for task in self._stale:  # a controller that ignores a task leaves it stale
            task.update()
        for k, level in enumerate(self.levels):
            total = 0.0
            for task in level.tasks:
                vector = task.error if level.measure == "error" else task.jacobian @ qdot - task.target_velocity
                total += float(vector @ vector)
            self._out[k] = np.sqrt(total)
        return self._out
