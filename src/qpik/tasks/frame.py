"""Pose of a frame: three position rows, then three orientation rows (world frame)."""

from __future__ import annotations

import mujoco
import numpy as np

from ..errors import InvalidInput
from ..robot import Robot
from .task import Task, finite_vector, positive


def rotation_error(desired: np.ndarray, current: np.ndarray) -> np.ndarray:
    """World-frame rotation vector e with exp([e]) R_current = R_desired."""
    qd, qc, local = np.empty(4), np.empty(4), np.empty(3)
    mujoco.mju_mat2Quat(qd, np.ascontiguousarray(desired).ravel())
    mujoco.mju_mat2Quat(qc, np.ascontiguousarray(current).ravel())
    mujoco.mju_subQuat(local, qd, qc)  # qc * exp(local) = qd, local in the current frame
    return current @ local


class FrameTask(Task):
    """Track a site's pose: 3 position rows then 3 orientation rows (world frame).

    :math:`v = [\\dot p_d + K_p e_p;\\ \\omega_d + K_o e_o]`, with :math:`e_o` the
    rotation vector of :math:`R_d R^T`.
    """

    name = "frame task"

    def __init__(self, robot: Robot, site: str, position_gain=1.0, orientation_gain=1.0, weight=1.0, hard: bool = False,
                 lm_damping: float = 0.0):
        super().__init__(robot, 6, weight, hard)
        self.lm_damping = positive(lm_damping, 1, "lm_damping", allow_zero=True)[0]
        self.site = site
        self.site_id = robot.site_id(site)
        self.position_gain = positive(position_gain, 3, "position gain", allow_zero=True)
        self.orientation_gain = positive(orientation_gain, 3, "orientation gain", allow_zero=True)
        self.target_position = robot.site_position(self.site_id).copy()
        self.target_rotation = robot.site_rotation(self.site_id).copy()
        self.target_linear_velocity = np.zeros(3)
        self.target_angular_velocity = np.zeros(3)
        self.position_error = self.error[:3]
        self.orientation_error = self.error[3:]

    def set_target(self, position, rotation, linear_velocity=None, angular_velocity=None) -> None:
        """Desired pose (world frame) and feed-forward twist."""
        self.target_position[:] = finite_vector(position, 3, "target position")
        rot = np.asarray(rotation, dtype=float)
        if rot.shape != (3, 3) or not np.all(np.isfinite(rot)):
            raise InvalidInput(f"target rotation must be a finite 3x3 matrix, got shape {rot.shape}")
        if not np.allclose(rot @ rot.T, np.eye(3), atol=1e-6) or np.linalg.det(rot) < 0:
            raise InvalidInput("target rotation is not a rotation matrix")
        self.target_rotation[:] = rot
        self.target_linear_velocity[:] = 0.0 if linear_velocity is None else finite_vector(linear_velocity, 3, "target linear velocity")
        self.target_angular_velocity[:] = 0.0 if angular_velocity is None else finite_vector(angular_velocity, 3, "target angular velocity")

    def update(self) -> None:
        self.robot.site_jacobian(self.site_id, self.jacobian[:3], self.jacobian[3:])
        self.update_target_velocity()

    def update_target_velocity(self) -> None:
        """Errors and v only (what a law without the Jacobian needs)."""
        np.subtract(self.target_position, self.robot.site_position(self.site_id), out=self.position_error)
        self.orientation_error[:] = rotation_error(self.target_rotation, self.robot.site_rotation(self.site_id))
        self.target_velocity[:3] = self.target_linear_velocity + self.position_gain * self.position_error
        self.target_velocity[3:] = self.target_angular_velocity + self.orientation_gain * self.orientation_error
