"""Every task's Jacobian against central finite differences of its own error, on the bundled
robots and the third-party models; targets with velocity feed-forward against the formulas.

The error e(q) of a tracking task has de/dq = −J where it vanishes (and everywhere for
position, relative position and CoM rows); the displacement q ⊕ h e_k is MuJoCo's own
(``mj_integratePos``), so free and ball dofs are differentiated in MuJoCo's tangent space.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from qpik import (
    ComTask,
    DampingTask,
    FrameTask,
    InvalidInput,
    ModelError,
    OrientationTask,
    PositionTask,
    PostureTask,
    QPController,
    RelativeFrameTask,
    Robot,
    UnknownName,
)

STEP = 1e-6
# |finite difference − J| allowed, relative to the largest |J| entry: central differences
# at h = 1e-6 agree to ~1e-9 here (rounding ε|e|/h and curvature h²).
AGREEMENT = 1e-7

# Per model: a point (frame, frame type) to track, other frames of each type, a root for
# relative tasks, a body for a subtree CoM.
MODELS = {
    "arm": dict(frame=("end_effector", "site"), body=("link3", "body"), geom=("wrist", "geom"),
                root=("link1", "body"), subtree="link2"),
    "hexapod": dict(frame=("platform_center", "site"), body=("leg3", "body"), geom=None,
                    root=("leg1", "body"), subtree="platform"),
    "jaco": dict(frame=("wristsite", "site"), body=("b_4", "body"), geom=("link_3", "geom"),
                 root=("b_2", "body"), subtree="b_3"),
    "humanoid": dict(frame=("rfoot_touch", "site"), body=("lhand", "body"), geom=("head", "geom"),
                     root=("thorax", "body"), subtree="lfemur"),
    "pusher": dict(frame=("tips_arm", "body"), body=("r_forearm_link", "body"), geom=("tip_arml", "geom"),
                   root=("r_shoulder_lift_link", "body"), subtree="r_upper_arm_link"),
}


def displaced_configuration(robot: Robot, seed: int) -> None:
    """Move away from the model's special configuration (zeros, home) by a random tangent step."""
    rng = np.random.default_rng(seed)
    mujoco.mj_integratePos(robot.model, robot.q, rng.normal(scale=0.3, size=robot.nv), 1.0)
    robot.update_kinematics()


def load(model_path, name: str, seed: int = 0) -> Robot:
    robot = Robot.load(model_path(name))
    displaced_configuration(robot, seed)
    return robot


def error_jacobian(task, sign: float = -1.0) -> np.ndarray:
    """Central differences of ``task.error`` along each dof (times ``sign``), at the robot's q."""
    robot = task.robot
    q0 = robot.q.copy()
    columns = []
    for k in range(robot.nv):
        errors = []
        for h in (STEP, -STEP):
            robot.q[:] = q0
            step = np.zeros(robot.nv)
            step[k] = h
            mujoco.mj_integratePos(robot.model, robot.q, step, 1.0)
            robot.update_kinematics()
            task.update()
            errors.append(task.error.copy())
        columns.append(sign * (errors[0] - errors[1]) / (2 * STEP))
    robot.q[:] = q0
    robot.update_kinematics()
    task.update()
    return np.array(columns).T


def check_jacobian(task, sign: float = -1.0) -> float:
    """Assert the task's J equals the finite differences of its error; return the gap."""
    task.update()
    jacobian = task.jacobian.copy()
    fd = error_jacobian(task, sign)
    gap = float(np.max(np.abs(fd - jacobian)))
    scale = max(1.0, float(np.max(np.abs(jacobian))))
    assert gap <= AGREEMENT * scale, f"{type(task).__name__}: |FD − J| = {gap:.2e}"
    np.testing.assert_array_equal(task.jacobian, jacobian)  # the differences left J as it was
    return gap


def frame_tasks(robot: Robot, spec: dict):
    """Every frame-based task of the model, on each frame type it has."""
    frame, frame_type = spec["frame"]
    tasks = [
        PositionTask(robot, frame, frame_type),
        PositionTask(robot, frame, frame_type, axes="xz"),
        PositionTask(robot, frame, frame_type, axes="xy", axes_frame="local"),
        OrientationTask(robot, frame, frame_type),
        OrientationTask(robot, frame, frame_type, axes="xz", axes_frame="local"),
        FrameTask(robot, frame, frame_type),
        FrameTask(robot, frame, frame_type, position_axes="xy", orientation_axes="z", axes_frame="local"),
        RelativeFrameTask(robot, frame, spec["root"][0], frame_type, spec["root"][1]),
        PositionTask(robot, *spec["body"]),
        FrameTask(robot, *spec["body"], axes_frame="local"),
    ]
    if spec["geom"] is not None:
        tasks += [FrameTask(robot, *spec["geom"]), RelativeFrameTask(robot, spec["geom"][0], frame, "geom", frame_type)]
    return tasks


@pytest.mark.parametrize("name", sorted(MODELS))
def test_frame_task_jacobians_match_finite_differences(model_path, name):
    robot = load(model_path, name)
    for task in frame_tasks(robot, MODELS[name]):
        check_jacobian(task)


@pytest.mark.parametrize("name", sorted(MODELS))
def test_position_rows_match_finite_differences_away_from_the_target(model_path, name):
    """World and relative position rows are exact derivatives whatever the error."""
    robot = load(model_path, name, seed=1)
    frame, frame_type = MODELS[name]["frame"]
    world = PositionTask(robot, frame, frame_type)
    world.set_target(world.target + [0.1, -0.2, 0.05])
    relative = RelativeFrameTask(robot, frame, MODELS[name]["root"][0], frame_type, MODELS[name]["root"][1])
    relative.set_target(relative.target_position + 0.1, relative.target_rotation)
    check_jacobian(world)
    task = relative
    task.update()
    fd = error_jacobian(task)
    np.testing.assert_allclose(fd[:3], task.jacobian[:3], atol=AGREEMENT * max(1.0, np.abs(task.jacobian).max()))


@pytest.mark.parametrize("name", sorted(MODELS))
def test_com_jacobians_match_finite_differences(model_path, name):
    robot = load(model_path, name)
    whole = ComTask(robot)
    whole.set_target(whole.target + 0.05)  # exact away from the target too
    check_jacobian(whole)
    check_jacobian(ComTask(robot, subtree=MODELS[name]["subtree"], axes="xz"))


def test_com_is_the_mass_weighted_mean_of_the_bodies(humanoid_path):
    robot = Robot.load(humanoid_path)
    displaced_configuration(robot, 3)
    m, d = robot.model, robot.data
    mean = (m.body_mass[:, None] * d.xipos).sum(axis=0) / m.body_mass.sum()
    np.testing.assert_allclose(ComTask(robot).target, mean, atol=1e-12)
    with pytest.raises(UnknownName, match="lfemur"):
        ComTask(robot, subtree="lfemr")


@pytest.mark.parametrize("name", ["arm", "humanoid"])
def test_joint_space_tasks_are_the_dof_selection(model_path, name):
    robot = load(model_path, name)
    posture = PostureTask(robot)  # hinge and slide dofs only: a free base is left alone
    check_jacobian(posture)
    selection = np.eye(robot.nv)[posture.dofs]
    np.testing.assert_array_equal(posture.jacobian, selection)
    assert posture.joint_space and DampingTask(robot).joint_space
    free = [j for j in range(robot.model.njnt) if robot.model.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE]
    assert not set(range(6)) & set(posture.dofs) if free else len(posture.dofs) == robot.nv


def test_relative_frame_task_with_the_world_as_root_is_the_frame_task(jaco_path):
    robot = Robot.load(jaco_path)
    displaced_configuration(robot, 5)
    rng = np.random.default_rng(5)
    absolute = FrameTask(robot, "wristsite", position_gain=3.0, orientation_gain=2.0)
    relative = RelativeFrameTask(robot, "wristsite", "world", root_type="body", position_gain=3.0,
                                 orientation_gain=2.0)
    target = (absolute.target_position + rng.normal(scale=0.05, size=3),
              _rotation(rng.normal(scale=0.2, size=3)) @ absolute.target_rotation,
              rng.normal(size=3), rng.normal(size=3))
    absolute.set_target(*target)
    relative.set_target(*target)
    absolute.update()
    relative.update()
    np.testing.assert_allclose(relative.jacobian, absolute.jacobian, atol=1e-15)
    np.testing.assert_allclose(relative.target_velocity, absolute.target_velocity, atol=1e-14)
    with pytest.raises(InvalidInput, match="same"):
        RelativeFrameTask(robot, "wristsite", "wristsite")


def _rotation(rotvec) -> np.ndarray:
    quat, matrix = np.empty(4), np.empty(9)
    angle = float(np.linalg.norm(rotvec))
    mujoco.mju_axisAngle2Quat(quat, np.asarray(rotvec) / angle, angle)
    mujoco.mju_quat2Mat(matrix, quat)
    return matrix.reshape(3, 3)


def test_feed_forward_and_gains_enter_v_in_the_rows_axes(jaco_path):
    """v = S ẋ_d + K S e with S the world rows, or the frame's rows (Rᵀ) in local axes."""
    robot = Robot.load(jaco_path)
    displaced_configuration(robot, 2)
    rng = np.random.default_rng(2)
    frame = robot.frame("wristsite")
    p, R = frame.position.copy(), frame.rotation.copy()
    p_d, R_d = p + rng.normal(scale=0.02, size=3), _rotation(rng.normal(scale=0.1, size=3)) @ R
    v_d, w_d = rng.normal(size=3), rng.normal(size=3)
    e_p, e_o = p_d - p, _log(R_d @ R.T)
    gains = np.array([2.0, 3.0])
    position = PositionTask(robot, "wristsite", axes="xz", gain=gains)
    position.set_target(p_d[[0, 2]], v_d[[0, 2]])
    local = PositionTask(robot, "wristsite", axes="yz", gain=gains, axes_frame="local")
    local.set_target(p_d, v_d)
    orientation = OrientationTask(robot, "wristsite", axes="xy", gain=gains, axes_frame="local")
    orientation.set_target(R_d, w_d)
    frame_task = FrameTask(robot, "wristsite", position_gain=4.0, orientation_gain=5.0)
    frame_task.set_target(p_d, R_d, v_d, w_d)
    for task in (position, local, orientation, frame_task):
        task.update()
    np.testing.assert_allclose(position.target_velocity, v_d[[0, 2]] + gains * e_p[[0, 2]], atol=1e-13)
    np.testing.assert_allclose(local.target_velocity, (R.T @ v_d)[1:] + gains * (R.T @ e_p)[1:], atol=1e-13)
    np.testing.assert_allclose(orientation.target_velocity, (R.T @ w_d)[:2] + gains * (R.T @ e_o)[:2], atol=1e-12)
    np.testing.assert_allclose(frame_task.target_velocity, np.r_[v_d + 4.0 * e_p, w_d + 5.0 * e_o], atol=1e-12)
    np.testing.assert_allclose(local.measured(), p)
    np.testing.assert_allclose(position.measured(), p[[0, 2]])


def _log(R: np.ndarray) -> np.ndarray:
    """Rotation vector of R (scipy-free, via MuJoCo's quaternions)."""
    quat, out = np.empty(4), np.empty(3)
    mujoco.mju_mat2Quat(quat, R.ravel())
    mujoco.mju_quat2Vel(out, quat, 1.0)
    return out


@pytest.mark.parametrize("axes_frame", ["world", "local"])
def test_feed_forward_tracks_a_moving_target_without_lag(jaco_path, axes_frame):
    """A hard frame task on a target moving at constant speed: with the feed-forward the
    QP follows it up to the discretisation (q̇ held over Δt on a curved map, ~1e-6 m
    here); without, it lags by ṗ/K (3e-3 m)."""
    gain, dt, speed = 20.0, 0.002, np.array([0.05, -0.03, 0.02])
    errors = {}
    for feed_forward in (True, False):
        robot = Robot.load(jaco_path, allow_outside_limits=True)  # displaced_configuration: joint_2 below its range
        displaced_configuration(robot, 4)
        task = FrameTask(robot, "wristsite", position_gain=gain, orientation_gain=gain, hard=True,
                         axes_frame=axes_frame)
        start, rotation = task.target_position.copy(), task.target_rotation.copy()
        controller = QPController(robot, [task, DampingTask(robot, 1e-6)], dt=dt)
        for k in range(300):
            task.set_target(start + speed * k * dt, rotation, speed if feed_forward else None)
            robot.update_kinematics()
            robot.integrate(controller.compute_velocity(), dt)
        robot.update_kinematics()
        errors[feed_forward] = np.linalg.norm(start + speed * 300 * dt - robot.frame_position(task.frame))
    assert errors[True] < 1e-3 * errors[False]
    assert errors[False] == pytest.approx(np.linalg.norm(speed) / gain, rel=0.05)


def test_bad_task_arguments_are_typed_errors(jaco_path):
    robot = Robot.load(jaco_path)
    with pytest.raises(UnknownName, match="wristsite"):
        FrameTask(robot, "wrist_site")
    with pytest.raises(InvalidInput, match="axes_frame"):
        PositionTask(robot, "wristsite", axes_frame="body")
    with pytest.raises(InvalidInput, match="axes"):
        OrientationTask(robot, "wristsite", axes="xw")
    with pytest.raises(InvalidInput, match="rotation"):
        FrameTask(robot, "wristsite").set_target(np.zeros(3), 2.0 * np.eye(3))
    with pytest.raises(InvalidInput, match="reflection"):
        FrameTask(robot, "wristsite").set_target(np.zeros(3), -np.eye(3))
    with pytest.raises(InvalidInput, match="NaN"):
        OrientationTask(robot, "wristsite").set_target(np.full((3, 3), np.nan))
    with pytest.raises(InvalidInput, match=r"shape \(3,\)"):
        PositionTask(robot, "wristsite", axes="xy", axes_frame="local").set_target([0.1, 0.2])
    with pytest.raises(ModelError, match="no mass"):
        ComTask(Robot(mujoco.MjModel.from_xml_string(MASSLESS)), subtree="marker")


MASSLESS = """<mujoco><worldbody><body name="marker"><geom size="0.1" mass="0"/></body>
<body name="link"><joint axis="0 0 1"/><geom size="0.1" pos="0.2 0 0"/></body></worldbody></mujoco>"""


def test_humanoid_reaches_while_its_com_stays_put(humanoid_path):
    """The DESIGN's API on a foreign floating-base model: a hard CoM task (x, y), a soft
    hand pose task toward a target 20 cm away, posture and damping; joint ranges kept."""
    from qpik import JointPositionLimit, JointVelocityLimit

    robot = Robot.load(humanoid_path, allow_outside_limits=True)  # qpos0: knees below range
    robot.update_kinematics()
    hand = FrameTask(robot, "lhand", "body", position_gain=10.0, orientation_gain=1.0, weight=[1, 1, 1, 0.1, 0.1, 0.1])
    goal = hand.target_position + [0.1, 0.1, 0.15]
    hand.set_target(goal, hand.target_rotation)
    com = ComTask(robot, gain=10.0, axes="xy", hard=True)
    free = robot.model.joint(0).name
    tasks = [hand, com, PostureTask(robot, weight=1e-3), DampingTask(robot, 1e-4, joints=[free])]
    limits = [JointPositionLimit(robot), JointVelocityLimit(robot, np.full(robot.nv, 5.0))]
    controller = QPController(robot, tasks, limits, dt=0.01)
    start = np.linalg.norm(goal - hand.frame.position)
    for _ in range(300):
        robot.update_kinematics()
        robot.integrate(controller.compute_velocity(), 0.01)
    robot.update_kinematics()
    assert np.linalg.norm(goal - hand.frame.position) < 0.05 * start
    np.testing.assert_allclose(com.measured(), com.target, atol=1e-6)
    # DAQP keeps an inactive bound to its primal tolerance (1e-6 on q̇), so fingers that
    # start at a bound end ~1e-8 rad past it: 1e-6 Δt, not a task's doing.
    assert robot.joint_limits.violation(robot.q) <= 1e-6 * 0.01 * 2


@pytest.mark.parametrize("gain", [None, "fast", [1.0, 2.0], np.nan, np.inf, -50.0, -1e-300])
def test_a_bad_posture_gain_is_refused_as_every_other_tasks(gain, jaco_path):
    """A negative gain makes the error grow (e(k+1) = (1 − KΔt) e(k)), NaN poisons every
    answer: the posture task checks its gain as the frame tasks do."""
    robot = Robot.load(jaco_path)
    with pytest.raises(InvalidInput, match="posture gain"):
        PostureTask(robot, gain=gain)
    if gain is not None:  # None is the frame tasks' dead-beat default, not a posture gain
        with pytest.raises(InvalidInput):
            PositionTask(robot, "wristsite", gain=gain)  # the reference: the same input refused


@pytest.mark.parametrize("gain", [0.0, 3, np.float32(2.5)])
def test_a_posture_gain_of_zero_or_any_number_type_is_kept(gain, jaco_path):
    task = PostureTask(Robot.load(jaco_path), gain=gain)
    assert task.gain == float(gain) and type(task.gain) is float
