"""dm_control's CMU humanoid keeps its feet, lowers its centre of mass and reaches with a hand.

A floating-base model (a free joint and 56 hinges): both feet are held in place by hard
6-D pose tasks on the foot bodies, the whole-body centre of mass goes 12 cm down and the
right hand reaches 45 cm forward and down (soft tasks, each along a smooth segment with
its feed-forward velocity), a posture task keeps the rest near the start, inside the
joint ranges and under joint speed bounds (the model has none: 5 rad/s on every hinge).
Prints how far the feet drifted and the CoM and hand errors.

    python examples/humanoid_reach.py [--duration 3] [--solver daqp] [--viewer]

The model is read from the installed dm_control package (``pip install -e ".[models]"`` from a clone).
"""

from __future__ import annotations

import sys
from pathlib import Path

import mujoco
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from demo_support import Demo, add_mocap_target, check_arguments, parser, report, rotation_angle, speed_violation, \
    view  # noqa: E402

from qpik import ComTask, FrameTask, JointPositionLimit, JointVelocityLimit, PositionTask, PostureTask, Robot, \
    Segment  # noqa: E402
from qpik.models import third_party  # noqa: E402
from qpik.rollout import Reference  # noqa: E402

NAME = "humanoid_reach"
DT = 0.002
DURATION = 3.0  # s: the motion's; a shorter run stops part way
FEET = ("lfoot", "rfoot")
HAND = "rhand"
KNEE_BEND = 0.2  # rad: the start's knees (qpos0 has them at 0, outside their range)
FEET_GAIN = 200.0  # 1/s (K·Δt = 0.4): the feet's second-order drift is corrected fast
GAIN = 50.0  # 1/s for the CoM, the hand and the posture (K·Δt = 0.1)
COM_DROP = 0.12  # m
HAND_REACH = np.array([0.2, -0.35, -0.15])  # m: inward, forward (the model faces −y) and down
WEIGHTS = {"com": 10.0, "hand": 1.0, "posture": 1e-4}
MAX_SPEED = 5.0  # rad/s on every hinge


class SquatAndReach(Reference):
    """The CoM and the hand along their segments; measures feet drift and the two errors."""

    def __init__(self, com: ComTask, hand: PositionTask, feet: list[FrameTask], duration: float):
        self.com, self.hand, self.feet = com, hand, feet
        self.com_path = Segment(com.target, com.target - [0.0, 0.0, COM_DROP], duration, time_law="quintic")
        self.hand_path = Segment(hand.target, hand.target + HAND_REACH, duration, time_law="quintic")
        self.feet_start = [(foot.target_position.copy(), foot.target_rotation.copy()) for foot in feet]

    def apply(self, t: float) -> None:
        self.com.set_target(*self.com_path.sample(t))
        self.hand.set_target(*self.hand_path.sample(t))

    def desired(self) -> np.ndarray:
        return self.hand.target

    def measure(self, robot: Robot) -> dict:
        drift = max(float(np.linalg.norm(robot.frame_position(foot.frame) - position))
                    for foot, (position, _) in zip(self.feet, self.feet_start))
        turn = max(rotation_angle(rotation, robot.frame_rotation(foot.frame))
                   for foot, (_, rotation) in zip(self.feet, self.feet_start))
        com = robot.data.subtree_com[self.com.body]
        return {"x": robot.frame_position(self.hand.frame).copy(), "feet_drift": drift, "feet_turn": turn,
                "com_error": float(np.linalg.norm(self.com.target - com))}


def start_configuration(robot: Robot) -> np.ndarray:
    """qpos0 with the knees bent into their range, the body lowered until the lowest foot
    geom touches the floor."""
    model, data = robot.model, robot.data
    q = model.qpos0.copy()
    for knee in ("ltibiarx", "rtibiarx"):
        q[robot.joint_qpos_index(knee)] = KNEE_BEND
    robot.set_q(q)
    robot.update_kinematics()
    floor = robot.geom_id("floor")
    soles = ("lfoot", "rfoot", "ltoes", "rtoes")
    feet = [g for g in range(model.ngeom) if model.body(model.geom_bodyid[g]).name in soles]
    clearance = min(mujoco.mj_geomDistance(model, data, floor, g, 1.0, None) for g in feet)
    q[2] -= clearance
    return q


def build(duration: float = DURATION, viewer: bool = False) -> Demo:
    """The humanoid with its feet, CoM, hand and posture tasks and limits, run for ``duration``
    seconds of the three-second motion."""
    spec = mujoco.MjSpec.from_file(str(third_party("humanoid")))
    if viewer:
        add_mocap_target(spec, position=(0.0, 0.0, 0.0), pose=False)  # placed on the target by the viewer
    robot = Robot(spec.compile(), name="humanoid")
    robot.set_q(start_configuration(robot))
    robot.update_kinematics()
    feet = [FrameTask(robot, foot, "body", position_gain=FEET_GAIN, orientation_gain=FEET_GAIN, hard=True)
            for foot in FEET]
    com = ComTask(robot, gain=GAIN, weight=WEIGHTS["com"])
    hand = PositionTask(robot, HAND, "body", gain=GAIN, weight=WEIGHTS["hand"])
    posture = PostureTask(robot, gain=GAIN, weight=WEIGHTS["posture"])
    free = mujoco.mjtJoint.mjJNT_FREE
    speeds = {name: MAX_SPEED for name in robot.joint_names if robot.model.joint(name).type[0] != free}
    limits = [JointPositionLimit(robot), JointVelocityLimit(robot, speeds)]
    reference = SquatAndReach(com, hand, feet, DURATION)
    return Demo(NAME, robot, [*feet, com, hand, posture], limits, reference, DT, duration, follow=hand,
                moving=(com, hand))


def summarize(demo: Demo, log) -> list[tuple[str, float, str]]:
    return [("max feet drift", float(np.max(log.extras["feet_drift"])), "m"),
            ("max feet rotation", float(np.max(log.extras["feet_turn"])), "rad"),
            ("max CoM error", float(np.max(log.extras["com_error"])), "m"),
            ("final CoM error", float(log.extras["com_error"][-1]), "m"),
            ("max hand error", float(np.max(log.error)), "m"),
            ("final hand error", float(log.error[-1]), "m"),
            ("joint range violation", float(np.max(log.limit_violation)), "rad"),
            ("joint speed violation", speed_violation(log, demo.limits[1].max_velocity), "rad/s"),
            ("step time median", float(np.median(log.step_time[1:]) * 1e6), "µs")]


def main(argv=None) -> int:
    args_parser = parser(__doc__.splitlines()[0], DURATION)
    args = args_parser.parse_args(argv)
    check_arguments(args_parser, args)
    demo = build(args.duration, viewer=args.viewer)
    if args.viewer:
        hand = demo.follow
        return view(demo, lambda position, _: hand.set_target(position), args.solver)
    log = demo.run(args.solver)
    report(NAME, f"CMU humanoid (dm_control), feet held (hard), CoM {COM_DROP:g} m down, right hand "
                 f"{np.linalg.norm(HAND_REACH):.2f} m away, {args.duration:g} s at {DT * 1e3:g} ms "
                 f"({len(log.t)} steps, {args.solver})", summarize(demo, log))
    return 0


if __name__ == "__main__":
    sys.exit(main())
