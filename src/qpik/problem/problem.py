"""The problem of a control step, laid out once from (robot, tasks, limits, dt) and filled
every step, in every world: the tasks measured, the box lb ≤ q̇ ≤ ub (one (N, 2, nv)
array) and the general rows G q̇ ≤ h written by the limits."""

from __future__ import annotations

import warnings
from typing import Sequence

import numpy as np

from ..errors import HostStepWarning, InvalidInput
from ..limits.limit import Limit, order_limits
from ..robot import check_same_robot
from ..tasks import Task
from .rows import row_slices


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


def warn_host_step(robot, owner: str) -> None:
    """A :class:`~qpik.errors.HostStepWarning` when the worlds' kinematics live on a device
    (MuJoCo Warp): the step's math runs on the host, the device's kinematics copied over
    every step (the primitives have device functions, the tasks, limits, cost and
    held-bounds iteration none: docs/batch.md)."""
    device = robot.backend.device if robot.batched else None
    if device is not None:
        warnings.warn(f"{owner}: the step's tasks, limits, cost and held-bounds iteration have no device function "
                      f"and run on the host; only the kinematics of {robot!r} run on {device}", HostStepWarning,
                      stacklevel=4)


class Problem:
    """Tasks and limits laid out once; :meth:`fill` measures them for the step.

    Each task gets the period (``dt``; None for a law without one, and no limits then);
    ``hard`` and ``soft`` split them. ``box`` (N, 2, nv) holds the step's bounds
    (``lower``, ``upper``: its two rows, views), ``G`` (N, rows, nv) and ``h`` (N, rows) the
    general rows; constant limits (speed bounds) are written once into ``box0``, which
    every step starts from. ``owner`` names the controller in messages.
    """

    def __init__(self, robot, tasks: Sequence[Task], limits: Sequence[Limit] = (), dt: float | None = None,
                 owner: str = "the controller"):
        self.dt = None if dt is None else check_dt(dt)
        check_same_robot(robot, tasks, limits, owner)
        warn_host_step(robot, owner)
        self.robot = robot
        self.tasks = list(tasks)
        for task in self.tasks:
            task.attach(self.dt)
        self.hard = [task for task in self.tasks if task.hard]
        self.soft = [task for task in self.tasks if not task.hard]
        if self.dt is None and limits:
            raise InvalidInput(f"{owner} takes no limits")
        self.limits = order_limits(limits)
        n, nv = robot.n, robot.nv
        self.box0 = np.empty((n, 2, nv))
        self.box0[:, 0], self.box0[:, 1] = -np.inf, np.inf
        for limit in self.limits:
            if limit.constant:
                if limit.inequality_rows:
                    raise InvalidInput(f"{type(limit).__name__}: a constant limit writes the box only (no rows)")
                limit.apply(self.dt, self.box0[:, 0], self.box0[:, 1])
        self.box = self.box0.copy()
        self.lower, self.upper = self.box[:, 0], self.box[:, 1]
        changing = [limit for limit in self.limits if not limit.constant]
        sizes = [limit.inequality_rows for limit in changing]
        self.rows = sum(sizes)
        self.G, self.h = np.zeros((n, self.rows, nv)), np.zeros((n, self.rows))
        self.inequalities = (self.G, self.h) if self.rows else (None, None)  # as the closed form takes them
        self.row_limits = [(limit, rows) for limit, rows in zip(changing, row_slices(sizes)) if limit.inequality_rows]
        self._writes = [(limit.apply, (self.dt, self.lower, self.upper) if not limit.inequality_rows else
                         (self.dt, self.lower, self.upper, self.G[:, rows], self.h[:, rows]))
                        for limit, rows in zip(changing, row_slices(sizes))]
        self._updates = [task.update for task in self.tasks]

    def fill(self) -> None:
        """The step's kinematics (if q changed), every task measured, every limit written."""
        self.robot.ensure_kinematics()
        for update in self._updates:
            update()
        if self._writes:
            self.box[...] = self.box0
            for apply, arguments in self._writes:
                apply(*arguments)
