"""Generated chains of hinges and gymnasium's 7-DoF pusher tracking a pose circle: the
problems benchmarks/third_party.py and tests/app/test_third_party.py run beside the
other examples' (as :class:`~demo_support.Demo` objects).

Each: a hard 6-D pose task (soft with ``chain_demo(n, hard=False)``) at the tip along
jaco_circle's circle (5 cm, tilting 10°), a posture task, joint position limits and speed
bounds.

    from pose_circles import chain_demo, pusher_demo
    demo = chain_demo(30)        # 30 hinges, 1 m long, 2 s
    log = demo.run()
"""

from __future__ import annotations

import sys
from pathlib import Path

import mujoco
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from demo_support import Demo  # noqa: E402
from jaco_circle import PoseCircle  # noqa: E402

from qpik import FrameTask, JointPositionLimit, JointVelocityLimit, PostureTask, Robot  # noqa: E402
from qpik.models import third_party as third_party_model  # noqa: E402

DT = 0.002
CHAIN_LENGTH = 1.0  # m
CHAIN_AXES = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))  # joint i turns about axis i mod 3
CHAIN_BEND = (1.5, 0.8, 0.4)  # rad shared by the joints of each axis at the start (curled, far from singular)
CHAIN_RANGE = 2.0  # rad, each hinge
POSE_GAIN = 100.0  # 1/s
POSTURE = dict(gain=10.0, weight=1e-3)
SPEED = 3.0  # rad/s, each hinge
CIRCLE = dict(radius=0.05, plane=((1.0, 0.0, 0.0), (0.0, 0.6, 0.8)), tilt_deg=10.0)
# The wrist flexed to -0.8 of its [-1.094, 0] range: from -0.6 the circle takes it to its
# end at 1.41 s, where the hard pose and the limits leave no step (both contenders stop).
PUSHER_START = np.array([0.2, 0.3, 0.0, -1.2, 0.0, -0.8, 0.0])
CHAIN_MOTION, PUSHER_MOTION = 2.0, 3.0  # s


def chain_model(n: int) -> mujoco.MjModel:
    """A chain of n hinges (axes x, y, z in turn), 1 m long, a site ``tip`` at its end."""
    spec = mujoco.MjSpec()
    spec.modelname = f"chain{n}"
    spec.compiler.degree = False
    link = CHAIN_LENGTH / n
    body = spec.worldbody
    for i in range(n):
        body = body.add_body(name=f"link{i}", pos=[0.0, 0.0, link if i else 0.0])
        body.add_joint(name=f"joint{i}", type=mujoco.mjtJoint.mjJNT_HINGE, axis=list(CHAIN_AXES[i % 3]),
                       range=[-CHAIN_RANGE, CHAIN_RANGE], limited=mujoco.mjtLimited.mjLIMITED_TRUE)
        body.add_geom(type=mujoco.mjtGeom.mjGEOM_CAPSULE, fromto=[0.0, 0.0, 0.0, 0.0, 0.0, link], size=[0.01, 0, 0],
                      mass=0.1)
    body.add_site(name="tip", pos=[0.0, 0.0, link])
    return spec.compile()


def pose_demo(name: str, robot: Robot, frame: str, frame_type: str, motion: float, duration: float,
              hard: bool = True) -> Demo:
    """A 6-D pose task (``hard``, or a cost beside the posture's) on ``frame`` along the circle
    (``motion`` seconds), posture, position and speed limits, run for ``duration`` seconds."""
    robot.update_kinematics()
    pose = FrameTask(robot, frame, frame_type, position_gain=POSE_GAIN, orientation_gain=POSE_GAIN, hard=hard)
    posture = PostureTask(robot, **POSTURE)
    limits = [JointPositionLimit(robot), JointVelocityLimit(robot, np.full(robot.nv, SPEED))]
    reference = PoseCircle(pose, motion, **CIRCLE)
    return Demo(name, robot, [pose, posture], limits, reference, DT, duration, follow=pose, moving=(pose,))


def chain_demo(n: int, duration: float = CHAIN_MOTION, hard: bool = True) -> Demo:
    robot = Robot(chain_model(n), name=f"chain{n}")
    bend = np.array(CHAIN_BEND) * 3.0 / n
    robot.set_q(np.array([bend[i % 3] for i in range(n)]))
    return pose_demo(f"chain{n}" if hard else f"chain{n}-soft", robot, "tip", "site", CHAIN_MOTION, duration, hard)


def pusher_demo(duration: float = PUSHER_MOTION) -> Demo:
    """gymnasium's pusher without its puck and goal (4 slide joints that no task moves)."""
    spec = mujoco.MjSpec.from_file(str(third_party_model("pusher")))
    for body in ("object", "goal"):
        spec.delete(spec.body(body))
    robot = Robot(spec.compile(), name="pusher")
    robot.set_q(PUSHER_START)
    return pose_demo("pusher", robot, "tips_arm", "body", PUSHER_MOTION, duration)
