"""dm_control's Kinova Jaco arm tracks a 3-D circle with a 6-D pose task.

The wrist site follows a 10 cm circle in a tilted plane while its orientation tilts by up
to 15° and back (a pose target with its feed-forward twist), 5 s at 2 ms, inside the
joint ranges (joints 2 and 3 are limited) and under joint speed bounds (the model has
none: they are given per joint). Prints the largest position and orientation errors and
any limit violation.

    python examples/jaco_circle.py [--duration 5] [--solver daqp] [--viewer]

The model is read from the installed dm_control package (``pip install -e ".[models]"`` from a clone).
"""

from __future__ import annotations

import sys
from pathlib import Path

import mujoco
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from demo_support import Demo, add_mocap_target, check_arguments, parser, quaternion_to_matrix, report, rotation_angle, \
    speed_violation, view  # noqa: E402

from qpik import Circle, FrameTask, JointPositionLimit, JointVelocityLimit, Robot  # noqa: E402
from qpik.models import third_party  # noqa: E402
from qpik.rollout import Reference  # noqa: E402
from qpik.trajectories import CircularTilt, rpy_rotation_and_rate  # noqa: E402

NAME = "jaco_circle"
DT = 0.002
DURATION = 5.0  # s: the circle's; a shorter run stops part way
START = np.array([0.0, 3.6, 2.0, -1.0, -1.5, 1.0])  # inside the ranges, away from singularities
GAIN = 100.0  # 1/s on every pose row (K·Δt = 0.2)
RADIUS = 0.10  # m
PLANE = ((0.0, 1.0, 0.0), (0.5, 0.0, np.sqrt(3.0) / 2.0))  # the circle's plane: y and a tilted z axis
TILT_DEG = 15.0
# Joint speed bounds (rad/s) for the demo: the shoulder and elbow slower than the wrist.
MAX_SPEED = {"joint_1": 1.0, "joint_2": 1.0, "joint_3": 1.0, "joint_4": 1.5, "joint_5": 1.5, "joint_6": 1.5}


class PoseCircle(Reference):
    """The wrist's pose target: position on the circle, rotation R(t) = R_tilt(t) R_0 (the
    tilt is a world rotation, so its angular velocity is the target's)."""

    def __init__(self, task: FrameTask, duration: float, radius: float = RADIUS, plane=PLANE,
                 tilt_deg: float = TILT_DEG):
        self.task = task
        self.start_rotation = task.target_rotation.copy()
        u, w = np.array(plane[0], dtype=float), np.array(plane[1], dtype=float)
        self.circle = Circle(task.target_position - radius * u, radius, duration, u=u, w=w)  # starts at the frame
        self.tilt = CircularTilt(self.circle, tilt_deg)

    def apply(self, t: float) -> None:
        position, velocity = self.circle.sample(t)
        rotation, angular_velocity = rpy_rotation_and_rate(*self.tilt.sample(t))
        self.task.set_target(position, rotation @ self.start_rotation, velocity, angular_velocity)

    def desired(self) -> np.ndarray:
        return self.task.target_position

    def measure(self, robot: Robot) -> dict:
        frame = self.task.frame
        return {"x": robot.frame_position(frame).copy(),
                "orientation_error": rotation_angle(self.task.target_rotation, robot.frame_rotation(frame))}


def build(duration: float = DURATION, viewer: bool = False) -> Demo:
    """The Jaco with its pose task, limits and circle, run for ``duration`` seconds of the circle's
    five (``viewer``: with a draggable target)."""
    spec = mujoco.MjSpec.from_file(str(third_party("jaco")))
    if viewer:
        add_mocap_target(spec, position=(0.0, 0.0, 0.0))  # placed on the target by the viewer
    robot = Robot(spec.compile(), name="jaco")
    robot.set_q(START)
    robot.update_kinematics()
    pose = FrameTask(robot, "wristsite", "site", position_gain=GAIN, orientation_gain=GAIN)
    limits = [JointPositionLimit(robot), JointVelocityLimit(robot, MAX_SPEED)]
    return Demo(NAME, robot, [pose], limits, PoseCircle(pose, DURATION), DT, duration, follow=pose, moving=(pose,))


def summarize(demo: Demo, log) -> list[tuple[str, float, str]]:
    speed = demo.limits[1].max_velocity
    return [("max position error", float(np.max(log.error)), "m"),
            ("max orientation error", float(np.max(log.extras["orientation_error"])), "rad"),
            ("joint range violation", float(np.max(log.limit_violation)), "rad"),
            ("joint speed violation", speed_violation(log, speed), "rad/s"),
            ("peak speed / bound", float(np.max(np.abs(log.qdot) / speed)), ""),
            ("step time median", float(np.median(log.step_time[1:]) * 1e6), "µs")]


def main(argv=None) -> int:
    args_parser = parser(__doc__.splitlines()[0], DURATION)
    args = args_parser.parse_args(argv)
    check_arguments(args_parser, args)
    demo = build(args.duration, viewer=args.viewer)
    if args.viewer:
        pose = demo.follow
        return view(demo, lambda p, quat: pose.set_target(p, quaternion_to_matrix(quat)), args.solver)
    log = demo.run(args.solver)
    report(NAME, f"Kinova Jaco (dm_control), 6-D pose task on 'wristsite' along a {RADIUS:g} m circle tilting "
                 f"{TILT_DEG:g}°, {args.duration:g} s at {DT * 1e3:g} ms ({len(log.t)} steps, {args.solver})",
           summarize(demo, log))
    return 0


if __name__ == "__main__":
    sys.exit(main())
