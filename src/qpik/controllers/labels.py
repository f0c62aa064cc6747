"""Names of tasks in messages."""

from __future__ import annotations


def task_label(task) -> str:
    """A task's name with the frame it acts on, so that two tasks of one kind differ
    (``hard position task on site 'left_foot'``)."""
    frame = getattr(task, "frame", None)
    name = getattr(frame, "name", frame)
    kind = getattr(frame, "type", None)
    where = f" on {kind + ' ' if kind else ''}{name!r}" if isinstance(name, str) else ""
    return f"{'hard ' if task.hard else ''}{task.name}{where}"
