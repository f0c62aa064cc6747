"""Headless MuJoCo rollouts of a controller along a reference, and their log.

Two modes, both at the control period Δt (2 ms):

- ``kinematic`` (the source's scheme): q ← q ⊕ q̇Δt with ``mj_integratePos``, then
  held inside the model's joint ranges, the hardware end stops.
- ``physics``: the controller integrates its own commanded configuration (as IK
  front-ends do) and the plant, a second MjData on the same model, tracks it with
  its position actuators (velocity actuators, if the scene has them, get q̇ as
  feed-forward) through ``mj_step``. Everything logged (x, error, q) is measured on
  the plant.

``limit_violation`` is, per step, the larger excursion beyond the limits the controllers
were given (a scenario may tighten the model's ranges) of the measured configuration
and of the commanded one q ⊕ q̇Δt, before the end stops act: a controller is charged
with what it asks for, which the stops would hide, and with what the plant does.

A controller with ``actuated_only = True`` (the hexapod's classical law) moves only the
actuated joints; ``closure`` then places the rest (the platform and the passive joints
of a closed chain) after each step, as the mechanism itself does.

Per step the controller time covers the kinematics update and
``compute_velocity``: the work of the control step, nothing of the logging.
"""

from __future__ import annotations

import time
from typing import Callable, Protocol

import mujoco
import numpy as np

from ..errors import DivergenceError, InfeasibleProblem, InvalidInput, SolverError
from ..robot import JointLimits, Robot
from .log import RolloutLog
from .plant import Actuation

MODES = ("kinematic", "physics")


class Controller(Protocol):
    kind: str
    solver: str
    robot: Robot

    def compute_velocity(self) -> np.ndarray: ...


class Reference(Protocol):
    """Drives a tracking task along a trajectory and measures how well it is tracked."""

    def apply(self, t: float) -> None:
        """Set the task's target (and feed-forward velocity) for time t."""

    def desired(self) -> np.ndarray:
        """The desired tracked position at the last ``apply``."""

    def measure(self, robot: Robot) -> dict[str, np.ndarray | float]:
        """``{"x": tracked position, **extras}`` on a robot with up-to-date kinematics."""


def simulate(
    controller: Controller,
    reference: Reference,
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
) -> RolloutLog:
    """Run ``controller`` along ``reference`` for ``duration`` seconds at period ``dt``.

    The controller's robot starts from its current configuration. A controller
    failure (singularity, infeasible QP, solver failure) raises its typed error,
    naming the time; with ``on_failure="stop"`` it ends the rollout instead and the
    log keeps the steps done, with the reason in ``completed``/``failure``.
    """
    if on_failure not in ("raise", "stop"):
        raise InvalidInput(f"on_failure must be 'raise' or 'stop', got {on_failure!r}")
    if mode not in MODES:
        raise InvalidInput(f"unknown mode {mode!r}; expected one of {MODES}")
    if not (np.isfinite(duration) and duration > 0 and np.isfinite(dt) and dt > 0):
        raise InvalidInput(f"duration and dt must be positive, got {duration}, {dt}")
    robot = controller.robot
    limits = robot.joint_limits if joint_limits is None else joint_limits
    actuated_only = getattr(controller, "actuated_only", False)
    if actuated_only and closure is None:
        raise InvalidInput(f"controller {controller.kind!r} moves only the actuated joints: give a loop closure")
    stops = robot.joint_limits
    stop_buffer = np.zeros(len(stops.names))
    steps = int(round(duration / dt)) + 1
    plant = robot
    actuation = None
    substeps = 1
    if mode == "physics":
        plant = Robot(robot.model, name=robot.name, keyframe=None)
        plant.data.qpos[:] = robot.q
        actuation = Actuation(robot.model)
        substeps = max(1, int(round(dt / robot.model.opt.timestep)))
        if abs(substeps * robot.model.opt.timestep - dt) > 1e-12:
            raise InvalidInput(f"dt={dt} is not a multiple of the model timestep {robot.model.opt.timestep}")
        actuation.write(plant.data, robot.q, np.zeros(robot.nv))
        mujoco.mj_forward(plant.model, plant.data)

    t_log = np.zeros(steps)
    q_log = np.zeros((steps, robot.nq))
    qdot_log = np.zeros((steps, robot.nv))
    q_commanded_log = np.full((steps, robot.nq), np.nan)  # q ⊕ q̇Δt asked for at step k
    time_log = np.zeros(steps)
    viol_log = np.zeros(steps)
    manip_log = np.zeros(steps)
    x_log, xd_log, extras = [], [], {}
    failure = ""
    done = 0
    for k in range(steps):
        t = k * dt
        if plant is not robot:
            plant.update_kinematics()
        reference.apply(t)
        start = time.perf_counter()
        robot.update_kinematics()
        try:
            qdot = controller.compute_velocity()
        except (DivergenceError, InfeasibleProblem, SolverError) as exc:
            if on_failure == "raise":
                raise type(exc)(f"at t = {t:.3f} s: {exc}") from None
            failure = f"{type(exc).__name__} at t = {t:.3f} s: {exc}"
            break
        time_log[k] = time.perf_counter() - start
        sample = reference.measure(plant)
        x_log.append(np.array(sample.pop("x"), dtype=float))
        xd_log.append(reference.desired().copy())
        for name, value in sample.items():
            extras.setdefault(name, []).append(float(value))
        t_log[k] = t
        q_log[k] = plant.q
        viol_log[k] = limits.violation(plant.q)
        qdot_log[k] = qdot
        manip_log[k] = manipulability(plant) if manipulability else np.nan
        done = k + 1
        if k == steps - 1:
            break
        robot.integrate(qdot, dt)
        q_commanded_log[k] = robot.q
        # Worst of the measured configuration and the commanded one (before the end stops
        # act): a controller is charged with what it asks for, and with what the plant does.
        viol_log[k] = max(viol_log[k], limits.violation(robot.q))
        np.clip(robot.q[stops.qpos_index], stops.lower, stops.upper, out=stop_buffer)
        robot.q[stops.qpos_index] = stop_buffer
        if actuated_only:
            closure(robot)
        if actuation is not None:
            actuation.write(plant.data, robot.q, qdot)
            for _ in range(substeps):
                mujoco.mj_step(plant.model, plant.data)
            if not np.all(np.isfinite(plant.data.qpos)):
                failure = f"at t = {t:.3f} s: physics simulation diverged (non-finite state)"
        if not failure and not np.all(np.isfinite(robot.q)):
            failure = f"at t = {t:.3f} s: the controller drove the configuration to non-finite values"
        if failure:
            if on_failure == "raise":
                raise DivergenceError(failure)
            break
        if progress is not None:
            progress(k + 1, steps)
    if done == 0:
        raise DivergenceError(f"the controller failed at the first step: {failure}")
    x = np.array(x_log)
    x_des = np.array(xd_log)
    return RolloutLog(
        robot=robot_name or robot.name,
        controller=controller.kind,
        solver=controller.solver,
        scenario=scenario,
        mode=mode,
        dt=dt,
        t=t_log[:done],
        q=q_log[:done],
        qdot=qdot_log[:done],
        q_commanded=q_commanded_log[:done],
        x=x,
        x_des=x_des,
        error=np.linalg.norm(x_des - x, axis=1),
        manipulability=manip_log[:done],
        step_time=time_log[:done],
        limit_violation=viol_log[:done],
        extras={name: np.array(v) for name, v in extras.items()},
        manipulability_measure=manipulability_measure,
        speed_dofs=None if speed_dofs is None else np.asarray(speed_dofs, dtype=int),
        completed=not failure,
        failure=failure,
    )
