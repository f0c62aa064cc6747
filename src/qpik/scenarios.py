"""Named scenarios (a contract: the CLI, tests and benchmarks use these names).

A scenario builds, for one run, a fresh robot with its tasks, limits, reference
trajectory and gains; every controller of a comparison gets an identical copy.

Arm scenarios (SPEC §1; K = diag(500, 500), Δt = 2 ms, start q0 = [π/2, 0, 0, 0.5]):

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

from dataclasses import dataclass, field
from typing import Callable

import mujoco
import numpy as np

from .errors import InvalidInput, UnknownName
from .limits import JointPositionLimit, JointVelocityLimit
from .pinv import JacobianTransposeController, PseudoinverseController
from .qp import QPController
from .robot import BUNDLED_SCENES, JointLimits, Robot, scene_path
from .solvers import available_solvers
from .tasks import DampingTask, ManipulabilityTask, PositionTask, SigmaProxy, Task, Yoshikawa
from .trajectory import Segment

DT = 0.002
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


class PositionReference:
    """Feeds a trajectory to a position task; measures the tracked site on any robot."""

    def __init__(self, task: PositionTask, trajectory):
        if trajectory.dim != task.dim:
            raise InvalidInput(f"trajectory has {trajectory.dim} coordinates, the task {task.dim}")
        self.task = task
        self.trajectory = trajectory

    def apply(self, t: float) -> None:
        position, velocity = self.trajectory.sample(t)
        self.task.set_target(position, velocity)

    def desired(self) -> np.ndarray:
        return self.task.target

    def measure(self, robot: Robot) -> dict:
        return {"x": robot.site_position(self.task.site_id)[self.task.rows].copy()}


@dataclass(frozen=True)
class JointPlotSpec:
    """Which joints figures show: names, qpos/qvel columns, limits (inf: none), units."""

    names: tuple[str, ...]
    qpos_index: tuple[int, ...]
    dof_index: tuple[int, ...]
    lower: tuple[float, ...]
    upper: tuple[float, ...]
    units: tuple[str, ...]

    @classmethod
    def from_limits(cls, robot: Robot, limits: JointLimits, names=None) -> JointPlotSpec:
        names = tuple(limits.names if names is None else names)
        idx = [limits.names.index(n) for n in names]
        slide = int(mujoco.mjtJoint.mjJNT_SLIDE)
        units = tuple("m" if int(robot.model.jnt_type[robot.joint_id(n)]) == slide else "rad" for n in names)
        return cls(names, tuple(int(limits.qpos_index[i]) for i in idx), tuple(int(limits.dof_index[i]) for i in idx),
                   tuple(float(limits.lower[i]) for i in idx), tuple(float(limits.upper[i]) for i in idx), units)


@dataclass
class Setup:
    """Everything one run of a scenario needs; ``controller()`` builds a controller on it."""

    scenario: str
    robot_name: str
    robot: Robot
    duration: float
    reference: object
    qp_tasks: list[Task]
    limits: list
    joint_limits: JointLimits
    manipulability: Callable[[Robot], float]
    manipulability_measure: str
    classical: dict[str, Callable[[], object]]
    plot_joints: JointPlotSpec
    params: dict = field(default_factory=dict)
    dt: float = DT
    closure: Callable[[Robot], None] | None = None  # closes the loops of a closed chain

    def controller(self, kind: str = "qp", solver: str = "daqp", **options):
        if kind == "qp":
            return QPController(self.robot, self.qp_tasks, self.limits, solver=solver, dt=self.dt, **options)
        if kind in self.classical:
            return self.classical[kind]()
        raise UnknownName(f"unknown controller {kind!r} for {self.scenario}; choose from {['qp', *self.classical]}")


@dataclass(frozen=True)
class ScenarioInfo:
    name: str
    robot: str
    description: str
    build: Callable[..., Setup]


SCENARIOS: dict[str, ScenarioInfo] = {}


def register(name: str, robot: str, description: str):
    def decorator(build: Callable[..., Setup]) -> Callable[..., Setup]:
        SCENARIOS[name] = ScenarioInfo(name, robot, description, build)
        return build

    return decorator


def build_scenario(name: str, robot: str | None = None, **options) -> Setup:
    """A fresh setup of scenario ``name``.

    ``robot`` is checked against the scenario's robot (``"arm"``, ``"hexapod"``); an
    MJCF path instead replaces the bundled scene (it must define the same names).
    """
    if name not in SCENARIOS:
        raise UnknownName(f"unknown scenario {name!r}; known: {', '.join(SCENARIOS)}")
    info = SCENARIOS[name]
    if robot is not None and robot not in BUNDLED_SCENES:
        scene_path(robot)  # raises a clear error for an unknown name or a missing file
        options.setdefault("scene", robot)
    elif robot is not None and robot != info.robot:
        raise UnknownName(f"scenario {name!r} is for robot {info.robot!r}, not {robot!r}")
    return info.build(**options)


def check_solver(solver: str) -> str:
    if solver not in available_solvers():
        raise UnknownName(f"unknown or uninstalled QP solver {solver!r}; available: {', '.join(available_solvers())}")
    return solver


# --- The arm -----------------------------------------------------------------------

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
) -> Setup:
    """The arm with its position task (x, y), optional σ task, limits and reference."""
    robot = Robot.load(scene)
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
    limits = [JointPositionLimit(robot, joint_limits, influence=DAMPER_INFLUENCE, damper_rate=DAMPER_RATE),
              JointVelocityLimit(robot)]
    return Setup(
        scenario=scenario,
        robot_name="arm",
        robot=robot,
        duration=trajectory.duration if duration is None else duration,
        reference=PositionReference(position, trajectory),
        qp_tasks=[position, regular],
        limits=limits,
        joint_limits=joint_limits,
        manipulability=manip.value,
        manipulability_measure=manip.label,
        classical={
            "pinv": lambda: PseudoinverseController(robot, [position], secondary),
            "jt": lambda: JacobianTransposeController(robot, [position], alpha=JT_ALPHA),
        },
        plot_joints=JointPlotSpec.from_limits(robot, joint_limits),
        params={"gain": gain, "k0": k0 if redundant else 0.0, "hard": hard, "ranges": ranges or {}},
    )


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


# The hexapod's scenarios register themselves on import (after the arm's, for the listing).
from . import hexapod_scenarios  # noqa: E402,F401
