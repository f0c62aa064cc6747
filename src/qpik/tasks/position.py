"""Position of a frame (site, body or geom) on selected world or local axes."""

from __future__ import annotations

import numpy as np

from ..robot import Robot
from .task import (
    PointTarget,
    PoseRows,
    Task,
    axis_rows,
    check_axes_frame,
    contiguous_rows,
    feedback_gain,
    mocap_pose,
)


class PositionTask(Task):
    r"""Track a frame's position on selected axes (the arm's task uses ``"xy"``).

    .. math::
        J = S J_p,\qquad v = S\,\dot p_d + K\,S (p_d - p)

    with :math:`S` the rows of the mask ``axes``, :math:`J_p` MuJoCo's translational
    Jacobian of the frame. In world axes (the default) targets are given on the masked
    axes (length ``len(axes)``). With ``axes_frame="local"`` the mask, gains and weights
    refer to the frame's own axes (:math:`S R^T`): the target is then a whole world
    position (3,) and only its components along the frame's kept axes are tracked.

    ``lm_damping`` μ adds μ w ‖e‖² ‖q̇‖²/2 to the cost of a soft task (adaptive
    Levenberg–Marquardt, as mink's ``lm_damping``): negligible while tracking, it
    calms the step when the target is out of reach and the error stays large.

    Args:
        robot: the robot.
        frame: name of the site, body or geom.
        frame_type: ``"site"``, ``"body"`` (its origin) or ``"geom"``.
        axes: the rows kept, a subset of ``"xyz"``.
        gain: K (1/s), a scalar or one per row; default ``None``: dead-beat, 1/Δt of the
            controller the task is given to (K·Δt = 1, mink's default ``gain=1``).
        weight: cost weight of a soft task, a scalar or one per row.
        hard: enforce the rows as equalities in the QP.
        lm_damping: μ above.
        axes_frame: ``"world"`` or ``"local"`` (the frame's own axes).

    Raises:
        UnknownName: no frame of that type has this name (the closest are listed).
        InvalidInput: a bad gain, weight, mask or ``axes_frame``.
    """

    name = "position task"

    def __init__(self, robot: Robot, frame: str, frame_type: str = "site", axes: str = "xyz", gain=None, weight=1.0,
                 hard: bool = False, lm_damping: float = 0.0, axes_frame: str = "world"):
        self.rows = axis_rows(axes)
        self.axes_frame = axes_frame
        self.local = check_axes_frame(axes_frame)
        super().__init__(robot, len(self.rows), weight, hard, lm_damping=lm_damping)
        self.frame = robot.frame(frame, frame_type)
        self._use_gain(feedback_gain(gain, self.dim, "position gain"))
        self._jacp = np.zeros((3, robot.nv))
        self._fill_jacobian = self.frame.jacobian_filler(self._jacp)
        self._views = False
        if self.local:
            self._pose_rows = PoseRows(self.frame, robot.nv, self.rows, None, local=True)
            self._feedforward = np.zeros(self.dim)
            self._goal = PointTarget(self.frame.position, "target position", "target velocity")
            self.target, self.target_rate = self._goal.target, self._goal.rate
            return
        # With contiguous axes ("xy", "xyz") the Jacobian and position are views that
        # MuJoCo's own arrays fill: no copies in the loop.
        rows = contiguous_rows(self.rows)
        self._views = rows is not None
        if self._views:
            self.jacobian = self._jacp[rows]
            self.position = self.frame.position[rows]
        else:
            self.position = self.frame.position[self.rows]
        self._goal = PointTarget(self.frame.position[self.rows], "target position", "target velocity")
        self.target, self.target_rate = self._goal.target, self._goal.rate

    @property
    def target_dim(self) -> int:
        """Length of a target: ``len(axes)`` in world axes, 3 (a world position) in local axes."""
        return len(self.target)

    def set_target(self, position, velocity=None) -> None:
        """Desired position and feed-forward velocity: on the masked world axes, or a
        world position (3,) and velocity with ``axes_frame="local"``.

        Raises:
            InvalidInput: a wrong length, NaN or inf.
        """
        self._goal.set(position, velocity)

    def set_target_from_configuration(self) -> None:
        """Desired position: the frame's position at the robot's current configuration."""
        self.robot.ensure_kinematics()
        self.set_target(self.measured())

    def set_target_from_mocap(self, body: str) -> None:
        """Desired position: a mocap body's (``data.mocap_pos``, the masked world axes in
        world axes), read now.

        Raises:
            UnknownName: no body of that name.
            InvalidInput: the body is not a mocap body.
        """
        position = mocap_pose(self.robot, body)[0]
        self.set_target(position if self.local else position[self.rows])

    def measured(self, robot: Robot | None = None) -> np.ndarray:
        """The tracked position in the target's coordinates (a copy), on the bound robot
        or another robot of the same model (valid after its kinematics update)."""
        position = (robot or self.robot).frame_position(self.frame)
        return position.copy() if self.local else position[self.rows]

    def update(self) -> None:
        if self.local:
            self._pose_rows.jacobian(self.jacobian)
            self.update_target_velocity()
            return
        self._fill_jacobian()
        if not self._views:
            self._jacp.take(self.rows, 0, self.jacobian)
            self.frame.position.take(self.rows, None, self.position)
        # update_target_velocity's, inline: e = x_d − x, v = K e + ẋ_d
        np.subtract(self.target, self.position, self.error)
        np.multiply(self.gain, self.error, self.target_velocity)
        np.add(self.target_velocity, self.target_rate, self.target_velocity)

    def update_target_velocity(self) -> None:
        """Error and v only (what a law without the Jacobian needs)."""
        if self.local:
            self._pose_rows.errors(self.target, None, self.target_rate, None, self.error, self._feedforward)
            self._track(self._feedforward)
            return
        if not self._views:
            self.frame.position.take(self.rows, None, self.position)
        np.subtract(self.target, self.position, self.error)
        self._track(self.target_rate)
