"""Headless MuJoCo rollouts of the arm scenarios: the source's results and the QP's."""

import numpy as np
import pytest

from qpik.robots.arm import model as arm
from qpik.app.runs import run
from qpik.robots.arm.scenarios import JOINT_LIMITS_RANGES, UNREACHABLE_TARGET


@pytest.fixture(scope="module")
def logs():
    cache = {}

    def get(scenario, controller, mode="kinematic", solver="daqp"):
        key = (scenario, controller, mode, solver)
        if key not in cache:
            cache[key] = run("arm", scenario, controller, solver, mode)[1]
        return cache[key]

    return get


def test_seed_primary_pinv_reproduces_the_source(logs):
    log = logs("seed-primary", "pinv")
    s = log.summary()
    assert s.max_error <= 1e-5  # source: order 1e-7
    assert s.steps == 2501 and log.t[-1] == pytest.approx(5.0)
    np.testing.assert_allclose(log.x[-1], [1.5, 1.0], atol=1e-5)
    # σ stays near 0.1 once the arm moves (it starts at 0 with θ2 = θ3 = 0).
    assert 0.085 <= s.manipulability_final <= 0.1  # 0.0897 here
    assert 0.09 <= np.max(log.manipulability) <= 0.105  # 0.103 here
    # σ from the log equals the formula on the logged q (independent check).
    np.testing.assert_allclose(log.manipulability[-1], arm.sigma(log.q[-1]), atol=1e-15)


def test_seed_redundant_pinv_raises_sigma_as_the_source(logs):
    log = logs("seed-redundant", "pinv")
    above = np.flatnonzero(log.manipulability > 0.99)
    assert above.size
    first = log.t[above[0]]
    assert 2.0 <= first <= 2.5, f"σ first passes 0.99 at t = {first:.3f} s"
    assert np.all(log.manipulability[above[0]:] > 0.99)  # and stays near 1
    assert log.summary().max_error <= 1e-5
    # The joint-velocity peak the source reports near t ≈ 2 s.
    peak_t = log.t[np.argmax(np.max(np.abs(log.qdot), axis=1))]
    assert 1.5 <= peak_t <= 2.5


@pytest.mark.parametrize("scenario", ["seed-primary", "seed-redundant"])
@pytest.mark.parametrize("solver", ["daqp", "osqp"])
def test_qp_equals_pinv_on_the_seed_scenarios(logs, scenario, solver):
    qp, pinv = logs(scenario, "qp", solver=solver), logs(scenario, "pinv")
    assert np.max(np.abs(qp.q[-1] - pinv.q[-1])) <= 1e-3
    assert np.max(np.linalg.norm(qp.x - pinv.x, axis=1)) <= 1e-6  # the same path
    assert qp.summary().limit_violation_max == 0.0


def test_joint_limits_pinv_violates_qp_keeps_and_tracks(logs):
    pinv, qp = logs("joint-limits", "pinv").summary(), logs("joint-limits", "qp").summary()
    assert pinv.limit_violation_max > 1e-3
    assert qp.limit_violation_max == 0.0
    assert qp.max_error <= 1e-3
    q = np.array(qp.q_final)
    for name, (lo, hi) in JOINT_LIMITS_RANGES.items():
        idx = ("theta1", "theta2", "theta3", "d4").index(name)
        assert lo <= q[idx] <= hi


def test_unreachable_pinv_blows_up_qp_stays_bounded_and_settles(logs):
    pinv, qp = logs("unreachable", "pinv"), logs("unreachable", "qp")
    closest = arm.closest_reachable_point(UNREACHABLE_TARGET, reach=arm.A1 + arm.A2 + 1.0)
    # The classical law asks for velocities two orders beyond the joints' limits.
    assert pinv.summary().peak_joint_speed > 50.0
    vmax = np.array([8.0, 8.0, 8.0, 2.0])
    assert np.all(np.abs(qp.qdot) <= vmax + 1e-9)
    assert qp.summary().limit_violation_max == 0.0
    assert np.linalg.norm(qp.x[-1] - closest) <= 1e-3
    # Settled: the last 0.2 s barely move.
    assert np.max(np.abs(qp.q[-1] - qp.q[-100])) <= 1e-4
    # No chattering against the boundary: the joint speeds' total variation stays small
    # (bang-bang between ±8 rad/s would add 16 rad/s per step).
    assert np.max(np.sum(np.abs(np.diff(qp.qdot, axis=0)), axis=0)) < 50.0


def test_physics_mode_qp_tracks_within_5_mm(logs):
    log = logs("seed-redundant", "qp", mode="physics")
    s = log.summary()
    assert s.info.mode == "physics"
    assert s.max_error <= 5e-3
    assert s.manipulability_final > 0.99
    # The plant really is simulated: it does not follow the command exactly.
    assert s.max_error > logs("seed-redundant", "qp").summary().max_error
