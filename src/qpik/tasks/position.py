"""Position of a frame (site, body or geom) on selected world axes."""

from __future__ import annotations

import mujoco
import numpy as np

from ..robot import Robot
from .task import Task, axis_rows, finite_vector, positive


class PositionTask(Task):
    """Track a site's position on selected world axes (the arm's task uses ``"xy"``).

    :math:`v = \\dot p_d + K (p_d - p)` on the masked rows. Targets are given in the
    masked coordinates (length ``len(axes)``).

    ``lm_damping`` μ adds μ w ‖e‖² ‖q̇‖²/2 to the cost of a soft task (adaptive
    Levenberg–Marquardt, as mink's ``lm_damping``): negligible while tracking, it
    calms the step when the target is out of reach and the error stays large.
    """

    name = "position task"

    def __init__(self, robot: Robot, site: str, axes: str = "xyz", gain=1.0, weight=1.0, hard: bool = False,
                 lm_damping: float = 0.0):
        self.rows = axis_rows(axes)
        super().__init__(robot, len(self.rows), weight, hard)
        self.lm_damping = positive(lm_damping, 1, "lm_damping", allow_zero=True)[0]
        self.site = site
        self.site_id = robot.site_id(site)
        self.gain = positive(gain, self.dim, "position gain", allow_zero=True)
        self._model, self._data = robot.model, robot.data
        self._jacp = np.zeros((3, robot.nv))
        site_position = robot.data.site_xpos[self.site_id]
        # With contiguous axes ("xy", "xyz") the Jacobian and position are views that
        # MuJoCo's own arrays fill: no copies in the loop.
        self._views = bool(self.rows[-1] - self.rows[0] + 1 == self.dim)
        if self._views:
            rows = slice(int(self.rows[0]), int(self.rows[-1]) + 1)
            self.jacobian = self._jacp[rows]
            self.position = site_position[rows]
        else:
            self.position = site_position[self.rows]
        self.target = site_position[self.rows].copy()
        self.target_rate = np.zeros(self.dim)

    def set_target(self, position, velocity=None) -> None:
        """Desired position (and feed-forward velocity) on the masked axes."""
        self.target[:] = finite_vector(position, self.dim, "target position")
        self.target_rate[:] = 0.0 if velocity is None else finite_vector(velocity, self.dim, "target velocity")

    def update(self) -> None:
        mujoco.mj_jacSite(self._model, self._data, self._jacp, None, self.site_id)
        if not self._views:
            self.jacobian[:] = self._jacp[self.rows]
        self.update_target_velocity()

    def update_target_velocity(self) -> None:
        """Error and v only (what a law without the Jacobian needs)."""
        if not self._views:
            self.position[:] = self._data.site_xpos[self.site_id][self.rows]
        np.subtract(self.target, self.position, out=self.error)
        np.multiply(self.gain, self.error, out=self.target_velocity)
        self.target_velocity += self.target_rate
