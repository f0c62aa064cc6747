"""Joint velocity limits |q̇| ≤ q̇max."""

from __future__ import annotations

import numpy as np

from ..errors import InvalidInput
from ..robot import Robot
from .limit import Limit


class JointVelocityLimit(Limit):
    """|q̇_i| ≤ q̇max_i on the dofs that have a limit (default: the scene's numerics)."""

    constant = True  # the same bounds every step: the controller applies them once

    def __init__(self, robot: Robot, max_velocity: np.ndarray | None = None):
        vmax = robot.velocity_limits if max_velocity is None else np.asarray(max_velocity, dtype=float)
        if vmax.shape != (robot.nv,):
            raise InvalidInput(f"velocity limits must have shape ({robot.nv},), got {vmax.shape}")
        if np.any(np.isnan(vmax)) or np.any(vmax <= 0):
            raise InvalidInput("velocity limits must be positive (inf for none)")
        self.max_velocity = vmax

    def apply(self, dt: float, lb: np.ndarray, ub: np.ndarray) -> None:
        np.maximum(lb, -self.max_velocity, out=lb)
        np.minimum(ub, self.max_velocity, out=ub)
