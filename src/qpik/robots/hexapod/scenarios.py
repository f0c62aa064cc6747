"""The hexapod's named scenarios (a contract, like the arm's).

All start at the home keyframe (platform at (0.08, 0.02, 0.11) m, identity rotation),
with gains K = 500 1/s on position, orientation and the loop closures,
Δt = 2 ms, stroke limits [0, 0.35] m, hinge limits ±π/2 and 0.5 m/s slider speed.

- ``hexapod-circle``: the platform centre on a horizontal circle of radius 3 cm through
  home (quintic law, 4 s) while it tilts by up to 3° (θx = 3° sin Δφ, θy = 3°(1 − cos Δφ)).
- ``hexapod-stroke-limits``: a 0.20 m translation along x in 2 s, then held 1 s. Every
  slider runs along x, so every stroke grows by 0.20 m: the longest would reach 0.41 m
  > 0.35. The frame task is soft (with Levenberg–Marquardt damping) so the QP keeps
  the strokes in range and tracks as closely as the mechanism allows.
- ``hexapod-position-only``: the circle without its tilt, the position task alone; the
  three free rotations serve the manipulability task (k0 = 2). ``k0=0`` gives the same
  run without it.
"""

from __future__ import annotations

import numpy as np

from .control import (
    HexapodClassicalController,
    HexapodModel,
    PlatformManipulability,
    PlatformManipulabilityTask,
    PlatformReference,
    StrokeDrivenClosure,
)
from .kinematics import HexapodGeometry
from ...limits import JointPositionLimit, JointVelocityLimit
from ...robot import Robot
from ...rollout.levels import Level, LevelErrors
from ...scenario import JointPlotSpec, Setup, register
from ...tasks import DampingTask, EqualityTask, FrameTask, PositionTask
from ...trajectories import Circle, CircularTilt, PoseTrajectory, Segment

HEXAPOD_GAIN = 500.0
LOOP_GAIN = 500.0
HEXAPOD_K0 = 2.0
CIRCLE_RADIUS = 0.03
CIRCLE_DURATION = 4.0
TILT_DEG = 3.0
STROKE_TRAVEL = 0.20
SOFT_DAMPING = 1e-4
LM_DAMPING = 10.0


def hexapod_setup(scenario: str, trajectory: PoseTrajectory, *, orientation: bool, hard: bool,
                  k0: float = 0.0, duration: float | None = None, scene: str = "hexapod") -> Setup:
    """The hexapod with its platform task, loop closures, limits and reference; ``duration``
    (default the trajectory's) may exceed the trajectory's, which then holds its end pose."""
    robot = Robot.load(scene, keyframe="home")
    model = HexapodModel(robot)
    loops = EqualityTask(robot, model.loop_names, gain=LOOP_GAIN)
    lm = 0.0 if hard else LM_DAMPING
    if orientation:
        task = FrameTask(robot, "platform_center", position_gain=HEXAPOD_GAIN, orientation_gain=HEXAPOD_GAIN,
                         hard=hard, lm_damping=lm)
    else:
        task = PositionTask(robot, "platform_center", axes="xyz", gain=HEXAPOD_GAIN, hard=hard, lm_damping=lm)
    tasks = [task, loops]
    if k0:
        tasks.append(PlatformManipulabilityTask(model, gain=k0, weight=1.0))
    # Every dof, the platform's free joint included (the mechanism's, not a floating base).
    tasks.append(DampingTask(robot, weight=1e-6 if hard else SOFT_DAMPING, joints=robot.joint_names))
    # The hierarchy (hqp, sns): the loops closed first, then the platform, then the
    # manipulability task, the damping last (the minimum-norm choice of what is left).
    for level, level_task in enumerate([loops, task] + tasks[2:]):
        level_task.priority = level
    levels = [Level("loops", (loops,), "m"), Level("platform", (task,), "m, rad" if orientation else "m")]
    joint_limits = robot.joint_limits
    sliders = tuple(f"slider{i}" for i in range(1, 7))
    return Setup(
        scenario=scenario,
        robot_name="hexapod",
        robot=robot,
        duration=trajectory.duration if duration is None else duration,
        reference=PlatformReference(model, task, trajectory, loops),
        qp_tasks=tasks,
        limits=[JointPositionLimit(robot, joint_limits), JointVelocityLimit(robot)],
        joint_limits=joint_limits,
        manipulability=PlatformManipulability(model),
        manipulability_measure="hexapod inverse condition number",
        classical={"pinv": lambda: HexapodClassicalController(model, task, k0=k0)},
        plot_joints=JointPlotSpec.from_limits(robot, joint_limits, names=sliders),
        params={"gain": HEXAPOD_GAIN, "loop_gain": LOOP_GAIN, "k0": k0, "hard": hard},
        hierarchy=[loops, task] + tasks[2:],
        level_errors=LevelErrors(levels),
        closure=StrokeDrivenClosure(model),
    )


def _home() -> np.ndarray:
    return np.array(HexapodGeometry.default().home_position)


def _circle(home: np.ndarray) -> Circle:
    return Circle(home - [CIRCLE_RADIUS, 0.0, 0.0], CIRCLE_RADIUS, CIRCLE_DURATION, time_law="quintic")


@register("hexapod-circle", "hexapod", "platform on a 3 cm circle through home with a 3 deg tilt, 4 s")
def hexapod_circle(scene: str = "hexapod") -> Setup:
    circle = _circle(_home())
    return hexapod_setup("hexapod-circle", PoseTrajectory(circle, CircularTilt(circle, TILT_DEG)),
                         orientation=True, hard=True, scene=scene)


@register("hexapod-stroke-limits", "hexapod", "0.20 m along x: strokes would reach 0.41 m > 0.35; soft task")
def hexapod_stroke_limits(scene: str = "hexapod") -> Setup:
    home = _home()
    segment = Segment(home, home + [STROKE_TRAVEL, 0.0, 0.0], 2.0, time_law="quintic")
    return hexapod_setup("hexapod-stroke-limits", PoseTrajectory(segment), duration=3.0,
                         orientation=True, hard=False, scene=scene)


@register("hexapod-position-only", "hexapod", "the circle, position task only; free rotations raise manipulability")
def hexapod_position_only(scene: str = "hexapod", k0: float = HEXAPOD_K0) -> Setup:
    return hexapod_setup("hexapod-position-only", PoseTrajectory(_circle(_home())),
                         orientation=False, hard=True, k0=k0, scene=scene)

