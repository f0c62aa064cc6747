"""SNS's saturation loop was rewritten for speed; its results must not change. Step by step
along every bundled scenario that offers SNS, and on random arm states under tight boxes,
the package's SNSController and the implementation it replaced (sns_reference.py, the
code of commit a61460b) give the same joint velocities, task scales and saturation counts.

Same means equal to rounding. Where a level has saturated joints, SNS writes each pass as
q̇(s) = s a + b and both implementations compute b = q̇ − a: when the joints left free are
nearly singular for the task, a (the task's share) is large and b cancels it, so each
carries a rounding error of about 1e-16 |a| (too-fast reaches |a| ~ 3e4 rad/s with two
joints saturated, unreachable ~ 1e7 at its stretched end). The tolerance is 1e-12 plus
1e-14 |a|, |a| the largest task share of that step's passes (zero without saturation).

On random states only q̇ is compared: there, a level below one that saturated often scales
along a line s a + b that passes through the velocity of the levels above, a vertex of the
box, where two joints limit s at exactly the same value; rounding then decides between
"scaled to that s" and "left out", which give the same q̇ but report different scales."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from qpik.app.runs import start_run
from qpik.controllers.sns import SNSController
from qpik.limits import JointPositionLimit, JointVelocityLimit
from qpik.robot import Robot
from qpik.robots.arm import model as arm
from qpik.robots.arm.planar import PlanarOrientationTask
from qpik.tasks import ManipulabilityTask, PositionTask, SigmaProxy

_spec = importlib.util.spec_from_file_location("sns_reference", Path(__file__).with_name("sns_reference.py"))
_reference = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_reference)
ReferenceSNSController = _reference.ReferenceSNSController

SCENARIOS = [("arm", "seed-primary"), ("arm", "seed-redundant"), ("arm", "joint-limits"), ("arm", "unreachable"),
             ("arm", "too-fast"), ("arm", "three-tasks"), ("hexapod", "hexapod-circle"),
             ("hexapod", "hexapod-stroke-limits"), ("hexapod", "hexapod-position-only")]
ABSOLUTE = 1e-12
PER_SHARE = 1e-14


class _SideBySide:
    """The reference SNS on the same tasks and limits, computed at each state the
    package's SNS sees, with the largest task share |a| of its passes."""

    def __init__(self, robot, levels, limits, dt, **options):
        self.reference = ReferenceSNSController(robot, levels=levels, limits=limits, dt=dt, **options)
        self.share = 0.0
        scaling = self.reference._scaling

        def recording(a, b, saturated):
            self.share = max(self.share, float(np.max(np.abs(a))))
            return scaling(a, b, saturated)

        self.reference._scaling = recording

    def compare(self, sns: SNSController, qdot: np.ndarray, where: str, reports: bool = True) -> float:
        self.share = 0.0
        expected = self.reference.compute_velocity().copy()
        difference = float(np.max(np.abs(qdot - expected)))
        assert difference <= ABSOLUTE + PER_SHARE * self.share, \
            f"{where}: q̇ differs by {difference:.3g} (task share {self.share:.3g})"
        if not reports:
            return difference
        np.testing.assert_allclose(sns.task_scale, self.reference.task_scale, rtol=0,
                                   atol=ABSOLUTE + PER_SHARE * self.share, err_msg=where)
        assert list(sns.saturated) == list(self.reference.saturated), where
        return difference


@pytest.mark.parametrize("robot, scenario", SCENARIOS, ids=[s for _, s in SCENARIOS])
def test_every_step_of_every_sns_scenario_is_unchanged(robot, scenario):
    setup, rollout = start_run(robot, scenario, "sns")
    sns = rollout.controller
    levels = [level.tasks for level in sns.levels]
    side = _SideBySide(setup.robot, levels, setup.limits, setup.dt)
    compute = sns.compute_velocity
    steps, saturating = [0], [0]

    def checked():
        qdot = compute()
        side.compare(sns, qdot, f"{scenario}, step {steps[0]}")
        steps[0] += 1
        saturating[0] += bool(sns.saturated.any())
        return qdot

    sns.compute_velocity = checked
    rollout.advance()
    assert steps[0] == rollout.log().t.size
    if scenario in ("joint-limits", "too-fast", "three-tasks"):
        assert saturating[0] > 100  # the saturation loop itself was exercised


def _arm_levels(robot, rng, top: str):
    """Level 0 the path (x, y), or its x alone (which leaves the levels below three
    directions, so that φ can hold two joints in them); then φ; then σ."""
    axes = "xy" if top == "path" else "x"
    position = PositionTask(robot, "end_effector", axes=axes, gain=500.0)
    here = arm.end_effector_position(robot.q)[:len(axes)]
    position.set_target(here + rng.normal(0.0, 1e-3, len(axes)), rng.normal(0.0, 0.5, len(axes)))
    phi = PlanarOrientationTask(robot, "end_effector", gain=50.0)
    phi.set_target(phi.angle() + rng.normal(0.0, 0.05))
    sigma = ManipulabilityTask(robot, SigmaProxy(robot, ["theta2", "theta3"]), gain=5.0)
    return [[position], [phi], [sigma]]


@pytest.mark.parametrize("top", ["path", "x"])
@pytest.mark.parametrize("seed", range(3))
def test_random_states_under_tight_boxes_are_unchanged(seed, top):
    """Three levels at random configurations, with random speed limits tight enough to
    saturate one to three joints, and position limits near the configuration: every
    branch of the loop (saturations at each level, in joint space and within the levels
    above's null space, scaling, levels left out)."""
    rng = np.random.default_rng(seed)
    robot = Robot.load("arm")
    patterns = set()
    for _ in range(40):
        q = np.concatenate([rng.uniform(-2.5, 2.5, 3), rng.uniform(0.1, 0.9, 1)])
        robot.set_q(q)
        robot.update_kinematics()
        levels = _arm_levels(robot, rng, top)
        # θ2 just above its lower bound, θ3 just below its upper one (in the joints' ±2.6 rad)
        ranges = robot.joint_limits.tightened({"theta2": (q[1] - rng.uniform(0.0, 0.02), min(q[1] + 1.0, 2.6)),
                                               "theta3": (max(q[2] - 1.0, -2.6), q[2] + rng.uniform(0.0, 0.02))})
        limits = [JointPositionLimit(robot, ranges), JointVelocityLimit(robot, rng.uniform(0.02, 0.6, 4))]
        for max_acceleration in (None, 5.0):
            sns = SNSController(robot, levels=levels, limits=limits, dt=0.002, max_acceleration=max_acceleration)
            side = _SideBySide(robot, levels, limits, 0.002, max_acceleration=max_acceleration)
            qdot = sns.compute_velocity()
            side.compare(sns, qdot, f"seed {seed}, q = {q.tolist()}", reports=False)
            patterns.add(tuple(sns.saturated))
    assert len(patterns) >= 3  # several saturation patterns met, not one path checked 80 times
    if top == "x":  # φ held two joints within the null space of x
        assert any(held[1] == 2 for held in patterns)
