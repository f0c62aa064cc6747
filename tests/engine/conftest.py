"""Fixtures of the engine's tests: small generated models, norm-wise comparisons, and a
controller's rollout checked step by step against an independent solve of its QP."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import mujoco
import numpy as np
import pytest

_spec = importlib.util.spec_from_file_location("references", Path(__file__).with_name("references.py"))
references = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(references)


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
    """``lockstep(robot, controller, steps, dt, before=None, after=None, box=None, rel=1e-9,
    regularization=1e-12, every=1)``: the QP controller of one robot rolls out (integrating its own
    answers); at every step its answer must equal the minimiser of the same QP solved
    independently (:mod:`references`: the cost and hard rows written out from the tasks'
    rows, DAQP called directly, the active set solved exactly) to ``rel`` of its norm, or
    of 1e-3 (a slow joint's speed) for an answer at rest (the issue's figure: 1e-9). The
    box and general rows are the limits' own, applied into fresh arrays
    (:func:`references.limits_box`), or ``box(k)`` -> (lower, upper) given by the test
    (a limit with memory). ``before(k)`` sets the step's targets, ``after(k, qdot)`` checks
    what the step did (after integrating). ``every``: check every so many steps (a long
    rollout whose steps are all alike).

    Returns:
        The answers, (steps, nv).
    """

    def run(robot, controller, steps: int, dt: float, before=None, after=None, box=None, rel: float = 1e-9,
            regularization: float = 1e-12, every: int = 1) -> np.ndarray:
        answers = []
        for k in range(steps):
            if before is not None:
                before(k)
            actual = np.array(controller.compute_velocity())
            if k % every:
                answers.append(actual)
                robot.integrate(actual, dt)
                if after is not None:
                    after(k, actual)
                continue
            if box is None:
                lower, upper, G, h = references.limits_box(controller.limits, dt, 1, robot.nv)
                bounds, rows = (lower[0], upper[0]), (G[0], h[0])
            else:
                bounds, rows = box(k), (None, None)
            expected = references.qp_answer(controller.tasks, 0, robot.nv, bounds, rows, regularization)
            assert references.close(actual, expected, rel), (k, actual, expected)
            answers.append(actual)
            robot.integrate(actual, dt)
            if after is not None:
                after(k, actual)
        return np.array(answers)

    return run
