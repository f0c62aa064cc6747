"""Pose of a frame in another frame's coordinates, in every world."""

from __future__ import annotations

import numpy as np

from ..errors import InvalidInput
from ..numerics import RotationError, skew
from .frame import PoseTask


class RelativeFrameTask(PoseTask):
    r"""Track the pose of ``frame`` in the coordinates of ``root`` (both move).

    With :math:`d = p_f - p_r`, the relative pose is :math:`p = R_r^T d`,
    :math:`R = R_r^T R_f`, and its time derivative, in root coordinates,

    .. math::
        \dot p = R_r^T\,(J_{p,f} - J_{p,r} + [d]_\times J_{\omega,r})\,\dot q,\qquad
        \omega = R_r^T\,(J_{\omega,f} - J_{\omega,r})\,\dot q,

    the task's two 3-row blocks. As for :class:`~qpik.tasks.frame.FrameTask`,
    :math:`v = [\dot p_d + K_p (p_d - p);\ \omega_d + K_o e_o]` with
    :math:`\exp([e_o]_\times) R = R_d`, all in root coordinates. With ``root`` the world
    body this is the FrameTask. mink's RelativeFrameTask regulates the same pose.

    Args:
        robot: the robot (one world or N).
        frame: name of the tracked site, body or geom.
        root: name of the site, body or geom whose coordinates the pose is taken in.
        frame_type: type of ``frame``: ``"site"``, ``"body"`` or ``"geom"``.
        root_type: type of ``root``.
        position_gain, orientation_gain: :math:`K_p`, :math:`K_o` (1/s), a scalar or one
            per axis each; default ``None``: dead-beat, as a :class:`~qpik.tasks.task.Task`'s.
        weight, hard, lm_damping: as for :class:`~qpik.tasks.task.Task` (6 rows).

    Raises:
        UnknownName: a frame name unknown for its type (the closest are listed).
        InvalidInput: a bad gain or weight, or ``frame`` and ``root`` the same frame.

    The target is the relative pose when the task is built; :meth:`set_target` moves it
    (one for every world, or one per world).
    """

    name = "relative frame task"

    def __init__(self, robot, frame: str, root: str, frame_type: str = "site", root_type: str = "site",
                 position_gain=None, orientation_gain=None, weight=1.0, hard: bool = False, lm_damping: float = 0.0):
        super().__init__(robot, 6, weight, hard, lm_damping=lm_damping)
        self.frame = robot.frame(frame, frame_type)
        self.root = robot.frame(root, root_type)
        if (self.frame.type, self.frame.id) == (self.root.type, self.root.id):
            raise InvalidInput(f"{self.name}: frame and root are the same {frame_type} {frame!r}")
        n, nv = robot.n, robot.nv
        self._jac_frame, self._jac_root = np.zeros((n, 6, nv)), np.zeros((n, 6, nv))
        self._moved, self._crossed = np.zeros((n, 3, nv)), np.zeros((n, 3, nv))
        self._offset = np.zeros((n, 3))  # d
        self._skew = np.zeros((n, 3, 3))  # [d]×
        self._root_transposed = self.root.rotations.transpose(0, 2, 1)  # R_rᵀ of every world (a view)
        self.positions = np.zeros((n, 3))  # the relative pose, refreshed by every update
        self.rotations = np.zeros((n, 3, 3))
        self._relative_pose()
        self._start_pose(self.positions, self.rotations, self.rates, position_gain, orientation_gain, 3)
        self._rotation_error = RotationError(n)
        self.position, self.rotation = robot.present(self.positions), robot.present(self.rotations)

    def _relative_pose(self) -> None:
        """p = R_rᵀ d (as the row dᵀR_r) and R = R_rᵀ R_f in every world."""
        np.subtract(self.frame.positions, self.root.positions, self._offset)
        np.matmul(self._offset[:, None, :], self.root.rotations, self.positions[:, None, :])
        np.matmul(self._root_transposed, self.frame.rotations, self.rotations)

    def _pose_now(self) -> tuple[np.ndarray, np.ndarray]:
        self._relative_pose()
        return self.positions, self.rotations

    def measure_rows(self) -> None:
        jf, jr, moved = self._jac_frame, self._jac_root, self._moved
        self.frame.jacobians(jf[:, :3], jf[:, 3:])
        self.root.jacobians(jr[:, :3], jr[:, 3:])
        self._relative_pose()
        # R_rᵀ (J_pf − J_pr + [d]× J_ωr), then R_rᵀ (J_ωf − J_ωr)
        np.subtract(jf[:, :3], jr[:, :3], moved)
        np.matmul(skew(self._offset, self._skew), jr[:, 3:], self._crossed)
        np.add(moved, self._crossed, moved)
        np.matmul(self._root_transposed, moved, self.jacobians[:, :3])
        np.subtract(jf[:, 3:], jr[:, 3:], moved)
        np.matmul(self._root_transposed, moved, self.jacobians[:, 3:])
        np.subtract(self.target_positions, self.positions, self.errors[:, :3])
        self._rotation_error(self.target_rotations, self.rotations, self.errors[:, 3:])
