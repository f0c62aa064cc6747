"""The arm's orientation in its plane: φ = θ1 + θ2 + θ3, the angle of a site about world z.

A minimal one-row task for the ``three-tasks`` scenario (until the general orientation
task covers a single axis): φ = atan2(R[1, 0], R[0, 0]) of the site's rotation R, and
J the z row of the site's rotational Jacobian, which on the arm is [1, 1, 1, 0].
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from ...robot import Robot
from ...tasks.task import Task, finite_vector, positive


class PlanarOrientationTask(Task):
    """Track a site's angle φ about the world z axis: v = φ̇_d + K wrap(φ_d − φ).

    Args:
        robot: the robot.
        site: the site whose frame turns.
        gain: K (1/s).
        weight: cost weight when soft.
        hard: enforce as an equality in the QP.
    """

    name = "planar orientation task"

    def __init__(self, robot: Robot, site: str, gain: float = 1.0, weight=1.0, hard: bool = False):
        super().__init__(robot, 1, weight, hard)
        self.site_id = robot.site_id(site)
        self._use_gain(positive(gain, 1, "orientation gain", allow_zero=True))
        self._jacr = np.zeros((3, robot.nv))
        self.jacobian = self._jacr[2:3]  # a view MuJoCo fills
        self.target = np.array([self.angle()])
        self.target_rate = np.zeros(1)

    def angle(self) -> float:
        """φ of the site now, in (−π, π]."""
        R = self.robot.site_rotation(self.site_id)
        return math.atan2(R[1, 0], R[0, 0])

    def set_target(self, angle, rate=None) -> None:
        """Desired φ (rad) and its rate (rad/s), each a number or a (1,) array."""
        self.target[:] = finite_vector(np.reshape(angle, -1), 1, "target angle")
        self.target_rate[:] = 0.0 if rate is None else finite_vector(np.reshape(rate, -1), 1, "target rate")

    def update(self) -> None:
        mujoco.mj_jacSite(self.robot.model, self.robot.data, None, self._jacr, self.site_id)
        difference = float(self.target[0]) - self.angle()
        self.error[0] = math.remainder(difference, 2.0 * math.pi)  # the short way round
        self._track(self.target_rate)
