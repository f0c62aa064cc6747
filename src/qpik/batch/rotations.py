"""MuJoCo's quaternion routines across worlds (leading axis N), as the serial tasks call them.

Each function is the vectorised form of one MuJoCo routine (named in its docstring), with
the same branches, so that a batched task's rotation error equals the serial task's to
rounding (tests/batch/test_batch_rotations.py compares them with MuJoCo's).
"""

from __future__ import annotations

import numpy as np

MINVAL = 1e-15  # mjMINVAL


# mju_mat2Quat's four branches, by the largest component: (that component, the signs of
# m0, m4, m8 under its square root), then for each other component (index, a, b, sign):
# 0.25 (m[a] + sign m[b]) / the largest.
_MAT2QUAT = (
    ((0, 1.0, 1.0, 1.0), ((1, 7, 5, -1), (2, 2, 6, -1), (3, 3, 1, -1))),
    ((1, 1.0, -1.0, -1.0), ((0, 7, 5, -1), (2, 1, 3, 1), (3, 2, 6, 1))),
    ((2, -1.0, 1.0, -1.0), ((0, 2, 6, -1), (1, 1, 3, 1), (3, 5, 7, 1))),
    ((3, -1.0, -1.0, 1.0), ((0, 3, 1, -1), (1, 2, 6, 1), (2, 5, 7, 1))),
)


def mat2quat(R: np.ndarray) -> np.ndarray:
    """``mju_mat2Quat``: unit quaternions (N, 4), w-x-y-z, of rotation matrices (N, 3, 3)."""
    m = R.reshape(-1, 9)
    q = np.empty((len(m), 4))
    trace = m[:, 0] + m[:, 4] + m[:, 8]
    first = trace > 0
    if first.all():  # the usual case, without selecting rows
        branch = None
    else:
        branch = np.select([first, (m[:, 0] > m[:, 4]) & (m[:, 0] > m[:, 8]), m[:, 4] > m[:, 8]], [0, 1, 2], default=3)
    with np.errstate(divide="ignore", invalid="ignore"):
        for k, (lead, others) in enumerate(_MAT2QUAT):
            if branch is None:
                if k:
                    break
                mk, out, rows = m, q, None
            else:
                rows = branch == k
                if not rows.any():
                    continue
                mk, out = m[rows], np.empty((int(rows.sum()), 4))
            index, s0, s4, s8 = lead
            main = 0.5 * np.sqrt(1.0 + s0 * mk[:, 0] + s4 * mk[:, 4] + s8 * mk[:, 8])
            out[:, index] = main
            for target, a, bb, sign in others:
                out[:, target] = 0.25 * (mk[:, a] + sign * mk[:, bb]) / main
            if rows is not None:
                q[rows] = out
    return normalize4(q)


def normalize4(q: np.ndarray) -> np.ndarray:
    """``mju_normalize4`` (a quaternion of norm < mjMINVAL becomes the identity)."""
    norm = np.sqrt(np.einsum("ni,ni->n", q, q))
    small = norm < MINVAL
    out = q / np.where(small, 1.0, norm)[:, None]
    out[small] = (1.0, 0.0, 0.0, 0.0)
    return out


def mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``mju_mulQuat``."""
    shape = np.broadcast_shapes(a.shape, b.shape)
    (a0, a1, a2, a3), (b0, b1, b2, b3) = _components(a, shape), _components(b, shape)
    out = np.empty((4, shape[0]))  # worlds along the last axis: each line one pass
    out[0] = a0 * b0 - a1 * b1 - a2 * b2 - a3 * b3
    out[1] = a0 * b1 + a1 * b0 + a2 * b3 - a3 * b2
    out[2] = a0 * b2 - a1 * b3 + a2 * b0 + a3 * b1
    out[3] = a0 * b3 + a1 * b2 - a2 * b1 + a3 * b0
    return out.T


def _components(q: np.ndarray, shape: tuple) -> np.ndarray:
    """The four components of quaternions (N, 4) (or one, (1, 4)), each contiguous."""
    return np.ascontiguousarray(np.broadcast_to(q, shape).T)


def quat2vel(q: np.ndarray, dt: float = 1.0) -> np.ndarray:
    """``mju_quat2Vel``: the rotation vector (over dt) of unit quaternions."""
    w, axis = q[:, 0], np.ascontiguousarray(q[:, 1:].T)  # axis (3, N)
    sin_half = np.sqrt(axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2])
    small = sin_half < MINVAL
    axis /= np.where(small, 1.0, sin_half)
    if small.any():
        axis[:, small] = ((1.0,), (0.0,), (0.0,))
    speed = 2.0 * np.arctan2(sin_half, w)
    speed = np.where(speed > np.pi, speed - 2.0 * np.pi, speed)
    axis *= speed / dt
    return axis.T


def sub(qa: np.ndarray, qb: np.ndarray) -> np.ndarray:
    """``mju_subQuat``: v with qb * exp(v) = qa, in qb's frame."""
    conj = qb * np.array([1.0, -1.0, -1.0, -1.0])
    return quat2vel(mul(conj, qa))


def quat2mat(q: np.ndarray) -> np.ndarray:
    """``mju_quat2Mat`` (N, 4) -> (N, 3, 3)."""
    w, x, y, z = q.T
    ww, xx, yy, zz = w * w, x * x, y * y, z * z
    R = np.empty((len(q), 3, 3))
    R[:, 0, 0] = ww + xx - yy - zz
    R[:, 1, 1] = ww - xx + yy - zz
    R[:, 2, 2] = ww - xx - yy + zz
    R[:, 0, 1] = 2 * (x * y - w * z)
    R[:, 0, 2] = 2 * (x * z + w * y)
    R[:, 1, 0] = 2 * (x * y + w * z)
    R[:, 1, 2] = 2 * (y * z - w * x)
    R[:, 2, 0] = 2 * (x * z - w * y)
    R[:, 2, 1] = 2 * (y * z + w * x)
    return R


def rotation_error_local(desired: np.ndarray, current: np.ndarray, desired_quat: np.ndarray | None = None) -> np.ndarray:
    """e in the current frame's axes with R_current exp([e]) = R_desired (the serial
    ``RotationError.compute``); ``desired_quat``: ``mat2quat(desired)`` when known."""
    return sub(mat2quat(desired) if desired_quat is None else desired_quat, mat2quat(current))


def rotation_error_world(desired: np.ndarray, current: np.ndarray, desired_quat: np.ndarray | None = None) -> np.ndarray:
    """The same error in world axes (the serial ``RotationError.world``): R_current e."""
    return np.einsum("nij,nj->ni", current, rotation_error_local(desired, current, desired_quat))
