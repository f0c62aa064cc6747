"""Shared fixtures: the third-party test models, read from the installed PyPI packages
(dm_control, gymnasium; the ``test`` extra) and never copied into the repository, and a
finite-difference Jacobian for the tasks' derivative tests."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest

from qpik.errors import ModelError
from qpik.models import third_party


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
