"""The sweep's per-world metrics against an independent computation: a few worlds re-run
with the serial controllers (qpik.QPController, qpik.PseudoinverseController) built from
the scenario constructors' parts, the reference sampled by the serial trajectory classes,
and every metric computed again in a plain per-step loop."""

from __future__ import annotations

import numpy as np
import pytest

import qpik
from qpik.app.sweep.rollout import REACH_TOLERANCE, run_chunk
from qpik.app.sweep.studies import DT, MOVE, STEPS, ported, study
from qpik.robots.arm.scenarios import (
    ARM_K0,
    DAMPER_INFLUENCE,
    DAMPER_RATE,
    LM_DAMPING,
    SOFT_DAMPING,
)
from qpik.trajectories import Segment

WORLDS = slice(0, 12)


def serial_arm(kind: str, start_q, gain):
    robot = qpik.Robot.load("arm")
    robot.set_q(start_q)
    robot.update_kinematics()
    hard = kind != "qp-soft"
    task = qpik.PositionTask(robot, "end_effector", axes="xy", gain=gain, hard=hard,
                             lm_damping=0.0 if hard else LM_DAMPING)
    sigma = qpik.ManipulabilityTask(robot, qpik.SigmaProxy(robot, ("theta2", "theta3")), gain=ARM_K0, weight=1.0)
    if kind == "pinv":
        return robot, task, qpik.PseudoinverseController(robot, [task], sigma)
    cost = sigma if hard else qpik.DampingTask(robot, weight=SOFT_DAMPING)
    limits = [qpik.JointPositionLimit(robot, influence=DAMPER_INFLUENCE, damper_rate=DAMPER_RATE),
              qpik.JointVelocityLimit(robot)]
    return robot, task, qpik.QPController(robot, [task, cost], limits, solver="daqp", dt=DT)


def serial_metrics(kind: str, start_q, target, gain) -> dict:
    """One world, step by step, with the serial library; the metrics as the sweep defines them."""
    robot, task, controller = serial_arm(kind, start_q, gain)
    site = robot.site_id("end_effector")
    start = robot.site_position(site)[:2].copy()
    segment = Segment(start, target, MOVE, time_law="quintic")
    lim, vmax = robot.joint_limits, robot.velocity_limits
    out = dict(max_error=0.0, range_violation=0.0, speed_violation=0.0, peak_speed=np.zeros(robot.nv),
               stopped_at=-1)
    distances = []
    for k in range(STEPS):
        position, velocity = segment.sample(k * DT)
        task.set_target(position, velocity)
        try:
            qdot = controller.compute_velocity().copy()
        except qpik.QpikError:
            out["stopped_at"] = k
            break
        x = robot.site_position(site)[:2]
        out["max_error"] = max(out["max_error"], float(np.linalg.norm(position - x)))
        distances.append(float(np.linalg.norm(target - x)))
        robot.integrate(qdot, DT)
        out["peak_speed"] = np.maximum(out["peak_speed"], np.abs(qdot))
        out["speed_violation"] = max(out["speed_violation"], float(np.max(np.abs(qdot) - vmax)))
        q = robot.q[lim.qpos_index]
        out["range_violation"] = max(out["range_violation"], float(np.max(np.maximum(lim.lower - q, q - lim.upper))),
                                     0.0)
    robot.update_kinematics()
    out["final_error"] = float(np.linalg.norm(target - robot.site_position(site)[:2]))
    distances.append(out["final_error"])
    far = [k for k, d in enumerate(distances) if d > REACH_TOLERANCE]
    reached = out["stopped_at"] < 0 and out["final_error"] <= REACH_TOLERANCE
    out["converge_time"] = ((far[-1] + 1) * DT if far else 0.0) if reached else np.nan
    return out


@pytest.mark.parametrize("kind", ["qp", "qp-soft", "pinv"])
def test_arm_metrics_equal_a_serial_rerun_of_the_same_worlds(kind):
    if not ported("arm", kind):
        pytest.skip(f"the arm's {kind} sweep needs a batched class the engine does not have yet")
    arm = study("arm")
    samples = {key: value[WORLDS] for key, value in arm.samples(seed=3, start=0, stop=12).items()}
    batched = run_chunk(arm, kind, samples)
    stops = 0
    for w in range(len(samples["gain"])):
        ref = serial_metrics(kind, samples["start_q"][w], samples["target"][w], samples["gain"][w])
        assert batched["stopped_at"][w] == ref["stopped_at"], f"world {w}"
        stops += ref["stopped_at"] >= 0
        for key in ("max_error", "final_error", "range_violation", "speed_violation"):
            assert batched[key][w] == pytest.approx(ref[key], abs=1e-9), (w, key)
        np.testing.assert_allclose(batched["peak_speed"][w], ref["peak_speed"], rtol=0, atol=1e-9)
        np.testing.assert_equal(np.isnan(batched["converge_time"][w]), np.isnan(ref["converge_time"]))
        if np.isfinite(ref["converge_time"]):
            assert batched["converge_time"][w] == pytest.approx(ref["converge_time"], abs=1e-12)
    if kind == "qp":
        assert 0 < stops < len(samples["gain"])  # the worlds include stopped and finished runs
    if kind == "pinv":
        assert (batched["range_violation"] > 1e-6).any()  # the law breaks limits in some worlds
