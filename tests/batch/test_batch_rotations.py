"""qpik.batch.rotations against MuJoCo's own quaternion routines, world by world, on
rotations that take every branch of mju_mat2Quat."""

import mujoco
import numpy as np

from qpik.batch import rotations


def _rotations(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    quats = rng.normal(size=(n, 4))
    quats /= np.linalg.norm(quats, axis=1, keepdims=True)
    # near the identity and near half turns about each axis: each branch, and its edges
    quats[:4] = [(1.0, 0.0, 0.0, 0.0), (0.0, 1.0, 0.0, 0.0), (0.0, 0.0, 1.0, 0.0), (0.0, 0.0, 0.0, 1.0)]
    return rotations.quat2mat(quats)


def _mujoco(function, *arrays, size):
    out = np.empty((len(arrays[0]), size))
    for i in range(len(out)):
        function(out[i], *(np.ascontiguousarray(a[i]).ravel() for a in arrays))
    return out


def test_mat2quat_equals_mujoco_in_every_branch_and_when_all_worlds_share_one():
    R = _rotations(400, 0)
    trace = R[:, 0, 0] + R[:, 1, 1] + R[:, 2, 2]
    assert (trace > 0).any() and (trace <= 0).sum() > 100  # every branch is taken
    for batch in (R, R[trace > 0]):  # mixed branches; the first branch alone
        np.testing.assert_allclose(rotations.mat2quat(batch), _mujoco(mujoco.mju_mat2Quat, batch, size=4),
                                   rtol=0, atol=1e-15)


def test_quaternion_routines_equal_mujoco():
    qa = rotations.mat2quat(_rotations(200, 1))
    qb = rotations.mat2quat(_rotations(200, 2))
    np.testing.assert_allclose(rotations.mul(qa, qb), _mujoco(mujoco.mju_mulQuat, qa, qb, size=4), rtol=0, atol=1e-15)
    np.testing.assert_allclose(rotations.sub(qa, qb), _mujoco(mujoco.mju_subQuat, qa, qb, size=3), rtol=0, atol=1e-14)
    np.testing.assert_allclose(rotations.quat2mat(qa).reshape(-1, 9), _mujoco(mujoco.mju_quat2Mat, qa, size=9),
                               rtol=0, atol=1e-15)
