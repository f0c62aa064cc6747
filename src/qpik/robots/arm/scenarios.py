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
from ...errors import UnknownName
from ...limits import JointPositionLimit, JointVelocityLimit
from ...robot import Robot
from ...rollout import PositionReference
from ...scenario import JointPlotSpec, Setup, register
from ...tasks import DampingTask, ManipulabilityTask, PositionTask, SigmaProxy, Yoshikawa
from ...trajectories import Segment

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
