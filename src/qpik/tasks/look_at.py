"""Point a frame's axis at a target point, in every world; the roll about the axis is left free."""

from __future__ import annotations

import numpy as np

from ..errors import InvalidInput, InvalidWorlds, listed
from ..numerics import skew
from .inputs import feedback_gain, finite_vector, world_values
from .task import Task

SMALLEST_NORM = 1e-12  # an axis, a direction or a distance to the target shorter than this is none


def unit_axis(axis, what: str) -> np.ndarray:
    """``axis`` as a unit (3,) vector; InvalidInput for a wrong shape, NaN or zero."""
    vector = finite_vector(axis, 3, what)
    norm = float(np.linalg.norm(vector))
    if norm < SMALLEST_NORM:
        raise InvalidInput(f"{what} must be a non-zero vector, got {vector}")
    return vector / norm


def world_unit_vectors(robot, value, what: str) -> np.ndarray:
    """(N, 3) unit vectors from one (3,) vector for every world or (N, 3) one per world.

    Raises:
        InvalidInput: a wrong shape, NaN, inf or a zero vector (InvalidWorlds: in some worlds).
    """
    vectors = world_values(robot, value, (3,), what)
    norms = np.sqrt(np.einsum("ni,ni->n", vectors, vectors))
    bad = np.flatnonzero(~(norms >= SMALLEST_NORM))
    if len(bad) and not robot.batched:
        raise InvalidInput(f"{what} must be a non-zero vector, got {vectors[0]}")
    if len(bad):
        raise InvalidWorlds(f"{what} of worlds {listed(bad)}: a zero vector", bad)
    return vectors / norms[:, None]


class FrameAxes:
    """A frame's Jacobians in its own axes, :math:`R^T J_v` and :math:`R^T J_\\omega`
    (N, 3, nv) each, in every world: what the look-at and axis-align rows are made of."""

    def __init__(self, robot, frame):
        n, nv = robot.n, robot.nv
        self.frame = frame
        self._world = np.zeros((n, 6, nv))  # [J_v; J_ω], world axes
        self.linear, self.angular = np.zeros((n, 3, nv)), np.zeros((n, 3, nv))
        self._transposed = frame.rotations.transpose(0, 2, 1)  # Rᵀ of every world (a view)

    def update(self, linear: bool = True) -> None:
        """Refresh ``angular`` (and ``linear``) from the current kinematics."""
        jac = self._world
        self.frame.jacobians(jac[:, :3] if linear else None, jac[:, 3:])
        if linear:
            np.matmul(self._transposed, jac[:, :3], self.linear)
        np.matmul(self._transposed, jac[:, 3:], self.angular)


class Sight:
    r"""The target point as a frame sees it, in every world: :math:`r = R^T (p^* - p)` (N, 3),
    its length :math:`\|r\|` (at least :data:`SMALLEST_NORM`) and :math:`\hat d = r/\|r\|`."""

    def __init__(self, n: int):
        self.offset, self.r, self.direction = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3))
        self.norm = np.zeros((n, 1, 1))
        self._norm = self.norm[:, 0]  # (N, 1)

    def __call__(self, points: np.ndarray, positions: np.ndarray, rotations: np.ndarray) -> Sight:
        np.subtract(points, positions, self.offset)
        r = self.r
        np.matmul(self.offset[:, None, :], rotations, r[:, None, :])  # (Rᵀ(p* − p))ᵀ
        np.matmul(r[:, None, :], r[:, :, None], self.norm)
        np.sqrt(self.norm, self.norm)
        np.maximum(self.norm, SMALLEST_NORM, self.norm)
        np.divide(r, self._norm, self.direction)
        return self


class FrameAxisTask(Task):
    """What :class:`LookAtTask` and :class:`~qpik.tasks.axis_align.AxisAlignTask` share: a
    frame's axis (its own coordinates, normalised), its Jacobians in its own axes and a
    dead-beat gain by default, as every tracking task's; a subclass sets its target up in ``_start``."""

    dim = 3

    def __init__(self, robot, frame: str, frame_type: str = "site", axis=(0.0, 0.0, 1.0), **options):
        super().__init__(robot, **options)
        if self.gains is None:
            self.set_gain(feedback_gain(None, self.dim, f"{self.name} gain"))
        self.frame = robot.frame(frame, frame_type)
        self.axis = unit_axis(axis, f"{self.name} axis")
        robot.ensure_kinematics()
        self._axes = FrameAxes(robot, self.frame)
        self._skew = np.zeros((robot.n, 3, 3))
        self._start(robot)

    def _frame_on(self, robot) -> tuple:
        """(robot, the task's frame on it): the bound robot (None) or another of the same model."""
        if robot is None or robot is self.robot:
            return self.robot, self.frame
        return robot, robot.frame(self.frame.name, self.frame.type)

    def _no_velocity(self, velocity, target: str) -> None:
        if velocity is not None:
            raise InvalidInput(f"{self.name}: the target is {target}; it takes no velocity")


class LookAtTask(FrameAxisTask):
    r"""Point a frame's axis :math:`a` (its own coordinates) at a target point :math:`p^*`,
    as mink's ``LookAtTask``: only where the axis points is constrained (rank 2), the
    roll about it is left to other tasks.

    With the frame's rotation R and origin p, the direction to the target in the
    frame's axes is :math:`r = R^T (p^* - p)`, :math:`\hat d = r / \|r\|`. The task
    drives :math:`x = \hat d` to :math:`x_d = a`, in every world:

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
        robot: the robot (one world or N).
        frame: name of the site, body or geom.
        frame_type: ``"site"``, ``"body"`` or ``"geom"``.
        axis: the axis in the frame's own coordinates (normalised), default +z; one for
            every world.
        gain, weight, hard, priority, lm_damping: as for :class:`~qpik.tasks.task.Task`.

    The target is one unit along the axis at construction (the task is met);
    :meth:`set_target` moves it.

    Raises:
        UnknownName: no frame of that type has this name.
        InvalidInput: a zero or non-finite axis or target, a bad gain or weight.
    """

    name = "look-at task"

    def _start(self, robot) -> None:
        self.points = self.frame.positions + np.matmul(self.frame.rotations, self.axis)  # (N, 3)
        self.point = robot.present(self.points)
        self._sight = Sight(robot.n)
        n, nv = robot.n, robot.nv
        self._crossed, self._projected = np.zeros((n, 3, nv)), np.zeros((n, 3, nv))
        self._along = np.zeros((n, 1, nv))  # d̂ᵀ(J_v − [r]× J_ω)
        self._negative_norm = np.zeros((n, 1, 1))

    def set_target(self, point, velocity=None) -> None:
        """The world point (3,) the axis should point at, or (N, 3) one per world.

        Raises:
            InvalidInput: a wrong shape, NaN or inf (InvalidWorlds: in some worlds), or a
                feed-forward velocity (a point has none here: move the point instead).
        """
        self._no_velocity(velocity, "a point to look at")
        self.points[...] = world_values(self.robot, point, (3,), f"{self.name} target point")

    def measured(self, robot=None) -> np.ndarray:
        """x = d̂, the unit direction to the target in the frame's axes (a copy), on the
        bound robot or another robot of the same model and number of worlds."""
        robot, frame = self._frame_on(robot)
        sight = Sight(robot.n)(self.points, frame.positions, frame.rotations)
        return robot.present(sight.direction)

    def measure_rows(self) -> None:
        frame, axes = self.frame, self._axes
        sight = self._sight(self.points, frame.positions, frame.rotations)
        axes.update()
        np.subtract(self.axis, sight.direction, self.errors)
        # B = J_v − [r]× J_ω; J = −(B − d̂ (d̂ᵀB)) / ‖r‖
        bent = self._projected
        np.matmul(skew(sight.r, self._skew), axes.angular, self._crossed)
        np.subtract(axes.linear, self._crossed, bent)
        np.matmul(sight.direction[:, None, :], bent, self._along)
        np.multiply(sight.direction[:, :, None], self._along, self._crossed)
        np.subtract(bent, self._crossed, bent)
        np.negative(sight.norm, self._negative_norm)
        np.divide(bent, self._negative_norm, self.jacobians)
