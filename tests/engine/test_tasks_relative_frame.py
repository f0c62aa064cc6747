"""The engine's RelativeFrameTask: on one robot equal to its formula written out on MuJoCo's
own poses and Jacobians of the two frames (SciPy's rotation vector); on 4 worlds with
their own states and targets, each world equal to its own one-world run; J against finite
differences of the error (at the target, and the position rows away from it); with the
world body as root, the FrameTask; bad input is a typed error naming the worlds."""

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

# Per model: the tracked frame and the root (name, type).
MODELS = {
    "arm": (("end_effector", "site"), ("link1", "body")),
    "hexapod": (("platform_center", "site"), ("leg1", "body")),
    "jaco": (("wristsite", "site"), ("b_2", "body")),
    "humanoid": (("rfoot_touch", "site"), ("thorax", "body")),
    "pusher": (("tips_arm", "body"), ("r_shoulder_lift_link", "body")),
}


def quaternions(rng, n: int) -> np.ndarray:
    q = rng.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def tracking(robot, name, t):
    (frame, frame_type), (root, root_type) = MODELS[name]
    task = engine.RelativeFrameTask(robot, frame, root, frame_type, root_type, position_gain=[1.0, 2.0, 3.0],
                                    orientation_gain=4.0, weight=[1.0, 1.0, 2.0, 2.0, 3.0, 3.0], lm_damping=0.1)
    task.set_target(task.target_position + t["offset"], t["quat"], t["linear"], t["angular"])
    return task


def dead_beat(robot, name, t):
    (frame, frame_type), (root, root_type) = MODELS[name]
    task = engine.RelativeFrameTask(robot, frame, root, frame_type, root_type)
    task.set_target(task.target_position - t["offset"], t["quat"])
    return task


def targets(rng, n: int) -> dict:
    return dict(offset=rng.normal(scale=0.05, size=(n, 3)), quat=quaternions(rng, n), linear=rng.normal(size=(n, 3)),
                angular=rng.normal(size=(n, 3)))


def relative_rows(model, q, name, offset, rotation, twist, gains):
    """With d = p_f − p_r: p = R_rᵀd, R = R_rᵀR_f; e = [p + offset − p; rotation vector of
    R_d Rᵀ], J = R_rᵀ[J_p,f − J_p,r + [d]× J_ω,r; J_ω,f − J_ω,r], v = K e + the twist
    (root coordinates): MuJoCo's poses and Jacobians at q."""
    (frame, frame_type), (root, root_type) = MODELS[name]
    pf, Rf, Jpf, Jrf = references.frame_state(model, q, frame, frame_type)
    pr, Rr, Jpr, Jrr = references.frame_state(model, q, root, root_type)
    d = pf - pr
    e = np.concatenate([offset, references.rotation_vector(references.quaternion_matrix(rotation), Rr.T @ Rf)])
    J = np.vstack([Rr.T @ (Jpf - Jpr + references.skew(d) @ Jrr), Rr.T @ (Jrf - Jrr)])
    return e, J, np.asarray(gains) * e + twist


@pytest.mark.parametrize("name", sorted(MODELS))
def test_one_robot_equals_the_formula_on_mujocos_kinematics(model_path, name):
    path = model_path(name)
    start = support.one_robot(path)
    q = support.displaced(start.model, start.q, seed=1)
    t = {k: v[0] for k, v in targets(np.random.default_rng(2), 1).items()}
    support.assert_rows(tracking(support.one_robot(path, q), name, t),
                        relative_rows(start.model, q, name, t["offset"], t["quat"],
                                      np.concatenate([t["linear"], t["angular"]]), [1.0, 2.0, 3.0, 4.0, 4.0, 4.0]))
    support.assert_rows(dead_beat(support.one_robot(path, q), name, t),
                        relative_rows(start.model, q, name, -t["offset"], t["quat"], np.zeros(6),
                                      [1.0 / support.DT] * 6))


@pytest.mark.parametrize("name", ["arm", "jaco", "humanoid"])
def test_each_of_four_worlds_is_its_own_one_world_run(model_path, name):
    robots = support.worlds(model_path(name), n=4, seed=3)
    t = targets(np.random.default_rng(4), robots.n)
    for case in (tracking, dead_beat):
        support.assert_each_world(robots, lambda robot, w, case=case: case(
            robot, name, t if w is None else {k: v[w] for k, v in t.items()}))


@pytest.mark.parametrize("name", sorted(MODELS))
def test_jacobians_are_the_derivatives_of_the_errors(model_path, name):
    robot = support.one_robot(model_path(name))
    robot.q[:] = support.displaced(robot.model, robot.q, seed=5)
    robot.update_kinematics()
    (frame, frame_type), (root, root_type) = MODELS[name]
    support.assert_jacobian_is_the_derivative(engine.RelativeFrameTask(robot, frame, root, frame_type, root_type))
    away = engine.RelativeFrameTask(robot, frame, root, frame_type, root_type)
    away.set_target(away.target_position + 0.1, away.target_rotation)
    away.attach(support.DT)
    away.update()
    jacobian = away.jacobian[:3].copy()  # at q, before the differences move the robot
    fd = -support.finite_differences(robot, lambda: (away.update(), away.error.copy())[1])
    # The position rows are exact derivatives whatever the error (see support.AGREEMENT).
    assert np.abs(fd[:3] - jacobian).max() <= support.AGREEMENT * max(1.0, np.abs(jacobian).max())


def test_with_the_world_as_root_it_is_the_frame_task():
    robots = support.worlds("arm", n=4, seed=6)
    relative = engine.RelativeFrameTask(robots, "end_effector", "world", root_type="body", position_gain=2.0,
                                        orientation_gain=3.0)
    frame = engine.FrameTask(robots, "end_effector", position_gain=2.0, orientation_gain=3.0)
    rng = np.random.default_rng(7)
    positions, rotations = rng.normal(size=(4, 3)), quaternions(rng, 4)
    relative.set_target(positions, rotations)
    frame.set_target(positions, rotations)
    for a, b in zip(support.measured(relative), support.measured(frame)):
        assert support.relative(a, b) <= support.REFERENCE  # R_r = I, p_r = 0: the same numbers


def test_bad_input_is_a_typed_error():
    robots = support.worlds("arm", n=4)
    task = engine.RelativeFrameTask(robots, "end_effector", "link1", root_type="body")
    positions = np.zeros((4, 3))
    positions[1] = np.nan
    with pytest.raises(InvalidWorlds, match="worlds 1") as caught:
        task.set_target(positions, np.eye(3))
    np.testing.assert_array_equal(caught.value.worlds, [1])
    rotations = np.tile(np.eye(3), (4, 1, 1))
    rotations[2] *= 2.0
    with pytest.raises(InvalidWorlds, match="worlds 2"):
        task.set_target(np.zeros(3), rotations)
    with pytest.raises(InvalidInput, match="same"):
        engine.RelativeFrameTask(robots, "link1", "link1", "body", "body")
    with pytest.raises(InvalidInput, match="homogeneous"):
        task.set_target_transform(np.eye(4) * 2.0)
    one = engine.RelativeFrameTask(support.one_robot("arm"), "end_effector", "link1", root_type="body")
    with pytest.raises(InvalidInput, match="NaN"):
        one.set_target([0.0, 0.0, np.inf], np.eye(3))
    one.set_target_transform(np.eye(4))
    np.testing.assert_array_equal(one.target_rotation, np.eye(3))
