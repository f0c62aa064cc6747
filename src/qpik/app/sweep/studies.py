"""What a sweep studies on each bundled robot: the samples and the batched controllers.

Both robots follow the Monte-Carlo benchmark's trials (``benchmarks/monte_carlo.py``):
a target the robot can reach, a straight reference segment from the start to it under
the quintic law in ``MOVE`` s, then the target held ``HOLD`` s, 2 ms steps. The sweep
adds what the Monte Carlo keeps fixed: the start state (inside the joint ranges) and the
task's feedback gain K, drawn per world.

- arm: the target is the forward kinematics of q drawn uniformly within the joint ranges,
  the start q is drawn the same way, K log-uniform in [``GAIN_RANGE``]. ``qp``: the
  position task hard and the σ task (k0 = 5) as the cost, joint ranges with their
  velocity damper and joint speed limits (``seed-redundant``'s QP); ``qp-soft``: the
  Monte Carlo's soft priority, the position task weighted and Levenberg–Marquardt
  damped with a small damping task as the rest of the cost (as ``unreachable``), the
  same limits; ``pinv``: J†v + (I − J†J) k0∇σ, no limits.
- hexapod: the target and the start are platform poses drawn as for the calibration
  (home ± (8, 6, 4) cm and ±10°, every leg within its stroke, well conditioned); the
  start's joints from the analytic inverse kinematics, loops closed. ``qp``: the 6-D
  pose task hard, the loop closures hard, stroke and hinge ranges and speed limits
  (``hexapod-circle``'s QP); ``qp-soft``: the pose task weighted with LM damping;
  ``pinv``: the pseudoinverse of the pose rows stacked over the loop-closure rows (the
  batched law; the serial rollouts' inverse-Jacobian law with its forward-kinematics
  closure is not batched): q̇ = J⁺ [v; −K e_loops], no limits.

Samples come in blocks of ``SAMPLE_BLOCK`` worlds, each block drawn from its own
generator ``(seed, block)``: world i's sample is the same whatever the chunk size.
"""

from __future__ import annotations

import numpy as np

from ...errors import InvalidInput
from ...trajectories import QuinticTimeLaw, rpy_rotations_and_rates

DT = 0.002
MOVE, HOLD = 1.0, 0.5  # s: as benchmarks/monte_carlo.py
STEPS = round((MOVE + HOLD) / DT)


def steps_of(move: float, hold: float) -> int:
    """Control steps of a rollout moving ``move`` s, then holding ``hold`` s."""
    return round((move + hold) / DT)

GAIN_RANGE = (50.0, 500.0)  # 1/s, log-uniform; 500 is the scenarios' K (K·Δt = 1)
SAMPLE_BLOCK = 256
CONTROLLERS = ("qp", "qp-soft", "pinv")


def block_rng(seed: int, block: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([int(seed), int(block)]))


def blocks_of(start: int, stop: int) -> range:
    return range(start // SAMPLE_BLOCK, (stop - 1) // SAMPLE_BLOCK + 1)


def stitched(draw, seed: int, start: int, stop: int) -> dict[str, np.ndarray]:
    """``draw(rng, SAMPLE_BLOCK)`` for each block overlapping [start, stop), cut to it."""
    parts = [draw(block_rng(seed, b), SAMPLE_BLOCK) for b in blocks_of(start, stop)]
    offset = start - blocks_of(start, stop)[0] * SAMPLE_BLOCK
    return {key: np.concatenate([p[key] for p in parts])[offset:offset + stop - start] for key in parts[0]}


def log_uniform(rng: np.random.Generator, n: int, bounds: tuple[float, float]) -> np.ndarray:
    low, high = np.log(bounds)
    return np.exp(rng.uniform(low, high, n))


def set_world_gains(task, gains: np.ndarray) -> None:
    """Each world's feedback gain K_w on every row of ``task`` (v = K_w e + ẋ_d): the
    engine's gains are (N, dim). The task is built with the largest gain, so that the
    controller's K·Δt check covers every world."""
    task.gains[...] = np.asarray(gains, dtype=float)[:, None]


NEEDS = {"qp": (), "qp-soft": (), "pinv": ("PseudoinverseController",)}


def missing_classes(needs: tuple[str, ...]) -> list[str]:
    """The names of ``needs`` that :mod:`qpik.batch` does not export (yet)."""
    from ... import batch

    return [name for name in needs if name not in batch.__all__]


def ported(robot: str, kind: str) -> bool:
    """Whether :mod:`qpik.batch` has every class the study of ``robot`` needs for ``kind``."""
    return not missing_classes(STUDIES[robot].needs + NEEDS[kind])


def check_ported(robot: str, controllers) -> None:
    """Refuse controllers whose batched classes the engine does not have yet.

    Raises:
        NotBatched: the first such controller, with the classes it needs.
    """
    from ...batch.errors import NotBatched

    for kind in controllers:
        absent = missing_classes(STUDIES[robot].needs + NEEDS[kind])
        if absent:
            runnable = [k for k in CONTROLLERS if ported(robot, k)]
            raise NotBatched(f"qpik sweep {robot} --controllers {kind} needs batch.{', batch.'.join(absent)}, not "
                             f"ported to the engine (qpik.engine) yet; "
                             + (f"{robot} runs {', '.join(runnable)} now" if runnable else f"no {robot} sweep runs yet"))


class Built:
    """One controller over a chunk's worlds and what the rollout reads of it."""

    def __init__(self, robots, controller, task, loops=None):
        self.robots, self.controller, self.task, self.loops = robots, controller, task, loops


class ArmStudy:
    """The arm: 2-D targets of the end effector (see the module's description)."""

    name = "arm"
    frame = "end_effector"
    position_dims = 2
    needs: tuple[str, ...] = ()  # what qpik.batch must export beyond NEEDS[controller]

    def __init__(self):
        from ...robot import Robot

        self.template = Robot.load("arm")
        self._site = self.template.site_id(self.frame)
        self.limits = self.template.joint_limits

    def samples(self, seed: int, start: int, stop: int) -> dict[str, np.ndarray]:
        """targets (n, 2) m, start configurations (n, nq), gains (n,) 1/s."""
        return stitched(self._draw, seed, start, stop)

    def _draw(self, rng: np.random.Generator, n: int) -> dict[str, np.ndarray]:
        lim, robot = self.limits, self.template
        target_q = np.tile(robot.q, (n, 1))
        target_q[:, lim.qpos_index] = rng.uniform(lim.lower, lim.upper, (n, len(lim.names)))
        start_q = np.tile(robot.q, (n, 1))
        start_q[:, lim.qpos_index] = rng.uniform(lim.lower, lim.upper, (n, len(lim.names)))
        gains = log_uniform(rng, n, GAIN_RANGE)
        targets = np.empty((n, 2))
        for k in range(n):
            robot.q[:] = target_q[k]
            robot.update_kinematics()
            targets[k] = robot.site_position(self._site)[:2]
        return {"target": targets, "start_q": start_q, "gain": gains}

    def build(self, kind: str, samples: dict[str, np.ndarray], nthread: int | None) -> Built:
        from ... import batch
        from ...robots.arm.scenarios import (
            ARM_K0,
            DAMPER_INFLUENCE,
            DAMPER_RATE,
            LM_DAMPING,
            SOFT_DAMPING,
        )

        robots = batch.Robot.load("arm", len(samples["gain"]), nthread=nthread)
        robots.set_q(samples["start_q"])
        robots.ensure_kinematics()
        hard = kind != "qp-soft"
        task = batch.PositionTask(robots, self.frame, axes="xy", gain=GAIN_RANGE[1], hard=hard,
                                  lm_damping=0.0 if hard else LM_DAMPING)
        set_world_gains(task, samples["gain"])
        sigma = batch.ManipulabilityTask(robots, batch.SigmaProxy(robots, ["theta2", "theta3"]), gain=ARM_K0)
        if kind == "pinv":
            return Built(robots, batch.PseudoinverseController(robots, [task], sigma), task)
        # The soft priority as the Monte Carlo's: a small damping task instead of σ, whose
        # pull would otherwise leave a steady error on a weighted position task.
        cost = sigma if hard else batch.DampingTask(robots, weight=SOFT_DAMPING)
        limits = [batch.JointPositionLimit(robots, influence=DAMPER_INFLUENCE, damper_rate=DAMPER_RATE),
                  batch.JointVelocityLimit(robots)]
        return Built(robots, batch.QPController(robots, [task, cost], limits, dt=DT), task)

    def reference(self, built: Built, samples: dict[str, np.ndarray], move: float) -> Reference:
        start = built.task.frame.position[:, :2].copy()
        return Reference(move, start, samples["target"])

    def set_reference(self, built: Built, ref: Reference, t: float, stopped: np.ndarray) -> None:
        position, velocity = ref.at(t)
        position[stopped], velocity[stopped] = self.position(built)[stopped], 0.0  # held where it stopped
        built.task.set_target(position, velocity)

    def position(self, built: Built) -> np.ndarray:
        return built.task.frame.position[:, :2]


class HexapodStudy:
    """The hexapod: platform poses [x, y, z (m), θx, θy, θz (deg)] (see the module's description)."""

    name = "hexapod"
    frame = "platform_center"
    position_dims = 3
    needs = ("EqualityTask",)  # the loop closures

    def __init__(self):
        from ...robot import Robot
        from ...robots.hexapod.control import HexapodModel

        self.template = Robot.load("hexapod", keyframe="home")
        self._model = HexapodModel(self.template)
        self.limits = self.template.joint_limits

    def samples(self, seed: int, start: int, stop: int) -> dict[str, np.ndarray]:
        """target poses (n, 6), start poses (n, 6), start configurations (n, nq), gains (n,)."""
        return stitched(self._draw, seed, start, stop)

    def _draw(self, rng: np.random.Generator, n: int) -> dict[str, np.ndarray]:
        from ...robots.hexapod.calibration import sample_poses
        from ...robots.hexapod.kinematics import HexapodGeometry, rotation_from_rpy
        from ...robots.hexapod.scene import assembly_qpos

        geometry = HexapodGeometry.default()
        targets = sample_poses(n, rng, [geometry])[0]
        starts = sample_poses(n, rng, [geometry])[0]
        gains = log_uniform(rng, n, GAIN_RANGE)
        hexapod = self._model.hexapod
        start_q = np.tile(self.template.q, (n, 1))
        for k, pose in enumerate(starts):
            R = rotation_from_rpy(pose[3:])
            strokes = hexapod.inverse_kinematics_matrix(pose[:3], R)
            start_q[k, self._model.assembly_index] = assembly_qpos(hexapod, strokes, pose[:3], R)
        return {"target": targets, "start": starts, "start_q": start_q, "gain": gains}

    def build(self, kind: str, samples: dict[str, np.ndarray], nthread: int | None) -> Built:
        from ... import batch
        from ...robots.hexapod.scenarios import LM_DAMPING, LOOP_GAIN, SOFT_DAMPING

        robots = batch.Robot.load("hexapod", len(samples["gain"]), nthread=nthread)
        robots.set_q(samples["start_q"])
        robots.ensure_kinematics()
        hard = kind != "qp-soft"
        task = batch.FrameTask(robots, self.frame, position_gain=GAIN_RANGE[1], orientation_gain=GAIN_RANGE[1],
                               hard=hard, lm_damping=0.0 if hard else LM_DAMPING)
        set_world_gains(task, samples["gain"])
        loops = batch.EqualityTask(robots, list(self._model.loop_names), gain=LOOP_GAIN)
        if kind == "pinv":
            return Built(robots, batch.PseudoinverseController(robots, [task, loops]), task, loops)
        damping = batch.DampingTask(robots, weight=1e-6 if hard else SOFT_DAMPING, joints=robots.template.joint_names)
        limits = [batch.JointPositionLimit(robots), batch.JointVelocityLimit(robots)]
        return Built(robots, batch.QPController(robots, [task, loops, damping], limits, dt=DT), task, loops)

    def reference(self, built: Built, samples: dict[str, np.ndarray], move: float) -> Reference:
        start = built.task.frame.position.copy()
        return Reference(move, start, samples["target"][:, :3], samples["start"][:, 3:], samples["target"][:, 3:])

    def set_reference(self, built: Built, ref: Reference, t: float, stopped: np.ndarray) -> None:
        position, velocity = ref.at(t)
        rotation, omega = ref.rotation_at(t)
        position[stopped], velocity[stopped] = self.position(built)[stopped], 0.0  # held where it stopped
        rotation[stopped], omega[stopped] = built.task.frame.rotation[stopped], 0.0
        built.task.set_target(position, rotation, velocity, omega)

    def position(self, built: Built) -> np.ndarray:
        return built.task.frame.position


class Reference:
    """Every world's straight segment under one quintic time law of ``move`` s, then held;
    optionally roll-pitch-yaw angles (degrees) moving linearly in s alongside."""

    def __init__(self, move: float, start, end, rpy_start=None, rpy_end=None):
        self.start, self.end = np.asarray(start, float), np.asarray(end, float)
        self.rpy_start, self.rpy_end = rpy_start, rpy_end
        self.law = QuinticTimeLaw(move)

    def at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        s, rate = self.law(t)
        span = self.end - self.start
        return self.start + s * span, rate * span

    def rotation_at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        s, rate = self.law(t)
        span = self.rpy_end - self.rpy_start
        return rpy_rotations_and_rates(self.rpy_start + s * span, rate * span)


STUDIES = {"arm": ArmStudy, "hexapod": HexapodStudy}


def study(robot: str):
    """The study of a bundled robot.

    Raises:
        InvalidInput: a robot without a study.
    """
    if robot not in STUDIES:
        raise InvalidInput(f"qpik sweep runs on the bundled robots {', '.join(STUDIES)}, got {robot!r}")
    return STUDIES[robot]()
