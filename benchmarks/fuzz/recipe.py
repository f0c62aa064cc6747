"""A case's recipe: every construction, call and attribute set that built its objects on
one robot, recorded as it ran, to build the same objects again on another robot — N
worlds of the model, or one world of them — with each world's own values.

A case builds through :meth:`Recipe.new`, :meth:`Recipe.call` and :meth:`Recipe.set`
(each records its step, then does it, so a step that raises is the recipe's last);
:meth:`Recipe.replay` does the steps again on another robot, every recorded object in
the arguments (the robot, tasks, lists of them, a measure inside a task) replaced by the
one built in its place, and returns the objects and where it stopped.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from typing import Callable

import numpy as np


@dataclass
class Step:
    """One recorded step: ``kind`` "new" (``target`` a class), "call" (``target`` an
    object, ``name`` its method) or "set" (``name`` an attribute, ``args`` its value)."""

    kind: str
    target: object
    name: str | None
    args: tuple
    kwargs: dict
    result: object = None


@dataclass
class Replayed:
    """What a replay built: ``objects`` (id of the recorded object → its counterpart) and,
    where a step raised, ``failed`` = (its index, the exception)."""

    objects: dict
    failed: tuple[int, Exception] | None = None

    def get(self, original):
        return self.objects.get(id(original))


def _copied(value):
    """``value`` with every array in it copied (a recorded argument outlives the step)."""
    if isinstance(value, np.ndarray):
        return value.copy()
    if isinstance(value, (list, tuple)):
        return type(value)(_copied(v) for v in value)
    if isinstance(value, dict):
        return {k: _copied(v) for k, v in value.items()}
    return value


@dataclass
class Recipe:
    """The steps that built a case's objects on ``robot``, from its model and configuration
    as they were when the recipe started (copies: the case may move on)."""

    robot: object
    model: object = None
    q: np.ndarray | None = None
    steps: list[Step] = field(default_factory=list)

    def __post_init__(self):
        self.model = copy.copy(self.robot.model)
        self.q = np.array(self.robot.q, dtype=float)

    def new(self, cls, *args, **kwargs):
        """``cls(*args, **kwargs)``, recorded."""
        return self._record(Step("new", cls, None, _copied(args), _copied(kwargs)))

    def call(self, obj, name: str, *args, **kwargs):
        """``obj.name(*args, **kwargs)``, recorded."""
        return self._record(Step("call", obj, name, _copied(args), _copied(kwargs)))

    def set(self, obj, name: str, value) -> None:
        """``obj.name = value``, recorded."""
        self._record(Step("set", obj, name, (_copied(value),), {}))

    def _record(self, step: Step):
        self.steps.append(step)
        step.result = _do(step, step.target, step.args, step.kwargs)
        return step.result

    def replay(self, robot, values: Callable[[Step, tuple, dict], tuple[tuple, dict]] | None = None) -> Replayed:
        """The steps again on ``robot`` (at the configuration it is given), ``values(step,
        args, kwargs)`` choosing each step's arguments where given; stops at the first
        step that raises (any exception: which one is the caller's to judge)."""
        made = Replayed({id(self.robot): robot})
        for index, step in enumerate(self.steps):
            args, kwargs = _resolved(step.args, made.objects), _resolved(step.kwargs, made.objects)
            if values is not None:
                args, kwargs = values(step, args, kwargs)
            target = step.target if step.kind == "new" else made.objects[id(step.target)]
            try:
                result = _do(step, target, args, kwargs)
            except Exception as exc:  # noqa: BLE001 - the caller compares it with the other replays'
                made.failed = (index, exc)
                return made
            if step.kind == "new" and step.result is not None:
                made.objects[id(step.result)] = result
        return made


def _do(step: Step, target, args: tuple, kwargs: dict):
    if step.kind == "new":
        return target(*args, **kwargs)
    if step.kind == "call":
        return getattr(target, step.name)(*args, **kwargs)
    setattr(target, step.name, args[0])
    return None


def _resolved(value, objects: dict):
    """``value`` with each recorded object replaced by its counterpart in ``objects`` (and
    arrays copied: a replay must not share an array with another)."""
    if id(value) in objects:
        return objects[id(value)]
    if isinstance(value, np.ndarray):
        return value.copy()
    if isinstance(value, (list, tuple)):
        return type(value)(_resolved(v, objects) for v in value)
    if isinstance(value, dict):
        return {k: _resolved(v, objects) for k, v in value.items()}
    return value
