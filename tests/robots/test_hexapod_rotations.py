"""The hexapod's rotation conversions (MuJoCo quaternions and NumPy) against SciPy's
Rotation, an independent implementation, on random rotations of every size: they agree
to 1e-12 (a few ulps of entries of order 1; the angles are well conditioned away from
gimbal lock and from π, which the draws avoid)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from qpik.robots.hexapod import rotations
from qpik.robots.hexapod.kinematics import rotation_from_rpy, rpy_from_rotation

TOLERANCE = 1e-12


def _rotvecs(seed, count=300):
    rng = np.random.default_rng(seed)
    for scale in (1e-10, 1e-5, 1e-2, 1.0, 2.5):
        for _ in range(count // 5):
            v = rng.normal(size=3) * scale
            yield v * min(1.0, 3.0 / np.linalg.norm(v))  # angles below π: a unique log


@pytest.mark.parametrize("seed", [0, 1])
def test_rotation_vectors_and_matrices_agree_with_scipy(seed):
    for v in _rotvecs(seed):
        R = Rotation.from_rotvec(v).as_matrix()
        np.testing.assert_allclose(rotations.matrix_from_rotvec(v), R, rtol=0, atol=TOLERANCE)
        np.testing.assert_allclose(rotations.rotvec_from_matrix(R), Rotation.from_matrix(R).as_rotvec(),
                                   rtol=0, atol=TOLERANCE)
        q = Rotation.from_matrix(R).as_quat(scalar_first=True)
        mine = rotations.quaternion_from_matrix(R)
        np.testing.assert_allclose(mine * np.sign(mine @ q), q, rtol=0, atol=TOLERANCE)
    np.testing.assert_array_equal(rotations.matrix_from_rotvec(np.zeros(3)), np.eye(3))


@pytest.mark.parametrize("seed", [0, 1])
def test_roll_pitch_yaw_agree_with_scipy(seed):
    rng = np.random.default_rng(seed)
    for _ in range(300):
        rpy = np.concatenate([rng.uniform(-3.1, 3.1, 1), rng.uniform(-1.5, 1.5, 1), rng.uniform(-3.1, 3.1, 1)])
        R = Rotation.from_euler("xyz", rpy).as_matrix()
        np.testing.assert_allclose(rotations.matrix_from_rpy(rpy), R, rtol=0, atol=TOLERANCE)
        np.testing.assert_allclose(rotations.rpy_from_matrix(R), Rotation.from_matrix(R).as_euler("xyz"),
                                   rtol=0, atol=TOLERANCE)
        degrees = np.degrees(rpy)
        np.testing.assert_allclose(rotation_from_rpy(degrees), R, rtol=0, atol=TOLERANCE)
        np.testing.assert_allclose(rpy_from_rotation(R), degrees, rtol=0, atol=TOLERANCE * 180 / np.pi)


def test_gimbal_lock_keeps_the_rotation():
    """At θy = ±90° only θz ∓ θx is defined: the angles returned rebuild the same R."""
    for pitch in (np.pi / 2, -np.pi / 2):
        R = rotations.matrix_from_rpy([0.3, pitch, -0.7])
        np.testing.assert_allclose(rotations.matrix_from_rpy(rotations.rpy_from_matrix(R)), R, rtol=0,
                                   atol=1e-8)
