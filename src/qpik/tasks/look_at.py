"""Point a frame's axis at a target point; the roll about the axis is left free."""

from __future__ import annotations

import numpy as np

from ..errors import InvalidInput
from ..robot import Robot
from .task import Task, finite_vector


def unit_axis(axis, what: str) -> np.ndarray:
    """``axis`` as a unit (3,) vector; InvalidInput for a wrong shape, NaN or zero."""
    vector = finite_vector(axis, 3, what)
    norm = float(np.linalg.norm(vector))
    if norm < 1e-12:
        raise InvalidInput(f"{what} must be a non-zero vector, got {vector}")
    return vector / norm


def skew(vector: np.ndarray) -> np.ndarray:
    """[v]×: the matrix of the cross product v × ·."""
    x, y, z = vector
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def local_jacobians(robot: Robot, frame) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(R, Jv, Jω): the frame's rotation and its Jacobians in its own axes (3 x nv each)."""
    jacp, jacr = np.zeros((3, robot.nv)), np.zeros((3, robot.nv))
    robot.frame_jacobian(frame, jacp, jacr)
    rotation = robot.frame_rotation(frame)
    return rotation, rotation.T @ jacp, rotation.T @ jacr


class LookAtTask(Task):
    r"""Point a frame's axis :math:`a` (its own coordinates) at a target point :math:`p^*`,
    as mink's ``LookAtTask``: only where the axis points is constrained (rank 2), the
    roll about it is left to other tasks.

    With the frame's rotation R and origin p, the direction to the target in the
    frame's axes is :math:`r = R^T (p^* - p)`, :math:`\hat d = r / \|r\|`. The task
    drives :math:`x = \hat d` to :math:`x_d = a`:

    .. math::
        e = a - \hat d,\qquad
        J = \frac{\partial \hat d}{\partial q}
          = -\frac{1}{\|r\|} (I - \hat d \hat d^T) (J_v - [r]_\times J_\omega),

    :math:`J_v, J_\omega` the frame's Jacobians in its own axes (mink's J with the
    opposite sign: mink's J is :math:`\partial e / \partial q`). The translation term
    lets the controller move the frame, not only turn it. Degenerate with the target at
    the frame's origin or straight behind the axis (:math:`\hat d = -a`): there
    ``lm_damping`` keeps the step bounded. The three rows have rank 2: keep the task soft
    (a hard one gives dependent equality rows).

    Args:
        robot: the robot.
        frame: name of the site, body or geom.
        frame_type: ``"site"``, ``"body"`` or ``"geom"``.
        axis: the axis in the frame's own coordinates (normalised), default +z.
        gain, weight, hard, priority, lm_damping: as for :class:`~qpik.tasks.task.Task`.

    The target is one unit along the axis at construction (the task is met);
    :meth:`set_target` moves it.

    Raises:
        UnknownName: no frame of that type has this name.
        InvalidInput: a zero or non-finite axis or target, a bad gain or weight.
    """

    name = "look-at task"
    dim = 3

    def __init__(self, robot: Robot, frame: str, frame_type: str = "site", axis=(0.0, 0.0, 1.0), **options):
        super().__init__(robot, **options)
        self.frame = robot.frame(frame, frame_type)
        self.axis = unit_axis(axis, f"{self.name} axis")
        robot.ensure_kinematics()
        self.point = self.frame.position + self.frame.rotation @ self.axis

    def set_target(self, point, velocity=None) -> None:
        """The world point (3,) the axis should point at.

        Raises:
            InvalidInput: a wrong shape, NaN or inf, or a feed-forward velocity (a point
                has none here: move the point instead).
        """
        if velocity is not None:
            raise InvalidInput(f"{self.name}: the target is a point to look at; it takes no velocity")
        self.point = finite_vector(point, 3, f"{self.name} target point")

    def measured(self, robot: Robot | None = None) -> np.ndarray:
        """x = d̂, the unit direction to the target in the frame's axes."""
        return self._direction(robot or self.robot)[1]

    def _direction(self, robot: Robot) -> tuple[np.ndarray, np.ndarray, float]:
        rotation = robot.frame_rotation(self.frame)
        r = rotation.T @ (self.point - robot.frame_position(self.frame))
        n = max(float(np.linalg.norm(r)), 1e-12)
        return r, r / n, n

    def compute_error(self, robot: Robot) -> np.ndarray:
        return self.axis - self._direction(robot)[1]

    def compute_jacobian(self, robot: Robot) -> np.ndarray:
        r, d, n = self._direction(robot)
        _, jac_v, jac_w = local_jacobians(robot, self.frame)
        return -((np.eye(3) - np.outer(d, d)) @ (jac_v - skew(r) @ jac_w)) / n
