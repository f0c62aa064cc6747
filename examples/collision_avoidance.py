"""The Jaco's hand is pulled down through a box and stops at the minimum distance above it.

A box (added to dm_control's Jaco model with MuJoCo's MjSpec) lies under the hand; the
wrist's pose target goes 25 cm straight down, through the box, and stays there. A
:class:`~qpik.CollisionAvoidanceLimit` between the hand's three bodies and the box keeps
every pair at least 2 cm apart: the hand slows down as it comes near (the velocity
damper) and stops at 2 cm, however hard the task pulls. Prints the minimum distance
reached.

    python examples/collision_avoidance.py [--duration 3] [--solver daqp] [--viewer]

The model is read from the installed dm_control package (``pip install -e ".[models]"`` from a clone).
"""

from __future__ import annotations

import sys
from pathlib import Path

import mujoco
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from demo_support import Demo, add_mocap_target, check_arguments, parser, quaternion_to_matrix, report, \
    view  # noqa: E402

from qpik import CollisionAvoidanceLimit, FrameTask, JointPositionLimit, JointVelocityLimit, Robot, \
    Segment  # noqa: E402
from qpik.models import third_party  # noqa: E402
from qpik.rollout import Reference  # noqa: E402

NAME = "collision_avoidance"
DT = 0.002
DURATION = 3.0
APPROACH = 2.0  # s: the target's descent (then it stays inside the box)
START = np.array([0.0, 3.6, 2.0, -1.0, -1.5, 1.0])
HAND = ("b_4", "b_5", "b_6")  # the wrist's bodies: a body name stands for all its geoms
BOX_SIZE = (0.12, 0.12, 0.02)  # half-sizes (m)
BOX_GAP = 0.10  # m from the hand's lowest point to the box's top at the start
DROP = 0.25  # m: how far down the target goes (through the box)
MINIMUM_DISTANCE = 0.02  # m
DETECTION_DISTANCE = 0.10  # m
GAIN = 50.0  # 1/s
NATIVE_CCD_OFF = int(mujoco.mjtDisableBit.mjDSBL_NATIVECCD)
MAX_SPEED = {"joint_1": 1.0, "joint_2": 1.0, "joint_3": 1.0, "joint_4": 1.5, "joint_5": 1.5, "joint_6": 1.5}


class Descent(Reference):
    """The wrist's target straight down at a fixed orientation; measures the hand's
    distance to the box (the smallest over the limit's pairs)."""

    def __init__(self, pose: FrameTask, collision: CollisionAvoidanceLimit):
        self.pose, self.collision = pose, collision
        self.rotation = pose.target_rotation.copy()
        start = pose.target_position.copy()
        self.path = Segment(start, start - [0.0, 0.0, DROP], APPROACH, time_law="quintic")
        self._fromto = np.zeros(6)

    def apply(self, t: float) -> None:
        position, velocity = self.path.sample(t)
        self.pose.set_target(position, self.rotation, velocity)

    def desired(self) -> np.ndarray:
        return self.pose.target_position

    def measure(self, robot: Robot) -> dict:
        return {"x": robot.frame_position(self.pose.frame).copy(),
                "distance": hand_distance(robot, self.collision.pairs, self._fromto)}


def hand_distance(robot: Robot, pairs, fromto: np.ndarray, cutoff: float = 1.0) -> float:
    """The smallest signed distance between the pairs' geoms (``mj_geomDistance``), with
    MuJoCo's native convex collision: the Jaco's MJCF disables it, and the fallback's
    (libccd MPR) mesh distances depend on the cutoff."""
    options = robot.model.opt
    flags = options.disableflags
    options.disableflags = flags & ~NATIVE_CCD_OFF
    try:
        return min(mujoco.mj_geomDistance(robot.model, robot.data, g1, g2, cutoff, fromto) for g1, g2 in pairs)
    finally:
        options.disableflags = flags


def add_box(spec: mujoco.MjSpec, robot: Robot) -> None:
    """A box under the hand, its top ``BOX_GAP`` below the hand's lowest point."""
    model, data = robot.model, robot.data
    hand = [g for g in range(model.ngeom) if model.body(model.geom_bodyid[g]).name in HAND]
    lowest = min(_lowest_point(model, data, g) for g in hand)
    wrist = data.site_xpos[robot.site_id("wristsite")]
    spec.worldbody.add_geom(name="box", type=mujoco.mjtGeom.mjGEOM_BOX, size=list(BOX_SIZE),
                            pos=[wrist[0], wrist[1], lowest - BOX_GAP - BOX_SIZE[2]], rgba=[0.8, 0.3, 0.2, 1.0])


def _lowest_point(model: mujoco.MjModel, data: mujoco.MjData, geom: int) -> float:
    """The lowest height of a geom's bounding box (its local AABB placed in the world)."""
    center, half = model.geom_aabb[geom][:3], model.geom_aabb[geom][3:]
    vertical = data.geom_xmat[geom].reshape(3, 3)[2]  # the world z row of the geom's rotation
    return float(data.geom_xpos[geom][2] + vertical @ center - np.abs(vertical) @ half)


def build(duration: float = DURATION, viewer: bool = False, damper_rate: float | None = 0.5,
          native_ccd: bool = False) -> Demo:
    """The Jaco above the box, its pose task, joint limits and the collision limit
    (``damper_rate=None``: the limit without its velocity damper; ``native_ccd``: the
    model's contacts, hence any library's distance queries, with MuJoCo's native convex
    collision, which the Jaco's MJCF disables)."""
    spec = mujoco.MjSpec.from_file(str(third_party("jaco")))
    if native_ccd:
        spec.option.disableflags &= ~NATIVE_CCD_OFF
    bare = Robot(spec.compile(), name="jaco")
    bare.set_q(START)
    bare.update_kinematics()
    add_box(spec, bare)
    if viewer:
        add_mocap_target(spec, position=(0.0, 0.0, 0.0))
    robot = Robot(spec.compile(), name="jaco + box")
    robot.set_q(START)
    robot.update_kinematics()
    pose = FrameTask(robot, "wristsite", "site", position_gain=GAIN, orientation_gain=GAIN)
    collision = CollisionAvoidanceLimit(robot, [(list(HAND), ["box"])], minimum_distance=MINIMUM_DISTANCE,
                                        detection_distance=DETECTION_DISTANCE, damper_rate=damper_rate)
    limits = [JointPositionLimit(robot), JointVelocityLimit(robot, MAX_SPEED), collision]
    return Demo(NAME, robot, [pose], limits, Descent(pose, collision), DT, duration, follow=pose, moving=(pose,))


def summarize(demo: Demo, log) -> list[tuple[str, float, str]]:
    distance = log.extras["distance"]
    return [("start distance", float(distance[0]), "m"),
            ("minimum distance", float(np.min(distance)), "m", 8),
            ("final distance", float(distance[-1]), "m", 8),
            ("closest below the minimum distance", float(max(0.0, MINIMUM_DISTANCE - np.min(distance))), "m"),
            ("final wrist error", float(log.error[-1]), "m"),
            ("joint range violation", float(np.max(log.limit_violation)), "rad")]


def main(argv=None) -> int:
    args_parser = parser(__doc__.splitlines()[0], DURATION)
    args = args_parser.parse_args(argv)
    check_arguments(args_parser, args)
    demo = build(args.duration, viewer=args.viewer)
    if args.viewer:
        pose = demo.follow
        return view(demo, lambda p, quat: pose.set_target(p, quaternion_to_matrix(quat)), args.solver)
    log = demo.run(args.solver)
    report(NAME, f"Kinova Jaco (dm_control) + a box, wrist target {DROP:g} m down through the box, minimum "
                 f"distance {MINIMUM_DISTANCE:g} m, {args.duration:g} s at {DT * 1e3:g} ms ({len(log.t)} steps, "
                 f"{args.solver})", summarize(demo, log))
    return 0


if __name__ == "__main__":
    sys.exit(main())
