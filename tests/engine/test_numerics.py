"""The engine's primitives: each N = 1 fast path (MuJoCo's or LAPACK's call) against the
N > 1 path across worlds and against an independent reference (NumPy's LAPACK, SciPy's
rotations, MuJoCo's own functions)."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from qpik import numerics
from qpik.robot import Robot

EPS = np.finfo(float).eps


def _spd(rng, n: int, k: int) -> np.ndarray:
    J = rng.normal(size=(n, k + 2, k))
    return J.transpose(0, 2, 1) @ J + 1e-2 * np.eye(k)


@pytest.mark.parametrize("local", [False, True])
def test_rotation_error_at_one_world_and_many_equals_scipy(local):
    desired = Rotation.random(16, random_state=1).as_matrix()
    current = Rotation.random(16, random_state=2).as_matrix()
    many = numerics.rotation_error(desired, current, local)
    ones = np.vstack([numerics.rotation_error(desired[i:i + 1], current[i:i + 1], local) for i in range(16)])
    relative = Rotation.from_matrix(current).inv() * Rotation.from_matrix(desired) if local else \
        Rotation.from_matrix(desired) * Rotation.from_matrix(current).inv()
    expected = relative.as_rotvec()
    assert np.abs(many - expected).max() <= 1e-13  # angles of O(1) rad, a few roundings
    assert np.abs(ones - many).max() <= 1e-13


def test_quaternion_routines_equal_mujoco():
    rng = np.random.default_rng(3)
    qa, qb = Rotation.random(8, random_state=4).as_quat()[:, [3, 0, 1, 2]], Rotation.random(8, random_state=5).as_quat()[:, [3, 0, 1, 2]]
    for i in range(8):
        mul, mat, quat = np.empty(4), np.empty(9), np.empty(4)
        mujoco.mju_mulQuat(mul, qa[i], qb[i])
        mujoco.mju_quat2Mat(mat, qa[i])
        mujoco.mju_mat2Quat(quat, mat)
        assert np.abs(numerics.mul(qa[i:i + 1], qb[i:i + 1])[0] - mul).max() <= 1e-15
        assert np.abs(numerics.quat2mat(qa[i:i + 1])[0].ravel() - mat).max() <= 1e-15
        assert np.abs(numerics.mat2quat(mat.reshape(1, 3, 3))[0] - quat).max() <= 1e-15
    del rng


def test_configuration_difference_equals_mj_differentiate_pos(humanoid_path):
    robot = Robot.load(humanoid_path)
    model, rng = robot.model, np.random.default_rng(6)
    q1 = np.tile(robot.q, (4, 1))
    q2 = q1.copy()
    for q in (q1, q2):
        for w in range(4):
            mujoco.mj_integratePos(model, q[w], rng.normal(size=model.nv), 0.3)
    many = numerics.ConfigurationDifference(model, 4)(q1, q2, np.empty((4, model.nv)))
    for w in range(4):
        expected = np.empty(model.nv)
        mujoco.mj_differentiatePos(model, expected, 1.0, q1[w], q2[w])
        one = numerics.ConfigurationDifference(model, 1)(q1[w:w + 1], q2[w:w + 1], np.empty((1, model.nv)))
        assert np.abs(many[w] - expected).max() <= 1e-14 and np.abs(one[0] - expected).max() == 0.0


def test_all_finite_and_the_shared_flags():
    assert numerics.all_finite(np.ones((1, 4))) and not numerics.all_finite(np.array([[1.0, np.nan]]))
    assert not numerics.all_finite(np.full((100, 3), np.inf)) and numerics.all_finite(np.ones((3, 100))[:, ::2])
    everywhere = numerics.everywhere(3)
    assert numerics.both(everywhere, everywhere) is everywhere
    assert numerics.both(everywhere, np.array([True, False, True])).tolist() == [True, False, True]
    with pytest.raises(ValueError):
        everywhere[0] = False  # shared: read-only


@pytest.mark.parametrize("n", [1, 5])
@pytest.mark.parametrize("m, k, p", [(2, 4, 3), (3, 7, 5), (6, 7, 6), (1, 1, 1)])
def test_products_of_every_worlds_matrices_equal_numpy_world_by_world(n, m, k, p):
    """matvec (A x), vecmat (Aᵀ y) and outer_product (A Bᵀ, through the worlds-last path
    when m·p <= 16 and through matmul above) against NumPy's 2-D products of each world:
    sums of k products of O(1) numbers in another order, 1e-14 of their scale."""
    rng = np.random.default_rng(n * 100 + m * 10 + p)
    A, B = rng.normal(size=(n, m, k)), rng.normal(size=(n, p, k))
    x, y = rng.normal(size=(n, k)), rng.normal(size=(n, m))
    results = (numerics.matvec(A, x, np.empty((n, m))), numerics.vecmat(y, A, np.empty((n, k))),
               numerics.outer_product(A, B, np.empty((n, m, p))))
    for w in range(n):
        for result, expected in zip(results, (A[w] @ x[w], y[w] @ A[w], A[w] @ B[w].T)):
            np.testing.assert_allclose(result[w], expected, rtol=0, atol=1e-14 * k)
