"""The engine's PositionTask, OrientationTask and FrameTask (world and local axes, masks, a
site, a body and a geom): on one robot equal to their formulas written out on MuJoCo's own
poses and Jacobians (SciPy's rotation vectors); on 4 worlds with their own states and
targets, each world equal to its own one-world run; J against finite differences of the
error; bad targets are typed errors naming the worlds."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from qpik import InvalidInput
from qpik import tasks as engine
from qpik.errors import InvalidWorlds


def _load(name: str):
    spec = importlib.util.spec_from_file_location(name, Path(__file__).with_name(f"{name}.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


support, references = _load("tasks_support"), _load("references")
DEAD_BEAT = 1.0 / support.DT  # the gain a default (dead-beat) gain becomes once attached

# Per model: the tracked frame, a body frame and a geom frame (None: the model has no named one).
MODELS = {
    "arm": dict(frame=("end_effector", "site"), body=("link3", "body"), geom=("wrist", "geom")),
    "jaco": dict(frame=("wristsite", "site"), body=("b_4", "body"), geom=("link_3", "geom")),
    "pusher": dict(frame=("tips_arm", "body"), body=("r_forearm_link", "body"), geom=("tip_arml", "geom")),
}


def unit_quaternions(rng, n: int) -> np.ndarray:
    q = rng.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def targets(rng, n: int) -> dict:
    """Per-world targets (leading axis N): offsets, rotations and feed-forward velocities."""
    return dict(offset=rng.normal(scale=0.05, size=(n, 3)), quat=unit_quaternions(rng, n),
                linear=rng.normal(size=(n, 3)), angular=rng.normal(size=(n, 3)))


# Each case builds its task on ``robot`` and gives it targets t (per world, or one world's)
# relative to ``start`` (the frame's pose); it returns the task and, for one world, the
# arguments of references.pose_rows that write the same rows out (the gains of each row,
# whole 3-vector targets and velocities in world axes).
def position_xz(robot, spec, t, start):
    task = engine.PositionTask(robot, *spec["frame"], axes="xz", gain=20.0, weight=[1.0, 2.0])
    task.set_target((start[0] + t["offset"])[..., [0, 2]], t["linear"][..., :2])
    linear = np.array([t["linear"][..., 0], 0.0, t["linear"][..., 1]]) if np.ndim(t["linear"]) == 1 else None
    return task, dict(frame=spec["frame"], gains=[20.0, 20.0], position=start[0] + t["offset"], position_axes="xz",
                      linear=linear)


def position_local(robot, spec, t, start):
    task = engine.PositionTask(robot, *spec["frame"], axes="xy", gain=[5.0, 7.0], axes_frame="local", lm_damping=0.1)
    task.set_target(start[0] + t["offset"], t["linear"])
    return task, dict(frame=spec["frame"], gains=[5.0, 7.0], position=start[0] + t["offset"], position_axes="xy",
                      local=True, linear=t["linear"])


def orientation_world(robot, spec, t, start):
    task = engine.OrientationTask(robot, *spec["frame"], gain=30.0)
    task.set_target(t["quat"], t["angular"])
    return task, dict(frame=spec["frame"], gains=[30.0] * 3, rotation=_matrix(t["quat"]), angular=t["angular"])


def orientation_local_xz(robot, spec, t, start):
    task = engine.OrientationTask(robot, *spec["frame"], axes="xz", axes_frame="local")  # dead-beat
    task.set_target(t["quat"], t["angular"])
    return task, dict(frame=spec["frame"], gains=[DEAD_BEAT] * 2, rotation=_matrix(t["quat"]), orientation_axes="xz",
                      local=True, angular=t["angular"])


def frame_world(robot, spec, t, start):
    task = engine.FrameTask(robot, *spec["frame"], position_gain=10.0, orientation_gain=[1.0, 2.0, 3.0])
    task.set_target(start[0] + t["offset"], t["quat"], t["linear"], t["angular"])
    return task, dict(frame=spec["frame"], gains=[10.0, 10.0, 10.0, 1.0, 2.0, 3.0], position=start[0] + t["offset"],
                      rotation=_matrix(t["quat"]), linear=t["linear"], angular=t["angular"])


def frame_local_masked(robot, spec, t, start):
    task = engine.FrameTask(robot, *spec["frame"], position_axes="xy", orientation_axes="z", axes_frame="local",
                            weight=[1.0, 2.0, 3.0])
    task.set_target(start[0] + t["offset"], t["quat"], t["linear"], t["angular"])
    return task, dict(frame=spec["frame"], gains=[DEAD_BEAT] * 3, position=start[0] + t["offset"],
                      rotation=_matrix(t["quat"]), position_axes="xy", orientation_axes="z", local=True,
                      linear=t["linear"], angular=t["angular"])


def frame_body_local(robot, spec, t, start):
    task = engine.FrameTask(robot, *spec["body"], position_gain=3.0, orientation_gain=4.0, axes_frame="local")
    task.set_target(start[1] + t["offset"], t["quat"])
    return task, dict(frame=spec["body"], gains=[3.0] * 3 + [4.0] * 3, position=start[1] + t["offset"],
                      rotation=_matrix(t["quat"]), local=True)


def frame_geom(robot, spec, t, start):
    task = engine.FrameTask(robot, *spec["geom"], position_gain=3.0, orientation_gain=4.0, position_axes="yz")
    task.set_target(start[2] + t["offset"], t["quat"], t["linear"])
    return task, dict(frame=spec["geom"], gains=[3.0] * 2 + [4.0] * 3, position=start[2] + t["offset"],
                      rotation=_matrix(t["quat"]), position_axes="yz", linear=t["linear"])


def _matrix(quat):
    """One world's target rotation (MuJoCo's matrix of the quaternion); None for (N, 4)."""
    return references.quaternion_matrix(quat) if np.ndim(quat) == 1 else None


CASES = [position_xz, position_local, orientation_world, orientation_local_xz, frame_world, frame_local_masked,
         frame_body_local, frame_geom]


def starts(robot, spec) -> list[np.ndarray]:
    """The positions of the model's frame, body and geom (N, 3): the targets' origins."""
    return [np.array(robot.frame(*spec[key]).positions) for key in ("frame", "body", "geom")]


@pytest.mark.parametrize("name", sorted(MODELS))
def test_one_robot_equals_the_formulas_on_mujocos_kinematics(model_path, name):
    spec, rng = MODELS[name], np.random.default_rng(1)
    path = model_path(name)
    q = support.displaced(support.one_robot(path).model, support.one_robot(path).q, seed=2)
    t = {k: v[0] for k, v in targets(rng, 1).items()}
    for case in CASES:
        robot = support.one_robot(path, q)
        start = [s[0] for s in starts(robot, spec)]
        task, reference = case(robot, spec, t, start)
        support.assert_rows(task, references.pose_rows(robot.model, q, **reference))


@pytest.mark.parametrize("name", sorted(MODELS))
def test_each_of_four_worlds_is_its_own_one_world_run(model_path, name):
    spec, rng = MODELS[name], np.random.default_rng(3)
    robots = support.worlds(model_path(name), n=4, seed=4)
    t, origin = targets(rng, robots.n), starts(robots, spec)
    for case in CASES:
        def build(robot, w, case=case):
            if w is None:
                return case(robot, spec, t, origin)[0]
            return case(robot, spec, {k: v[w] for k, v in t.items()}, [s[w] for s in origin])[0]

        support.assert_each_world(robots, build)


@pytest.mark.parametrize("name", sorted(MODELS))
def test_jacobians_are_the_derivatives_of_the_errors(model_path, name):
    """At the target (e = 0, where de/dq = −J exactly for every row) and, for world
    position rows, away from it too."""
    spec = MODELS[name]
    robot = support.one_robot(model_path(name))
    robot.q[:] = support.displaced(robot.model, robot.q, seed=5)
    robot.update_kinematics()
    tasks = [engine.PositionTask(robot, *spec["frame"]), engine.PositionTask(robot, *spec["frame"], axes="xz"),
             engine.PositionTask(robot, *spec["frame"], axes="xy", axes_frame="local"),
             engine.OrientationTask(robot, *spec["frame"]),
             engine.OrientationTask(robot, *spec["frame"], axes="xz", axes_frame="local"),
             engine.FrameTask(robot, *spec["frame"]),
             engine.FrameTask(robot, *spec["frame"], position_axes="xy", orientation_axes="z", axes_frame="local"),
             engine.FrameTask(robot, *spec["body"], axes_frame="local"), engine.FrameTask(robot, *spec["geom"])]
    away = engine.PositionTask(robot, *spec["frame"])
    away.set_target(away.target + [0.1, -0.2, 0.05])
    for task in tasks + [away]:
        support.assert_jacobian_is_the_derivative(task)


def test_bad_targets_are_typed_errors_naming_the_worlds():
    robots = support.worlds("arm", n=4)
    position = engine.PositionTask(robots, "end_effector", axes="xy")
    frame = engine.FrameTask(robots, "end_effector")
    orientation = engine.OrientationTask(robots, "end_effector")
    good = np.array(position.targets)
    bad = good.copy()
    bad[2, 1] = np.nan
    with pytest.raises(InvalidWorlds, match="worlds 2") as caught:
        position.set_target(bad)
    np.testing.assert_array_equal(caught.value.worlds, [2])
    np.testing.assert_array_equal(position.targets, good)  # nothing written
    rotations = np.tile(np.eye(3), (4, 1, 1))
    rotations[1] = np.diag([1.0, 1.0, -1.0])  # a reflection
    rotations[3, 0, 0] = 1.1  # not orthonormal
    with pytest.raises(InvalidWorlds, match="worlds 1, 3") as caught:
        frame.set_target(np.zeros(3), rotations)
    np.testing.assert_array_equal(caught.value.worlds, [1, 3])
    quats = np.tile([1.0, 0.0, 0.0, 0.0], (4, 1))
    quats[0] = [2.0, 0.0, 0.0, 0.0]
    with pytest.raises(InvalidWorlds, match="worlds 0"):
        orientation.set_target(quats)
    velocity = np.zeros((4, 3))
    velocity[3] = np.inf
    with pytest.raises(InvalidWorlds, match="worlds 3"):
        frame.set_target(np.zeros(3), np.eye(3), velocity)
    with pytest.raises(InvalidInput, match="shape"):
        position.set_target(np.zeros((3, 2)))  # neither one target nor one per world


def test_bad_targets_on_one_robot_are_invalid_input():
    robot = support.one_robot("arm")
    with pytest.raises(InvalidInput, match="NaN"):
        engine.PositionTask(robot, "end_effector", axes="xy").set_target([0.1, np.nan])
    with pytest.raises(InvalidInput, match="beyond"):
        engine.FrameTask(robot, "end_effector").set_target([1e200, 0.0, 0.0], np.eye(3))
    with pytest.raises(InvalidInput, match="reflection"):
        engine.OrientationTask(robot, "end_effector").set_target(np.diag([1.0, 1.0, -1.0]))
