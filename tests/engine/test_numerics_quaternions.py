"""The engine's quaternion primitives (qpik.numerics) against MuJoCo's own routines,
world by world, on rotations that take every branch of mju_mat2Quat: what the tasks'
rotation errors and the CPU back-end's geom poses and integration are made of."""

import mujoco
import numpy as np

from qpik import numerics

# Unit quaternions and rotations of entries <= 1: MuJoCo's and the vectorised arithmetic
# differ by a few roundings of O(1) numbers.
ROUNDING = 1e-15


def _rotations(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    quats = rng.normal(size=(n, 4))
    quats /= np.linalg.norm(quats, axis=1, keepdims=True)
    # the identity and half turns about each axis: each branch, and its edges
    quats[:4] = [(1.0, 0.0, 0.0, 0.0), (0.0, 1.0, 0.0, 0.0), (0.0, 0.0, 1.0, 0.0), (0.0, 0.0, 0.0, 1.0)]
    return numerics.quat2mat(quats)


def _mujoco(function, *arrays, size, extra=()):
    out = np.empty((len(arrays[0]), size))
    for i in range(len(out)):
        function(out[i], *(np.ascontiguousarray(a[i]).ravel() for a in arrays), *extra)
    return out


def test_mat2quat_equals_mujoco_in_every_branch_and_when_all_worlds_share_one():
    R = _rotations(400, 0)
    trace = R[:, 0, 0] + R[:, 1, 1] + R[:, 2, 2]
    assert (trace > 0).any() and (trace <= 0).sum() > 100  # every branch is taken
    for batch in (R, R[trace > 0]):  # mixed branches; the first branch alone
        np.testing.assert_allclose(numerics.mat2quat(batch), _mujoco(mujoco.mju_mat2Quat, batch, size=4),
                                   rtol=0, atol=ROUNDING)


def test_quaternion_routines_equal_mujoco():
    qa = numerics.mat2quat(_rotations(200, 1))
    qb = numerics.mat2quat(_rotations(200, 2))
    np.testing.assert_allclose(numerics.mul(qa, qb), _mujoco(mujoco.mju_mulQuat, qa, qb, size=4), rtol=0,
                               atol=ROUNDING)
    np.testing.assert_allclose(numerics.quat2mat(qa).reshape(-1, 9), _mujoco(mujoco.mju_quat2Mat, qa, size=9),
                               rtol=0, atol=ROUNDING)
    # rotation vectors of angles up to π: a few roundings of π
    np.testing.assert_allclose(numerics.quat2vel(qa), _mujoco(mujoco.mju_quat2Vel, qa, size=3, extra=(1.0,)),
                               rtol=0, atol=10 * ROUNDING)


def test_normalize4_and_quat_integrate_equal_mujoco_with_its_small_branches():
    rng = np.random.default_rng(3)
    raw = rng.normal(size=(50, 4)) * rng.uniform(0.5, 2.0, (50, 1))
    raw[0] = 0.0  # below mjMINVAL: the identity
    expected = raw.copy()
    for q in expected:
        mujoco.mju_normalize4(q)
    np.testing.assert_allclose(numerics.normalize4(raw), expected, rtol=0, atol=ROUNDING)
    quats = numerics.normalize4(rng.normal(size=(50, 4)))
    velocity = rng.normal(size=(50, 3))
    velocity[0] = 0.0  # no rotation
    velocity[1] = 1e-17  # below mjMINVAL: no rotation either
    for scale in (0.002, 0.7):
        expected = quats.copy()
        for q, v in zip(expected, velocity):
            mujoco.mju_quatIntegrate(q, v, scale)
            mujoco.mju_normalize4(q)  # as mj_integratePos
        np.testing.assert_allclose(numerics.quat_integrate(quats, velocity, scale), expected, rtol=0,
                                   atol=ROUNDING)
