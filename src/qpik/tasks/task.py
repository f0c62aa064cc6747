r"""The Task interface: linear relations :math:`J \dot q \approx v` shared by every controller.

After :meth:`Task.update` a task exposes

- ``jacobian`` (dim x nv) and ``target_velocity`` (dim,): the rows :math:`J\dot q = v`;
- ``error`` (dim,): what the task measures (its units: metres, radians, ...);
- ``weight`` (dim,): the cost weight when soft;
- ``hard``: enforced as an equality (QP) or weighed in the cost;
- ``priority``: the task's level in a strict hierarchy (0 the highest; tasks of equal
  priority share a level and are weighed against each other there);
- ``lm_damping``: adaptive Levenberg–Marquardt weight μ, adding
  :math:`\tfrac12 \mu\, e^T W e\, \|\dot q\|^2` to the cost of a soft task;
- ``joint_space``: True when J is a fixed selection of rows of the identity
  (``dofs``): a controller may then add the task to the Hessian's diagonal without
  reading J. A task says this itself; controllers never guess from its type.

The QP either enforces a task (``hard=True``: :math:`J\dot q = v`) or adds
:math:`\tfrac12 \|J\dot q - v\|_W^2`; the classical laws use the same two arrays. Tracking
tasks use the closed-loop inverse kinematics velocity :math:`v = \dot x_d + K (x_d - x)`.

Frame-based tasks (position, orientation, pose, relative pose) act on a site, a body (its
origin) or a geom (``frame_type``). Their masks (``axes``), gains and weights refer to the
world's axes (``axes_frame="world"``, the default) or to the frame's own moving axes
(``axes_frame="local"``: e, the feed-forward velocity and J rotated by :math:`R^T`).

All arrays are preallocated: ``update`` writes in place and allocates nothing big.
"""

from __future__ import annotations

import math
import warnings
from typing import Sequence

import mujoco
import numpy as np

from ..errors import GainWarning, InvalidInput
from ..robot import Robot

_AXES = "xyz"
AXES_FRAMES = ("world", "local")


def axis_rows(axes: str, what: str = "axes") -> np.ndarray:
    """Row indices of a mask such as ``"xy"`` (a non-empty subset of ``"xyz"``)."""
    if not isinstance(axes, str) or not axes or any(a not in _AXES for a in axes) or len(set(axes)) != len(axes):
        raise InvalidInput(f"{what} must be a non-empty subset of 'xyz', got {axes!r}")
    return np.array(sorted(_AXES.index(a) for a in axes), dtype=int)


def check_axes_frame(axes_frame: str) -> bool:
    """Whether masks, gains and weights refer to the frame's own axes (``"local"``) or the
    world's (``"world"``); InvalidInput otherwise."""
    if axes_frame not in AXES_FRAMES:
        raise InvalidInput(f"axes_frame must be one of {AXES_FRAMES}, got {axes_frame!r}")
    return axes_frame == "local"


def contiguous_rows(rows: np.ndarray) -> slice | None:
    """``rows`` as a slice when they are consecutive (then views replace copies), else None."""
    if rows[-1] - rows[0] + 1 == len(rows):
        return slice(int(rows[0]), int(rows[-1]) + 1)
    return None


def rotation_matrix(rotation, what: str = "target rotation") -> np.ndarray:
    """``rotation`` as a float (3, 3) array after a cheap check that it is a rotation.

    ``rotation`` is a 3x3 rotation matrix, or a unit quaternion (4,) in MuJoCo's
    w-x-y-z order (converted with ``mju_quat2Mat``).

    Raises:
        InvalidInput: not a finite 3x3 matrix, not orthonormal to 1e-6, or a reflection;
            or a quaternion that is not finite or not of unit norm to 1e-6.
    """
    try:
        rot = np.asarray(rotation, dtype=float)
    except (TypeError, ValueError):
        raise InvalidInput(f"{what} must be a 3x3 matrix or a w-x-y-z quaternion of numbers, got {rotation!r}") from None
    if rot.shape == (4,):
        rot = quaternion_matrix(rot, what)
    elif rot.shape != (3, 3):
        raise InvalidInput(f"{what} must be a 3x3 matrix or a (4,) w-x-y-z quaternion, got shape {rot.shape}")
    # In floats (NumPy reductions cost several times more on a 3x3): columns of unit
    # length, pairwise orthogonal (each entry of RᵀR − I within 1e-6), determinant +1.
    (a, b, c), (d, e, f), (g, h, i) = rot.tolist()
    gram = xx, yy, zz, xy, xz, yz = (a * a + d * d + g * g - 1.0, b * b + e * e + h * h - 1.0,
                                     c * c + f * f + i * i - 1.0, a * b + d * e + g * h,
                                     a * c + d * f + g * i, b * c + e * f + h * i)
    tol = 1e-6  # comparisons only, no calls (NaN fails them)
    if not (-tol <= xx <= tol and -tol <= yy <= tol and -tol <= zz <= tol and -tol <= xy <= tol
            and -tol <= xz <= tol and -tol <= yz <= tol):
        if not math.isfinite(sum(gram)):
            raise InvalidInput(f"{what} contains NaN or inf")
        raise InvalidInput(f"{what} is not a rotation matrix (|RᵀR − I| = {max(abs(x) for x in gram):.2g})")
    if a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g) < 0:
        raise InvalidInput(f"{what} is a reflection (det < 0), not a rotation")
    return rot


def quaternion_matrix(quaternion, what: str = "target quaternion") -> np.ndarray:
    """The rotation matrix of a unit quaternion in MuJoCo's w-x-y-z order.

    Raises:
        InvalidInput: not 4 finite numbers, or a norm farther than 1e-6 from 1 (a
            quaternion is not normalised silently: a wrong order or a typo shows here).
    """
    quat = finite_vector(quaternion, 4, what)
    norm = math.sqrt(sum(x * x for x in quat.tolist()))
    if abs(norm - 1.0) > 1e-6:
        raise InvalidInput(f"{what} must be a unit quaternion (w, x, y, z), got norm {norm:.6g}")
    flat = np.empty(9)
    mujoco.mju_quat2Mat(flat, quat)
    return flat.reshape(3, 3)


def homogeneous_transform(transform, what: str = "target transform") -> tuple[np.ndarray, np.ndarray]:
    """(position (3,), rotation (3, 3)) of a homogeneous 4x4 transform [[R, p], [0, 0, 0, 1]].

    Raises:
        InvalidInput: not a finite 4x4 array, a last row other than (0, 0, 0, 1), or a
            block R that is no rotation.
    """
    try:
        matrix = np.asarray(transform, dtype=float)
    except (TypeError, ValueError):
        raise InvalidInput(f"{what} must be a 4x4 matrix of numbers, got {transform!r}") from None
    if matrix.shape != (4, 4):
        raise InvalidInput(f"{what} must be a 4x4 homogeneous matrix, got shape {matrix.shape}")
    if not np.array_equal(matrix[3], [0.0, 0.0, 0.0, 1.0]):
        raise InvalidInput(f"{what}: the last row of a homogeneous transform must be (0, 0, 0, 1), got {matrix[3]}")
    return finite_vector(matrix[:3, 3], 3, f"{what}'s translation"), rotation_matrix(matrix[:3, :3], f"{what}'s rotation")


def mocap_pose(robot: Robot, body: str) -> tuple[np.ndarray, np.ndarray]:
    """(position, rotation matrix) of a mocap body, read from ``data.mocap_pos/quat`` (copies).

    Raises:
        UnknownName: no body of that name.
        InvalidInput: the body is not a mocap body.
    """
    body_id = robot.body_id(body)
    mocap = int(robot.model.body_mocapid[body_id])
    if mocap < 0:
        raise InvalidInput(f"body {body!r} is not a mocap body (mocap=\"true\"); mocap bodies: "
                           f"{[robot.model.body(i).name for i in range(robot.model.nbody) if robot.model.body_mocapid[i] >= 0]}")
    return robot.data.mocap_pos[mocap].copy(), quaternion_matrix(robot.data.mocap_quat[mocap], f"mocap body {body!r}'s quaternion")


def feedback_gain(value, size: int, what: str) -> np.ndarray:
    """A task's gain K (1/s): a scalar or one per row, finite and >= 0; ``None`` for the
    dead-beat default, NaN until a controller gives its period (:meth:`Task.attach`)."""
    if value is None:
        return np.full(size, np.nan)
    return positive(value, size, what, allow_zero=True)


class RotationError:
    """e with exp([e]) R_current = R_desired, world (or current-frame) axes, no allocation.

    MuJoCo's quaternion difference (``mju_subQuat``) gives the rotation vector in the
    current frame's axes; :meth:`world` rotates it into the world's.
    """

    def __init__(self) -> None:
        self._desired, self._current = np.empty(4), np.empty(4)
        self.local = np.empty(3)

    def compute(self, desired: np.ndarray, current: np.ndarray) -> np.ndarray:
        """The error in the current frame's axes (``self.local``, overwritten next call)."""
        mujoco.mju_mat2Quat(self._desired, desired.reshape(9))
        mujoco.mju_mat2Quat(self._current, current.reshape(9))
        mujoco.mju_subQuat(self.local, self._desired, self._current)  # qc * exp(local) = qd
        return self.local

    def world(self, desired: np.ndarray, current: np.ndarray, out: np.ndarray) -> np.ndarray:
        """The error in world axes, written into ``out``."""
        return current.dot(self.compute(desired, current), out)


def rotation_error(desired: np.ndarray, current: np.ndarray) -> np.ndarray:
    """World-frame rotation vector e with exp([e]) R_current = R_desired."""
    out = np.empty(3)
    return RotationError().world(np.ascontiguousarray(desired), np.ascontiguousarray(current), out)


def finite_vector(value, size: int, what: str) -> np.ndarray:
    """``value`` as a float array of shape (size,), or InvalidInput naming ``what``."""
    arr = float_array(value, size, what)
    # Per target, every step: a sum of floats is NaN or inf when an entry is (0.2 µs
    # where np.isfinite and np.all cost 2 µs); an overflowing sum is refused as well.
    if not math.isfinite(sum(arr.tolist())):
        raise InvalidInput(f"{what} contains NaN or inf (or overflows): {arr}")
    return arr


def float_array(value, size: int, what: str) -> np.ndarray:
    """``value`` as a float array of shape (size,) (its entries not checked), or InvalidInput."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise InvalidInput(f"{what} must be {size} numbers, got {value!r}") from None
    if arr.shape != (size,):
        raise InvalidInput(f"{what} must have shape ({size},), got {arr.shape}")
    return arr


# A target (or feed-forward velocity) entry beyond this is refused: no model is that large,
# and it keeps K·e, its square and J q̇ − v finite for any gain with K·Δt <= 2 and Δt > 1e-150.
TARGET_MAGNITUDE_LIMIT = 1e150


def check_targets(*named: tuple[np.ndarray, str]) -> None:
    """Each (array, what) checked as :func:`target_vector` checks it, in one pass over all
    of them (a step's targets: the pass is the check's cost)."""
    values = []
    for array, _ in named:
        values += array.tolist()
    # One C call: the norm is at most the limit only if every entry is finite and within
    # it (NaN fails the comparison); past it, each entry is checked and the culprit named.
    if not math.hypot(*values) <= TARGET_MAGNITUDE_LIMIT:
        for array, what in named:
            target_vector(array, len(array), what)  # the culprit, named


class PointTarget:
    """A tracked point's target x_d and feed-forward ẋ_d (each (size,)), as one array:
    ``target`` and ``rate`` are its rows (views); :meth:`set` checks and writes both."""

    def __init__(self, target: np.ndarray, what: str, rate_what: str):
        self._both = np.zeros((2, len(target)))
        self._both[0] = target
        self.target, self.rate = self._both
        self._flat, self._names = self._both.reshape(-1), (what, rate_what)

    def set(self, position, velocity=None) -> None:
        """x_d = ``position``, ẋ_d = ``velocity`` (zero when None), checked as
        :func:`check_targets` checks them and written once both are (one write: a step's cost)."""
        size, (what, rate_what) = len(self.target), self._names
        position = float_array(position, size, what)
        rate = [0.0] * size if velocity is None else float_array(velocity, size, rate_what).tolist()
        values = position.tolist() + rate
        if not math.hypot(*values) <= TARGET_MAGNITUDE_LIMIT:  # the culprit named
            check_targets((position, what), (np.array(rate), rate_what))
        self._flat[:] = values


def target_vector(value, size: int, what: str) -> np.ndarray:
    """:func:`finite_vector`, and InvalidInput for an entry beyond
    :data:`TARGET_MAGNITUDE_LIMIT` (the feedback K·e would overflow)."""
    arr = float_array(value, size, what)
    values = arr.tolist()  # checked in floats, one pass each (every target, every step)
    if not math.isfinite(sum(values)):
        raise InvalidInput(f"{what} contains NaN or inf (or overflows): {arr}")
    if size and not (-TARGET_MAGNITUDE_LIMIT <= min(values) and max(values) <= TARGET_MAGNITUDE_LIMIT):
        raise InvalidInput(f"{what} {arr} is beyond {TARGET_MAGNITUDE_LIMIT:g} in magnitude: the feedback "
                           "K·e (and its square) would overflow; give a target the robot could reach")
    return arr


def positive(value, size: int, what: str, allow_zero: bool = False) -> np.ndarray:
    """A scalar (broadcast) or a (size,) vector of positive (or >= 0) finite values."""
    if np.ndim(value) == 0:
        try:
            arr = np.full(size, float(value))
        except (TypeError, ValueError):
            raise InvalidInput(f"{what} must be a number, got {value!r}") from None
    else:
        arr = finite_vector(value, size, what)
    ok = arr >= 0 if allow_zero else arr > 0
    if not np.all(np.isfinite(arr)) or not np.all(ok):
        raise InvalidInput(f"{what} must be {'non-negative' if allow_zero else 'positive'} and finite, got {value}")
    return arr


def positive_scalar(value, what: str, allow_zero: bool = False) -> float:
    """One positive (or >= 0) finite number as a float, checked as :func:`positive` checks
    a task's gains: for a parameter that takes no per-row values (InvalidInput otherwise)."""
    if isinstance(value, (str, bytes)) or np.ndim(value) != 0:
        raise InvalidInput(f"{what} must be a number, got {value!r}")
    return float(positive(value, 1, what, allow_zero)[0])


class ScalarGain:
    """A task's scalar gain K >= 0 (1/s) as an attribute, checked when set and kept as a
    0-d array too (``task._k``): NumPy multiplies by it with less overhead than by a float."""

    def __init__(self, what: str):
        self.what = what

    def __get__(self, task, owner=None):
        return self if task is None else task._gain

    def __set__(self, task, value) -> None:
        task._gain = positive_scalar(value, self.what, allow_zero=True)
        task._k = np.array(task._gain)


def _row_count(dim, name: str) -> int:
    """A task's row count: an integer >= 1 (InvalidInput otherwise)."""
    if isinstance(dim, (bool, np.bool_)) or not isinstance(dim, (int, np.integer)) or dim < 1:
        raise InvalidInput(f"{name} needs its row count dim, an integer >= 1 (a class attribute or dim=...), "
                           f"got {dim!r}")
    return int(dim)


def _checked_rows(value, shape: tuple, name: str, method: str) -> np.ndarray:
    """What a user task's method returned, as finite floats of the promised shape."""
    try:
        rows = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise InvalidInput(f"{name}.{method} must return numbers, got {value!r}") from None
    if rows.shape != shape:
        raise InvalidInput(f"{name}.{method} must return shape {shape}, got {rows.shape}")
    if not math.isfinite(float(rows.sum())):
        raise InvalidInput(f"{name}.{method} returned NaN or inf")
    return rows


class Task:
    r"""Base class: ``dim`` rows of :math:`J\dot q \approx v` with a weight.

    A task is written as in mink, with two methods and its row count::

        class TipHeight(qpik.Task):
            dim = 1
            def compute_error(self, robot):     # (dim,): e = x_d − x
                return np.array([self.target[0] - robot.data.site_xpos[site, 2]])
            def compute_jacobian(self, robot):  # (dim, nv): J = ∂x/∂q
                ...
        task = TipHeight(robot, gain=20.0, weight=1.0, hard=False, priority=0)

    The base class then owns the rest: each step it writes ``error`` and ``jacobian``
    from the two methods and :math:`v = \dot x_d + K e` (the feed-forward
    :math:`\dot x_d`, ``target_rate``, zero unless set), the gains K (checked
    against the controller's period: :meth:`attach`), the weights, ``hard``,
    ``priority`` and ``lm_damping``. Such a task runs in every controller.

    The built-in tasks override :meth:`update` instead (a faster in-place path, same
    arrays); :meth:`compute_error` and :meth:`compute_jacobian` then evaluate that path.

    Args:
        robot: the robot whose kinematics the task reads.
        dim: number of task rows (default: the class attribute ``dim``).
        weight: cost weight of a soft task (scalar or one per row); a zero weight
            leaves a row out of the cost (a mask).
        hard: enforce the task as an equality constraint in the QP.
        gain: K (1/s), a scalar or one per row, >= 0; default ``None``: dead-beat,
            1/Δt of the controller the task is given to (mink's ``gain=1``).
        priority: level in a strict hierarchy (0 the highest).
        lm_damping: adaptive Levenberg–Marquardt weight μ of a soft task (see
            :mod:`qpik.tasks.task`).

    Raises:
        InvalidInput: no row count, a bad weight, gain, priority or ``lm_damping``, or a
            subclass that defines neither :meth:`update` nor both compute methods.
    """

    name = "task"
    dim: int | None = None  # a subclass written with compute_error/compute_jacobian sets it
    lm_damping = 0.0
    target: np.ndarray | None = None  # x_d, for a task that tracks one (set_target)
    _priority = 0  # a class default, so every subclass has one without a constructor argument
    _gains: np.ndarray | None = None  # K when the base class owns it (feedback_gains)

    def __init__(self, robot: Robot, dim: int | None = None, weight=1.0, hard: bool = False, *, gain=None,
                 priority: int = 0, lm_damping: float = 0.0):
        if type(self).name == Task.name:  # a user's subclass: messages name its class
            self.name = type(self).__name__
        self.robot = robot
        self.dim = _row_count(type(self).dim if dim is None else dim, self.name)
        self.hard = bool(hard)
        self.weight = positive(weight, self.dim, f"{self.name} weight", allow_zero=True)
        self.priority = priority
        self.lm_damping = positive_scalar(lm_damping, f"{self.name} lm_damping", allow_zero=True)
        self._allocate_jacobian()
        self.target_velocity = np.zeros(self.dim)
        self.error = np.zeros(self.dim)
        generic = self._computes_rows()
        if generic or gain is not None:
            self._use_gain(feedback_gain(gain, self.dim, f"{self.name} gain"))
        self.target_rate = np.zeros(self.dim)  # ẋ_d (a built-in task may replace it)

    def _computes_rows(self) -> bool:
        """Whether the rows come from compute_error/compute_jacobian (no own ``update``)."""
        cls = type(self)
        if cls.update is not Task.update:
            return False
        missing = [m for m in ("compute_error", "compute_jacobian") if getattr(cls, m) is getattr(Task, m)]
        if missing:
            raise InvalidInput(f"{self.name} must define {' and '.join(m + '(robot)' for m in missing)} "
                               "(or an update() filling jacobian, target_velocity and error)")
        return True

    def compute_error(self, robot: Robot) -> np.ndarray:
        """The error e = x_d − x (dim,) on ``robot``: a subclass defines it (a built-in
        task evaluates its own ``update`` on its robot)."""
        self._update_own(robot)
        return self.error.copy()

    def compute_jacobian(self, robot: Robot) -> np.ndarray:
        """The Jacobian J = ∂x/∂q (dim, nv) on ``robot``: a subclass defines it (a
        built-in task evaluates its own ``update`` on its robot)."""
        self._update_own(robot)
        return np.array(self.jacobian, dtype=float)

    def _update_own(self, robot: Robot) -> None:
        if robot is not self.robot:
            raise InvalidInput(f"{self.name} evaluates its error and Jacobian on the robot it was built with")
        robot.ensure_kinematics()
        self.update()

    @property
    def target_dim(self) -> int:
        """Length of a target (``set_target``): ``dim`` unless a task says otherwise."""
        return self.dim

    def set_target(self, target, velocity=None) -> None:
        """Desired x_d (``target``, target_dim) and feed-forward ẋ_d (``target_rate``,
        zero by default), for a task whose ``compute_error`` reads ``self.target``.

        Raises:
            InvalidInput: a wrong length, NaN or inf.
        """
        value = finite_vector(target, self.target_dim, f"{self.name} target")
        if self.target is None:
            self.target = value.copy()
        else:
            self.target[:] = value
        self.target_rate[:] = 0.0 if velocity is None else finite_vector(velocity, self.dim, f"{self.name} target velocity")

    def measured(self, robot: Robot | None = None) -> np.ndarray:
        """The tracked x = x_d − e (a copy) on the bound robot or another of the same
        model (after its kinematics update): what a rollout's reference records.

        Raises:
            InvalidInput: the task has no target (``set_target``) to measure from.
        """
        if self.target is None:
            raise InvalidInput(f"{self.name} has no target to measure against: set_target(...) first, "
                               "or define measured(robot)")
        return self.target - self.compute_error(robot or self.robot)

    def _allocate_jacobian(self) -> None:
        self.jacobian = np.zeros((self.dim, self.robot.nv))

    @property
    def joint_space(self) -> bool:
        """Whether J is the fixed identity selection ``I[dofs]`` (never for a general task)."""
        return False

    @property
    def priority(self) -> int:
        """Level in a strict hierarchy: 0 is the highest; equal priorities share a level."""
        return self._priority

    @priority.setter
    def priority(self, value) -> None:
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or value < 0:
            raise InvalidInput(f"{self.name} priority must be an integer >= 0 (0 the highest), got {value!r}")
        self._priority = int(value)

    _dead_beat: tuple[np.ndarray, ...] = ()  # gain arrays left to the controller's period
    _dead_beat_rows: tuple[np.ndarray, ...] = ()

    def _mark_dead_beat(self, *gains: np.ndarray) -> None:
        """Mark gain arrays (views the task computes with) whose NaN entries are the
        dead-beat default: :meth:`attach` sets them to 1/Δt of the controller's period."""
        self._dead_beat = tuple(g for g in gains if np.isnan(g).any())
        self._dead_beat_rows = tuple(np.isnan(g) for g in self._dead_beat)

    @property
    def needs_period(self) -> bool:
        """Whether a default (dead-beat) gain still waits for a controller's period."""
        return any(np.isnan(g).any() for g in self._dead_beat)

    def attach(self, dt: float | None) -> None:
        """Called by a controller with its control period Δt (None for a law without one)
        before the first step.

        A gain left at its default (``None``) becomes K = 1/Δt here, dead-beat as mink's
        default ``gain=1``: a met task's linearised error is removed in one step.
        The error of a met task follows e_{k+1} = (1 − KΔt) e_k: it overshoots (changes
        sign every step) for KΔt > 1 and grows for KΔt > 2. The first is warned about
        (:class:`~qpik.errors.GainWarning`), the second refused.

        Raises:
            InvalidInput: a gain with KΔt > 2.
        """
        if dt is not None:
            for gains, rows in zip(self._dead_beat, self._dead_beat_rows):
                gains[rows] = 1.0 / dt
        gains = self.feedback_gains()
        if dt is None or gains is None or not len(gains):  # None: a law without a period
            return
        # 1/Δt·Δt may round to 1 + 1 ulp: the dead-beat default is not an overshoot.
        worst = float(np.max(gains)) * dt * (1.0 - 1e-12)
        if worst > 2.0:
            raise InvalidInput(f"{self.name}: gain {float(np.max(gains)):g} 1/s with dt = {dt:g} s gives K·dt = "
                               f"{worst:.3g} > 2: the discrete error e(k+1) = (1 - K·dt) e(k) grows every step; "
                               f"use K <= {1.0 / dt:g} 1/s")
        if worst > 1.0:
            warnings.warn(f"{self.name}: gain {float(np.max(gains)):g} 1/s with dt = {dt:g} s gives K·dt = "
                          f"{worst:.3g} > 1: the error overshoots, changing sign every step; "
                          f"K <= {1.0 / dt:g} 1/s converges without overshoot", GainWarning, stacklevel=3)

    def feedback_gains(self) -> np.ndarray | None:
        """The gains K (1/s) of the task's error feedback v = ẋ_d + K e, one per row (the
        base class's ``gain``), or None for a task without one (a gradient, a damping)."""
        return self._gains

    def update(self) -> None:
        """Refresh ``jacobian``, ``target_velocity`` and ``error`` from the robot's
        kinematics (current: a controller updates them first)."""
        jacobian = self.compute_jacobian(self.robot)
        self.jacobian[...] = _checked_rows(jacobian, (self.dim, self.robot.nv), self.name, "compute_jacobian")
        self.update_target_velocity()

    def update_target_velocity(self) -> None:
        """``error`` and v = ẋ_d + K e only (what a law without the Jacobian needs)."""
        if not self._computes_rows():  # a task with its own update and no cheaper path
            self.update()
            return
        error = self.compute_error(self.robot)
        self.error[...] = _checked_rows(error, (self.dim,), self.name, "compute_error")
        self._track(self.target_rate)

    def _use_gain(self, gain: np.ndarray) -> None:
        """The gains K (dim,) of v = ẋ_d + K e (NaN rows: dead-beat, set by :meth:`attach`)."""
        self.gain = self._gains = gain
        self._mark_dead_beat(gain)

    def _track(self, rate: np.ndarray) -> None:
        """v = ẋ_d + K e, from ``error`` and the feed-forward ``rate`` (outputs passed by
        position: a keyword costs more per call)."""
        np.multiply(self.gain, self.error, self.target_velocity)
        np.add(self.target_velocity, rate, self.target_velocity)

    def __repr__(self) -> str:
        return f"{type(self).__name__}(dim={self.dim}, hard={self.hard})"


def scalar_dofs(robot: Robot) -> np.ndarray:
    """The dofs of every hinge and slide joint (free and ball joints left out)."""
    m = robot.model
    scalar = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
    return np.array([m.jnt_dofadr[j] for j in range(m.njnt) if int(m.jnt_type[j]) in scalar], dtype=int)


def joint_dofs(robot: Robot, joints: Sequence[str] | None) -> np.ndarray:
    """The dofs of the named joints (every dof of a free or ball joint), in the model's order;
    ``None``: every hinge and slide joint, so a floating base is left alone."""
    if joints is None:
        return scalar_dofs(robot)
    if isinstance(joints, str):
        raise InvalidInput(f"joints must be a list of joint names, got the string {joints!r}")
    dofs = [int(dof) for name in joints for dof in robot.joint_dofs(name)]
    if len(set(dofs)) != len(dofs):
        raise InvalidInput(f"a joint is named twice in {list(joints)}")
    return np.array(sorted(dofs), dtype=int)


class JointSpaceTask(Task):
    """A task whose Jacobian is the selection ``I[dofs]`` (posture, damping, gradients).

    ``jacobian`` is read-only. Assigning another matrix to it (a subclass with its own
    J) turns the task into a general one: ``joint_space`` becomes False and every
    controller reads the new J, so nothing silently assumes J = I.

    Args:
        robot: the robot.
        joints: joint names whose dofs the task covers (default: every hinge and slide
            joint; name a free or ball joint to include its dofs).
        weight: cost weight (scalar or one per covered dof).
    """

    def __init__(self, robot: Robot, joints: Sequence[str] | None = None, weight=1.0):
        self.dofs = joint_dofs(robot, joints)
        if len(self.dofs) == 0:
            raise InvalidInput(f"{self.name}: the model has no joint to act on (give joints=...)")
        self._custom_jacobian = None
        self._attached = False
        super().__init__(robot, len(self.dofs), weight, hard=False)
        self.hard = False

    def attach(self, dt: float | None) -> None:
        self._attached = True
        super().attach(dt)

    def _allocate_jacobian(self) -> None:
        selection = np.zeros((self.dim, self.robot.nv))
        selection[np.arange(self.dim), self.dofs] = 1.0
        selection.setflags(write=False)
        self._selection = selection

    @property
    def jacobian(self) -> np.ndarray:
        return self._selection if self._custom_jacobian is None else self._custom_jacobian

    @jacobian.setter
    def jacobian(self, value) -> None:
        if self._attached:  # a controller put this task on its Hessian's diagonal
            raise InvalidInput(f"{self.name}: its Jacobian cannot change after the task was given to a "
                               "controller (which reads a joint-space task's J = I once); set it before")
        value = np.asarray(value, dtype=float)
        if value.shape != (self.dim, self.robot.nv):
            raise InvalidInput(f"{self.name} jacobian must have shape ({self.dim}, {self.robot.nv}), got {value.shape}")
        self._custom_jacobian = value

    @property
    def joint_space(self) -> bool:
        return self._custom_jacobian is None and type(self).jacobian is JointSpaceTask.jacobian


class PoseRows:
    """Masked rows of a frame's pose error, feed-forward velocity and Jacobian.

    The blocks are the position (rows 0-2) and/or the orientation (next three) of
    ``frame``; ``rows`` picks among them. In world axes the rows are the world's; in the
    frame's own axes (``local``) the error e, the feed-forward velocity and the Jacobian
    J are rotated by :math:`R^T`: the rows then measure the pose along the frame's
    current axes. (:math:`\\dot{(R^T e)} = R^T\\dot e + \\dot R^T e`: the second term,
    of order \\|e\\| \\|ω\\|, is left out, as in placo's local masks.)

    Everything is preallocated; the tasks built on it allocate nothing per step.
    """

    def __init__(self, frame, nv: int, position_rows: np.ndarray | None, orientation_rows: np.ndarray | None,
                 local: bool):
        self.frame = frame
        self.local = local
        self.has_position = position_rows is not None
        self.has_orientation = orientation_rows is not None
        blocks = int(self.has_position) + int(self.has_orientation)
        offset = 3 if self.has_position else 0
        parts = ([position_rows] if self.has_position else []) + ([offset + orientation_rows] if self.has_orientation else [])
        self.rows = np.concatenate(parts).astype(int)
        self._jac = np.zeros((3 * blocks, nv))
        self._rotated = np.zeros((3 * blocks, nv))
        self._jacp = self._jac[:3] if self.has_position else None
        self._jacr = self._jac[offset:] if self.has_orientation else None
        self._error = np.zeros(3 * blocks)
        self._feedforward = np.zeros(3 * blocks)
        self._scratch = np.zeros(3)
        self._blocks = [slice(3 * b, 3 * b + 3) for b in range(blocks)]
        self._position = slice(0, 3) if self.has_position else None
        self._orientation = slice(offset, offset + 3) if self.has_orientation else None
        self._rotation_error = RotationError()

    def jacobian(self, out: np.ndarray) -> None:
        """Write the masked Jacobian rows into ``out`` (len(rows) x nv)."""
        self.frame.jacobian(self._jacp, self._jacr)
        jac = self._jac
        if self.local:
            Rt = self.frame.rotation.T
            for block in self._blocks:
                Rt.dot(jac[block], self._rotated[block])
            jac = self._rotated
        jac.take(self.rows, 0, out)

    def errors(self, target_position, target_rotation, linear_velocity, angular_velocity,
               error: np.ndarray, feedforward: np.ndarray) -> None:
        """Write the masked pose error and feed-forward velocity into ``error``, ``feedforward``."""
        frame, e, f = self.frame, self._error, self._feedforward
        R = frame.rotation
        if self.has_position:
            np.subtract(target_position, frame.position, out=e[self._position])
            f[self._position] = linear_velocity
            if self.local:  # vᵀR = (Rᵀv)ᵀ
                e[self._position].dot(R, self._scratch)
                e[self._position] = self._scratch
                f[self._position].dot(R, self._scratch)
                f[self._position] = self._scratch
        if self.has_orientation:
            part = self._orientation
            if self.local:
                e[part] = self._rotation_error.compute(target_rotation, R)
                angular_velocity.dot(R, f[part])
            else:
                self._rotation_error.world(target_rotation, R, out=e[part])
                f[part] = angular_velocity
        e.take(self.rows, None, error)
        f.take(self.rows, None, feedforward)
