"""The hexapod under control: loop closures, the classical law, and the scenarios' claims."""

import json

import mujoco
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from qpik.app.cli import main
from qpik.robots.hexapod.kinematics import rotation_from_rpy
from qpik.robots.hexapod.control import HexapodModel, StrokeDrivenClosure
from qpik.robot import Robot
from qpik.app.runs import run
from qpik.scenario import build_scenario
from qpik.tasks import EqualityTask
from qpik.trajectories import Circle, CircularTilt, PoseTrajectory


@pytest.fixture(scope="module")
def logs():
    cache = {}

    def get(scenario, controller, mode="kinematic"):
        key = (scenario, controller, mode)
        if key not in cache:
            cache[key] = run("hexapod", scenario, controller, "daqp", mode)[1]
        return cache[key]

    return get


def test_loop_closure_rows_equal_mujoco_full_constraint_pipeline():
    robot = Robot.load("hexapod")
    rng = np.random.default_rng(4)
    robot.q[:18] += rng.normal(0.0, 0.02, 18)  # open the loops a little
    robot.update_kinematics()
    task = EqualityTask(robot, gain=1.0)
    task.update()
    m, d = robot.model, robot.data
    mujoco.mj_forward(m, d)
    rows = d.efc_type == mujoco.mjtConstraint.mjCNSTR_EQUALITY
    efc_J = np.zeros((d.nefc, m.nv))
    if mujoco.mj_isSparse(m):
        mujoco.mju_sparse2dense(efc_J, d.efc_J, d.efc_J_rownnz, d.efc_J_rowadr, d.efc_J_colind)
    else:
        efc_J = d.efc_J.reshape(d.nefc, m.nv)
    assert np.max(np.abs(task.error)) > 1e-3
    np.testing.assert_allclose(task.error, d.efc_pos[rows], atol=1e-14)
    np.testing.assert_allclose(task.jacobian, efc_J[rows], atol=1e-12)
    # And the Jacobian is the derivative of the residual (finite differences).
    k = 7
    dq = np.zeros(m.nv)
    dq[k] = 1e-7
    probe = Robot(m, keyframe=None)
    probe.data.qpos[:] = robot.q
    probe.integrate(dq, 1.0)
    probe.update_kinematics()
    probe_task = EqualityTask(probe, gain=1.0)
    probe_task.update()
    np.testing.assert_allclose((probe_task.error - task.error) / 1e-7, task.jacobian[:, k], atol=1e-5)


def test_fast_inverse_jacobian_and_manipulability_match_the_analytic_model():
    model = HexapodModel(Robot.load("hexapod"))
    poses = [((0.15, 0.10, 0.05), (-3, 2, 3)), ((0.07, 0.08, 0.04), (4, -3, -2)), ((0.08, 0.02, 0.11), (0, 0, 0))]
    for position, rpy in poses:
        R, p = rotation_from_rpy(rpy), np.array(position)
        np.testing.assert_allclose(model.scaled_inverse_jacobian(p, R) / model._scale,
                                   model.hexapod.inverse_jacobian(p, R), atol=1e-12)
        assert model.manipulability(p, R) == pytest.approx(model.hexapod.manipulability(p, R), abs=1e-14)
        fd = np.array([(model.hexapod.manipulability(p, Rotation.from_rotvec(e).as_matrix() @ R)
                        - model.hexapod.manipulability(p, Rotation.from_rotvec(-e).as_matrix() @ R)) / 2e-6
                       for e in np.eye(3) * 1e-6])
        np.testing.assert_allclose(model.manipulability_gradient(p, R), fd, atol=1e-8)
    assert model.manipulability(np.array([0.5, 0.5, 0.5]), np.eye(3)) == 0.0  # no assembly


def test_pose_trajectory_angular_velocity_matches_finite_differences():
    circle = Circle([0.0, 0.0, 0.1], 0.03, 4.0)
    trajectory = PoseTrajectory(circle, CircularTilt(circle, 3.0))
    for t in (0.3, 1.7, 3.2):
        _, _, R, omega = trajectory.sample_pose(t)
        _, _, R2, _ = trajectory.sample_pose(t + 1e-6)
        np.testing.assert_allclose(Rotation.from_matrix(R2 @ R.T).as_rotvec() / 1e-6, omega, atol=1e-6)
    _, _, R0, w0 = trajectory.sample_pose(0.0)
    np.testing.assert_allclose(R0, np.eye(3), atol=1e-15)
    np.testing.assert_allclose(w0, 0.0, atol=1e-15)


@pytest.mark.parametrize("controller", ["qp", "pinv"])
def test_circle_is_tracked_with_closed_loops(logs, controller):
    s = logs("hexapod-circle", controller).summary()
    assert s.max_error <= 1e-4
    assert s.orientation_error_max <= 1e-4
    assert s.constraint_violation_max <= 1e-6
    assert s.limit_violation_max == 0.0
    # How long a step takes (inside the 2 ms control period?) is measured by
    # benchmarks/step_time.py, not asserted here: a test must not depend on the machine's load.


def test_circle_qp_and_classical_law_agree(logs):
    qp, pinv = logs("hexapod-circle", "qp"), logs("hexapod-circle", "pinv")
    sliders = [0, 3, 6, 9, 12, 15]
    assert np.max(np.abs(qp.q[:, sliders] - pinv.q[:, sliders])) <= 1e-5
    # The tilt really happened: θy = 3°(1 − cos Δφ) reaches 6° half-way round.
    quats = qp.q[:, 21:25]  # the platform's free joint (w, x, y, z)
    angles = np.degrees(Rotation.from_quat(quats[:, [1, 2, 3, 0]]).magnitude())
    assert 5.9 <= angles.max() <= 6.1


def test_circle_in_physics_mode(logs):
    s = logs("hexapod-circle", "qp", "physics").summary()
    assert s.max_error <= 2e-3
    assert s.info.mode == "physics"
    # The plant's loops are MuJoCo's soft constraints, so they open a little under load.
    assert 1e-7 < s.constraint_violation_max <= 1e-3


def test_stroke_limits_classical_exceeds_qp_keeps(logs):
    pinv, qp = logs("hexapod-stroke-limits", "pinv"), logs("hexapod-stroke-limits", "qp")
    assert pinv.summary().limit_violation_max > 1e-3
    assert qp.summary().limit_violation_max == 0.0
    strokes = qp.q[:, [0, 3, 6, 9, 12, 15]]
    assert strokes.min() >= 0.0 and strokes.max() <= 0.35
    assert strokes.max() >= 0.35 - 1e-6  # it does use the whole stroke
    # As close as it can: the x travel stops short of 0.20 m, but most of it is done.
    travel = qp.x[-1, 0] - qp.x[0, 0]
    assert 0.12 < travel < 0.20


def test_position_only_raises_manipulability(logs):
    with_task = logs("hexapod-position-only", "qp").summary()
    setup, without_log = run("hexapod", "hexapod-position-only", "qp", setup=build_scenario("hexapod-position-only", k0=0.0))
    without = without_log.summary()
    assert with_task.max_error <= 1e-4 and without.max_error <= 1e-4
    assert with_task.manipulability_mean > without.manipulability_mean + 0.01
    assert with_task.manipulability_final > without.manipulability_final + 0.02
    # The classical law with the same null-space gradient reaches the same orientation.
    classical = logs("hexapod-position-only", "pinv").summary()
    assert classical.manipulability_final == pytest.approx(with_task.manipulability_final, abs=1e-3)


def test_stroke_driven_closure_assembles_or_jams():
    setup = build_scenario("hexapod-circle")
    robot, closure = setup.robot, setup.closure
    model = HexapodModel(robot)
    start = robot.q.copy()
    robot.q[model.slider_qpos] += 0.002  # a translation along x by 2 mm
    closure(robot)
    assert setup.reference.loops.max_residual(robot) <= 1e-12
    np.testing.assert_allclose(model.platform_pose()[0] - model.hexapod.geometry.home_position, [0.002, 0, 0], atol=1e-10)
    before = robot.q.copy()
    robot.q[model.slider_qpos[0]] += 0.2  # no assembly with one stroke 20 cm off
    closure(robot)
    assert isinstance(closure, StrokeDrivenClosure) and closure.jams == 1
    np.testing.assert_array_equal(robot.q, before)
    assert not np.array_equal(before, start)


def test_hexapod_cli_summary_has_its_keys(tmp_path):
    out = tmp_path / "hx"
    assert main(["run", "hexapod", "--scenario", "hexapod-circle", "--controller", "pinv", "--out", str(out), "--plot"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["robot"] == "hexapod"
    assert summary["orientation_error_max"] <= 1e-4 and summary["constraint_violation_max"] <= 1e-6
    assert (out / "extras.png").exists() and (out / "joints.png").exists()
    assert main(["run", "hexapod", "--scenario", "seed-primary", "--out", str(out / "x")]) == 2
