"""Fixtures of the engine's tests: small generated models and the comparisons every
engine class makes against the serial class it replaces."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest


@pytest.fixture(scope="session")
def chain_model():
    """``chain_model(n=6, free_base=False)``: an n-hinge spatial chain (axes z, y, x in
    turn, links 0.2 m, ranges ±3 rad) with a site ``tip`` at its end, optionally on a
    free-floating base body ``base`` (joint ``root``)."""

    def build(n: int = 6, free_base: bool = False) -> mujoco.MjModel:
        bodies, closing = "", ""
        for i in range(n):
            axis = ("0 0 1", "0 1 0", "1 0 0")[i % 3]
            bodies += (f'<body name="b{i}" pos="0 0 0.2"><joint name="j{i}" axis="{axis}" range="-3 3"/>'
                       f'<geom type="capsule" size="0.02" fromto="0 0 0 0 0 0.2" mass="{2.0 / (i + 1):g}"/>')
            closing += "</body>"
        chain = f'{bodies}<site name="tip" pos="0 0 0.2"/>{closing}'
        if free_base:
            chain = (f'<body name="base"><freejoint name="root"/><geom type="box" size="0.1 0.1 0.05" mass="5"/>'
                     f'{chain}</body>')
        return mujoco.MjModel.from_xml_string(f'<mujoco><compiler angle="radian"/><worldbody>{chain}</worldbody>'
                                              '</mujoco>')

    return build


@pytest.fixture(scope="session")
def assert_same():
    """``assert_same(actual, expected, rel=1e-10)``: ‖actual − expected‖ ≤ rel·‖expected‖
    (Frobenius norms; entries ±inf must match exactly, and are left out of the norms)."""

    def check(actual, expected, rel: float = 1e-10) -> None:
        actual, expected = np.asarray(actual, dtype=float), np.asarray(expected, dtype=float)
        assert actual.shape == expected.shape
        infinite = np.isinf(expected)
        np.testing.assert_array_equal(actual[infinite], expected[infinite])
        difference = np.linalg.norm(actual[~infinite] - expected[~infinite])
        assert difference <= rel * max(np.linalg.norm(expected[~infinite]), 1e-300), (difference, actual, expected)

    return check


@pytest.fixture(scope="session")
def lockstep():
    """``lockstep(serial, engine, steps, dt, before=None, rel=1e-10)``: the serial
    controller rolls out (integrating its answers); at every step the engine's one-world
    robot is put at the serial robot's configuration and its controller answers the same
    problem, which must equal the serial answer to ``rel`` of its norm, or of 1e-3 (a
    slow joint's speed) for an answer at rest (a rollout of its
    own could part from the serial one by more: a bound that switches, the damper's
    influence, turns a rounding difference in q into a different step). ``serial`` and
    ``engine`` are (robot, controller); ``before(k)`` sets the step's targets.

    Returns:
        The serial answers, (steps, nv).
    """

    def run(serial, engine, steps: int, dt: float, before=None, rel: float = 1e-10) -> np.ndarray:
        (serial_robot, serial_controller), (engine_robot, engine_controller) = serial, engine
        answers = []
        for k in range(steps):
            if before is not None:
                before(k)
            engine_robot.q[:] = serial_robot.q
            expected = np.array(serial_controller.compute_velocity())
            actual = np.array(engine_controller.compute_velocity())
            assert np.linalg.norm(actual - expected) <= rel * max(np.linalg.norm(expected), 1e-3), (k, actual, expected)
            answers.append(expected)
            serial_robot.integrate(expected, dt)
        return np.array(answers)

    return run
