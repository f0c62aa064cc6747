"""The peers (mink, placo) on the arm and the hexapod: same problem as the QP, hence the same motion.

Why the q tolerances are tight: each peer is given the QP's problem exactly (weights,
gain and feed-forward through the shifted target, σ task, bounds, regulariser; see
qpik.app.peers.problem), only scaled to the step Δq = q̇Δt. With exact active-set solvers
(DAQP, placo's eiquadprog) both sides reach the same minimiser up to rounding, so the
trajectories agree to ~1e-13 rad; 1e-8 leaves room for rounding drift over 2500 steps
while still catching any mapping error (a dropped feed-forward alone moves q by ~1e-3).

On the hexapod the strokes agree to 1e-9 m (HEXAPOD_STROKES). Measured over the 4 s
circle: 5e-12 m for mink (its SE(3) log Jacobian rounds at small rotation steps), 2e-11 m
for placo (its loop rows differ from the QP's at second order, |e_c| |ω|Δt). The target a
first-order mapping would give mink, the desired pose shifted by the feed-forward
T_d ⊕ (ṗd, ωd)/K instead of T exp(u), already moves them by 3e-8 m: 1e-9 tells the two apart.
"""

import json

import mujoco
import numpy as np
import pytest

from qpik.app.cli import main
from qpik.app.peers import PLACO_SOLVER, PeerUnsupported, peer_controller
from qpik.app.peers.problem import PeerProblem
from qpik.robot import Robot
from qpik.rollout import PositionReference
from qpik.tasks import PositionTask
from qpik.rollout import simulate
from qpik.app.runs import compare
from qpik.robots.arm.scenarios import _seed_segment, arm_setup
from qpik.scenario import build_scenario, scenarios

mink = pytest.importorskip("mink")
placo = pytest.importorskip("placo")

from qpik.app.peers.placo_peer import URDF_SCENES  # noqa: E402  (needs placo)

AGREEMENT = 1e-8
TRACKING = 1e-3


def rollout(setup, controller):
    return simulate(controller, setup.reference, setup.duration, dt=setup.dt,
                    manipulability=setup.manipulability, joint_limits=setup.joint_limits)


@pytest.fixture(scope="module")
def qp_logs():
    """The QP (DAQP) on each scenario the tests compare against, rolled out once."""
    logs = {}
    for name in ("seed-primary", "seed-redundant", "unreachable"):
        setup = build_scenario(name, "arm")
        logs[name] = rollout(setup, setup.controller("qp", "daqp"))
    return logs


def peer_log(kind: str, scenario: str, solver: str = "daqp"):
    setup = build_scenario(scenario, "arm")
    return setup, rollout(setup, peer_controller(kind, setup, solver))


def test_urdf_matches_the_mjcf_at_random_configurations():
    robot = Robot.load("arm")
    wrapper = placo.RobotWrapper(str(URDF_SCENES["arm"]), placo.Flags.ignore_collisions)
    site = robot.site_id("end_effector")
    jacp, jacr = np.zeros((3, robot.nv)), np.zeros((3, robot.nv))
    offsets = [wrapper.get_joint_offset(n) for n in robot.joint_limits.names]
    v_offsets = [wrapper.get_joint_v_offset(n) for n in robot.joint_limits.names]
    rng = np.random.default_rng(7)
    limits = robot.joint_limits
    for _ in range(50):
        q = rng.uniform(limits.lower, limits.upper)
        robot.set_q(q)
        robot.update_kinematics()
        mujoco.mj_jacSite(robot.model, robot.data, jacp, jacr, site)
        wrapper.state.q[offsets] = q
        wrapper.update_kinematics()
        pose = wrapper.get_T_world_frame("end_effector")
        jacobian = wrapper.frame_jacobian("end_effector", "local_world_aligned")[:, v_offsets]
        np.testing.assert_allclose(pose[:3, 3], robot.site_position(site), atol=1e-10, rtol=0)
        np.testing.assert_allclose(pose[:3, :3], robot.site_rotation(site), atol=1e-10, rtol=0)
        np.testing.assert_allclose(jacobian[:3], jacp, atol=1e-10, rtol=0)
        np.testing.assert_allclose(jacobian[3:], jacr, atol=1e-10, rtol=0)
    # Same limits and speed bounds as the MJCF (its ranges and qpik_velocity_limit numerics).
    np.testing.assert_allclose(wrapper.model.lowerPositionLimit[offsets], limits.lower)
    np.testing.assert_allclose(wrapper.model.upperPositionLimit[offsets], limits.upper)
    np.testing.assert_allclose(wrapper.model.velocityLimit[v_offsets], robot.velocity_limits)


@pytest.mark.parametrize("scenario", ["seed-primary", "seed-redundant"])
@pytest.mark.parametrize("kind", ["mink", "placo"])
def test_peer_tracks_and_moves_like_the_qp(kind, scenario, qp_logs):
    _, log = peer_log(kind, scenario)
    ref = qp_logs[scenario]
    assert log.completed and log.error.max() <= TRACKING
    assert log.limit_violation.max() == 0.0
    np.testing.assert_allclose(log.q, ref.q, atol=AGREEMENT, rtol=0)
    if scenario == "seed-redundant":  # the σ task did its job, as in the source (σ → 1)
        assert log.manipulability[-1] > 0.99


@pytest.mark.parametrize("kind", ["mink", "placo"])
def test_peer_keeps_the_tightened_joint_limits(kind):
    setup, log = peer_log(kind, "joint-limits")
    assert log.completed and log.error.max() <= TRACKING
    assert log.limit_violation.max() == 0.0
    lim = setup.joint_limits
    q = log.q[:, lim.qpos_index]
    assert np.all(q >= lim.lower) and np.all(q <= lim.upper)
    # The σ gradient pushes θ2, θ3 past ±1: the bounds are reached (within the damper's reach).
    assert np.max(np.abs(q[:, 1:3])) > 0.99


def test_soft_task_with_lm_damping(qp_logs):
    """unreachable: soft task + Levenberg–Marquardt damping.

    placo gets the QP's damping term exactly (a regularization weight μw‖e‖² set each
    step): same motion. mink's own lm_damping scales ‖α e_mink‖², whose error includes the
    feed-forward share ṗdΔt of the shifted target: a slightly stronger damping while the
    target moves (q within 1e-3 rad), the same rest point once it stops.
    """
    ref = qp_logs["unreachable"]
    _, placo_log = peer_log("placo", "unreachable")
    np.testing.assert_allclose(placo_log.q, ref.q, atol=AGREEMENT, rtol=0)
    _, mink_log = peer_log("mink", "unreachable")
    assert np.abs(mink_log.q - ref.q).max() < 1e-3
    np.testing.assert_allclose(mink_log.q[-1], ref.q[-1], atol=1e-8, rtol=0)


def test_step_gain_below_one_is_mapped_exactly():
    """K = 250, Δt = 2 ms: mink's gain 0.5, placo's target p + 0.5(p_t − p)."""
    def setup():
        return arm_setup("gain-250", _seed_segment(), redundant=True, gain=250.0)

    reference = setup()
    ref = rollout(reference, reference.controller("qp", "daqp"))
    for kind in ("mink", "placo"):
        s = setup()
        np.testing.assert_allclose(rollout(s, peer_controller(kind, s, "daqp")).q, ref.q, atol=AGREEMENT, rtol=0)


@pytest.mark.parametrize("kind, frame, frame_type", [("mink", "ram", "body"), ("placo", "ram", "body"),
                                                     ("mink", "ram", "geom")])
def test_peer_tracks_a_body_or_geom_frame(kind, frame, frame_type):
    """The peers get the tracked frame's type (mink's FrameTask takes it as qpik's does;
    placo has a URDF link per body): one peer step equals one QP step."""
    setup = arm_setup("seed-redundant", _seed_segment(), redundant=True)
    robot = setup.robot
    task = PositionTask(robot, frame, frame_type, axes="xy", gain=500.0, hard=True)
    setup.qp_tasks[0] = task
    setup.reference = PositionReference(task, _seed_segment())
    task.set_target(task.measured() + [1e-4, -2e-4], [0.1, -0.05])
    qp = setup.controller("qp", "daqp").compute_velocity().copy()
    np.testing.assert_allclose(peer_controller(kind, setup, "daqp").compute_velocity(), qp, atol=1e-10, rtol=0)


def test_placo_has_no_geom_frames():
    setup = arm_setup("seed-primary", _seed_segment(), redundant=False)
    task = PositionTask(setup.robot, "ram", "geom", axes="xy", gain=500.0, hard=True)
    setup.qp_tasks[0] = task
    setup.reference = PositionReference(task, _seed_segment())
    with pytest.raises(PeerUnsupported, match="geom"):
        peer_controller("placo", setup)


def test_compare_json_holds_the_peer_runs(tmp_path, capsys):
    out = tmp_path / "cmp"
    assert main(["compare", "arm", "--scenario", "seed-primary", "--solvers", "daqp", "--out", str(out)]) == 0
    runs = {(r["controller"], r["solver"]): r for r in json.loads((out / "compare.json").read_text())["runs"]}
    assert {("qp", "daqp"), ("pinv", "none"), ("mink", "daqp"), ("placo", PLACO_SOLVER)} <= set(runs)
    for key in (("mink", "daqp"), ("placo", PLACO_SOLVER)):
        assert runs[key]["max_error"] <= TRACKING
        np.testing.assert_allclose(runs[key]["q_final"], runs[("qp", "daqp")]["q_final"], atol=AGREEMENT)
    table = capsys.readouterr().out
    assert "mink" in table and "placo" in table


def test_missing_peer_is_skipped_with_a_note(monkeypatch):
    monkeypatch.setattr("qpik.app.runs.peer_installed", lambda kind: kind != "mink")
    _, logs, notes = compare("arm", "seed-primary", ["daqp"], classical=())
    assert "mink not installed: skipped" in notes
    assert [log.info.controller for log in logs] == ["qp", "placo"]




# --- The hexapod --------------------------------------------------------------------

HEXAPOD_STROKES = 1e-9  # m, see the module docstring
STROKES = slice(0, 18, 3)  # qpos of slider1..6 (each followed by its two hinges)
hexapod_only = pytest.mark.skipif("hexapod-circle" not in scenarios(), reason="no hexapod scenarios")


@pytest.fixture(scope="module")
def hexapod_qp_logs():
    logs = {}
    for name in ("hexapod-circle", "hexapod-stroke-limits", "hexapod-position-only"):
        setup = build_scenario(name)
        logs[name] = rollout(setup, setup.controller("qp", "daqp"))
    return logs


def hexapod_log(kind: str, scenario: str, solver: str = "daqp"):
    setup = build_scenario(scenario)
    return setup, rollout(setup, peer_controller(kind, setup, solver))


def random_hexapod_state(setup, seed: int, closed: bool) -> None:
    """A random assembly near home (closed loops, or every joint nudged by ~1e-5 so the
    loops are open by ~1e-5 m), a random target near the platform and a random twist."""
    from scipy.spatial.transform import Rotation

    from qpik.robots.hexapod.kinematics import Hexapod
    from qpik.robots.hexapod.scene import close_loops, platform_pose
    from qpik.tasks import FrameTask

    rng = np.random.default_rng(seed)
    robot = setup.robot
    home, _ = platform_pose(robot.model, robot.data)
    pose = home + rng.uniform(-0.01, 0.01, 3), Rotation.from_rotvec(rng.uniform(-0.05, 0.05, 3)).as_matrix()
    close_loops(robot.model, robot.data, Hexapod().inverse_kinematics_matrix(*pose))
    if not closed:
        mujoco.mj_integratePos(robot.model, robot.data.qpos, rng.normal(scale=1e-5, size=robot.nv), 1.0)
    robot.update_kinematics()
    task = setup.reference.task
    p = task.frame.position + rng.normal(scale=1e-5, size=3)
    if isinstance(task, FrameTask):
        R = Rotation.from_rotvec(rng.normal(scale=1e-4, size=3)).as_matrix() @ task.frame.rotation
        task.set_target(p, R, rng.normal(scale=0.03, size=3), rng.normal(scale=0.1, size=3))
    else:
        task.set_target(p, rng.normal(scale=0.03, size=3))


# Largest |q̇_peer − q̇_qp| at one random state (m/s, rad/s), by peer and scenario.
ONE_STEP_TOLERANCE = {("mink", "hexapod-circle"): 1e-9, ("mink", "hexapod-position-only"): 1e-12,
                      ("placo", "hexapod-circle"): 1e-10, ("placo", "hexapod-position-only"): 1e-12}


@hexapod_only
@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("closed", [True, False], ids=["closed", "open-loops"])
@pytest.mark.parametrize("scenario", ["hexapod-circle", "hexapod-position-only"])
@pytest.mark.parametrize("kind", ["mink", "placo"])
def test_one_peer_step_is_one_qp_step(kind, scenario, closed, seed):
    """The peer's Δq/Δt equals QPController.compute_velocity at the same state.

    mink, pose task (hard, 6-D, with the loop rows: 24 equalities on 24 dofs): the only
    difference is mink's rounding of its SE(3) log Jacobian at rotation steps of ~1e-4 rad
    (its coefficient (1 − θ²/2 − cos θ)/θ⁴ cancels), ~1e-10 m/s on speeds of ~0.3 m/s.
    Position task + manipulability: mink's log Jacobian is the identity there, ~1e-14.
    placo: its loop rows differ from the QP's by a term proportional to the loop residual,
    so only on a closed assembly.
    """
    if kind == "placo" and not closed:
        pytest.skip("placo's loop rows equal the QP's only on a closed assembly")
    setup = build_scenario(scenario)
    random_hexapod_state(setup, seed, closed)
    qp = setup.controller("qp", "daqp").compute_velocity().copy()
    peer_qdot = peer_controller(kind, setup, "daqp").compute_velocity()  # placo: its own solver
    np.testing.assert_allclose(peer_qdot, qp, atol=ONE_STEP_TOLERANCE[kind, scenario], rtol=0)


@hexapod_only
@pytest.mark.parametrize("kind", ["mink", "placo"])
def test_peer_tracks_the_hexapod_circle_like_the_qp(kind, hexapod_qp_logs):
    _, log = hexapod_log(kind, "hexapod-circle")
    ref = hexapod_qp_logs["hexapod-circle"]
    assert log.completed and log.error.max() <= 1e-4
    assert log.extras["constraint_violation"].max() <= 1e-6
    assert log.extras["orientation_error"].max() <= 1e-5
    assert log.limit_violation.max() == 0.0
    np.testing.assert_allclose(log.q[:, STROKES], ref.q[:, STROKES], atol=HEXAPOD_STROKES, rtol=0)


@hexapod_only
@pytest.mark.parametrize("kind", ["mink", "placo"])
def test_peer_keeps_the_strokes_in_range(kind, hexapod_qp_logs):
    """hexapod-stroke-limits: soft pose task, strokes would reach 0.41 m.

    placo gets the QP's LM damping exactly and its orientation rows are the QP's: same
    rest point. mink weighs the residual through its SE(3) log Jacobian J_l⁻¹(u), u ≈ the
    3.5 cm error at the stall, and its LM term includes the feed-forward share: it stalls
    1e-5 m (strokes) from the QP, 5e-7 m in tracking error.
    """
    setup, log = hexapod_log(kind, "hexapod-stroke-limits")
    ref = hexapod_qp_logs["hexapod-stroke-limits"]
    strokes = log.q[:, STROKES]
    assert log.completed and log.limit_violation.max() == 0.0
    assert strokes.min() >= 0.0 and strokes.max() <= 0.35
    assert strokes[-1].max() > 0.35 - 1e-6  # the limit is reached, and held
    assert log.extras["constraint_violation"].max() <= 1e-6
    assert abs(log.error[-1] - ref.error[-1]) <= (1e-12 if kind == "placo" else 1e-6)
    np.testing.assert_allclose(strokes[-1], ref.q[-1, STROKES], atol=1e-12 if kind == "placo" else 1e-4, rtol=0)


@hexapod_only
@pytest.mark.parametrize("kind", ["mink", "placo"])
def test_peer_runs_the_manipulability_task(kind, hexapod_qp_logs):
    """hexapod-position-only: the platform's free rotations serve k0 ∇θ m as in the QP."""
    _, log = hexapod_log(kind, "hexapod-position-only")
    ref = hexapod_qp_logs["hexapod-position-only"]
    assert log.completed and log.error.max() <= 1e-4
    np.testing.assert_allclose(log.q[:, STROKES], ref.q[:, STROKES], atol=HEXAPOD_STROKES, rtol=0)
    assert log.manipulability[-1] > 0.085  # 0.060 without the task


@hexapod_only
def test_generated_hexapod_urdf_matches_the_mjcf():
    """Frames (platform centre, platform points, leg tips) and the platform's Jacobian
    agree with MuJoCo's at random configurations (pinocchio's free-flyer velocity is in
    the body frame: its linear columns are MuJoCo's times R)."""
    from qpik.app.peers.placo_peer import _JointMap
    from qpik.app.peers.urdf import mjcf_to_urdf

    robot = Robot.load("hexapod", allow_outside_limits=True)  # random q: sliders beyond their stroke
    model, data = robot.model, robot.data
    wrapper = placo.RobotWrapper(".", placo.Flags.ignore_collisions,
                                 mjcf_to_urdf(model, robot.velocity_limits, "hexapod"))
    joints = _JointMap(model, wrapper)
    sites = ["platform_center"] + [f"platform_point{i}" for i in range(1, 7)] + [f"leg{i}_tip" for i in range(1, 7)]
    jacp, jacr = np.zeros((3, robot.nv)), np.zeros((3, robot.nv))
    rng = np.random.default_rng(3)
    for _ in range(20):
        q = robot.q.copy()
        mujoco.mj_integratePos(model, q, rng.normal(scale=0.3, size=robot.nv), 1.0)
        robot.set_q(q)
        robot.update_kinematics()
        joints.to_placo(robot.q, wrapper.state.q)
        wrapper.update_kinematics()
        for site in sites:
            pose = wrapper.get_T_world_frame(site)
            np.testing.assert_allclose(pose[:3, 3], data.site(site).xpos, atol=1e-12, rtol=0)
            np.testing.assert_allclose(pose[:3, :3].ravel(), data.site(site).xmat, atol=1e-12, rtol=0)
        mujoco.mj_jacSite(model, data, jacp, jacr, robot.site_id("platform_center"))
        jacobian = wrapper.frame_jacobian("platform_center", "local_world_aligned")
        mapped = np.zeros((6, robot.nv))
        for k in range(robot.nv):  # each MuJoCo dof's unit velocity, as placo's step
            unit = np.zeros(robot.nv)
            unit[k] = 1.0
            step = np.zeros(wrapper.model.nv)
            step[joints.placo_v] = unit[joints.dofs]
            for _, dof, body, _, voff in joints.free_map:
                step[voff:voff + 3] = data.xmat[body].reshape(3, 3).T @ unit[dof:dof + 3]
                step[voff + 3:voff + 6] = unit[dof + 3:dof + 6]
            mapped[:, k] = jacobian @ step
        np.testing.assert_allclose(mapped, np.vstack([jacp, jacr]), atol=1e-12, rtol=0)


@hexapod_only
@pytest.mark.parametrize("kind", ["mink", "placo"])
def test_unmappable_gains_are_reported_not_crashed(kind):
    """One gain per task is all either peer can express (mink's ``gain``, placo's dead-beat)."""
    setup = build_scenario("hexapod-circle")
    setup.reference.task.orientation_gain[:] = 250.0
    with pytest.raises(PeerUnsupported, match="same on every axis"):
        peer_controller(kind, setup)
