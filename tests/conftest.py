"""Shared fixtures: the third-party test models, read from the installed PyPI packages
(dm_control, gymnasium; the ``test`` extra) and never copied into the repository; a
finite-difference Jacobian for the tasks' derivative tests; a subprocess runner in which
chosen packages cannot be imported (the extras' tests)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import mujoco
import numpy as np
import pytest
from hypothesis import settings

from qpik.errors import ModelError
from qpik.models import pusher_arm, third_party

# The property tests draw the same examples on every run and machine: a CI run fails only
# where the code changed, never on a draw no earlier run made (the fuzz benchmarks explore).
settings.register_profile("qpik", derandomize=True)
settings.load_profile("qpik")


def third_party_path(name: str) -> Path:
    """The installed MJCF of a third-party model (:func:`qpik.models.third_party`), or a
    skip saying what is missing."""
    try:
        return third_party(name)
    except ModelError as exc:
        pytest.skip(str(exc))


@pytest.fixture(scope="session")
def jaco_path() -> Path:
    return third_party_path("jaco")


@pytest.fixture(scope="session")
def humanoid_path() -> Path:
    return third_party_path("humanoid")


@pytest.fixture(scope="session")
def pusher_path() -> Path:
    return third_party_path("pusher")


@pytest.fixture(scope="module")
def pusher_model() -> mujoco.MjModel:
    """gymnasium's pusher arm without its puck and goal (``qpik.models.pusher_arm``), or a skip."""
    try:
        return pusher_arm()
    except ModelError as exc:
        pytest.skip(str(exc))


@pytest.fixture(scope="session")
def model_path():
    """``model_path(name)``: a bundled robot's name as is, a third-party model's path."""

    def get(name: str) -> str:
        return name if name in ("arm", "hexapod") else str(third_party_path(name))

    return get


@pytest.fixture(scope="session")
def finite_difference_jacobian():
    """``finite_difference_jacobian(robot, measure, eps=1e-6)``: central differences of
    ``measure(robot)`` along each dof (q ⊕ ±eps e_i), the robot left at its start."""

    def jacobian(robot, measure, eps=1e-6):
        q0 = robot.q.copy()
        columns = []
        for i in range(robot.nv):
            values = []
            for sign in (1.0, -1.0):
                step = np.zeros(robot.nv)
                step[i] = sign * eps
                q = q0.copy()
                mujoco.mj_integratePos(robot.model, q, step, 1.0)
                robot.set_q(q)
                robot.update_kinematics()
                values.append(np.atleast_1d(np.asarray(measure(robot), dtype=float)))
            columns.append((values[0] - values[1]) / (2 * eps))
        robot.set_q(q0)
        robot.update_kinematics()
        return np.array(columns).T

    return jacobian


# Prepended to a subprocess's code: the modules named are not found, as if not installed.
_HIDE = """\
import importlib.machinery, sys
HIDDEN = {hidden!r}
class Hide(importlib.machinery.PathFinder):
    @classmethod
    def find_spec(cls, name, path=None, target=None):
        return None if name.split(".")[0] in HIDDEN else super().find_spec(name, path, target)
sys.meta_path[:] = [Hide if finder is importlib.machinery.PathFinder else finder for finder in sys.meta_path]
"""


@pytest.fixture(scope="session")
def run_without_modules():
    """``run_without_modules(code, hidden, timeout=None)``: ``code`` run in a new Python
    process in which the top-level packages ``hidden`` cannot be imported."""

    def run(code: str, hidden: tuple[str, ...], timeout: float | None = None) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-c", _HIDE.format(hidden=hidden) + code], capture_output=True,
                              text=True, timeout=timeout)

    return run
