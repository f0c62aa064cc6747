"""The problem of a control step, laid out once from (robot, tasks, limits, dt)."""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ..errors import InvalidInput
from ..limits.limit import Limit
from ..robot import Robot, check_same_robot
from ..tasks import Task
from .limits import Inequalities


def check_dt(dt) -> float:
    """The control period as a positive finite float, or InvalidInput."""
    if dt is None:
        raise InvalidInput("dt is required: the control period in seconds (e.g. dt=0.002), "
                           "which the limits use to bound the next step")
    try:
        value = float(dt)
    except (TypeError, ValueError):
        raise InvalidInput(f"dt must be a number of seconds, got {dt!r}") from None
    if not (np.isfinite(value) and value > 0):
        raise InvalidInput(f"dt must be positive and finite, got {dt}")
    return value


class Problem:
    """Tasks and limits laid out once; :meth:`fill` measures them for the step. Each task
    gets the period (``dt``; None for a law without one, and no limits then); ``hard`` and
    ``soft`` split them; ``inequalities`` holds the box and general rows, written into
    ``out`` = (lb, ub, G, h) (a solver's own arrays) or arrays of its own; ``owner``
    names the controller in messages.
    """

    def __init__(self, robot: Robot, tasks: Sequence[Task], limits: Sequence[Limit] = (), dt: float | None = None,
                 owner: str = "the controller", out: tuple | None = None):
        self.dt = None if dt is None else check_dt(dt)
        check_same_robot(robot, tasks, limits, owner)
        self.robot = robot
        self.tasks = list(tasks)
        for task in self.tasks:
            task.attach(self.dt)
        self.hard = [task for task in self.tasks if task.hard]
        self.soft = [task for task in self.tasks if not task.hard]
        self.inequalities = None if self.dt is None else Inequalities(robot.nv, limits, self.dt, out)
        self.limits = [] if self.inequalities is None else self.inequalities.limits
        self._updates = [task.update for task in self.tasks]

    def fill(self) -> None:
        """The step's kinematics (if q changed), every task measured, every limit written."""
        self.robot.ensure_kinematics()
        for update in self._updates:
            update()
        if self.inequalities is not None:
            self.inequalities.write()
