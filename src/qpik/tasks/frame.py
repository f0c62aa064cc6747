"""Pose of a frame (site, body or geom): position rows, then orientation rows."""

from __future__ import annotations

import numpy as np

from .inputs import (axis_rows, check_axes_frame, feedback_gain, homogeneous_transform, mocap_pose, world_rotations,
                     world_values)
from .pose import PoseRows
from .task import Task


class PoseTask(Task):
    """What :class:`FrameTask` and :class:`~qpik.tasks.relative_frame.RelativeFrameTask`
    share: position rows then orientation rows, their gains, and a target pose and
    feed-forward twist per world (a subclass measures the pose now: ``_pose_now``)."""

    def _start_pose(self, positions, rotations, twist: np.ndarray, position_gain, orientation_gain, p: int) -> None:
        """Gains K_p (``p`` rows) then K_o, targets copied from ``positions`` (N, 3) and
        ``rotations`` (N, 3, 3), the feed-forward ``twist`` (N, 6), and the views a user reads."""
        robot = self.robot
        self.set_gain(np.concatenate([feedback_gain(position_gain, p, "position gain"),
                                      feedback_gain(orientation_gain, self.dim - p, "orientation gain")]))
        self.position_gain, self.orientation_gain = self.gain[..., :p], self.gain[..., p:]
        self.target_positions, self.target_rotations, self._twist = np.array(positions), np.array(rotations), twist
        self._linear_twist, self._angular_twist = twist[:, :3], twist[:, 3:]
        self.target_position = robot.present(self.target_positions)
        self.target_rotation = robot.present(self.target_rotations)
        view = robot.present(twist)
        self.target_linear_velocity, self.target_angular_velocity = view[..., :3], view[..., 3:]
        self.position_error, self.orientation_error = self.error[..., :p], self.error[..., p:]

    def set_target(self, position, rotation, linear_velocity=None, angular_velocity=None) -> None:
        """Desired pose and feed-forward twist in the task's coordinates (the world's for a
        :class:`FrameTask`, whatever ``axes_frame``; ``root``'s for a relative one): one for
        every world, or (N, ...) one per world. ``rotation`` is a 3x3 rotation matrix or a
        unit quaternion in MuJoCo's w-x-y-z order.

        Raises:
            InvalidInput: a wrong shape, NaN/inf, or a matrix that is no rotation
                (InvalidWorlds: in some worlds).
        """
        robot = self.robot
        position = world_values(robot, position, (3,), "target position")
        rotation = world_rotations(robot, rotation)
        linear = 0.0 if linear_velocity is None else world_values(robot, linear_velocity, (3,), "target linear velocity")
        angular = 0.0 if angular_velocity is None else world_values(robot, angular_velocity, (3,),
                                                                    "target angular velocity")
        self.target_positions[...] = position  # every argument checked before any is written
        self.target_rotations[...] = rotation
        self._linear_twist[...] = linear
        self._angular_twist[...] = angular

    def set_target_from_configuration(self) -> None:
        """Desired pose: the pose at the current configuration, in every world."""
        self.robot.ensure_kinematics()
        self.target_positions[...], self.target_rotations[...] = self._pose_now()
        self._twist[...] = 0.0

    def set_target_transform(self, transform, linear_velocity=None, angular_velocity=None) -> None:
        """:meth:`set_target` from a homogeneous 4x4 transform [[R, p], [0, 0, 0, 1]] (one
        for every world).

        Raises:
            InvalidInput: not a 4x4 homogeneous transform with a rotation block.
        """
        position, rotation = homogeneous_transform(transform)
        self.set_target(position, rotation, linear_velocity, angular_velocity)


class FrameTask(PoseTask):
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
        position_gain, orientation_gain: :math:`K_p`, :math:`K_o` (1/s), a scalar or one per
            position (orientation) row; default ``None``: dead-beat (see below).
        weight, hard, lm_damping: as for :class:`~qpik.tasks.task.Task`.
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

    def __init__(self, robot, frame: str, frame_type: str = "site", position_gain=None, orientation_gain=None,
                 weight=1.0, hard: bool = False, lm_damping: float = 0.0, position_axes: str = "xyz",
                 orientation_axes: str = "xyz", axes_frame: str = "world"):
        self.position_rows = axis_rows(position_axes, "position_axes")
        self.orientation_rows = axis_rows(orientation_axes, "orientation_axes")
        self.axes_frame = axes_frame
        local = check_axes_frame(axes_frame)
        self.frame = robot.frame(frame, frame_type)
        self._pose = PoseRows(robot, self.frame, self.position_rows, self.orientation_rows, local)
        n_position = len(self.position_rows)
        super().__init__(robot, n_position + len(self.orientation_rows), weight, hard, lm_damping=lm_damping)
        self._start_pose(self.frame.positions, self.frame.rotations, np.zeros((robot.n, 6)), position_gain,
                         orientation_gain, n_position)
        # Every world axis: MuJoCo fills the task's own Jacobian rows, the feed-forward is
        # the twist itself, the errors are views: no copies.
        self._whole = self._pose.whole_rows()
        if self._whole:
            self._fill = self.frame.jacobians_filler(self.jacobians[:, :3], self.jacobians[:, 3:])
            self.rates = self._twist
            self.target_rate = robot.present(self.rates)
            self._position_errors, self._orientation_errors = self.errors[:, :3], self.errors[:, 3:]

    def set_target_from_mocap(self, body: str) -> None:
        """Desired world pose: a mocap body's (``data.mocap_pos``/``mocap_quat``), read now."""
        self.set_target(*mocap_pose(self.robot, body))

    def _pose_now(self) -> tuple[np.ndarray, np.ndarray]:
        return self.frame.positions, self.frame.rotations

    def measure_rows(self) -> None:
        pose = self._pose
        if not self._whole:
            pose.write(self, self.target_positions, self.target_rotations, self._linear_twist, self._angular_twist)
            return
        self._fill()
        np.subtract(self.target_positions, self.frame.positions, self._position_errors)
        pose._rotation_error(self.target_rotations, self.frame.rotations, self._orientation_errors)
