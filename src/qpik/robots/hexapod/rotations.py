"""The few rotation conversions the hexapod's kinematics need, with MuJoCo's quaternion
functions and NumPy (no SciPy in a QP step).

Conventions: a rotation vector is axis × angle (rad), MuJoCo's quaternions are w-x-y-z,
and roll-pitch-yaw ``[θx, θy, θz]`` means R = Rz(θz) Ry(θy) Rx(θx) (fixed axes x, y, z).
"""

from __future__ import annotations

import math

import mujoco
import numpy as np


def matrix_from_rotvec(rotvec) -> np.ndarray:
    """exp([v]×), by Rodrigues' formula: R = I + sin θ K + (1 − cos θ) K², K = [v/θ]×."""
    v = np.asarray(rotvec, dtype=float)
    angle = math.sqrt(float(v @ v))
    if angle == 0.0:
        return np.eye(3)
    x, y, z = v / angle
    K = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * (K @ K)


def matrices_from_rotvecs(rotvecs) -> np.ndarray:
    """:func:`matrix_from_rotvec` of each row, stacked (n, 3, 3)."""
    return np.array([matrix_from_rotvec(v) for v in np.asarray(rotvecs, dtype=float)])


def quaternion_from_matrix(R: np.ndarray) -> np.ndarray:
    """The unit quaternion (w-x-y-z) of R; a nearly orthogonal R gives the nearest rotation's."""
    quaternion = np.empty(4)
    mujoco.mju_mat2Quat(quaternion, np.ascontiguousarray(R, dtype=float).reshape(9))
    return quaternion


def rotvec_from_matrix(R: np.ndarray) -> np.ndarray:
    """log(R) as a rotation vector, angle in [0, π] (MuJoCo's quaternion to velocity over
    a unit time, accurate for small angles where arccos of the trace is not)."""
    rotvec = np.empty(3)
    mujoco.mju_quat2Vel(rotvec, quaternion_from_matrix(R), 1.0)
    return rotvec


def matrix_from_rpy(rpy_rad) -> np.ndarray:
    """R = Rz(θz) Ry(θy) Rx(θx) from ``[θx, θy, θz]`` in radians."""
    (cx, cy, cz), (sx, sy, sz) = np.cos(rpy_rad), np.sin(rpy_rad)
    return np.array([[cz * cy, cz * sy * sx - sz * cx, cz * sy * cx + sz * sx],
                     [sz * cy, sz * sy * sx + cz * cx, sz * sy * cx - cz * sx],
                     [-sy, cy * sx, cy * cx]])


def rpy_from_matrix(R: np.ndarray) -> np.ndarray:
    """Inverse of :func:`matrix_from_rpy`, in radians, θy in [−π/2, π/2] (a nearly
    orthogonal R is read as its nearest rotation). At θy = ±π/2 (gimbal lock) only
    θz ∓ θx is defined: θx is returned as 0."""
    rotation = np.empty(9)
    mujoco.mju_quat2Mat(rotation, quaternion_from_matrix(R))
    r = rotation.reshape(3, 3)
    pitch = math.atan2(-r[2, 0], math.hypot(r[2, 1], r[2, 2]))
    if math.hypot(r[2, 1], r[2, 2]) < 1e-12:  # gimbal lock
        return np.array([0.0, pitch, math.atan2(-r[0, 1], r[1, 1])])
    return np.array([math.atan2(r[2, 1], r[2, 2]), pitch, math.atan2(r[1, 0], r[0, 0])])
