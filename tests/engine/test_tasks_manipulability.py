"""The engine's manipulability measures (SigmaProxy, Yoshikawa, a user's own) and
ManipulabilityTask: on one robot equal to their formulas written out (Yoshikawa's
√det(JJᵀ) on MuJoCo's Jacobian rows, its gradient against fourth-order central
differences of that value, σ's rows); on 4 worlds with their own states, each world equal
to its own one-world run (a singular world included); Yoshikawa's analytic gradient against
central differences of its own value (free, ball, hinge and slide dofs); an overflowing
gradient is a DivergenceError; bad input is a typed error.

The mixed-joint model and the cases are the core tests' (tests/core/test_manipulability.py)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import mujoco
import numpy as np
import pytest

from qpik import DivergenceError, InvalidInput, UnknownName
from qpik import tasks as engine


def _load(name: str, path: Path):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


support = _load("tasks_support", Path(__file__).with_name("tasks_support.py"))
references = _load("references", Path(__file__).with_name("references.py"))
core = _load("core_manipulability", Path(__file__).parents[1] / "core" / "test_manipulability.py")

# A two-link planar arm: w = l1 l2 |sin q2| on its xy rows, exactly 0 at q = (0, 0).
TWO_LINK = """<mujoco><worldbody><body><joint name="q1" axis="0 0 1"/><geom size=".05" mass="1"/>
<body pos="1 0 0"><joint name="q2" axis="0 0 1"/><geom size=".05" mass="1"/><site name="tip" pos="0.5 0 0"/>
</body></body></worldbody></mujoco>"""
# An unlimited slide: gradient ascent extends it until JJᵀ overflows (the core test's model).
SLIDE = """<mujoco><worldbody><body><joint name="h" axis="0 0 1"/><geom size="0.05" mass="1"/>
<body><joint name="s" type="slide" axis="1 0 0"/><geom size="0.05" mass="1"/>
<site name="tip" pos="0.5 0 0"/></body></body></worldbody></mujoco>"""


def scene(model_path, name: str):
    """A bundled or third-party model's path, or the mixed-joint model."""
    return mujoco.MjModel.from_xml_string(core.MIXED) if name == "mixed" else model_path(name)


def measure(robot, case):
    _, frame, frame_type, axes, orientation_axes = case
    return engine.Yoshikawa(robot, frame, frame_type, axes=axes, orientation_axes=orientation_axes)


def yoshikawa_value(model, q, case) -> float:
    """√det(JJᵀ) of the frame's Jacobian rows (translational ``axes``, then rotational),
    MuJoCo's, at q."""
    _, frame, frame_type, axes, orientation_axes = case
    _, _, Jp, Jr = references.frame_state(model, q, frame, frame_type)
    J = np.vstack([Jp[references.axis_rows(axes)], Jr[references.axis_rows(orientation_axes)]])
    return float(np.sqrt(max(np.linalg.det(J @ J.T), 0.0)))


# Fourth-order central differences (q ⊕ ±h e_k, ±2h e_k; MuJoCo's tangent steps) at
# h = 1e-3: truncation h⁴|w⁽⁵⁾|/30 ~ 1e-13, rounding 1.5 ε|w|/h ~ 3e-13 relative; the
# analytic gradient agrees to 1e-10 on every case (measured), 1e-9 allowed. (The exact
# reference, the analytic formula evaluated by other code, is the kinematic Hessian this
# measure exists to avoid writing twice.)
GRADIENT_STEP = 1e-3
GRADIENT_TOLERANCE = 1e-9


def yoshikawa_gradient(model, q, case) -> np.ndarray:
    gradient = np.zeros(model.nv)
    for k in range(model.nv):
        values = []
        for multiple in (2.0, 1.0, -1.0, -2.0):
            moved = np.array(q, dtype=float)
            mujoco.mj_integratePos(model, moved, np.eye(model.nv)[k] * multiple * GRADIENT_STEP, 1.0)
            values.append(yoshikawa_value(model, moved, case))
        gradient[k] = (-values[0] + 8.0 * values[1] - 8.0 * values[2] + values[3]) / (12.0 * GRADIENT_STEP)
    return gradient


@pytest.mark.parametrize("case", core.CASES, ids=[f"{c[0]}-{c[1]}-{c[3]}-{c[4]}" for c in core.CASES])
def test_yoshikawa_on_one_robot_equals_its_formula(model_path, case):
    path = scene(model_path, case[0])
    start = support.one_robot(path)
    q = support.displaced(start.model, start.q, seed=1, scale=0.4)
    ours = measure(support.one_robot(path, q), case)
    assert ours.value() == pytest.approx(yoshikawa_value(start.model, q, case), rel=support.REFERENCE)
    expected = yoshikawa_gradient(start.model, q, case)
    assert np.linalg.norm(expected) > 1e-3  # a measure that varies, so the check can fail
    assert support.relative(ours.gradient()[0], expected) <= GRADIENT_TOLERANCE


@pytest.mark.parametrize("case", core.CASES[::2], ids=[f"{c[0]}-{c[1]}-{c[3]}-{c[4]}" for c in core.CASES[::2]])
def test_yoshikawa_gradient_matches_finite_differences(model_path, case):
    robot = support.one_robot(scene(model_path, case[0]))
    robot.q[:] = support.displaced(robot.model, robot.q, seed=7, scale=0.4)
    robot.update_kinematics()
    yoshikawa = measure(robot, case)
    gradient = yoshikawa.gradient()[0].copy()
    fd = support.finite_differences(robot, lambda: yoshikawa.value())[0]
    assert np.max(np.abs(fd)) > 1e-3  # a measure that varies, so the check can fail
    # The core test's bound: central differences of w at h = 1e-6, relative to |∇w|.
    np.testing.assert_allclose(gradient, fd, rtol=0, atol=1e-6 * np.max(np.abs(fd)))


@pytest.mark.parametrize("name", ["jaco", "humanoid", "mixed"])
def test_each_of_four_worlds_is_its_own_one_world_run(model_path, name):
    robots = support.worlds(scene(model_path, name), n=4, seed=2, scale=0.4)
    case = next(c for c in core.CASES if c[0] == name)

    def task(robot, w):
        return engine.ManipulabilityTask(robot, measure(robot, case), gain=3.0, weight=2.0)

    batch_task = support.assert_each_world(robots, task)
    values = batch_task.measure.value()
    assert values.shape == (4,)
    for w in range(robots.n):
        assert values[w] == pytest.approx(measure(support.world_robot(robots, w), case).value(),
                                          rel=support.WORLDS)


def test_a_singular_world_has_a_zero_gradient_and_the_others_their_own():
    model = mujoco.MjModel.from_xml_string(TWO_LINK)
    robots = support.worlds(model, n=4, seed=3)
    robots.q[1] = 0.0  # stretched: JJᵀ exactly singular
    robots.update_kinematics()
    yoshikawa = engine.Yoshikawa(robots, "tip", axes="xy")
    gradient, values = yoshikawa.gradient(), yoshikawa.value()
    assert values[1] == 0.0 and np.all(gradient[1] == 0.0)
    for w in (0, 2, 3):
        robot = support.world_robot(robots, w)
        # w = l1 l2 |sin q2|, ∂w/∂q2 = l1 l2 cos q2 sign(sin q2): O(1), a few roundings.
        assert values[w] == pytest.approx(0.5 * abs(np.sin(robot.q[1])), rel=1e-12)
        expected = [0.0, 0.5 * np.cos(robot.q[1]) * np.sign(np.sin(robot.q[1]))]
        np.testing.assert_allclose(gradient[w], expected, rtol=0, atol=1e-12)
        assert support.relative(gradient[w], engine.Yoshikawa(robot, "tip", axes="xy").gradient()[0]) <= support.WORLDS


def test_sigma_proxy_on_one_robot_and_on_four_worlds():
    path = "arm"
    start = support.one_robot(path)
    q = support.displaced(start.model, start.q, seed=4)

    def build(robot):
        return engine.ManipulabilityTask(robot, engine.SigmaProxy(robot, ["theta2", "theta3"]), gain=2.0,
                                         joints=["theta1", "theta3", "d4"])

    # Rows on θ1, θ3, d4 (dofs 0, 2, 3): e = 0, J = I's rows, v = k0 ∂σ/∂q there, with
    # ∂σ/∂θ = sin θ cos θ on θ2 and θ3 (zero on θ1 and d4).
    gradient = np.array([0.0, np.sin(q[1]) * np.cos(q[1]), np.sin(q[2]) * np.cos(q[2]), 0.0])
    support.assert_rows(build(support.one_robot(path, q)), (np.zeros(3), np.eye(4)[[0, 2, 3]],
                                                            2.0 * gradient[[0, 2, 3]]))
    robots = support.worlds(path, n=4, seed=5)
    task = support.assert_each_world(robots, lambda robot, w: build(robot))
    sigma = task.measure.value()
    np.testing.assert_allclose(sigma, 0.5 * (np.sin(robots.q[:, 1]) ** 2 + np.sin(robots.q[:, 2]) ** 2), rtol=1e-15)
    gradient = task.measure.gradient()
    np.testing.assert_allclose(gradient[:, 1:3], np.sin(robots.q[:, 1:3]) * np.cos(robots.q[:, 1:3]), rtol=0,
                               atol=1e-16)
    np.testing.assert_array_equal(gradient[:, [0, 3]], 0.0)


class Extension:
    """A user's measure (the ManipulabilityMeasure protocol): m = ½‖p‖², a site's squared
    distance from the world origin, ∂m/∂q = pᵀJ_p, written over the world axis."""

    label = "extension"

    def __init__(self, robot, site: str):
        self.robot, self.frame = robot, robot.frame(site)
        self._jacobian, self._gradient = np.zeros((robot.n, 3, robot.nv)), np.zeros((robot.n, robot.nv))

    def value(self, robot=None):
        robot = robot or self.robot
        positions = robot.frame(self.frame.name).positions
        return robot.present(0.5 * np.einsum("ni,ni->n", positions, positions))

    def gradient(self) -> np.ndarray:
        self.frame.jacobians(self._jacobian)
        np.matmul(self.frame.positions[:, None, :], self._jacobian, self._gradient[:, None, :])
        return self._gradient


def test_a_users_measure_on_one_robot_and_on_four_worlds(jaco_path):
    """A measure written by a user drives the task: on one robot its rows are k0 ∂m/∂q on
    the task's dofs (MuJoCo's site position and Jacobian), on 4 worlds each world is its
    own one-world run."""
    start = support.one_robot(jaco_path)
    q = support.displaced(start.model, start.q, seed=8)

    def build(robot):
        return engine.ManipulabilityTask(robot, Extension(robot, "wristsite"), gain=2.0, weight=0.5)

    p, _, Jp, _ = references.frame_state(start.model, q, "wristsite")
    support.assert_rows(build(support.one_robot(jaco_path, q)), (np.zeros(start.nv), np.eye(start.nv),
                                                                   2.0 * p @ Jp))
    robots = support.worlds(jaco_path, n=4, seed=9)
    task = support.assert_each_world(robots, lambda robot, w: build(robot))
    assert task.measure.value().shape == (4,)


def test_an_overflowing_gradient_is_a_divergence_error():
    """Once JJᵀ overflows the measure raises (no RuntimeWarning: the suite runs with
    warnings as errors); a long but finite extension still gives a finite gradient, in
    every world. A configuration is refused past 1e10 (where MuJoCo resets one), so the
    overflow comes from a site 1e200 out on one robot."""
    model = mujoco.MjModel.from_xml_string(SLIDE)
    robots = support.worlds(model, n=4)
    robots.q[:] = [[0.3, 1e3], [0.1, 1e6], [0.2, 1e9], [0.4, 1.0]]
    robots.update_kinematics()
    task = engine.ManipulabilityTask(robots, engine.Yoshikawa(robots, "tip", axes="xy"))
    task.update()
    assert np.all(np.isfinite(task.target_velocity)) and np.all(np.abs(task.target_velocity).max(axis=1) > 0)
    with pytest.raises(InvalidInput, match=r"beyond 1e\+10"):
        support.one_robot(model, [0.3, 1e200])
    robot = support.one_robot(mujoco.MjModel.from_xml_string(SLIDE.replace('pos="0.5 0 0"', 'pos="1e200 0 0"')), [0.3, 1.0])
    task = engine.ManipulabilityTask(robot, engine.Yoshikawa(robot, "tip", axes="xy"))
    with pytest.raises(DivergenceError, match="overflowed"):
        task.update()


def test_bad_input_is_a_typed_error(jaco_path):
    robots = support.worlds(jaco_path, n=2)
    with pytest.raises(InvalidInput, match="at least one row"):
        engine.Yoshikawa(robots, "wristsite", axes="", orientation_axes="")
    with pytest.raises(InvalidInput, match="xyz"):
        engine.Yoshikawa(robots, "wristsite", axes="xw")
    with pytest.raises(UnknownName, match="wristsite"):
        engine.Yoshikawa(robots, "wristsit")
    with pytest.raises(UnknownName, match="theta2"):
        engine.SigmaProxy(robots, ["theta2", "theta3"])
    with pytest.raises(InvalidInput, match="list"):
        engine.SigmaProxy(robots, "joint_2")
    with pytest.raises(InvalidInput, match="ball or free"):
        engine.SigmaProxy(support.one_robot(mujoco.MjModel.from_xml_string(core.MIXED)), ["shoulder"])
    with pytest.raises(InvalidInput, match="gain"):
        engine.ManipulabilityTask(robots, engine.SigmaProxy(robots, ["joint_2"]), gain=-1.0)
