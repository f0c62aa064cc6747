r"""Batched tasks: the serial tasks' rows :math:`J\dot q \approx v` over N worlds.

Each class mirrors the serial task of the same name (:mod:`qpik.tasks`): the same
arguments, validated by the same functions (masks, gains, weights, targets), the same
dead-beat default gain and K·Δt check; its arrays carry a leading world axis:
``error`` (N, dim), ``jacobian`` (N, dim, nv), ``target_velocity`` (N, dim). Targets
are given for every world at once, ``(N, ...)``, or once for all, ``(...)``.

The vectorised math (rotation errors, relative poses, masks in local axes) restates the
serial task's formulas; :meth:`Task.serial_twin` builds the serial task of one world with
the same parameters and target, and the tests pin every batched task's error, Jacobian
and velocity to its twin's on random states of several models.

A NaN or inf target is not refused here: its world's velocity is not finite, and the
controller solves the other worlds and reports that one (:class:`~qpik.batch.WorldsFailed`).
"""

from __future__ import annotations

import warnings
from typing import Sequence

import mujoco
import numpy as np

from .. import tasks as serial
from ..errors import GainWarning, InvalidInput
from ..tasks.task import axis_rows, check_axes_frame, feedback_gain, joint_dofs, positive, positive_scalar
from . import rotations
from .linalg import worlds_last
from .errors import InvalidWorlds, NotBatched
from .robot import Robot, listed

__all__ = ["ComTask", "DampingTask", "EqualityTask", "FrameTask", "ManipulabilityTask", "OrientationTask",
           "PositionTask", "PostureTask", "RelativeFrameTask", "SigmaProxy", "Task"]


def world_values(robots: Robot, value, shape: tuple, what: str) -> np.ndarray:
    """``value`` as an (N, *shape) float array (one value broadcast to every world).
    NaN and inf pass (the controller reports their worlds); a wrong shape does not."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise InvalidInput(f"{what} must be numbers, got {value!r}") from None
    if arr.shape == shape:
        arr = np.broadcast_to(arr, (robots.n,) + shape)
    if arr.shape != (robots.n,) + shape:
        raise InvalidInput(f"{what} must have shape {shape} or ({robots.n}, {', '.join(map(str, shape))}), "
                           f"got {arr.shape}")
    return np.array(arr)


def world_rotations(robots: Robot, value, what: str = "target rotation") -> np.ndarray:
    """(N, 3, 3) rotations from matrices or w-x-y-z unit quaternions, one or one per world;
    the serial checks (orthonormal to 1e-6, no reflection, unit quaternion) on every
    finite world (a non-finite one is left for the controller to report)."""
    arr = np.asarray(value, dtype=float)
    if arr.shape[-1:] == (4,) and arr.ndim in (1, 2):
        quats = world_values(robots, arr, (4,), what)
        finite = np.isfinite(quats).all(axis=1)
        bad = finite & (np.abs(np.linalg.norm(np.where(finite[:, None], quats, 0.0), axis=1) - 1.0) > 1e-6)
        if bad.any():
            raise InvalidWorlds(f"{what} of worlds {listed(np.flatnonzero(bad))}: not a unit quaternion (w, x, y, z)",
                                np.flatnonzero(bad))
        return rotations.quat2mat(quats)
    mats = world_values(robots, arr, (3, 3), what)
    C = worlds_last(mats)  # C[a, i]: row a, column i, every world along the last axis
    if not np.isfinite(C.sum()):
        C = np.where(np.isfinite(C).all(axis=(0, 1)), C, np.eye(3)[:, :, None])
    gram = (C[:, :, None, :] * C[:, None, :, :]).sum(axis=0)  # columns' dot products, RᵀR
    deviation = np.abs(gram - np.eye(3)[:, :, None]).max(axis=(0, 1))
    det = (C[0, 0] * (C[1, 1] * C[2, 2] - C[2, 1] * C[1, 2]) - C[1, 0] * (C[0, 1] * C[2, 2] - C[2, 1] * C[0, 2])
           + C[2, 0] * (C[0, 1] * C[1, 2] - C[1, 1] * C[0, 2]))
    bad = (deviation > 1e-6) | (det < 0)
    if bad.any():
        raise InvalidWorlds(f"{what} of worlds {listed(np.flatnonzero(bad))} is not a rotation matrix", np.flatnonzero(bad))
    return mats


def row_selection(rows: np.ndarray, size: int):
    """``rows`` of a ``size``-row array as an index: None for all of them, a slice when
    they are consecutive (a view, not a copy), else the array."""
    rows = np.asarray(rows, dtype=int)
    if len(rows) == size and np.array_equal(rows, np.arange(size)):
        return None
    if len(rows) and np.array_equal(rows, np.arange(rows[0], rows[0] + len(rows))):
        return slice(int(rows[0]), int(rows[0]) + len(rows))
    return rows


def select(array: np.ndarray, rows) -> np.ndarray:
    """``array[:, rows]`` for a :func:`row_selection`."""
    return array if rows is None else array[:, rows]


class Task:
    """Base class of the batched tasks (see the module's description).

    Attributes:
        dim, weight (dim,), hard, lm_damping: as the serial task's.
        joint_space: J is the fixed selection ``I[dofs]`` (then ``jacobian`` is not read).
    """

    name = "task"
    joint_space = False
    lm_damping = 0.0
    dofs: np.ndarray | None = None

    def __init__(self, robots: Robot, dim: int, weight=1.0, hard: bool = False, gains: Sequence[np.ndarray] = ()):
        self.robots = robots
        self.dim = int(dim)
        self.hard = bool(hard)
        self.weight = positive(weight, self.dim, f"{self.name} weight", allow_zero=True)
        n, nv = robots.n, robots.nv
        self.error = np.zeros((n, self.dim))
        self.target_velocity = np.zeros((n, self.dim))
        self.jacobian = np.zeros((n, self.dim, nv))
        self._gains = list(gains)
        self._dead_beat = [np.isnan(g) for g in self._gains]

    @property
    def needs_period(self) -> bool:
        return any(np.isnan(g).any() for g in self._gains)

    def attach(self, dt: float | None) -> None:
        """The serial :meth:`qpik.Task.attach`: dead-beat gains become 1/Δt; K·Δt > 2 is
        refused, > 1 warned about (GainWarning)."""
        if dt is not None:
            for gain, rows in zip(self._gains, self._dead_beat):
                gain[rows] = 1.0 / dt
        gains = self.feedback_gains()
        if dt is None or gains is None or not len(gains):
            return
        worst = float(np.max(gains)) * dt * (1.0 - 1e-12)
        if worst > 2.0:
            raise InvalidInput(f"{self.name}: gain {float(np.max(gains)):g} 1/s with dt = {dt:g} s gives K·dt = "
                               f"{worst:.3g} > 2: the discrete error grows every step; use K <= {1.0 / dt:g} 1/s")
        if worst > 1.0:
            warnings.warn(f"{self.name}: gain {float(np.max(gains)):g} 1/s with dt = {dt:g} s gives K·dt = "
                          f"{worst:.3g} > 1: the error overshoots, changing sign every step", GainWarning, stacklevel=3)

    def feedback_gains(self) -> np.ndarray | None:
        return np.concatenate(self._gains) if self._gains else None

    def update(self) -> None:
        """Refresh ``error``, ``jacobian`` and ``target_velocity`` (kinematics current)."""
        raise NotImplementedError

    def serial_twin(self, robot, world: int):
        """The serial task of world ``world`` on ``robot`` (a serial Robot of the same model):
        same parameters and target (for tests and comparisons)."""
        raise NotImplementedError

    def __repr__(self) -> str:
        return f"batch.{type(self).__name__}(dim={self.dim}, hard={self.hard})"


class _PoseRows:
    """The masked position/orientation rows of a frame, world or local axes (the serial
    ``PoseRows``). Its Jacobian is written into buffers it keeps (the task's
    ``jacobian`` is valid until its next update)."""

    def __init__(self, robots: Robot, frame, position_rows, orientation_rows, local: bool):
        self.robots, self.frame, self.local = robots, frame, local
        self.position_rows, self.orientation_rows = position_rows, orientation_rows
        self.has_position = position_rows is not None
        self.has_orientation = orientation_rows is not None
        offset = 3 if self.has_position else 0
        parts = ([position_rows] if self.has_position else []) + \
                ([offset + orientation_rows] if self.has_orientation else [])
        self.rows = np.concatenate(parts).astype(int)
        blocks = int(self.has_position) + int(self.has_orientation)
        self._take = row_selection(self.rows, 3 * blocks)
        n, nv = robots.n, robots.nv
        self._jac = np.empty((n, 3 * blocks, nv))
        spare = np.empty((n, 3, nv))  # the block a pure position or orientation task does not read
        self._out_p = self._jac[:, :3] if self.has_position else spare
        self._out_r = self._jac[:, offset:offset + 3] if self.has_orientation else spare
        self._target_quat = None  # (the rotations it was computed from, their quaternions)

    def jacobian(self) -> np.ndarray:
        self.frame.jacobian(self.robots, self._out_p, self._out_r)
        jac = self._jac
        if self.local:
            Rt = self.frame.rotation.transpose(0, 2, 1)
            jac = np.concatenate([Rt @ jac[:, 3 * b:3 * b + 3] for b in range(jac.shape[1] // 3)], axis=1)
        return select(jac, self._take)

    def desired_quat(self, target_rotation: np.ndarray) -> np.ndarray:
        """``mju_mat2Quat`` of the target rotations, recomputed only when they change."""
        cached = self._target_quat
        if cached is None or not np.array_equal(cached[0], target_rotation):
            cached = (np.array(target_rotation), rotations.mat2quat(target_rotation))
            self._target_quat = cached
        return cached[1]

    def errors(self, target_position, target_rotation, linear_velocity, angular_velocity):
        R = self.frame.rotation
        errors, feedforward = [], []
        if self.has_position:
            e = target_position - self.frame.position
            f = linear_velocity
            if self.local:
                e, f = np.einsum("nj,nji->ni", e, R), np.einsum("nj,nji->ni", f, R)
            errors.append(e)
            feedforward.append(f)
        if self.has_orientation:
            desired = self.desired_quat(target_rotation)
            if self.local:
                errors.append(rotations.rotation_error_local(target_rotation, R, desired))
                feedforward.append(np.einsum("nj,nji->ni", angular_velocity, R))
            else:
                errors.append(rotations.rotation_error_world(target_rotation, R, desired))
                feedforward.append(angular_velocity)
        if len(errors) > 1:
            errors, feedforward = [np.concatenate(errors, axis=1)], [np.concatenate(feedforward, axis=1)]
        return select(errors[0], self._take), select(feedforward[0], self._take)


class FrameTask(Task):
    """Batched :class:`qpik.FrameTask`: a frame's pose, position rows then orientation rows."""

    name = "frame task"

    def __init__(self, robots: Robot, frame: str, frame_type: str = "site", position_gain=None,
                 orientation_gain=None, weight=1.0, hard: bool = False, lm_damping: float = 0.0,
                 position_axes: str = "xyz", orientation_axes: str = "xyz", axes_frame: str = "world"):
        position_rows = axis_rows(position_axes, "position_axes")
        orientation_rows = axis_rows(orientation_axes, "orientation_axes")
        local = check_axes_frame(axes_frame)
        npos = len(position_rows)
        self.position_gain = feedback_gain(position_gain, npos, "position gain")
        self.orientation_gain = feedback_gain(orientation_gain, len(orientation_rows), "orientation gain")
        super().__init__(robots, npos + len(orientation_rows), weight, hard, [self.position_gain, self.orientation_gain])
        self.lm_damping = float(positive(lm_damping, 1, "lm_damping", allow_zero=True)[0])
        self._args = dict(frame=frame, frame_type=frame_type, position_axes=position_axes,
                          orientation_axes=orientation_axes, axes_frame=axes_frame)
        self.frame = robots.frame(frame, frame_type)
        self._rows = _PoseRows(robots, self.frame, position_rows, orientation_rows, local)
        robots.ensure_kinematics()
        self.target_position = self.frame.position.copy()
        self.target_rotation = self.frame.rotation.copy()
        self.target_linear_velocity = np.zeros((robots.n, 3))
        self.target_angular_velocity = np.zeros((robots.n, 3))

    def set_target(self, position, rotation, linear_velocity=None, angular_velocity=None) -> None:
        """Desired poses: positions (N, 3) or (3,), rotations (N, 3, 3) / (3, 3) or
        w-x-y-z quaternions (N, 4) / (4,); feed-forward twists in world axes."""
        self.target_position = world_values(self.robots, position, (3,), "target position")
        self.target_rotation = world_rotations(self.robots, rotation)
        zero = np.zeros(3)
        self.target_linear_velocity = world_values(self.robots, zero if linear_velocity is None else linear_velocity,
                                                   (3,), "target linear velocity")
        self.target_angular_velocity = world_values(self.robots, zero if angular_velocity is None else angular_velocity,
                                                    (3,), "target angular velocity")

    def update(self) -> None:
        self.jacobian = self._rows.jacobian()
        self.error, feedforward = self._rows.errors(self.target_position, self.target_rotation,
                                                    self.target_linear_velocity, self.target_angular_velocity)
        self.target_velocity = self.feedback_gains() * self.error + feedforward

    def serial_twin(self, robot, world: int):
        task = serial.FrameTask(robot, position_gain=self.position_gain.copy(), orientation_gain=self.orientation_gain.copy(),
                                weight=self.weight.copy(), hard=self.hard, lm_damping=self.lm_damping, **self._args)
        task.set_target(self.target_position[world], self.target_rotation[world],
                        self.target_linear_velocity[world], self.target_angular_velocity[world])
        return task


class PositionTask(Task):
    """Batched :class:`qpik.PositionTask`: targets on the masked world axes (N, len(axes)),
    or world positions (N, 3) with ``axes_frame="local"``."""

    name = "position task"

    def __init__(self, robots: Robot, frame: str, frame_type: str = "site", axes: str = "xyz", gain=None,
                 weight=1.0, hard: bool = False, lm_damping: float = 0.0, axes_frame: str = "world"):
        self.rows = axis_rows(axes)
        self.local = check_axes_frame(axes_frame)
        self.gain = feedback_gain(gain, len(self.rows), "position gain")
        super().__init__(robots, len(self.rows), weight, hard, [self.gain])
        self.lm_damping = float(positive(lm_damping, 1, "lm_damping", allow_zero=True)[0])
        self._args = dict(frame=frame, frame_type=frame_type, axes=axes, axes_frame=axes_frame)
        self.frame = robots.frame(frame, frame_type)
        self._pose = _PoseRows(robots, self.frame, self.rows, None, self.local)
        self._take = row_selection(self.rows, 3)
        self._jacp, self._jacr = np.empty((robots.n, 3, robots.nv)), np.empty((robots.n, 3, robots.nv))
        robots.ensure_kinematics()
        self.target = self.frame.position.copy() if self.local else self.frame.position[:, self.rows].copy()
        self.target_rate = np.zeros_like(self.target)

    def set_target(self, position, velocity=None) -> None:
        size = self.target.shape[1]
        self.target = world_values(self.robots, position, (size,), "target position")
        self.target_rate = world_values(self.robots, np.zeros(size) if velocity is None else velocity, (size,),
                                        "target velocity")

    def update(self) -> None:
        if self.local:
            self.jacobian = self._pose.jacobian()
            self.error, feedforward = self._pose.errors(self.target, None, self.target_rate, None)
        else:
            self.frame.jacobian(self.robots, self._jacp, self._jacr)
            self.jacobian = select(self._jacp, self._take)
            self.error = self.target - select(self.frame.position, self._take)
            feedforward = self.target_rate
        self.target_velocity = self.gain * self.error + feedforward

    def serial_twin(self, robot, world: int):
        task = serial.PositionTask(robot, gain=self.gain.copy(), weight=self.weight.copy(), hard=self.hard,
                                   lm_damping=self.lm_damping, **self._args)
        task.set_target(self.target[world], self.target_rate[world])
        return task


class OrientationTask(Task):
    """Batched :class:`qpik.OrientationTask`."""

    name = "orientation task"

    def __init__(self, robots: Robot, frame: str, frame_type: str = "site", axes: str = "xyz", gain=None,
                 weight=1.0, hard: bool = False, lm_damping: float = 0.0, axes_frame: str = "world"):
        rows = axis_rows(axes)
        local = check_axes_frame(axes_frame)
        self.gain = feedback_gain(gain, len(rows), "orientation gain")
        super().__init__(robots, len(rows), weight, hard, [self.gain])
        self.lm_damping = float(positive(lm_damping, 1, "lm_damping", allow_zero=True)[0])
        self._args = dict(frame=frame, frame_type=frame_type, axes=axes, axes_frame=axes_frame)
        self.frame = robots.frame(frame, frame_type)
        self._pose = _PoseRows(robots, self.frame, None, rows, local)
        robots.ensure_kinematics()
        self.target_rotation = self.frame.rotation.copy()
        self.target_angular_velocity = np.zeros((robots.n, 3))

    def set_target(self, rotation, angular_velocity=None) -> None:
        self.target_rotation = world_rotations(self.robots, rotation)
        self.target_angular_velocity = world_values(self.robots, np.zeros(3) if angular_velocity is None
                                                    else angular_velocity, (3,), "target angular velocity")

    def update(self) -> None:
        self.jacobian = self._pose.jacobian()
        self.error, feedforward = self._pose.errors(None, self.target_rotation, None, self.target_angular_velocity)
        self.target_velocity = self.gain * self.error + feedforward

    def serial_twin(self, robot, world: int):
        task = serial.OrientationTask(robot, gain=self.gain.copy(), weight=self.weight.copy(), hard=self.hard,
                                      lm_damping=self.lm_damping, **self._args)
        task.set_target(self.target_rotation[world], self.target_angular_velocity[world])
        return task


class RelativeFrameTask(Task):
    """Batched :class:`qpik.RelativeFrameTask`: the pose of ``frame`` in ``root``'s coordinates."""

    name = "relative frame task"

    def __init__(self, robots: Robot, frame: str, root: str, frame_type: str = "site", root_type: str = "site",
                 position_gain=None, orientation_gain=None, weight=1.0, hard: bool = False, lm_damping: float = 0.0):
        self.position_gain = feedback_gain(position_gain, 3, "position gain")
        self.orientation_gain = feedback_gain(orientation_gain, 3, "orientation gain")
        super().__init__(robots, 6, weight, hard, [self.position_gain, self.orientation_gain])
        self.frame = robots.frame(frame, frame_type)
        self.root = robots.frame(root, root_type)
        if (self.frame.type, self.frame.id) == (self.root.type, self.root.id):
            raise InvalidInput(f"{self.name}: frame and root are the same {frame_type} {frame!r}")
        self.lm_damping = float(positive(lm_damping, 1, "lm_damping", allow_zero=True)[0])
        self._args = dict(frame=frame, root=root, frame_type=frame_type, root_type=root_type)
        robots.ensure_kinematics()
        position, rotation = self.relative_pose()
        self.target_position, self.target_rotation = position.copy(), rotation.copy()
        self.target_linear_velocity = np.zeros((robots.n, 3))
        self.target_angular_velocity = np.zeros((robots.n, 3))

    def relative_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """(R_rᵀ(p_f − p_r), R_rᵀR_f) in every world."""
        offset = self.frame.position - self.root.position
        Rr = self.root.rotation
        return np.einsum("nj,nji->ni", offset, Rr), Rr.transpose(0, 2, 1) @ self.frame.rotation

    def set_target(self, position, rotation, linear_velocity=None, angular_velocity=None) -> None:
        self.target_position = world_values(self.robots, position, (3,), "target position")
        self.target_rotation = world_rotations(self.robots, rotation)
        zero = np.zeros(3)
        self.target_linear_velocity = world_values(self.robots, zero if linear_velocity is None else linear_velocity,
                                                   (3,), "target linear velocity")
        self.target_angular_velocity = world_values(self.robots, zero if angular_velocity is None else angular_velocity,
                                                    (3,), "target angular velocity")

    def update(self) -> None:
        jpf, jrf = self.frame.jacobian(self.robots)
        jpr, jrr = self.root.jacobian(self.robots)
        position, rotation = self.relative_pose()
        d = self.frame.position - self.root.position
        # J_pf − J_pr + d × (each column of J_ωr)
        moved = jpf - jpr + np.cross(d[:, :, None], jrr, axis=1)
        Rt = self.root.rotation.transpose(0, 2, 1)
        self.jacobian = np.concatenate([Rt @ moved, Rt @ (jrf - jrr)], axis=1)
        self.error = np.concatenate([self.target_position - position,
                                     rotations.rotation_error_world(self.target_rotation, rotation)], axis=1)
        twist = np.concatenate([self.target_linear_velocity, self.target_angular_velocity], axis=1)
        self.target_velocity = self.feedback_gains() * self.error + twist

    def serial_twin(self, robot, world: int):
        task = serial.RelativeFrameTask(robot, position_gain=self.position_gain.copy(),
                                        orientation_gain=self.orientation_gain.copy(), weight=self.weight.copy(),
                                        hard=self.hard, lm_damping=self.lm_damping, **self._args)
        task.set_target(self.target_position[world], self.target_rotation[world],
                        self.target_linear_velocity[world], self.target_angular_velocity[world])
        return task


class ComTask(Task):
    """Batched :class:`qpik.ComTask`: the centre of mass of the model or of a subtree."""

    name = "CoM task"

    def __init__(self, robots: Robot, gain=None, weight=1.0, subtree: str | None = None, axes: str = "xyz",
                 hard: bool = False, lm_damping: float = 0.0):
        self._twin = serial.ComTask(robots.template, gain=gain, weight=weight, subtree=subtree, axes=axes,
                                    hard=hard, lm_damping=lm_damping)  # the serial checks
        self.rows, self.body = self._twin.rows, self._twin.body
        self.gain = feedback_gain(gain, len(self.rows), "CoM gain")
        super().__init__(robots, len(self.rows), weight, hard, [self.gain])
        self.lm_damping = float(self._twin.lm_damping)
        self._args = dict(subtree=subtree, axes=axes)
        self._com = robots.backend.subtree_com(self.body)
        robots.kinematics_stale()
        robots.ensure_kinematics()
        self.target = self._com[:, self.rows].copy()
        self.target_rate = np.zeros_like(self.target)

    def set_target(self, position, velocity=None) -> None:
        self.target = world_values(self.robots, position, (self.dim,), "target CoM")
        self.target_rate = world_values(self.robots, np.zeros(self.dim) if velocity is None else velocity,
                                        (self.dim,), "target CoM velocity")

    def update(self) -> None:
        self.jacobian = self.robots.backend.subtree_com_jacobian(self.body)[:, self.rows]
        self.error = self.target - self._com[:, self.rows]
        self.target_velocity = self.gain * self.error + self.target_rate

    def serial_twin(self, robot, world: int):
        task = serial.ComTask(robot, gain=self.gain.copy(), weight=self.weight.copy(), hard=self.hard,
                              lm_damping=self.lm_damping, **self._args)
        task.set_target(self.target[world], self.target_rate[world])
        return task


class _JointSpace(Task):
    """A task whose Jacobian is the selection I[dofs] (posture, damping, gradients)."""

    joint_space = True

    def __init__(self, robots: Robot, joints, weight, gains=()):
        self.dofs = joint_dofs(robots.template, joints)
        if len(self.dofs) == 0:
            raise InvalidInput(f"{self.name}: the model has no joint to act on (give joints=...)")
        super().__init__(robots, len(self.dofs), weight, False, gains)
        self.jacobian = np.zeros((self.dim, robots.nv))
        self.jacobian[np.arange(self.dim), self.dofs] = 1.0
        self.jacobian.setflags(write=False)
        self._joints = joints


class PostureTask(_JointSpace):
    """Batched :class:`qpik.PostureTask`: v = K (q_ref ⊖ q) on its dofs; ``target`` one
    configuration (nq,) or one per world (N, nq)."""

    name = "posture task"

    def __init__(self, robots: Robot, target=None, gain: float = 1.0, weight=1.0, joints: Sequence[str] | None = None):
        super().__init__(robots, joints, weight)
        self.gain = positive_scalar(gain, "posture gain", allow_zero=True)
        self.target = robots.q.copy() if target is None else world_values(robots, target, (robots.nq,), "posture target")
        self._difference = _Difference(robots.model)

    def set_target(self, target) -> None:
        self.target = world_values(self.robots, target, (self.robots.nq,), "posture target")

    def feedback_gains(self) -> np.ndarray:
        return np.full(self.dim, self.gain)

    def update(self) -> None:
        self.error = self._difference(self.robots.q, self.target)[:, self.dofs]
        self.target_velocity = self.gain * self.error

    def serial_twin(self, robot, world: int):
        return serial.PostureTask(robot, target=self.target[world], gain=self.gain, weight=self.weight.copy(),
                                  joints=self._joints)


class DampingTask(_JointSpace):
    """Batched :class:`qpik.DampingTask`: ½ w ‖q̇‖² on its dofs."""

    name = "damping task"

    def __init__(self, robots: Robot, weight=1e-3, joints: Sequence[str] | None = None):
        super().__init__(robots, joints, weight)

    def update(self) -> None:
        pass

    def serial_twin(self, robot, world: int):
        return serial.DampingTask(robot, weight=self.weight.copy(), joints=self._joints)


class SigmaProxy:
    """Batched :class:`qpik.SigmaProxy`: σ = ½ Σ sin² q_j over hinge or slide joints."""

    label = "sigma"

    def __init__(self, robots: Robot, joints: Sequence[str]):
        twin = serial.SigmaProxy(robots.template, joints)  # the serial checks
        self.robots, self.joints = robots, twin.joints
        self.qpos_index, self.dof_index = twin.qpos_index, twin.dof_index

    def value(self) -> np.ndarray:
        s = np.sin(self.robots.q[:, self.qpos_index])
        return 0.5 * np.einsum("ni,ni->n", s, s)

    def gradient(self) -> np.ndarray:
        out = np.zeros((self.robots.n, self.robots.nv))
        out[:, self.dof_index] = self.partial_gradient()
        return out

    def partial_gradient(self) -> np.ndarray:
        """(N, len(joints)): the gradient's entries on the measure's own dofs."""
        return 0.5 * np.sin(2.0 * self.robots.q[:, self.qpos_index])


class ManipulabilityTask(_JointSpace):
    """Batched :class:`qpik.ManipulabilityTask`: ½ w ‖q̇ − k0 ∇m(q)‖² (the measure a
    batched :class:`SigmaProxy`; Yoshikawa's measure is not batched yet)."""

    name = "manipulability task"

    def __init__(self, robots: Robot, measure, gain: float = 5.0, weight=1.0, joints: Sequence[str] | None = None):
        if not isinstance(measure, SigmaProxy):
            raise NotBatched(f"{self.name}: the batched engine climbs the gradient of a batch.SigmaProxy only, "
                             f"got {type(measure).__name__}")
        super().__init__(robots, joints, weight)
        self.measure = measure
        self.gain = positive_scalar(gain, "manipulability gain", allow_zero=True)
        self._own_dofs = np.array_equal(self.dofs, measure.dof_index)
        self._take = row_selection(self.dofs, robots.nv)

    def feedback_gains(self) -> None:
        return None

    def update(self) -> None:
        if self._own_dofs:  # the task's dofs are the measure's: no (N, nv) gradient
            self.target_velocity = self.measure.partial_gradient() * self.gain
        else:
            self.target_velocity = select(self.measure.gradient(), self._take) * self.gain

    def serial_twin(self, robot, world: int):
        measure = serial.SigmaProxy(robot, list(self.measure.joints))
        return serial.ManipulabilityTask(robot, measure, gain=self.gain, weight=self.weight.copy(), joints=self._joints)


class EqualityTask(Task):
    """Batched :class:`qpik.EqualityTask`: the model's ``connect`` (and ``joint``)
    equalities as rows J_e q̇ = −K e_e, hard by default; the rows are MuJoCo's
    (``mj_makeConstraint``'s layout), built by the back-end from the anchors' Jacobians."""

    name = "equality task"

    def __init__(self, robots: Robot, equalities: Sequence[str] | None = None, gain: float | None = None,
                 hard: bool = True, weight=1.0):
        self._twin = serial.EqualityTask(robots.template, equalities, gain=gain, hard=hard, weight=weight)
        self.equalities = np.array(self._twin.equalities, dtype=np.int64)
        self.gain = np.full(1, np.nan if gain is None else positive_scalar(gain, f"{self.name} gain", allow_zero=True))
        super().__init__(robots, self._twin.dim, weight, hard, [self.gain])
        self._names, self._gain_arg = equalities, gain
        robots.ensure_kinematics()
        self.robots.backend.equality_rows(self.equalities)  # NotBatched for a weld or tendon, now
        robots.kinematics_stale()

    def feedback_gains(self) -> np.ndarray:
        return np.full(self.dim, self.gain[0])

    def update(self) -> None:
        self.error, self.jacobian = self.robots.backend.equality_rows(self.equalities)
        self.target_velocity = -self.gain[0] * self.error

    def serial_twin(self, robot, world: int):
        return serial.EqualityTask(robot, self._names, gain=self._gain_arg, hard=self.hard, weight=self.weight.copy())


class _Difference:
    """``mj_differentiatePos(q1 → q2)`` over worlds (dt = 1): scalar joints subtract,
    ball and free joints take the quaternion difference."""

    def __init__(self, model: mujoco.MjModel):
        self.nv = model.nv
        self.scalar, self.quats, self.linear = [], [], []
        J = mujoco.mjtJoint
        for j in range(model.njnt):
            kind, qadr, vadr = int(model.jnt_type[j]), int(model.jnt_qposadr[j]), int(model.jnt_dofadr[j])
            if kind in (int(J.mjJNT_HINGE), int(J.mjJNT_SLIDE)):
                self.scalar.append((qadr, vadr))
            elif kind == int(J.mjJNT_FREE):
                self.linear.append((qadr, vadr))
                self.quats.append((qadr + 3, vadr + 3))
            else:
                self.quats.append((qadr, vadr))
        self.scalar_q = np.array([q for q, _ in self.scalar], dtype=np.int64)
        self.scalar_v = np.array([v for _, v in self.scalar], dtype=np.int64)

    def __call__(self, q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
        out = np.zeros((len(q1), self.nv))
        out[:, self.scalar_v] = q2[:, self.scalar_q] - q1[:, self.scalar_q]
        for qadr, vadr in self.linear:
            out[:, vadr:vadr + 3] = q2[:, qadr:qadr + 3] - q1[:, qadr:qadr + 3]
        for qadr, vadr in self.quats:
            out[:, vadr:vadr + 3] = rotations.sub(q2[:, qadr:qadr + 4], q1[:, qadr:qadr + 4])
        return out
