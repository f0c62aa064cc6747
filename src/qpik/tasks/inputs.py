"""What tasks and limits accept from their users, checked once, with errors that name the
culprit: masks, gains, weights, rotations, targets (one for every world, or one per world).

A target is written every step, so its check is cheap: the norm of its entries, one
``math.hypot`` call for one world, one pass for N (NaN, inf and anything beyond
:data:`TARGET_MAGNITUDE_LIMIT` fail one comparison); for N worlds past it, the entries are
checked one by one and the culprit worlds named (:class:`~qpik.errors.InvalidWorlds`).
"""

from __future__ import annotations

import math
from typing import Sequence

import mujoco
import numpy as np

from ..errors import InvalidInput, InvalidWorlds, listed
from ..numerics import norm
from ..robot import as_floats, as_index  # noqa: F401 (the tasks' inputs too)

_AXES = "xyz"
AXES_FRAMES = ("world", "local")
# A target (or feed-forward velocity) entry beyond this is refused: no model is that large,
# and it keeps K·e, its square and J q̇ − v finite for any gain with K·Δt <= 2 and Δt > 1e-150.
TARGET_MAGNITUDE_LIMIT = 1e150
# Weights, gains, distances and rates beyond this are refused: no cost or robot is that
# large, and it keeps a cost's Hessian (w JᵀJ) and a limit's bounds finite.
PARAMETER_LIMIT = 1e12


def axis_rows(axes: str, what: str = "axes") -> np.ndarray:
    """Row indices of a mask such as ``"xy"`` (a non-empty subset of ``"xyz"``)."""
    if not isinstance(axes, str) or not axes or any(a not in _AXES for a in axes) or len(set(axes)) != len(axes):
        raise InvalidInput(f"{what} must be a non-empty subset of 'xyz', got {axes!r}")
    return np.array(sorted(_AXES.index(a) for a in axes), dtype=int)


def optional_rows(axes: str, what: str) -> np.ndarray:
    """:func:`axis_rows`, ``""`` allowed (no row)."""
    return axis_rows(axes, what) if axes != "" else np.zeros(0, dtype=int)


def check_axes_frame(axes_frame: str) -> bool:
    """Whether masks, gains and weights refer to the frame's own axes (``"local"``) or the
    world's (``"world"``); InvalidInput otherwise."""
    if axes_frame not in AXES_FRAMES:
        raise InvalidInput(f"axes_frame must be one of {AXES_FRAMES}, got {axes_frame!r}")
    return axes_frame == "local"


def float_array(value, shape: int | tuple, what: str) -> np.ndarray:
    """``value`` as a float array of ``shape`` (its entries not checked), or InvalidInput."""
    shape = (shape,) if isinstance(shape, int) else tuple(shape)
    arr = as_floats(value, what)
    if arr.shape != shape:
        raise InvalidInput(f"{what} must have shape {shape}, got {arr.shape}")
    return arr


def finite_vector(value, size: int, what: str) -> np.ndarray:
    """``value`` as a float array of shape (size,) with finite entries, or InvalidInput."""
    arr = float_array(value, size, what)
    if not math.isfinite(sum(arr.tolist())):
        raise InvalidInput(f"{what} contains NaN or inf (or overflows): {arr}")
    return arr


def world_values(robot, value, shape: tuple, what: str) -> np.ndarray:
    """``value`` as (N, *shape) floats: one value for every world, or (for N worlds) one per
    world, each finite and within :data:`TARGET_MAGNITUDE_LIMIT`.

    Raises:
        InvalidInput: a wrong shape, or (one world) a bad entry.
        InvalidWorlds: (N worlds) the worlds whose value is not finite or too large.
    """
    if not robot.batched:
        arr = as_floats(value, what)
        if arr.shape != shape:
            raise InvalidInput(f"{what} must have shape {shape}, got {arr.shape}")
        if math.hypot(*(arr.tolist() if arr.ndim == 1 else arr.ravel().tolist())) <= TARGET_MAGNITUDE_LIMIT:
            return arr[None]
        if not np.isfinite(arr).all():
            raise InvalidInput(f"{what} contains NaN or inf: {arr}")
        raise InvalidInput(f"{what} {arr} is beyond {TARGET_MAGNITUDE_LIMIT:g} in magnitude: the feedback K·e (and its "
                           "square) would overflow; give a target the robot could reach")
    arr = as_floats(value, what)
    one = arr.shape == shape
    if not one and arr.shape != (robot.n,) + shape:
        raise InvalidInput(f"{what} must have shape {shape} or {(robot.n,) + shape}, got {arr.shape}")
    arr = np.ascontiguousarray(arr)  # a strided view copied once: the check and the caller's copy read it
    if norm(arr) <= TARGET_MAGNITUDE_LIMIT:  # the usual call: one pass (NaN, inf and overflow fail it)
        return np.broadcast_to(arr, (robot.n,) + shape) if one else arr
    worlds = np.broadcast_to(arr, (robot.n,) + shape)
    magnitude = np.abs(worlds).reshape(robot.n, -1).max(axis=1, initial=0.0)
    bad = np.flatnonzero(~(magnitude <= TARGET_MAGNITUDE_LIMIT))
    if not len(bad):  # every entry within the limit, their squares' sum past it
        return worlds
    raise InvalidWorlds(f"{what} of worlds {listed(bad)}: NaN, inf or beyond {TARGET_MAGNITUDE_LIMIT:g}", bad)


def rotation_matrix(rotation, what: str = "target rotation") -> np.ndarray:
    """``rotation`` (a 3x3 matrix, or a w-x-y-z unit quaternion, converted by
    ``mju_quat2Mat``) as a checked (3, 3) float rotation: orthonormal to 1e-6 (the norm
    of RᵀR − I's six distinct entries), no reflection, a quaternion of unit norm to 1e-6.
    Checked in floats: a step's target costs a few NumPy calls less so.

    Raises:
        InvalidInput: not a finite 3x3 matrix or (4,) quaternion, or not a rotation.
    """
    try:
        rot = np.asarray(rotation, dtype=float)
    except (TypeError, ValueError):
        raise InvalidInput(f"{what} must be a 3x3 matrix or a w-x-y-z quaternion of numbers, got {rotation!r}") from None
    if rot.shape == (4,):
        rot = _quaternion_matrix(rot, what)
    elif rot.shape != (3, 3):
        raise InvalidInput(f"{what} must be a 3x3 matrix or a (4,) w-x-y-z quaternion, got shape {rot.shape}")
    gram, det = _orthonormality(rot.ravel().tolist())
    if not math.hypot(*gram) <= 1e-6:  # NaN and inf fail too
        if not math.isfinite(sum(gram)):
            raise InvalidInput(f"{what} contains NaN or inf")
        raise InvalidInput(f"{what} is not a rotation matrix (|RᵀR − I| = {math.hypot(*gram):.2g})")
    if det < 0:
        raise InvalidInput(f"{what} is a reflection (det < 0), not a rotation")
    return rot


def _orthonormality(entries):
    """(RᵀR − I's six distinct entries, det R) of a matrix's nine entries row by row: floats
    for one matrix, or arrays (one entry of every world's matrix each) for many."""
    a, b, c, d, e, f, g, h, i = entries
    gram = (a * a + d * d + g * g - 1.0, b * b + e * e + h * h - 1.0, c * c + f * f + i * i - 1.0,
            a * b + d * e + g * h, a * c + d * f + g * i, b * c + e * f + h * i)
    return gram, a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)


def _quaternion_matrix(quaternion: np.ndarray, what: str) -> np.ndarray:
    values = quaternion.tolist()
    norm = math.sqrt(sum(x * x for x in values))
    if not abs(norm - 1.0) <= 1e-6:
        raise InvalidInput(f"{what} must be a unit quaternion (w, x, y, z), got norm {norm:.6g}")
    flat = np.empty(9)
    mujoco.mju_quat2Mat(flat, quaternion)
    return flat.reshape(3, 3)


def world_rotations(robot, value, what: str = "target rotation") -> np.ndarray:
    """Rotations (N, 3, 3) from matrices or w-x-y-z unit quaternions: one for every world
    (checked by :func:`rotation_matrix`), or (N worlds) one per world, (N, 3, 3) or (N, 4),
    checked across worlds.

    Raises:
        InvalidInput: a wrong shape, or one bad rotation.
        InvalidWorlds: (N worlds) the worlds whose rotation is bad.
    """
    if not robot.batched:
        return rotation_matrix(value, what)[None]
    shape = np.shape(value)
    if shape in ((3, 3), (4,)):
        return rotation_matrix(value, what)[None]
    arr = float_array(value, (robot.n,) + shape[1:] if shape[1:] in ((3, 3), (4,)) else (robot.n, 3, 3), what)
    if arr.shape[1:] == (4,):
        norm = np.sqrt(np.einsum("ni,ni->n", arr, arr))
        _refuse_worlds(~(np.abs(norm - 1.0) <= 1e-6), f"{what}: not a unit quaternion (w, x, y, z)")
        matrices = np.empty((robot.n, 9))
        for matrix, quat in zip(matrices, arr):
            mujoco.mju_quat2Mat(matrix, quat)
        arr = matrices.reshape(-1, 3, 3)
    gram, det = _orthonormality(arr.reshape(robot.n, 9).T)
    deviation = np.hypot.reduce(np.stack(gram), axis=0)  # as math.hypot for one world
    _refuse_worlds(~(deviation <= 1e-6) | (det < 0),
                   f"{what}: not a rotation matrix (NaN, not orthonormal to 1e-6, or a reflection)")
    return arr


def _refuse_worlds(bad: np.ndarray, message: str) -> None:
    if bad.any():
        worlds = np.flatnonzero(bad)
        raise InvalidWorlds(f"{message} in worlds {listed(worlds)}", worlds)


def homogeneous_transform(transform, what: str = "target transform") -> tuple[np.ndarray, np.ndarray]:
    """(position (3,), rotation (3, 3)) of a homogeneous 4x4 transform [[R, p], [0, 0, 0, 1]]."""
    matrix = float_array(transform, (4, 4), what)
    if not np.array_equal(matrix[3], [0.0, 0.0, 0.0, 1.0]):
        raise InvalidInput(f"{what}: the last row of a homogeneous transform must be (0, 0, 0, 1), got {matrix[3]}")
    return finite_vector(matrix[:3, 3], 3, f"{what}'s translation"), rotation_matrix(matrix[:3, :3], f"{what}'s rotation")


def mocap_pose(robot, body: str) -> tuple[np.ndarray, np.ndarray]:
    """(position, rotation matrix) of a mocap body of a one-world robot, read now (copies).

    Raises:
        UnknownName: no body of that name.
        InvalidInput: the body is not a mocap body, or the robot has N worlds.
    """
    if robot.batched:
        raise InvalidInput("a mocap body is read from one world's MjData: set N worlds' targets with set_target")
    body_id = robot.body_id(body)
    mocap = int(robot.model.body_mocapid[body_id])
    if mocap < 0:
        names = [robot.model.body(i).name for i in range(robot.model.nbody) if robot.model.body_mocapid[i] >= 0]
        raise InvalidInput(f"body {body!r} is not a mocap body (mocap=\"true\"); mocap bodies: {names}")
    rotation = rotation_matrix(robot.data.mocap_quat[mocap], f"mocap body {body!r}'s quaternion")
    return robot.data.mocap_pos[mocap].copy(), rotation


def positive(value, size: int, what: str, allow_zero: bool = False) -> np.ndarray:
    """A scalar (broadcast) or a (size,) vector of positive (or >= 0) finite values, at
    most :data:`PARAMETER_LIMIT`."""
    if np.ndim(value) == 0 and not isinstance(value, (str, bytes)):
        try:
            arr = np.full(size, float(value))
        except (TypeError, ValueError):
            raise InvalidInput(f"{what} must be a number, got {value!r}") from None
    else:
        arr = float_array(value, size, what)
    low_ok = arr >= 0 if allow_zero else arr > 0
    if not (np.all(low_ok) and np.all(arr <= PARAMETER_LIMIT)):  # NaN fails both
        raise InvalidInput(f"{what} must be {'non-negative' if allow_zero else 'positive'}, finite and at most "
                           f"{PARAMETER_LIMIT:g}, got {value}")
    return arr


def positive_scalar(value, what: str, allow_zero: bool = False) -> float:
    """One number checked as :func:`positive` checks a vector's entries."""
    if isinstance(value, (str, bytes)) or np.ndim(value) != 0:
        raise InvalidInput(f"{what} must be a number, got {value!r}")
    return float(positive(value, 1, what, allow_zero)[0])


def feedback_gain(value, size: int, what: str) -> np.ndarray:
    """A task's gain K (1/s): a scalar or one per row, finite and >= 0; ``None`` for the
    dead-beat default, NaN until a controller gives its period (:meth:`Task.attach`)."""
    if value is None:
        return np.full(size, np.nan)
    return positive(value, size, what, allow_zero=True)


def scalar_dofs(model: mujoco.MjModel) -> np.ndarray:
    """The dofs of every hinge and slide joint (free and ball joints left out)."""
    scalar = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
    return np.array([model.jnt_dofadr[j] for j in range(model.njnt) if int(model.jnt_type[j]) in scalar], dtype=int)


def joint_dofs(robot, joints: Sequence[str] | None) -> np.ndarray:
    """The dofs of the named joints (every dof of a free or ball joint), in the model's order;
    ``None``: every hinge and slide joint, so a floating base is left alone."""
    if joints is None:
        return scalar_dofs(robot.model)
    if isinstance(joints, str):
        raise InvalidInput(f"joints must be a list of joint names, got the string {joints!r}")
    dofs = [int(dof) for name in joints for dof in robot.joint_dofs(name)]
    if len(set(dofs)) != len(dofs):
        raise InvalidInput(f"a joint is named twice in {list(joints)}")
    return np.array(sorted(dofs), dtype=int)
