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
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Protocol

import mujoco
import numpy as np

from .errors import DivergenceError, InfeasibleProblem, InvalidInput, ModelError, SolverError
from .files import write_json, write_npz
from .robot import JointLimits, Robot

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


@dataclass
class RolloutLog:
    """Time series of one rollout; ``summary()`` gives DESIGN.md's metrics."""

    robot: str
    controller: str
    solver: str
    scenario: str
    mode: str
    dt: float
    t: np.ndarray
    q: np.ndarray
    qdot: np.ndarray
    x: np.ndarray
    x_des: np.ndarray
    error: np.ndarray
    manipulability: np.ndarray
    step_time: np.ndarray
    limit_violation: np.ndarray
    extras: dict[str, np.ndarray] = field(default_factory=dict)
    manipulability_measure: str = "sigma"
    speed_dofs: np.ndarray | None = None  # dofs whose speed peak_joint_speed reports (None: all)
    completed: bool = True
    failure: str = ""

    def summary(self) -> dict:
        """The summary.json record (plain Python types)."""
        err = self.error
        st = self.step_time * 1e6
        out = {
            "robot": self.robot,
            "controller": self.controller,
            "solver": self.solver,
            "scenario": self.scenario,
            "mode": self.mode,
            "dt": self.dt,
            "steps": int(len(self.t)),
            "max_error": float(np.max(err)),
            "rms_error": float(np.sqrt(np.mean(err**2))),
            "final_error": float(err[-1]),
            "manipulability_measure": self.manipulability_measure,
            "manipulability_min": float(np.min(self.manipulability)),
            "manipulability_mean": float(np.mean(self.manipulability)),
            "manipulability_final": float(self.manipulability[-1]),
            "limit_violation_max": float(np.max(self.limit_violation)),
            "peak_joint_speed": float(np.max(np.abs(self.qdot if self.speed_dofs is None
                                                     else self.qdot[:, self.speed_dofs]))),
            "step_time_median_us": float(np.median(st)),
            "step_time_p99_us": float(np.percentile(st, 99)),
            "q_final": [float(v) for v in self.q[-1]],
            "completed": self.completed,
        }
        for name, series in self.extras.items():
            out[f"{name}_max"] = float(np.max(series))
        if not self.completed:
            out["failure"] = self.failure
        return out

    def arrays(self) -> dict[str, np.ndarray]:
        data = dict(t=self.t, q=self.q, qdot=self.qdot, x=self.x, x_des=self.x_des, error=self.error,
                    manipulability=self.manipulability, step_time=self.step_time,
                    limit_violation=self.limit_violation)
        data.update(self.extras)
        return data

    def save(self, out_dir: str | Path) -> None:
        """Write ``summary.json`` and ``log.npz`` (each whole, or not at all)."""
        out_dir = Path(out_dir)
        write_npz(out_dir / "log.npz", **self.arrays())
        write_json(out_dir / "summary.json", self.summary())


class _Actuation:
    """Maps a commanded configuration and velocity onto the plant's joint actuators."""

    def __init__(self, model: mujoco.MjModel):
        pos_act, pos_q, vel_act, vel_dof = [], [], [], []
        for a in range(model.nu):
            if model.actuator_trntype[a] != mujoco.mjtTrn.mjTRN_JOINT:
                continue
            joint = model.actuator_trnid[a, 0]
            bias = model.actuator_biasprm[a]
            if bias[1] < 0:  # position servo: force = kp (ctrl - q) - kv q̇
                pos_act.append(a)
                pos_q.append(model.jnt_qposadr[joint])
            elif bias[1] == 0 and bias[2] < 0:  # velocity servo: kv (ctrl - q̇)
                vel_act.append(a)
                vel_dof.append(model.jnt_dofadr[joint])
        if not pos_act:
            raise ModelError("physics mode needs position actuators on the joints; the model has none")
        self.pos_act, self.pos_q = np.array(pos_act), np.array(pos_q)
        self.vel_act, self.vel_dof = np.array(vel_act, dtype=int), np.array(vel_dof, dtype=int)

    def write(self, data: mujoco.MjData, q_cmd: np.ndarray, qdot_cmd: np.ndarray) -> None:
        data.ctrl[self.pos_act] = q_cmd[self.pos_q]
        if len(self.vel_act):
            data.ctrl[self.vel_act] = qdot_cmd[self.vel_dof]


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
        actuation = _Actuation(robot.model)
        substeps = max(1, int(round(dt / robot.model.opt.timestep)))
        if abs(substeps * robot.model.opt.timestep - dt) > 1e-12:
            raise InvalidInput(f"dt={dt} is not a multiple of the model timestep {robot.model.opt.timestep}")
        actuation.write(plant.data, robot.q, np.zeros(robot.nv))
        mujoco.mj_forward(plant.model, plant.data)

    t_log = np.zeros(steps)
    q_log = np.zeros((steps, robot.nq))
    qdot_log = np.zeros((steps, robot.nv))
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
