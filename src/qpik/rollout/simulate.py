"""Headless MuJoCo rollouts of a controller along a reference, and their log.

Two modes, both at the control period Δt (2 ms):

- ``kinematic`` (the source's scheme): q ← q ⊕ q̇Δt with ``mj_integratePos``, then
  held inside the model's joint ranges, the hardware end stops.
- ``physics``: the controller integrates its own commanded configuration (as IK
  front-ends do) and the plant, a second MjData on the same model, tracks it with
  its position actuators (velocity actuators, if the scene has them, get q̇ as
  feed-forward) through ``mj_step`` (:class:`~qpik.rollout.plant.PhysicsPlant`).
  Everything logged (x, error, q) is measured on the plant. MuJoCo's "unstable, reset"
  stops the rollout with a :class:`~qpik.errors.DivergenceError`.

``limit_violation`` is, per step, the larger excursion beyond the limits the controllers
were given (a scenario may tighten the model's ranges) of the measured configuration
and of the commanded one q ⊕ q̇Δt, before the end stops act: a controller is charged
with what it asks for, which the stops would hide, and with what the plant does.

A controller with ``actuated_only = True`` (the hexapod's classical law) moves only the
actuated joints; ``closure`` then places the rest (the platform and the passive joints
of a closed chain) after each step, as the mechanism itself does.

Per step the controller time covers the kinematics update and
``compute_velocity``: the work of the control step, nothing of the logging. After it,
and outside the timed part, ``levels`` (a task hierarchy's per-level errors, the same
for every controller) are measured on the controller's robot, and a controller with a
``report()`` method (SNS's task scale) has it logged.

The loop itself only sets targets and copies numbers into preallocated arrays: the
reference is sampled for every step before the first (:mod:`qpik.rollout.references`),
and errors, limit violations and the measures of the bundled robots are evaluated,
vectorised, when the log is made. :class:`Rollout` runs in blocks of steps (the timing
harness of the benchmarks interleaves controllers that way); :func:`simulate` runs one
to the end.
"""

from __future__ import annotations

import math
import time
from typing import Callable, Protocol

import mujoco
import numpy as np

from ..errors import DivergenceError, InfeasibleProblem, InvalidInput, SolverError
from ..robot import JointLimits, Robot
from .log import LevelLog, RolloutLog, RunInfo, RunStop
from .plant import PhysicsPlant
from ..tasks.inputs import as_index
from .references import Reference, start_measurement, start_reference

MODES = ("kinematic", "physics")

_BLAS = None  # threadpoolctl's view of the loaded BLAS libraries, made on first use


def single_threaded_blas():
    """A context in which NumPy's and SciPy's BLAS run on one thread."""
    global _BLAS
    if _BLAS is None:
        from ..extras import installed

        if not installed("threadpoolctl"):  # the cli extra: without it BLAS keeps its threads
            import contextlib

            return contextlib.nullcontext()
        from threadpoolctl import ThreadpoolController

        _BLAS = ThreadpoolController()
    return _BLAS.limit(limits=1, user_api="blas")

__all__ = ["MODES", "Controller", "Reference", "Rollout", "simulate"]


class Controller(Protocol):
    kind: str
    solver: str
    robot: Robot

    def compute_velocity(self) -> np.ndarray: ...


class Rollout:
    """A rollout of ``controller`` along ``reference`` for ``duration`` seconds at period
    ``dt``, advanced in blocks of steps; :meth:`log` gives its :class:`RolloutLog`.

    The controller's robot starts from its current configuration. A controller failure
    (singularity, infeasible QP, solver failure) or a divergence (non-finite velocity or
    configuration, an unstable physics simulation) raises its typed error naming the
    time; with ``on_failure="stop"`` it ends the rollout instead and the log keeps the
    steps done, with the reason in ``completed``/``failure``.

    Args:
        controller: anything with ``robot``, ``kind``, ``solver`` and ``compute_velocity()``.
        reference: a :class:`~qpik.rollout.references.Reference` (or any object with
            ``apply``, ``desired``, ``measure``).
        duration: seconds; the rollout has ``round(duration / dt) + 1`` steps.
        dt: control period.
        mode: ``"kinematic"`` or ``"physics"``.
        manipulability: a measure of the plant logged per step (a callable of a robot,
            or one with ``start``, see :func:`~qpik.rollout.references.start_measurement`).
        joint_limits: the limits ``limit_violation`` is measured against (default the
            robot's).
        closure: places the passive joints after each step (controllers that move only
            the actuated joints).
        speed_dofs: the dofs whose speed ``peak_joint_speed`` reports (default all).
        levels: per-level errors to log (e.g. :class:`qpik.rollout.levels.LevelErrors`:
            ``names``, ``units`` and ``measure(qdot)``).

    Raises:
        InvalidInput: a bad mode, duration, dt, ``on_failure``, or a reference whose
            samples are not finite.
        ModelError: physics mode on a model without position actuators or with a bad
            timestep.
    """

    def __init__(
        self,
        controller: Controller,
        reference,
        duration: float,
        *,
        dt: float = 0.002,
        mode: str = "kinematic",
        manipulability: Callable[[Robot], float] | None = None,
        manipulability_measure: str = "sigma",
        joint_limits: JointLimits | None = None,
        scenario: str = "custom",
        robot_name: str | None = None,
        progress: Callable[[int, int], None] | None = None,
        on_failure: str = "raise",
        closure: Callable[[Robot], None] | None = None,
        speed_dofs=None,
        levels=None,
    ):
        if on_failure not in ("raise", "stop"):
            raise InvalidInput(f"on_failure must be 'raise' or 'stop', got {on_failure!r}")
        if mode not in MODES:
            raise InvalidInput(f"unknown mode {mode!r}; expected one of {MODES}")
        try:
            valid = math.isfinite(duration) and duration > 0 and math.isfinite(dt) and dt > 0
        except TypeError:
            valid = False
        if not valid:
            raise InvalidInput(f"duration and dt must be positive and finite, got {duration!r}, {dt!r}")
        robot = controller.robot
        self.controller = controller
        self.robot = robot
        self.dt = float(dt)
        self.mode = mode
        self.on_failure = on_failure
        self.progress = progress
        self.limits = robot.joint_limits if joint_limits is None else joint_limits
        self.actuated_only = getattr(controller, "actuated_only", False)
        if self.actuated_only and closure is None:
            raise InvalidInput(f"controller {controller.kind!r} moves only the actuated joints: give a loop closure")
        self.closure = closure
        self.info = RunInfo(robot=robot_name or robot.name, controller=controller.kind, solver=controller.solver,
                            scenario=scenario, mode=mode, dt=self.dt, manipulability_measure=manipulability_measure)
        self.speed_dofs = None if speed_dofs is None else np.asarray(speed_dofs, dtype=int)
        self.steps = int(round(duration / dt)) + 1
        self.times = np.arange(self.steps) * self.dt  # k·dt, the same bits as in a loop
        self.physics = PhysicsPlant(robot, self.dt) if mode == "physics" else None
        self.plant = self.physics.robot if self.physics else robot
        self._reference = start_reference(reference, self.plant, self.times)
        self._manipulability = start_measurement(manipulability, self.plant, self.steps)
        # End stops: the model's ranges, clipped in place (on a view when the joints are consecutive).
        stops = robot.joint_limits
        self._stop_index = as_index(stops.qpos_index)
        self._stop_lower, self._stop_upper = stops.lower, stops.upper
        self._has_stops = len(stops.names) > 0
        self._stop_view = robot.data.qpos[self._stop_index] if isinstance(self._stop_index, slice) else None
        self._q = np.empty((self.steps, robot.nq))
        self._q_commanded = np.full((self.steps, robot.nq), np.nan)  # NaN rows: no command (last step)
        self._qdot = np.empty((self.steps, robot.nv))
        self._step_time = np.empty(self.steps)
        self.levels = levels
        if levels is not None:
            levels.skip_updates_of(getattr(controller, "updated_tasks", ()))
        self._level_error = np.empty((self.steps, len(levels.names))) if levels is not None else None
        self._report = getattr(controller, "report", None)
        self._report_log: dict[str, list] = {}
        self._source_reference = reference
        self.done = 0  # steps logged
        self.stop: RunStop | None = None  # why and when the run stopped early
        self.finished = False

    def advance(self, count: int | None = None) -> int:
        """Run up to ``count`` more steps (all the remaining by default); the steps run.

        The steps run with the BLAS libraries single-threaded, as a real-time loop would:
        on a loaded machine a multithreaded product of two small matrices waits for a
        core for milliseconds (a 2 µs step once took 4-16 ms)."""
        if self.finished:
            return 0
        with single_threaded_blas():
            return self._advance(count)

    def _advance(self, count: int | None) -> int:
        start = self.done
        stop = self.steps if count is None else min(self.steps, start + int(count))
        robot, plant, controller, reference = self.robot, self.plant, self.controller, self._reference
        manipulability, physics, times = self._manipulability, self.physics, self.times
        q_log, qdot_log, time_log = self._q, self._qdot, self._step_time
        last = self.steps - 1
        clock = time.perf_counter
        plant_q = plant.data.qpos  # a view, valid for the data's life
        after_step = self._after_step if self._level_error is not None or self._report is not None else None
        for k in range(start, stop):
            if physics is not None:
                plant.update_kinematics()
            reference.apply(k)
            begin = clock()
            robot.update_kinematics()
            try:
                qdot = controller.compute_velocity()
            except (DivergenceError, InfeasibleProblem, SolverError) as exc:
                when = f"at t = {times[k]:.3f} s"
                self._fail(type(exc), f"{when}: {exc}", times[k], f"{type(exc).__name__} {when}: {exc}")
                break
            time_log[k] = clock() - begin
            if after_step is not None:
                after_step(k, qdot)
            reference.record(k)
            manipulability.record(k)
            q_log[k] = plant_q
            qdot_log[k] = qdot
            self.done = k + 1
            if k == last:
                self.finished = True
                break
            if not self._move(k):
                break
            if self.progress is not None:
                self.progress(k + 1, self.steps)
        return self.done - start

    def _after_step(self, k: int, qdot: np.ndarray) -> None:
        """Outside the timed part: the levels' errors and the controller's report."""
        if self._level_error is not None:
            self._level_error[k] = self.levels.measure(qdot)
        if self._report is not None:
            for name, value in self._report().items():
                self._report_log.setdefault(name, []).append(value)

    def _move(self, k: int) -> bool:
        """Integrate step k's logged velocity, hold the joints at their end stops, close
        the loops, step the plant; False when the rollout stops here."""
        robot, t, qdot = self.robot, self.times[k], self._qdot[k]  # the logged copy: contiguous and writable
        # A NaN velocity is the controller diverging, not a bad argument to integrate.
        if not math.isfinite(mujoco.mju_sum(qdot)):
            message = f"at t = {t:.3f} s: the controller returned a non-finite velocity"
            if self._fail(DivergenceError, message, t):
                return False
        q = robot.data.qpos  # a view, valid for the data's life
        robot.integrate(qdot, self.dt)
        self._q_commanded[k] = q
        stop_view = self._stop_view
        if stop_view is not None:  # two ufuncs: np.clip's Python wrapper costs 3 µs more
            np.maximum(stop_view, self._stop_lower, out=stop_view)
            np.minimum(stop_view, self._stop_upper, out=stop_view)
        elif self._has_stops:
            index = self._stop_index
            q[index] = np.clip(q[index], self._stop_lower, self._stop_upper)
        if self.actuated_only:
            self.closure(robot)
        failure = self.physics.step(q, qdot) if self.physics is not None else ""
        if not failure and not math.isfinite(mujoco.mju_sum(q)):
            failure = "the controller drove the configuration to non-finite values"
        return not (failure and self._fail(DivergenceError, f"at t = {t:.3f} s: {failure}", t))

    @property
    def q_commanded(self) -> np.ndarray:
        """The commanded configuration q ⊕ q̇Δt of each step done, before the end stops
        (a NaN row where no command was made: the last step, a failed one)."""
        return self._q_commanded[: self.done]

    def _fail(self, error: type, message: str, t: float, reason: str | None = None) -> bool:
        """Raise ``error(message)`` or, with ``on_failure="stop"``, end the rollout at time ``t``."""
        if self.on_failure == "raise":
            raise error(message) from None
        self.stop = RunStop(reason or message, error.__name__, float(t))
        self.finished = True
        return True

    def log(self) -> RolloutLog:
        """The log of the steps done so far, with its metrics evaluated (vectorised).

        Raises:
            DivergenceError: the controller failed at the first step.
        """
        n = self.done
        if n == 0:
            raise DivergenceError(f"the controller failed at the first step: {self.stop.failure if self.stop else ''}")
        x, x_des, extras = self._reference.results(n)
        q = self._q[:n]
        commanded = self.limits.violations(self._q_commanded[:n])
        levels = None
        if self.levels is not None:
            levels = LevelLog(tuple(self.levels.names), tuple(self.levels.units), self._level_error[:n])
        summarize = getattr(self._source_reference, "summarize", None)
        return RolloutLog(
            info=self.info, t=self.times[:n], q=q, qdot=self._qdot[:n], x=x, x_des=x_des,
            error=np.linalg.norm(x_des - x, axis=1), manipulability=self._manipulability.values(n),
            step_time=self._step_time[:n], limit_violation=np.maximum(self.limits.violations(q), commanded),
            extras=extras, speed_dofs=self.speed_dofs, stop=self.stop, levels=levels,
            report={name: np.array(values[:n]) for name, values in self._report_log.items()},
            reference_summary=summarize(self.times[:n], x) if summarize is not None else {},
            commanded_violation=commanded, q_commanded=self._q_commanded[:n])


def simulate(controller: Controller, reference, duration: float, **options) -> RolloutLog:
    """Run ``controller`` along ``reference`` for ``duration`` seconds: a :class:`Rollout`
    (same arguments) advanced to its end, and its log."""
    rollout = Rollout(controller, reference, duration, **options)
    rollout.advance()
    return rollout.log()
