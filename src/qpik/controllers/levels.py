"""Priority levels: the tasks of a strict hierarchy grouped and checked once.

Both :class:`~qpik.controllers.hierarchy.HierarchicalController` and
:class:`~qpik.controllers.sns.SNSController` take either tasks carrying an integer
``priority`` (0 the highest; equal priorities share a level) or explicit ``levels``
(a list of lists of tasks, level 0 first), and stack each level's rows here.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ..errors import InvalidInput
from ..robot import Robot
from ..tasks import Task
from .labels import task_label
from .qp import check_dt  # noqa: F401 (re-exported for hierarchy and sns)


def _describe(tasks: Sequence[Task]) -> str:
    return ", ".join(task_label(task) for task in tasks)


def group_levels(robot: Robot, tasks: Sequence[Task] | None, levels: Sequence[Sequence[Task]] | None,
                 owner: str) -> list[list[Task]]:
    """The hierarchy as a list of levels, level 0 (highest priority) first.

    Args:
        robot: the robot every task must read.
        tasks: tasks grouped by their ``priority`` (gaps between priorities are allowed:
            priorities {0, 2} give two levels).
        levels: explicit levels instead (their tasks' ``priority`` is then not read).
        owner: the controller's name, for the error messages.

    Raises:
        InvalidInput: both or neither of ``tasks``/``levels`` given, an empty level, a
            task listed twice (in one level or in two: the same task object, which would
            constrain itself), a task of another robot, or something that is no Task.
    """
    if (tasks is None) == (levels is None):
        raise InvalidInput(f"{owner}: give either tasks (grouped by their priority) or levels, not both or neither")
    if levels is None:
        tasks = list(tasks)
        if not tasks:
            raise InvalidInput(f"{owner} needs at least one task")
        for task in tasks:
            if not isinstance(task, Task):
                raise InvalidInput(f"{owner}: {task!r} is not a Task")
        priorities = sorted({task.priority for task in tasks})
        grouped = [[task for task in tasks if task.priority == p] for p in priorities]
    else:
        grouped = [list(level) if not isinstance(level, Task) else [level] for level in levels]
        if not grouped:
            raise InvalidInput(f"{owner} needs at least one level")
    seen: dict[int, int] = {}
    for k, level in enumerate(grouped):
        if not level:
            raise InvalidInput(f"{owner}: level {k} is empty")
        for task in level:
            if not isinstance(task, Task):
                raise InvalidInput(f"{owner}: level {k} holds {task!r}, which is not a Task")
            if task.robot is not robot:
                raise InvalidInput(f"{owner}: the {task.name} of level {k} reads another robot")
            if id(task) in seen:
                where = f"level {k}" if seen[id(task)] == k else f"levels {seen[id(task)]} and {k}"
                raise InvalidInput(f"{owner}: the {task.name} is listed twice ({where}); "
                                   "a task has one priority")
            seen[id(task)] = k
    return grouped


class StackedLevel:
    """The rows of one level stacked: ``J`` (m x nv) and ``v`` (m,), written in place.

    Rows of zero weight of a soft task are left out (they are not part of the level's
    objective); a hard task keeps all its rows.
    ``weighted=True`` scales each row by √w, so a least-squares solution of the stack
    weighs the level's tasks as the QP's cost does.
    """

    def __init__(self, robot: Robot, tasks: Sequence[Task], weighted: bool, out: tuple | None = None):
        self.tasks = list(tasks)
        self.names = _describe(self.tasks)
        self._rows = []  # (task, rows of the task kept, slice of the stack, √w of those rows)
        start = 0
        for task in self.tasks:
            keep = np.flatnonzero(task.weight > 0) if not task.hard else np.arange(task.dim)
            count = len(keep)
            full = count == task.dim
            root = np.sqrt(task.weight[keep]) if weighted else np.ones(count)
            self._rows.append((task, slice(None) if full else keep, slice(start, start + count),
                               None if np.all(root == 1.0) else root))
            start += count
        self.dim = start
        # One task whose rows need no scaling: its own arrays are the stack (no copy).
        self._direct = out is None and len(self._rows) == 1 and isinstance(self._rows[0][1], slice) and \
            (self._rows[0][3] is None or np.all(self._rows[0][3] == self._rows[0][3][0]))
        # J = I (a joint-space task on every dof, one weight): a controller may skip J.
        single = self.tasks[0] if len(self.tasks) == 1 else None
        self.identity = bool(self._direct and single.joint_space and np.array_equal(single.dofs, np.arange(robot.nv)))
        # ``out``: (J, v) views of a larger stack to write into (no copy afterwards).
        self.J, self.v = out if out is not None else (np.zeros((start, robot.nv)), np.zeros(start))
        if self.J.shape != (start, robot.nv) or self.v.shape != (start,):
            raise InvalidInput(f"stack buffers must have shapes ({start}, {robot.nv}) and ({start},)")

    def stack(self) -> None:
        """Copy each task's J and v (call after the tasks' ``update``)."""
        if self._direct:  # uniform weight on one task: the least-squares solution ignores it
            task = self.tasks[0]
            self.J, self.v = task.jacobian, task.target_velocity
            return
        for task, keep, rows, root in self._rows:
            self.J[rows] = task.jacobian[keep]
            self.v[rows] = task.target_velocity[keep]
            if root is not None:
                self.J[rows] *= root[:, None]
                self.v[rows] *= root
