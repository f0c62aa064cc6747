"""qpik and mink on the same third-party problems (the problems of benchmarks/third_party.py,
shortened, no timing; benchmarks.peers.equivalence runs them side by side): the same
trajectories where both solve the same QP, and what each collision bound does to a hand
pulled into a box."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("mink", reason="mink is not installed (pip install -e '.[peers]')")
pytest.importorskip("dm_control", reason="the models come with dm_control (pip install -e '.[test]')")
pytest.importorskip("gymnasium", reason="the pusher comes with gymnasium (pip install -e '.[test]')")

from benchmarks.peers.equivalence import PAIR, equivalence, mink_controller, qpik_controller, without_damper  # noqa: E402
from benchmarks.peers.mink_mirror import MinkMirror  # noqa: E402
from qpik import JointPositionLimit  # noqa: E402
from qpik.app.peers.problem import PeerUnsupported  # noqa: E402

# The problems are the examples' (a folder of scripts, imported as the scripts import each other).
sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "examples"))

import collision_avoidance  # noqa: E402
import humanoid_reach  # noqa: E402
import jaco_circle  # noqa: E402
import pose_circles  # noqa: E402

D_MIN = collision_avoidance.MINIMUM_DISTANCE
PROBLEMS = {
    "jaco": (jaco_circle.build, PAIR),
    "humanoid": (humanoid_reach.build, PAIR),
    "chain7": (lambda duration: pose_circles.chain_demo(7, duration), PAIR),
    "pusher": (pose_circles.pusher_demo, PAIR),
    "collision": (lambda duration: collision_avoidance.build(duration, native_ccd=True),
                  {"qpik": qpik_controller, "qpik (no damper)": lambda demo: qpik_controller(without_damper(demo)),
                   "mink": mink_controller}),
}


def run(case: str, duration: float) -> dict:
    build, contenders = PROBLEMS[case]
    result = equivalence(build, contenders, duration)
    for label, log in result["logs"].items():
        assert log.completed, f"{label}: {log.failure}"
    return result


def test_jaco_pose_circle_is_mink_s_to_1e6():
    result = run("jaco", 1.5)
    assert result["differences"]["mink"]["q_max_difference"] <= 1e-6
    qpik = result["runs"]["qpik"]
    assert qpik["max_error"] <= 1e-5 and qpik["orientation_error_max"] <= 1e-4
    assert qpik["range_violation"] == 0.0 and qpik["speed_violation"] == 0.0
    assert result["runs"]["mink"]["max_error"] == pytest.approx(qpik["max_error"], rel=1e-6)


def test_humanoid_ends_where_mink_does_with_its_feet_held():
    result = run("humanoid", 1.0)
    assert result["differences"]["mink"]["q_final_difference"] <= 1e-4
    for label in ("qpik", "mink"):
        assert result["runs"][label]["feet_drift_max"] <= 1e-6
        assert result["runs"][label]["feet_turn_max"] <= 1e-6


@pytest.mark.parametrize("case, duration", [("chain7", 0.5), ("pusher", pose_circles.PUSHER_MOTION)])
def test_hard_pose_with_posture_is_mink_s_to_1e6(case, duration):
    """The pusher over its whole circle: every step feasible (from its former start the
    wrist reached its range's end at 1.41 s, and both contenders stopped there)."""
    result = run(case, duration)
    assert result["differences"]["mink"]["q_max_difference"] <= 1e-6
    assert result["runs"]["qpik"]["max_error"] <= 1e-4


def test_collision_limits_qpik_keeps_the_minimum_distance_mink_crosses_it():
    """qpik's limit, with and without its damper, keeps d ≥ d_min to 1e-6; mink 1.3 bounds
    its step Δq by gain·(d − d_min)/Δt, 1/Δt looser than its other limits, so the hand
    arrives at d_min at speed and ends inside it (what the README reports)."""
    result = run("collision", 1.5)
    for label in ("qpik", "qpik (no damper)"):
        assert result["runs"][label]["distance_min"] >= D_MIN - 1e-6, label
    assert result["runs"]["qpik"]["distance_final"] <= D_MIN + 1e-3  # held there, not short of it
    mink = result["runs"]["mink"]
    assert mink["distance_min"] < D_MIN - 1e-5, "mink's collision bound changed: update the benchmark's note"
    assert mink["approach_speed_at_crossing"] > 0.05  # at speed: nothing slowed it before d_min


def test_the_mirror_refuses_what_mink_cannot_express():
    demo = pose_circles.chain_demo(7, 0.1)
    damped = [JointPositionLimit(demo.robot, influence=0.1)]
    with pytest.raises(PeerUnsupported, match="without the velocity damper"):
        MinkMirror(demo.robot, demo.tasks, damped, demo.dt)
    demo.tasks[0].position_gain[:] = [100.0, 100.0, 50.0]
    with pytest.raises(PeerUnsupported, match="gain must be the same on every row"):
        MinkMirror(demo.robot, demo.tasks, demo.limits, demo.dt)


def test_mirror_maps_weights_gains_and_limits_as_documented():
    demo = humanoid_reach.build(0.1)
    mirror = MinkMirror(demo.robot, demo.tasks, demo.limits, demo.dt, moving=demo.moving)
    feet, com, hand, posture = demo.tasks[0], demo.tasks[2], demo.tasks[3], demo.tasks[4]
    assert len(mirror.constraints) == 2 and all(c.gain == pytest.approx(feet.position_gain[0] * demo.dt)
                                                 for c in mirror.constraints)
    mink_com, mink_hand, mink_posture = mirror.tasks
    np.testing.assert_allclose(mink_com.cost, np.sqrt(com.weight))
    np.testing.assert_allclose(mink_hand.cost, [np.sqrt(hand.weight[0])] * 3 + [0.0] * 3)
    assert mink_posture.gain == pytest.approx(posture.gain * demo.dt)
    np.testing.assert_allclose(mink_posture.cost[posture.dofs], np.sqrt(posture.weight))
    assert not mink_posture.cost[:6].any()  # the free joint's dofs, as qpik's posture leaves them
    position_limit, speed_limit = mirror.limits
    assert position_limit.gain == demo.limits[0].gain and sorted(position_limit.indices) == \
        sorted(demo.robot.joint_limits.dof_index)
    np.testing.assert_array_equal(speed_limit.limit, demo.limits[1].max_velocity[speed_limit.indices])
