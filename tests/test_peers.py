"""The peers (mink, placo) on the arm: same problem as the QP, hence the same motion.

Why the q tolerances are tight: each peer is given the QP's problem exactly (weights,
gain and feed-forward through the shifted target, σ task, bounds, regulariser; see
qpik.peers.problem), only scaled to the step Δq = q̇Δt. With exact active-set solvers
(DAQP, placo's eiquadprog) both sides reach the same minimiser up to rounding, so the
trajectories agree to ~1e-13 rad; 1e-8 leaves room for rounding drift over 2500 steps
while still catching any mapping error (a dropped feed-forward alone moves q by ~1e-3).
"""

import json

import mujoco
import numpy as np
import pytest

from qpik.cli import main
from qpik.peers import PLACO_SOLVER, PeerUnsupported, peer_controller
from qpik.peers.problem import PeerProblem
from qpik.robot import Robot
from qpik.rollout import simulate
from qpik.runs import compare
from qpik.scenarios import SCENARIOS, _seed_segment, arm_setup, build_scenario

mink = pytest.importorskip("mink")
placo = pytest.importorskip("placo")

from qpik.peers.placo_peer import URDF_SCENES  # noqa: E402  (needs placo)

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
    monkeypatch.setattr("qpik.runs.peer_installed", lambda kind: kind != "mink")
    _, logs, notes = compare("arm", "seed-primary", ["daqp"], classical=())
    assert "mink not installed: skipped" in notes
    assert [log.controller for log in logs] == ["qp", "placo"]


@pytest.mark.skipif("hexapod-circle" not in SCENARIOS, reason="no hexapod scenarios")
def test_unmapped_scenario_is_reported_not_crashed():
    with pytest.raises(PeerUnsupported):
        PeerProblem.from_setup(build_scenario("hexapod-circle"), "mink")
