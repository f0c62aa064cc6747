"""References: drive a tracking task along a trajectory and measure how well it is tracked.

A reference has three methods: ``apply(t)`` sets its task's target for time t,
``desired()`` gives the desired tracked position, ``measure(robot)`` the tracked position
(and extras) on a robot with up-to-date kinematics. A rollout uses a reference through
:meth:`Reference.start`, which returns a :class:`ReferenceRun` for one rollout's times:

- the default run calls ``apply`` and ``measure`` once per step;
- the bundled references sample the whole trajectory before the first step (one
  vectorised pass, :func:`qpik.trajectories.sample_many`), copy a few of MuJoCo's numbers
  per step, and evaluate the measurements after the last step, vectorised. They give
  the same bits as the per-step calls (tested), at a fraction of their cost.

Manipulability measures follow the same pattern (:class:`Measurement`): any callable of a
robot works, one call per step; a measure with a ``start`` method records per step and
evaluates after the run.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from ..errors import InvalidInput
from ..robot import Robot
from ..tasks import ComTask, PositionTask
from ..trajectories import sample_many


class ReferenceRun:
    """One rollout's use of a reference, step by step.

    Args:
        reference: the reference (anything with ``apply``, ``desired``, ``measure``).
        plant: the robot the measurements read (the controller's, or the physics plant).
        times: the rollout's step times.
    """

    def __init__(self, reference, plant: Robot, times: np.ndarray):
        self.reference = reference
        self.plant = plant
        self.times = times
        self._x: list[np.ndarray] = []
        self._x_des: list[np.ndarray] = []
        self._extras: dict[str, list[float]] = {}

    def apply(self, k: int) -> None:
        """Set the task's target for step k."""
        self.reference.apply(float(self.times[k]))

    def record(self, k: int) -> None:
        """Measure the plant at step k (steps are recorded in order, each once)."""
        sample = self.reference.measure(self.plant)
        self._x.append(np.array(sample.pop("x"), dtype=float))
        self._x_des.append(np.array(self.reference.desired(), dtype=float))
        for name, value in sample.items():
            self._extras.setdefault(name, []).append(float(value))

    def results(self, count: int) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        """Tracked and desired positions (count x dim) and the extras of the first ``count`` steps."""
        return (np.array(self._x[:count]), np.array(self._x_des[:count]),
                {name: np.array(values[:count]) for name, values in self._extras.items()})


class Reference:
    """Base class of the references; subclasses implement ``apply``, ``desired``,
    ``measure`` and may return a faster :class:`ReferenceRun` from :meth:`start`."""

    def apply(self, t: float) -> None:
        """Set the task's target (and feed-forward velocity) for time t."""
        raise NotImplementedError

    def desired(self) -> np.ndarray:
        """The desired tracked position at the last ``apply``."""
        raise NotImplementedError

    def measure(self, robot: Robot) -> dict:
        """``{"x": tracked position, **extras}`` on a robot with up-to-date kinematics."""
        raise NotImplementedError

    def start(self, plant: Robot, times: np.ndarray) -> ReferenceRun:
        """A run of this reference over ``times``, measuring ``plant``."""
        return ReferenceRun(self, plant, times)


def start_reference(reference, plant: Robot, times: np.ndarray) -> ReferenceRun:
    """``reference.start(...)`` for a :class:`Reference`; the per-step run for any other
    object with ``apply``, ``desired`` and ``measure``."""
    if isinstance(reference, Reference):
        return reference.start(plant, times)
    for method in ("apply", "desired", "measure"):
        if not callable(getattr(reference, method, None)):
            raise InvalidInput(f"a reference needs apply, desired and measure methods; {reference!r} has no {method}")
    return ReferenceRun(reference, plant, times)


class PositionReference(Reference):
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

    def start(self, plant: Robot, times: np.ndarray) -> ReferenceRun:
        # A subclass that changes what a step does (another target, more measurements)
        # gets the per-step run, which calls its own methods.
        if any(getattr(type(self), name) is not getattr(PositionReference, name)
               for name in ("apply", "desired", "measure")):
            return ReferenceRun(self, plant, times)
        return _PositionRun(self, plant, times)


class _PositionRun(ReferenceRun):
    """The trajectory sampled once; per step a target set and the tracked point copied."""

    def __init__(self, reference: PositionReference, plant: Robot, times: np.ndarray):
        super().__init__(reference, plant, times)
        self.task = reference.task
        self.positions, self.velocities = sample_many(reference.trajectory, times)
        self._x = np.empty((len(times), self.task.target_dim))

    def apply(self, k: int) -> None:
        self.task.set_target(self.positions[k], self.velocities[k])

    def record(self, k: int) -> None:
        self._x[k] = self.task.measured(self.plant)

    def results(self, count: int) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        return self._x[:count], self.positions[:count], {}


def start_measurement(measure, plant: Robot, steps: int):
    """The per-step recorder of a scalar measure of the plant (e.g. a manipulability).

    A measure with its own ``start(plant, steps)`` returns its recorder (an object with
    ``record(k)`` and ``values(count)``: it records per step and evaluates after the
    run); any callable ``measure(robot) -> float`` is called once per step; ``None``
    logs NaN.
    """
    if measure is not None and callable(getattr(measure, "start", None)):
        return measure.start(plant, steps)
    if measure is not None and not callable(measure):
        raise InvalidInput(f"a measure must be callable on a robot, got {measure!r}")
    return Measurement(measure, plant, steps)


class Measurement:
    """A scalar measure of the plant called once per step (NaN without a measure)."""

    def __init__(self, measure: Callable[[Robot], float] | None, plant: Robot, steps: int):
        self.measure = measure
        self.plant = plant
        self._values = np.full(steps, np.nan)

    def record(self, k: int) -> None:
        if self.measure is not None:
            self._values[k] = self.measure(self.plant)

    def values(self, count: int) -> np.ndarray:
        return self._values[:count]
