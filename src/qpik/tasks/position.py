"""Position of a frame (site, body or geom) on selected world or local axes."""

from __future__ import annotations

import numpy as np

from .inputs import mocap_pose, world_values
from .pose import MaskedFrameTask


class PositionTask(MaskedFrameTask):
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
        robot: the robot (one world or N).
        frame: name of the site, body or geom.
        frame_type: ``"site"``, ``"body"`` (its origin) or ``"geom"``.
        axes: the rows kept, a subset of ``"xyz"``.
        gain, weight, hard: K, dead-beat by default, and the rest as for :class:`~qpik.tasks.task.Task`.
        lm_damping: μ above.
        axes_frame: ``"world"`` or ``"local"`` (the frame's own axes).

    Raises:
        UnknownName: no frame of that type has this name (the closest are listed).
        InvalidInput: a bad gain, weight, mask or ``axes_frame``.
    """

    name = "position task"

    def _start(self, robot) -> None:
        start = self.frame.positions if self.local else self.frame.positions[:, self.rows]
        self.targets = np.array(start)  # (N, target_dim)
        self.target = robot.present(self.targets)
        self._velocities = np.zeros((robot.n, 3)) if self.local else self.rates  # ẋ_d, world axes
        self._fill = self._pose._fill
        # World axes: the kept rows of the frame's position (a view when consecutive).
        rows = self._pose.rows
        self._kept = self.frame.positions[:, rows] if isinstance(rows, slice) else np.zeros((robot.n, self.dim))

    def _allocate_jacobians(self) -> None:
        # World axes: the rows of MuJoCo's own Jacobian (a view, no copy per step).
        rows = self._pose.rows
        self.jacobians = self._pose.position_jacobian[:, rows] if not self.local and isinstance(rows, slice) else \
            np.zeros((self.robot.n, self._pose.dim, self.robot.nv))

    @property
    def target_dim(self) -> int:
        """Length of a target: ``len(axes)`` in world axes, 3 (a world position) in local axes."""
        return self.targets.shape[1]

    def set_target(self, position, velocity=None) -> None:
        """Desired position and feed-forward velocity: on the masked world axes, or a
        world position (3,) and velocity with ``axes_frame="local"``; one for every world,
        or (N, ...) one per world.

        Raises:
            InvalidInput: a wrong shape, NaN or inf (InvalidWorlds: in some worlds).
        """
        size = self.target_dim
        target = world_values(self.robot, position, (size,), "target position")
        rate = None if velocity is None else world_values(self.robot, velocity, (size,), "target velocity")
        self.targets[...] = target
        self._velocities[...] = 0.0 if rate is None else rate

    def set_target_from_configuration(self) -> None:
        """Desired position: the frame's position at the current configuration, in every world."""
        self.robot.ensure_kinematics()
        self.set_target(self.robot.present(self.measured_positions()))

    def set_target_from_mocap(self, body: str) -> None:
        """Desired position: a mocap body's (``data.mocap_pos``), read now (one world)."""
        position = mocap_pose(self.robot, body)[0]
        self.set_target(position if self.local else position[self.rows])

    def measured_positions(self) -> np.ndarray:
        """The tracked position of every world in the target's coordinates (N, target_dim), a copy."""
        positions = self.frame.positions
        return positions.copy() if self.local else positions[:, self.rows]

    def measured(self, robot=None) -> np.ndarray:
        """The tracked position (a copy) as a user reads it, on the bound robot or another
        robot of the same model (after its kinematics update)."""
        if robot is None or robot is self.robot:
            return self.robot.present(self.measured_positions())
        position = robot.frame_position(self.frame)
        return position.copy() if self.local else position[self.rows]

    def measure_rows(self) -> None:
        if self.local:
            self._pose.write(self, self.targets, None, self._velocities)
            return
        self._fill()
        if not isinstance(self._pose.rows, slice):
            np.take(self._pose.position_jacobian, self.rows, 1, self.jacobians)
            np.take(self.frame.positions, self.rows, 1, self._kept)
        np.subtract(self.targets, self._kept, self.errors)
