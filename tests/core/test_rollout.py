"""The rollout loop: fast references and measures against the per-step protocol, blocks,
physics-mode failures (MuJoCo's silent "unstable, reset", a bad timestep)."""

import numpy as np
import pytest

from qpik.errors import DivergenceError, ModelError
from qpik.rollout import Rollout, simulate
from qpik.scenario import build_scenario


class PerStep:
    """A reference seen only through apply/desired/measure: the loop's per-step path."""

    def __init__(self, reference):
        self.inner = reference

    def apply(self, t):
        self.inner.apply(t)

    def desired(self):
        return self.inner.desired()

    def measure(self, robot):
        return self.inner.measure(robot)


def _rollout(scenario, per_step, mode="kinematic", duration=None, controller="qp"):
    setup = build_scenario(scenario)
    reference = PerStep(setup.reference) if per_step else setup.reference
    measure = (lambda robot: setup.manipulability(robot)) if per_step else setup.manipulability
    return simulate(setup.controller(controller), reference, duration or setup.duration, dt=setup.dt, mode=mode,
                    manipulability=measure, joint_limits=setup.joint_limits, closure=setup.closure)


@pytest.mark.parametrize("scenario, mode, duration", [
    ("seed-redundant", "kinematic", None), ("joint-limits", "physics", 1.0), ("hexapod-circle", "kinematic", None),
    ("hexapod-position-only", "kinematic", 1.0), ("hexapod-stroke-limits", "kinematic", 1.0)])
def test_sampled_up_front_and_evaluated_after_equals_one_call_per_step(scenario, mode, duration):
    fast, slow = _rollout(scenario, False, mode, duration), _rollout(scenario, True, mode, duration)
    fast_arrays, slow_arrays = fast.arrays(), slow.arrays()
    assert fast_arrays.keys() == slow_arrays.keys()
    for name in fast_arrays:
        if name != "step_time":
            np.testing.assert_array_equal(fast_arrays[name], slow_arrays[name], err_msg=name)
    assert {k: v for k, v in fast.summary().to_json().items() if "step_time" not in k} == \
        {k: v for k, v in slow.summary().to_json().items() if "step_time" not in k}


def test_a_rollout_advanced_in_blocks_equals_one_run_to_the_end():
    setup = build_scenario("hexapod-circle")
    rollout = Rollout(setup.controller("qp"), setup.reference, 0.5, manipulability=setup.manipulability)
    blocks = []
    while not rollout.finished:
        blocks.append(rollout.advance(50))
    assert blocks == [50] * 5 + [1] and rollout.advance(50) == 0
    whole = _rollout("hexapod-circle", False, duration=0.5)
    np.testing.assert_array_equal(rollout.log().q, whole.q)
    np.testing.assert_array_equal(rollout.log().manipulability, whole.manipulability)


def _unstable_arm():
    """The arm with servos 10⁶ times too stiff for the 2 ms timestep: MuJoCo's explicit
    step blows up within a few steps, then resets the state and carries on."""
    setup = build_scenario("seed-redundant")
    model = setup.robot.model
    servos = model.actuator_biasprm[:, 1] < 0
    model.actuator_gainprm[servos, 0] = 1e8
    model.actuator_biasprm[servos, 1] = -1e8
    return setup


def test_an_unstable_physics_simulation_stops_with_a_divergence_error_naming_the_time():
    setup = _unstable_arm()
    with pytest.raises(DivergenceError, match=r"at t = 0\.0\d\d s: physics simulation unstable.*acceleration"):
        simulate(setup.controller("qp"), setup.reference, 1.0, mode="physics")
    setup = _unstable_arm()
    log = simulate(setup.controller("qp"), setup.reference, 1.0, mode="physics", on_failure="stop")
    assert not log.completed and "MuJoCo reset its state" in log.failure
    assert len(log.t) < 50  # stopped at once, not run on from the reset state


@pytest.mark.parametrize("timestep", [0.0, float("nan"), -0.002])
def test_physics_mode_with_a_bad_timestep_is_a_model_error(timestep):
    setup = build_scenario("seed-redundant")
    setup.robot.model.opt.timestep = timestep  # after load, past Robot's own check
    with pytest.raises(ModelError, match="timestep"):
        simulate(setup.controller("qp"), setup.reference, 0.1, mode="physics")


def test_a_controller_returning_nan_is_a_divergence_at_its_time():
    setup = build_scenario("seed-redundant")
    controller = setup.controller("qp")
    steps = []

    class Faulty:
        kind, solver, robot = "faulty", "none", controller.robot

        def compute_velocity(self):
            steps.append(1)
            qdot = controller.compute_velocity().copy()
            if len(steps) == 4:
                qdot[2] = np.nan
            return qdot

    with pytest.raises(DivergenceError, match=r"at t = 0\.006 s: the controller returned a non-finite velocity"):
        simulate(Faulty(), setup.reference, 0.1)
    steps.clear()
    log = simulate(Faulty(), build_scenario("seed-redundant").reference, 0.1, on_failure="stop")
    assert len(log.t) == 4 and not log.completed and np.all(np.isfinite(log.q))
