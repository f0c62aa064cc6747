"""Task rows: tasks grouped into priority levels, and their rows J q̇ = v stacked, in
every world.

Every controller reads tasks through these: the QP's hard rows and its cost's general
rows, each level of the hierarchy, the pseudoinverse's primary task and each SNS level
are one :class:`Stack`.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ..errors import InvalidInput
from ..tasks import Task


def row_slices(sizes: Sequence[int], start: int = 0) -> list[slice]:
    """Consecutive row blocks of the given sizes, the first at ``start``."""
    slices = []
    for size in sizes:
        slices.append(slice(start, start + size))
        start += size
    return slices


def group_levels(robot, tasks: Sequence[Task] | None, levels: Sequence[Sequence[Task]] | None,
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
            task listed twice (in one level or in two: it would constrain itself), or
            something that is no Task.
    """
    if (tasks is None) == (levels is None):
        raise InvalidInput(f"{owner}: give either tasks (grouped by their priority) or levels, not both or neither")
    if levels is None:
        tasks = list(tasks)
        if not tasks:
            raise InvalidInput(f"{owner} needs at least one task")
        _check_tasks(tasks, owner, "")
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
        _check_tasks(level, owner, f" of level {k}")
        for task in level:
            if task.robot is not robot:
                raise InvalidInput(f"{owner}: the {task.name} of level {k} reads another robot")
            if id(task) in seen:
                where = f"level {k}" if seen[id(task)] == k else f"levels {seen[id(task)]} and {k}"
                raise InvalidInput(f"{owner}: the {task.name} is listed twice ({where}); a task has one priority")
            seen[id(task)] = k
    return grouped


def _check_tasks(tasks: Sequence, owner: str, where: str) -> None:
    for task in tasks:
        if not isinstance(task, Task):
            raise InvalidInput(f"{owner}: {task!r}{where} is not a Task")


class Stack:
    """The rows of some tasks stacked in every world: ``J`` (N, m, nv) and ``v`` (N, m),
    written by :meth:`stack` (after the tasks' ``update``).

    Rows of zero weight of a soft task are left out (a zero weight masks a row); a hard
    task keeps all its rows. ``weighted`` scales each soft row by √w, so that a
    least-squares solution of the stack weighs the tasks as the QP's cost does.
    ``spare_rows`` more rows follow the tasks', for the owner to write. One task whose
    rows need no change is its own stack (its arrays, no copy).
    """

    def __init__(self, robot, tasks: Sequence[Task], weighted: bool = False, spare_rows: int = 0):
        n, nv = robot.n, robot.nv
        self.tasks = list(tasks)
        kept = [np.arange(t.dim) if t.hard else np.flatnonzero(t.weight > 0) for t in self.tasks]
        self.dim = sum(len(keep) for keep in kept)
        self.task_rows = list(zip(self.tasks, row_slices([len(keep) for keep in kept])))  # (task, its rows)
        roots = [np.sqrt(t.weight[keep]) if weighted and not t.hard else np.ones(len(keep))
                 for t, keep in zip(self.tasks, kept)]
        single = len(self.tasks) == 1 and not spare_rows and len(kept[0]) == self.tasks[0].dim and \
            np.all(roots[0] == 1.0)
        self._direct = self.tasks[0] if single else None
        if single:
            self.J, self.v = self.tasks[0].jacobians, self.tasks[0].target_velocities
        else:
            self.J, self.v = np.zeros((n, self.dim + spare_rows, nv)), np.zeros((n, self.dim + spare_rows))
        self._blocks = []  # (task, its kept rows or None, its blocks of J and v (views), √w for J and v or None)
        for (task, rows), keep, root in zip(self.task_rows, kept, roots):
            scale = None if np.all(root == 1.0) else np.tile(root, (n, 1))
            self._blocks.append((task, None if len(keep) == task.dim else keep, self.J[:, rows], self.v[:, rows],
                                 None if scale is None else scale[:, :, None], scale))
        # J = I (a joint-space task on every dof): a controller may skip J.
        self.identity = bool(single and self.tasks[0].joint_space and np.array_equal(self.tasks[0].dofs, np.arange(nv)))

    def stack(self) -> None:
        """Copy each task's J and v (scaled where weighted)."""
        if self._direct is not None:
            return
        for task, keep, J, v, row_roots, roots in self._blocks:
            jacobians, velocities = task.jacobians, task.target_velocities
            if keep is not None:
                jacobians, velocities = jacobians[:, keep], velocities[:, keep]
            if roots is None:
                np.copyto(J, jacobians)
                np.copyto(v, velocities)
            else:
                np.multiply(jacobians, row_roots, J)
                np.multiply(velocities, roots, v)
