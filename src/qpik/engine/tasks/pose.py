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
from .inputs import as_index


class PoseRows:
    """A frame's masked pose rows (see the module's description).

    Args:
        frame: the robot's :class:`~qpik.robot.Frame`.
        position_rows: the kept rows of the position block (world or local axes), or None.
        orientation_rows: those of the orientation block, or None.
        local: the frame's own axes.
    """

    def __init__(self, robot, frame, position_rows: np.ndarray | None, orientation_rows: np.ndarray | None,
                 local: bool):
        n, nv = robot.n, robot.nv
        self.frame, self.local = frame, local
        offset = 0 if position_rows is None else 3
        blocks = ([] if position_rows is None else [position_rows]) + \
            ([] if orientation_rows is None else [offset + orientation_rows])
        self.rows = as_index(np.concatenate(blocks).astype(int))
        self.dim = sum(len(b) for b in blocks)
        width = offset + (0 if orientation_rows is None else 3)
        self._jac = np.zeros((n, width, nv))  # the blocks' whole Jacobian, then rotated if local
        self._error = np.zeros((n, width))
        self._jacp = self._jac[:, :3] if position_rows is not None else None
        self._jacr = self._jac[:, offset:] if orientation_rows is not None else None
        self._position = slice(0, 3) if position_rows is not None else None
        self._orientation = slice(offset, width) if orientation_rows is not None else None
        self._rotation_error = RotationError(n)
        self._rotated = np.zeros((n, width, nv)) if local else None
        self._transposed = frame.rotations.transpose(0, 2, 1)  # Rᵀ of every world (a view)
        self._feedforward = np.zeros((n, width))

    def whole_rows(self) -> bool:
        """Whether every row of the blocks is kept in world axes (then J is MuJoCo's own)."""
        return not self.local and isinstance(self.rows, slice) and self.rows == slice(0, self._jac.shape[1])

    def jacobian(self) -> np.ndarray:
        """The blocks' Jacobian (N, width, nv), rotated into the frame's axes if local: a
        scratch array, valid until the next call."""
        self.frame.jacobians(self._jacp, self._jacr)
        if not self.local:
            return self._jac
        for block in (self._position, self._orientation):
            if block is not None:
                np.matmul(self._transposed, self._jac[:, block], out=self._rotated[:, block])
        return self._rotated

    def errors(self, target_position: np.ndarray | None, target_rotation: np.ndarray | None) -> np.ndarray:
        """The blocks' pose error (N, width), in the task's axes (a scratch array)."""
        e, frame = self._error, self.frame
        if self._position is not None:
            np.subtract(target_position, frame.positions, out=e[:, self._position])
            if self.local:
                e[:, self._position] = np.einsum("nji,nj->ni", frame.rotations, e[:, self._position])
        if self._orientation is not None:
            self._rotation_error(target_rotation, frame.rotations, e[:, self._orientation], self.local)
        return e

    def feedforward(self, linear: np.ndarray | None, angular: np.ndarray | None) -> np.ndarray:
        """The blocks' feed-forward velocity (N, width) in the task's axes, from world-axes
        velocities (a scratch array)."""
        f = self._feedforward
        for block, velocity in ((self._position, linear), (self._orientation, angular)):
            if block is None:
                continue
            if self.local:
                np.einsum("nji,nj->ni", self.frame.rotations, velocity, out=f[:, block])
            else:
                f[:, block] = velocity
        return f

    def write(self, task, target_position, target_rotation, linear=None, angular=None) -> None:
        """Write the task's ``jacobians``, ``errors`` and (with velocities) ``rates``."""
        rows = self.rows
        task.jacobians[...] = self.jacobian()[:, rows]
        task.errors[...] = self.errors(target_position, target_rotation)[:, rows]
        if linear is not None or angular is not None:
            task.rates[...] = self.feedforward(linear, angular)[:, rows]
