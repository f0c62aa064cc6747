"""The arm's orientation in its plane: φ = θ1 + θ2 + θ3, the angle of a site about world z.

A minimal one-row task for the ``three-tasks`` scenario (until the general orientation
task covers a single axis): φ = atan2(R[1, 0], R[0, 0]) of the site's rotation R, and
J the z row of the site's rotational Jacobian, which on the arm is [1, 1, 1, 0].
"""

from __future__ import annotations

import numpy as np

from ...errors import InvalidInput
from ...tasks.inputs import positive, world_values
from ...tasks.task import Task


class PlanarOrientationTask(Task):
    """Track a site's angle φ about the world z axis: v = φ̇_d + K wrap(φ_d − φ), in every world.

    Args:
        robot: the robot (one world or N).
        site: the site whose frame turns.
        gain: K (1/s).
        weight: cost weight when soft.
        hard: enforce as an equality in the QP.
    """

    name = "planar orientation task"

    def __init__(self, robot, site: str, gain: float = 1.0, weight=1.0, hard: bool = False):
        self.frame = robot.frame(site, "site")
        self._jacr = np.zeros((robot.n, 3, robot.nv))
        super().__init__(robot, 1, weight, hard)
        self.set_gain(positive(gain, 1, "orientation gain", allow_zero=True))
        self._fill = self.frame.jacobians_filler(None, self._jacr)
        self.targets = self.angles()[:, None]
        self.target = robot.present(self.targets)

    def _allocate_jacobians(self) -> None:
        self.jacobians = self._jacr[:, 2:3]  # a view MuJoCo fills

    def angles(self) -> np.ndarray:
        """φ of the site in every world now, in (−π, π] (N,)."""
        rotations = self.frame.rotations
        return np.arctan2(rotations[:, 1, 0], rotations[:, 0, 0])

    def angle(self):
        """φ as a user reads it: a number for one robot, (N,) for a batch."""
        angles = self.angles()
        return float(angles[0]) if not self.robot.batched else angles

    def set_target(self, angle, rate=None) -> None:
        """Desired φ (rad) and its rate (rad/s): a number (or (1,)) for every world, or one per world."""
        target = self._per_world(angle, "target angle")
        self.rates[...] = 0.0 if rate is None else self._per_world(rate, "target rate")
        self.targets[...] = target

    def _per_world(self, value, what: str) -> np.ndarray:
        try:
            column = np.asarray(value, dtype=float).reshape(-1, 1)
        except (TypeError, ValueError):
            raise InvalidInput(f"{what} must be a number, or one per world, got {value!r}") from None
        return world_values(self.robot, column[0] if len(column) == 1 else column, (1,), what)

    def measure_rows(self) -> None:
        self._fill()
        difference = self.targets[:, 0] - self.angles()
        # The short way round (IEEE remainder, as math.remainder): the error in [−π, π].
        self.errors[:, 0] = difference - 2.0 * np.pi * np.round(difference / (2.0 * np.pi))
