"""The arm's named scenarios (a contract: the CLI, tests and benchmarks use these names).

Arm scenarios (docs/arm.md; K = diag(500, 500), Δt = 2 ms, start q0 = [π/2, 0, 0, 0.5]):

- ``seed-primary``: the source's segment (0.5, 2) → (1.5, 1), cubic law, 5 s;
  primary task only (the QP adds a tiny damping task, giving the minimum-norm J†v).
- ``seed-redundant``: the same plus the σ null-space task, k0 = 5.
- ``joint-limits``: as seed-redundant with θ2 ∈ [−1.0, 1.0] and θ3 ∈ [−1.0, 1.0]: the
  σ gradient pushes both past these bounds; the QP keeps them and still tracks.
- ``unreachable``: a segment from the start to (2.4, 2.4), 3.39 m from the base, beyond
  the arm's reach a1 + a2 + d4max = 3 m; then held. The position task is soft, so the
  QP settles at the closest reachable point (2.12, 2.12) instead of asking for the
  impossible.
"""

from __future__ import annotations

import numpy as np

from ...controllers.pinv import JacobianTransposeController, PseudoinverseController
from ...controllers.qp import QPController
from ...errors import UnknownName
from ...limits import JointPositionLimit, JointVelocityLimit
from ...robot import Robot
from ...rollout import PositionReference
from ...rollout.levels import Level, LevelErrors
from ...scenario import JointPlotSpec, Setup, register
from ...tasks import DampingTask, ManipulabilityTask, PositionTask, SigmaProxy, Yoshikawa
from ...trajectories import CubicTimeLaw, Segment
from . import model as arm_model
from .planar import PlanarOrientationTask

ARM_GAIN = 500.0
ARM_K0 = 5.0
ARM_START = (np.pi / 2, 0.0, 0.0, 0.5)
ARM_JOINTS = ("theta1", "theta2", "theta3", "d4")
SEED_PATH = ((0.5, 2.0), (1.5, 1.0))
SEED_DURATION = 5.0
# Jacobian-transpose step: α K λmax(JJᵀ) Δt < 2 for stability (λmax ≈ 6.4 at q0).
JT_ALPHA = 0.1
# Soft-task damping (the unreachable scenario): a constant Levenberg–Marquardt term plus one
# that grows with the squared error, so the QP does not chatter against the workspace
# boundary (tuned with /benchmarks, see README: 0.01 and 10 keep the tracking error
# at 4e-5 m while reachable and settle smoothly once not).
SOFT_DAMPING = 1e-2
# Velocity damper on the joint limits: within 0.8 (rad or m) of a bound the speed toward
# it is at most 2.0 × distance / 0.8 (2.5 1/s), so a joint slows down before it arrives
# instead of stopping dead in one step, which a physical servo cannot follow (on
# joint-limits in physics mode: 5.7 mrad overshoot and 22 mm tracking error without it,
# none and 2.8 mm with it). It binds on no joint of the seed scenarios.
DAMPER_INFLUENCE = 0.8
DAMPER_RATE = 2.0
LM_DAMPING = 10.0


class LoggedSigma:
    """σ as a rollout logs it: callable on a robot (:meth:`SigmaProxy.value`); in a
    rollout the joint angles are copied per step and σ of every step is evaluated in one
    pass afterwards, with the same floating-point operations (the same bits, tested)."""

    def __init__(self, proxy: SigmaProxy):
        self.proxy = proxy

    def __call__(self, robot: Robot) -> float:
        return self.proxy.value(robot)

    def start(self, plant: Robot, steps: int) -> _SigmaRecorder:
        return _SigmaRecorder(self.proxy, plant, steps)


class _SigmaRecorder:
    def __init__(self, proxy: SigmaProxy, plant: Robot, steps: int):
        self._qpos = plant.data.qpos  # a view of the plant's configuration
        self._index = proxy.qpos_index
        self.angles = np.empty((steps, len(self._index)))

    def record(self, k: int) -> None:
        self.angles[k] = self._qpos[self._index]

    def values(self, count: int) -> np.ndarray:
        s = np.sin(self.angles[:count])
        # ½ s·s per row as a batched dot product: SigmaProxy.value's ½ (s @ s).
        return 0.5 * np.matmul(s[:, None, :], s[:, :, None])[:, 0, 0]


def _arm_measure(robot: Robot, measure: str):
    if measure == "sigma":
        return SigmaProxy(robot, ("theta2", "theta3"))
    if measure == "yoshikawa":
        return Yoshikawa(robot, "end_effector", axes="xy")
    raise UnknownName(f"unknown manipulability measure {measure!r}; choose 'sigma' or 'yoshikawa'")


def arm_setup(
    scenario: str,
    trajectory,
    *,
    redundant: bool,
    hard: bool = True,
    ranges: dict[str, tuple[float, float]] | None = None,
    measure: str = "sigma",
    k0: float = ARM_K0,
    gain: float = ARM_GAIN,
    duration: float | None = None,
    scene: str = "arm",
    speed_limits: dict[str, float] | None = None,
) -> Setup:
    """The arm with its position task (x, y), optional σ task, limits and reference;
    ``speed_limits`` replaces some joints' velocity limits (rad/s or m/s)."""
    robot = Robot.load(scene)  # the scenarios start at ARM_START, home or not
    for joint in ARM_JOINTS:  # a custom scene must name what the arm scenarios use
        robot.joint_id(joint)
    robot.set_q(np.array(ARM_START))
    robot.update_kinematics()
    manip = _arm_measure(robot, measure)
    # A soft task gets adaptive Levenberg–Marquardt damping against unreachable targets.
    position = PositionTask(robot, "end_effector", axes="xy", gain=gain, hard=hard,
                            lm_damping=0.0 if hard else LM_DAMPING)
    secondary = ManipulabilityTask(robot, manip, gain=k0, weight=1.0) if redundant else None
    # Without a secondary task the QP still needs a (tiny) cost on q̇: the minimum norm.
    regular = secondary if secondary is not None else DampingTask(robot, weight=1e-3 if hard else SOFT_DAMPING)
    joint_limits = robot.joint_limits.tightened(ranges or {})
    max_velocity = robot.velocity_limits.copy()
    for joint, speed in (speed_limits or {}).items():
        max_velocity[robot.joint_dof_index(joint)] = speed
    limits = [JointPositionLimit(robot, joint_limits, influence=DAMPER_INFLUENCE, damper_rate=DAMPER_RATE),
              JointVelocityLimit(robot, max_velocity)]
    # The hierarchy (hqp, sns): the path first, the σ task below it. The QP's damping
    # task is a regulariser, not a level.
    position.priority = 0
    hierarchy = [position]
    levels = [Level("path", (position,), "m")]
    if secondary is not None:
        secondary.priority = 1
        hierarchy.append(secondary)
        # the residual of q̇ − k0∇σ: θ1–θ3 in rad/s, the ram d4 in m/s
        levels.append(Level("sigma", (secondary,), "rad/s, m/s", measure="residual"))
    return Setup(
        scenario=scenario,
        robot_name="arm",
        robot=robot,
        duration=trajectory.duration if duration is None else duration,
        reference=PositionReference(position, trajectory),
        qp_tasks=[position, regular],
        limits=limits,
        joint_limits=joint_limits,
        manipulability=LoggedSigma(manip) if isinstance(manip, SigmaProxy) else manip.value,
        manipulability_measure=manip.label,
        classical={
            "pinv": lambda: PseudoinverseController(robot, [position], secondary),
            "jt": lambda: JacobianTransposeController(robot, [position], alpha=JT_ALPHA),
        },
        plot_joints=JointPlotSpec.from_limits(robot, joint_limits),
        params={"gain": gain, "k0": k0 if redundant else 0.0, "hard": hard, "ranges": ranges or {},
                "speed_limits": speed_limits or {}},
        hierarchy=hierarchy,
        level_errors=LevelErrors(levels),
        variants={} if hard else {"qp-hard": _hard_variant(robot, [position, regular], [position], limits)},
    )


def _hard_variant(robot: Robot, tasks, hard_tasks, limits, dt: float = 0.002):
    """``qp-hard``: the scenario's QP with ``hard_tasks`` as equalities, the rest weighed."""

    def build(solver: str, **options) -> QPController:
        saved = [task.hard for task in hard_tasks]
        for task in hard_tasks:  # the QP sorts hard and soft tasks once, when it is built
            task.hard = True
        try:
            controller = QPController(robot, tasks, limits, solver=solver, dt=dt, **options)
        finally:
            for task, hard in zip(hard_tasks, saved):
                task.hard = hard
        controller.kind = "qp-hard"
        return controller

    return build


def _seed_segment() -> Segment:
    return Segment(SEED_PATH[0], SEED_PATH[1], SEED_DURATION, time_law="cubic")


@register("seed-primary", "arm", "source path (0.5,2)->(1.5,1) m, cubic law, 5 s; primary task only")
def seed_primary(measure: str = "sigma", scene: str = "arm") -> Setup:
    return arm_setup("seed-primary", _seed_segment(), redundant=False, measure=measure, scene=scene)


@register("seed-redundant", "arm", "source path plus the sigma null-space task, k0 = 5")
def seed_redundant(measure: str = "sigma", scene: str = "arm") -> Setup:
    return arm_setup("seed-redundant", _seed_segment(), redundant=True, measure=measure, scene=scene)


JOINT_LIMITS_RANGES = {"theta2": (-1.0, 1.0), "theta3": (-1.0, 1.0)}


@register("joint-limits", "arm", "seed-redundant with theta2, theta3 limited to [-1, 1] rad")
def joint_limits(measure: str = "sigma", scene: str = "arm") -> Setup:
    return arm_setup("joint-limits", _seed_segment(), redundant=True, ranges=JOINT_LIMITS_RANGES, measure=measure, scene=scene)


UNREACHABLE_TARGET = (2.4, 2.4)


@register("unreachable", "arm", "segment to (2.4, 2.4) m, 3.39 m away, beyond the 3 m reach; soft task")
def unreachable(measure: str = "sigma", scene: str = "arm") -> Setup:
    trajectory = Segment(SEED_PATH[0], UNREACHABLE_TARGET, 3.0, time_law="cubic")
    return arm_setup("unreachable", trajectory, redundant=False, hard=False, measure=measure, duration=4.0, scene=scene)


TOO_FAST_DURATION = 0.5  # s for the seed segment: 4.2 m/s at its peak
TOO_FAST_RUN = 2.0  # s simulated: the path's end is then held
# The minimum-norm law needs up to 1.5, 1.55, 1.96 rad/s and 0.9 m/s on this path, well
# inside the scene's 8 rad/s and 2 m/s: too-fast gives the joints slower servos, so the
# path is beyond them (every joint would have to exceed its limit).
TOO_FAST_SPEEDS = {"theta1": 1.0, "theta2": 1.0, "theta3": 1.0, "d4": 0.5}


class SegmentReference(PositionReference):
    """A position reference along a straight segment that also measures how far the
    tracked point strays from the segment (``path_deviation``, m) and, over the run,
    when it reached the segment's end for good (``completion_time``: the first time from
    which it stays within ``COMPLETION_TOLERANCE`` of the end; None if it never does)."""

    COMPLETION_TOLERANCE = 1e-3  # m

    def __init__(self, task: PositionTask, segment: Segment):
        super().__init__(task, segment)
        self._start, self._end = segment.start, segment.end
        self._direction = segment.end - segment.start
        self._length_sq = float(self._direction @ self._direction)

    def measure(self, robot: Robot) -> dict:
        sample = super().measure(robot)
        along = float(np.clip((sample["x"] - self._start) @ self._direction / self._length_sq, 0.0, 1.0))
        sample["path_deviation"] = float(np.linalg.norm(sample["x"] - self._start - along * self._direction))
        return sample

    def summarize(self, t: np.ndarray, x: np.ndarray) -> dict:
        far = np.flatnonzero(np.linalg.norm(x - self._end, axis=1) > self.COMPLETION_TOLERANCE)
        if not len(far):
            return {"completion_time": float(t[0])}
        return {"completion_time": float(t[far[-1] + 1]) if far[-1] + 1 < len(t) else None}


@register("too-fast", "arm", "the source segment in 0.5 s (4.2 m/s peak), beyond joint speed limits "
          "of 1 rad/s and 0.5 m/s; soft task")
def too_fast(measure: str = "sigma", scene: str = "arm") -> Setup:
    segment = Segment(SEED_PATH[0], SEED_PATH[1], TOO_FAST_DURATION, time_law="cubic")
    setup = arm_setup("too-fast", segment, redundant=False, hard=False, measure=measure, duration=TOO_FAST_RUN,
                      scene=scene, speed_limits=TOO_FAST_SPEEDS)
    setup.reference = SegmentReference(setup.reference.task, segment)
    return setup


# three-tasks: φ = θ1 + θ2 + θ3 ramps from its start to PHI_END with a bump of
# PHI_AMPLITUDE on top; with θ2, θ3 in [−1, 1] rad (as joint-limits) the arm cannot turn
# that far while on the path in the middle of the run (about 1 s to 4.5 s).
PHI_AMPLITUDE = 0.8  # rad
PHI_END = 1.0  # rad
# The start: the path's first point (0.5, 2) with θ2 = −0.5, θ3 = 0.5. The source's start
# (θ2 = θ3 = 0, arm stretched) is singular for path and φ together (the y row of the
# path's Jacobian is then half φ's): φ could not move at all there.
THREE_TASKS_ELBOW = 0.5  # rad: θ2 = −0.5, θ3 = +0.5
PHI_GAIN = ARM_GAIN
# The soft QP's weights, level by level: the path, φ, the σ task.
THREE_TASK_WEIGHTS = (1.0, 0.1, 0.01)


class PhiProfile:
    """φ_d(t) = φ0 + (φ1 − φ0) s(t) + A sin²(π t / T): a cubic ramp from φ0 to φ1 with a
    bump of height A on top, at rest at both ends; held outside [0, T]."""

    def __init__(self, start: float, end: float, amplitude: float, duration: float):
        self.start, self.end, self.amplitude = float(start), float(end), float(amplitude)
        self.law = CubicTimeLaw(duration)
        self.duration, self.dim = self.law.duration, 1

    def sample(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        s, ds = self.law(t)
        w = np.pi / self.duration
        inside = 0.0 < t < self.duration
        bump = self.amplitude * np.sin(w * t) ** 2 if inside else 0.0
        bump_rate = self.amplitude * w * np.sin(2.0 * w * t) if inside else 0.0
        return (np.array([self.start + (self.end - self.start) * s + bump]),
                np.array([(self.end - self.start) * ds + bump_rate]))


def three_tasks_start(elbow: float = THREE_TASKS_ELBOW) -> np.ndarray:
    """q with the end effector at the path's start, θ2 = −elbow, θ3 = +elbow.

    With θ2 + θ3 = 0 the ram is perpendicular to link 1, so in link 1's frame the end
    effector sits at u = (a1 + a2 cos θ2, a2 sin θ2 − d4): |u| = |p| gives d4, and θ1
    turns u onto p.
    """
    p = np.array(SEED_PATH[0])
    reach = arm_model.A1 + arm_model.A2 * np.cos(elbow)
    d4 = -arm_model.A2 * np.sin(elbow) + np.sqrt(p @ p - reach**2)
    u = np.array([reach, -arm_model.A2 * np.sin(elbow) - d4])
    theta1 = np.arctan2(p[1], p[0]) - np.arctan2(u[1], u[0])
    return np.array([theta1, -elbow, elbow, d4])


class PathAndOrientationReference(PositionReference):
    """The seed path for the position task and a φ profile for the orientation task."""

    def __init__(self, task: PositionTask, trajectory, orientation: PlanarOrientationTask, profile: PhiProfile):
        super().__init__(task, trajectory)
        self.orientation = orientation
        self.profile = profile

    def apply(self, t: float) -> None:
        super().apply(t)
        self.orientation.set_target(*self.profile.sample(t))


@register("three-tasks", "arm", "levels: path (x, y), then phi = th1+th2+th3 (infeasible part of the time "
          "with th2, th3 in [-1, 1]), then sigma")
def three_tasks(scene: str = "arm") -> Setup:
    """Three levels on the arm: the seed path, the orientation φ, the σ posture.

    ``qp`` weighs all three (soft, weights 1, 0.1, 0.01); ``qp-hard`` makes the path an
    equality and weighs the other two; ``hqp`` and ``sns`` order them strictly; ``pinv``
    stacks path and φ as its primary task with σ in their null space.
    """
    robot = Robot.load(scene)
    for joint in ARM_JOINTS:
        robot.joint_id(joint)
    robot.set_q(three_tasks_start())
    robot.update_kinematics()
    w_path, w_phi, w_sigma = THREE_TASK_WEIGHTS
    sigma = SigmaProxy(robot, ("theta2", "theta3"))
    position = PositionTask(robot, "end_effector", axes="xy", gain=ARM_GAIN, weight=w_path)
    phi = PlanarOrientationTask(robot, "end_effector", gain=PHI_GAIN, weight=w_phi)
    posture = ManipulabilityTask(robot, sigma, gain=ARM_K0, weight=w_sigma)
    for level, task in enumerate((position, phi, posture)):
        task.priority = level
    joint_limits = robot.joint_limits.tightened(JOINT_LIMITS_RANGES)
    limits = [JointPositionLimit(robot, joint_limits, influence=DAMPER_INFLUENCE, damper_rate=DAMPER_RATE),
              JointVelocityLimit(robot)]
    tasks = [position, phi, posture]
    profile = PhiProfile(phi.angle(), PHI_END, PHI_AMPLITUDE, SEED_DURATION)
    return Setup(
        scenario="three-tasks",
        robot_name="arm",
        robot=robot,
        duration=SEED_DURATION,
        reference=PathAndOrientationReference(position, _seed_segment(), phi, profile),
        qp_tasks=tasks,
        limits=limits,
        joint_limits=joint_limits,
        manipulability=sigma.value,
        manipulability_measure=sigma.label,
        classical={"pinv": lambda: PseudoinverseController(robot, [position, phi], posture)},
        plot_joints=JointPlotSpec.from_limits(robot, joint_limits),
        params={"gain": ARM_GAIN, "phi_gain": PHI_GAIN, "k0": ARM_K0, "weights": list(THREE_TASK_WEIGHTS),
                "phi_amplitude": PHI_AMPLITUDE, "ranges": JOINT_LIMITS_RANGES},
        hierarchy=tasks,
        level_errors=LevelErrors([Level("path", (position,), "m"), Level("phi", (phi,), "rad"),
                                  Level("sigma", (posture,), "rad/s, m/s", measure="residual")]),
        variants={"qp-hard": _hard_variant(robot, tasks, [position], limits)},
    )
