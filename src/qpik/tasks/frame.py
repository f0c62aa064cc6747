"""Pose of a frame (site, body or geom): position rows, then orientation rows."""

from __future__ import annotations

import mujoco
import numpy as np

from ..robot import Robot
from .task import (
    PoseRows,
    Task,
    axis_rows,
    check_axes_frame,
    feedback_gain,
    check_targets,
    float_array,
    homogeneous_transform,
    mocap_pose,
    rotation_error,
    rotation_matrix,
)

__all__ = ["FrameTask", "rotation_error"]

_ZERO3 = np.zeros(3)


class FrameTask(Task):
    r"""Track a frame's pose: position rows, then orientation rows.

    .. math::
        J = \begin{bmatrix} J_p \\ J_\omega \end{bmatrix},\qquad
        v = \begin{bmatrix} \dot p_d + K_p (p_d - p) \\ \omega_d + K_o\, e_o \end{bmatrix},

    with :math:`e_o` the rotation vector of :math:`R_d R^T` (so that
    :math:`\exp([e_o]_\times) R = R_d`) and :math:`J_p, J_\omega` MuJoCo's translational and
    rotational Jacobians of the frame. By default the rows are the world's x, y, z axes;
    with ``axes_frame="local"`` they are the frame's own (moving) axes: e, the
    feed-forward and J are rotated by :math:`R^T`, so that masks, gains and weights act
    along the frame's axes (placo's local masks; mink's FrameTask weighs these rows).

    Args:
        robot: the robot.
        frame: name of the site, body or geom.
        frame_type: ``"site"``, ``"body"`` (its origin) or ``"geom"``.
        position_gain: :math:`K_p` (1/s), a scalar or one per position row; default
            ``None``: dead-beat, 1/Δt of the controller the task is given to (see below).
        orientation_gain: :math:`K_o` (1/s), a scalar or one per orientation row; default
            ``None``: dead-beat as well.
        weight: cost weight of a soft task, a scalar or one per row.
        hard: enforce the rows as equalities in the QP.
        lm_damping: adaptive Levenberg–Marquardt weight μ (see :class:`~qpik.tasks.task.Task`).
        position_axes: the position rows kept, a subset of ``"xyz"``.
        orientation_axes: the orientation rows kept, a subset of ``"xyz"``.
        axes_frame: ``"world"`` or ``"local"``: the axes the rows, masks, gains and
            weights refer to.

    Raises:
        UnknownName: no frame of that type has this name (the closest are listed).
        InvalidInput: a bad gain, weight, mask or ``axes_frame``.

    The target is the frame's pose when the task is built; :meth:`set_target` moves it
    (a position and a 3x3 matrix or a w-x-y-z quaternion), as do
    :meth:`set_target_transform` (a 4x4 homogeneous transform), :meth:`set_target_from_mocap`
    (a mocap body's pose) and :meth:`set_target_from_configuration` (the frame's pose now).

    Default gains are dead-beat, as mink's (``gain=1``): K = 1/Δt of the controller's
    period, so K·Δt = 1 and a met task removes its (linearised) error in one step. Give a
    gain in 1/s for a slower, smoother approach (K·Δt < 1); a law without a period
    (:class:`~qpik.PseudoinverseController`) needs one.
    """

    name = "frame task"

    def __init__(self, robot: Robot, frame: str, frame_type: str = "site", position_gain=None, orientation_gain=None,
                 weight=1.0, hard: bool = False, lm_damping: float = 0.0, position_axes: str = "xyz",
                 orientation_axes: str = "xyz", axes_frame: str = "world"):
        self.position_rows = axis_rows(position_axes, "position_axes")
        self.orientation_rows = axis_rows(orientation_axes, "orientation_axes")
        self.axes_frame = axes_frame
        local = check_axes_frame(axes_frame)
        n_position = len(self.position_rows)
        super().__init__(robot, n_position + len(self.orientation_rows), weight, hard, lm_damping=lm_damping)
        self.frame = robot.frame(frame, frame_type)
        # Gains and the feed-forward twist live in one array each, the per-block names being
        # views: v = K e + ẋ_d is then two operations on all rows.
        self._use_gain(np.concatenate([feedback_gain(position_gain, n_position, "position gain"),
                                       feedback_gain(orientation_gain, self.dim - n_position, "orientation gain")]))
        self.position_gain, self.orientation_gain = self.gain[:n_position], self.gain[n_position:]
        self.target_position = self.frame.position.copy()
        self.target_rotation = self.frame.rotation.copy()
        self._twist = np.zeros(6)
        self.target_linear_velocity, self.target_angular_velocity = self._twist[:3], self._twist[3:]
        self.position_error = self.error[:n_position]
        self.orientation_error = self.error[n_position:]
        # Every world axis: MuJoCo fills the task's own Jacobian rows (views), no copies.
        self._whole = self.dim == 6 and not local
        if self._whole:
            self._jacp, self._jacr = self.jacobian[:3], self.jacobian[3:]
            self._fill_jacobian = self.frame.jacobian_filler(self._jacp, self._jacr)
            # The rotations as 9-vectors (views), as MuJoCo's quaternion conversion takes them,
            # their quaternions and the error in the frame's axes (RotationError's steps, inline).
            self._target_flat, self._current_flat = self.target_rotation.reshape(9), self.frame.rotation.reshape(9)
            self._quaternions, self._local_error = (np.empty(4), np.empty(4)), np.empty(3)
        else:
            self._rows = PoseRows(self.frame, robot.nv, self.position_rows, self.orientation_rows, local)
            self._feedforward = np.zeros(self.dim)

    def set_target(self, position, rotation, linear_velocity=None, angular_velocity=None) -> None:
        """Desired world pose and feed-forward twist (world axes), whatever ``axes_frame``.

        ``rotation`` is a 3x3 rotation matrix or a unit quaternion in MuJoCo's w-x-y-z order.

        Raises:
            InvalidInput: a wrong shape, NaN/inf, or a matrix that is no rotation.
        """
        position = float_array(position, 3, "target position")
        linear = _ZERO3 if linear_velocity is None else float_array(linear_velocity, 3, "target linear velocity")
        angular = _ZERO3 if angular_velocity is None else float_array(angular_velocity, 3, "target angular velocity")
        check_targets((position, "target position"), (linear, "target linear velocity"),
                      (angular, "target angular velocity"))
        self.target_rotation[:] = rotation_matrix(rotation)  # every argument checked before the others are written
        self.target_position[:] = position
        self.target_linear_velocity[:] = linear
        self.target_angular_velocity[:] = angular

    def set_target_transform(self, transform, linear_velocity=None, angular_velocity=None) -> None:
        """Desired world pose as a homogeneous 4x4 transform [[R, p], [0, 0, 0, 1]].

        Raises:
            InvalidInput: not a 4x4 homogeneous transform with a rotation block.
        """
        position, rotation = homogeneous_transform(transform)
        self.set_target(position, rotation, linear_velocity, angular_velocity)

    def set_target_from_mocap(self, body: str) -> None:
        """Desired world pose: a mocap body's (``data.mocap_pos``/``mocap_quat``), read now.

        Raises:
            UnknownName: no body of that name.
            InvalidInput: the body is not a mocap body.
        """
        self.set_target(*mocap_pose(self.robot, body))

    def set_target_from_configuration(self) -> None:
        """Desired world pose: the frame's pose at the robot's current configuration."""
        self.robot.ensure_kinematics()
        self.set_target(self.frame.position, self.frame.rotation)

    def update(self) -> None:
        if self._whole:
            self._fill_jacobian()
        else:
            self._rows.jacobian(self.jacobian)
        self.update_target_velocity()

    def update_target_velocity(self) -> None:
        """Errors and v only (what a law without the Jacobian needs)."""
        if not self._whole:
            self._rows.errors(self.target_position, self.target_rotation, self.target_linear_velocity,
                              self.target_angular_velocity, self.error, self._feedforward)
            self._track(self._feedforward)
            return
        frame, (desired, current), local = self.frame, self._quaternions, self._local_error
        np.subtract(self.target_position, frame.position, self.position_error)
        mujoco.mju_mat2Quat(desired, self._target_flat)
        mujoco.mju_mat2Quat(current, self._current_flat)
        mujoco.mju_subQuat(local, desired, current)  # q_current * exp(local) = q_desired
        frame.rotation.dot(local, self.orientation_error)  # in world axes
        self._track(self._twist)
