r"""Masked rows of a frame's pose, in every world: the position and/or orientation error,
its Jacobian and the feed-forward velocity, in world axes or in the frame's own.

The blocks are the position (rows 0-2) and the orientation (next three) of ``frame``;
``rows`` picks among them. In world axes the rows are the world's; in the frame's own
axes (``local``) the error e, the feed-forward velocity and J are rotated by
:math:`R^T`: the rows then measure the pose along the frame's current axes
(:math:`\dot{(R^T e)} = R^T\dot e + \dot R^T e`: the second term, of order
:math:`\|e\|\,\|\omega\|`, is left out, as in placo's local masks).

Shared by :class:`~qpik.PositionTask`, :class:`~qpik.OrientationTask` and
:class:`~qpik.FrameTask`; everything is preallocated, nothing is allocated per step.
"""

from __future__ import annotations

import numpy as np

from ..numerics import RotationError
from .inputs import as_index, axis_rows, check_axes_frame, feedback_gain
from .task import Task


class PoseRows:
    """A frame's masked pose rows (see the module's description).

    Args:
        robot: the robot (one world or N).
        frame: the robot's frame.
        position_rows: the kept rows of the position block (world or local axes), or None.
        orientation_rows: those of the orientation block, or None.
        local: the frame's own axes.
    """

    def __init__(self, robot, frame, position_rows: np.ndarray | None, orientation_rows: np.ndarray | None,
                 local: bool):
        n, nv = robot.n, robot.nv
        self.frame, self.local = frame, local
        offset = 0 if position_rows is None else 3
        kept = ([] if position_rows is None else [position_rows]) + \
            ([] if orientation_rows is None else [offset + orientation_rows])
        self.rows = as_index(np.concatenate(kept).astype(int))
        self.dim = sum(len(b) for b in kept)
        width = offset + (0 if orientation_rows is None else 3)
        self._jac, self._error, self._feedforward = np.zeros((n, width, nv)), np.zeros((n, width)), np.zeros((n, width))
        blocks = ([slice(0, 3)] if position_rows is not None else []) + \
            ([slice(offset, width)] if orientation_rows is not None else [])
        # Per block: (its rows of the Jacobian, of the error, of the feed-forward): views made once.
        self._blocks = [(self._jac[:, b], self._error[:, b], self._feedforward[:, b]) for b in blocks]
        self._position = self._blocks[0] if position_rows is not None else None
        self.position_jacobian = self._position[0] if self._position else None  # (N, 3, nv), MuJoCo's
        self._orientation = self._blocks[-1] if orientation_rows is not None else None
        self._rotation_error = RotationError(n)
        self._rotated = np.zeros((n, width, nv)) if local else None
        self._rotated_blocks = [self._rotated[:, b] for b in blocks] if local else None
        self._transposed = frame.rotations.transpose(0, 2, 1) if local else None  # Rᵀ of every world (a view)
        self._fill = frame.jacobians_filler(self._position[0] if self._position else None,
                                            self._orientation[0] if self._orientation else None)

    def whole_rows(self) -> bool:
        """Whether every row of the blocks is kept in world axes (then J is MuJoCo's own)."""
        return not self.local and isinstance(self.rows, slice) and self.rows == slice(0, self._jac.shape[1])

    def jacobian(self) -> np.ndarray:
        """The blocks' Jacobian (N, width, nv), rotated into the frame's axes if local: a
        scratch array, valid until the next call."""
        self._fill()
        if not self.local:
            return self._jac
        for (jac, _, _), rotated in zip(self._blocks, self._rotated_blocks):
            np.matmul(self._transposed, jac, rotated)
        return self._rotated

    def errors(self, target_position: np.ndarray | None, target_rotation: np.ndarray | None) -> np.ndarray:
        """The blocks' pose error (N, width), in the task's axes (a scratch array)."""
        frame = self.frame
        if self._position is not None:
            error = self._position[1]
            np.subtract(target_position, frame.positions, error)
            if self.local:
                error[...] = np.einsum("nji,nj->ni", frame.rotations, error)
        if self._orientation is not None:
            self._rotation_error(target_rotation, frame.rotations, self._orientation[1], self.local)
        return self._error

    def feedforward(self, linear: np.ndarray | None, angular: np.ndarray | None) -> np.ndarray:
        """The blocks' feed-forward velocity (N, width) in the task's axes, from world-axes
        velocities (a scratch array)."""
        for block, velocity in ((self._position, linear), (self._orientation, angular)):
            if block is None:
                continue
            if self.local:
                np.einsum("nji,nj->ni", self.frame.rotations, velocity, out=block[2])
            else:
                block[2][...] = velocity
        return self._feedforward

    def write(self, task, target_position, target_rotation, linear=None, angular=None) -> None:
        """Write the task's ``jacobians``, ``errors`` and (with velocities) ``rates``."""
        rows = self.rows
        task.jacobians[...] = self.jacobian()[:, rows]
        task.errors[...] = self.errors(target_position, target_rotation)[:, rows]
        if linear is not None or angular is not None:
            task.rates[...] = self.feedforward(linear, angular)[:, rows]


class MaskedFrameTask(Task):
    """What :class:`~qpik.PositionTask` and :class:`~qpik.OrientationTask` share: the rows
    ``rows`` of a mask ``axes`` of one block of a frame's pose (``block``), in world or
    local axes, and one gain K; a subclass sets its targets up in ``_start``."""

    block = "position"

    def __init__(self, robot, frame: str, frame_type: str = "site", axes: str = "xyz", gain=None, weight=1.0,
                 hard: bool = False, lm_damping: float = 0.0, axes_frame: str = "world"):
        self.rows = axis_rows(axes)
        self.axes_frame = axes_frame
        self.local = check_axes_frame(axes_frame)
        self.frame = robot.frame(frame, frame_type)
        position = self.block == "position"
        self._pose = PoseRows(robot, self.frame, self.rows if position else None, None if position else self.rows,
                              self.local)
        super().__init__(robot, len(self.rows), weight, hard, lm_damping=lm_damping)
        self.set_gain(feedback_gain(gain, self.dim, f"{self.block} gain"))
        self._start(robot)
