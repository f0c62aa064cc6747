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

All arrays are preallocated: ``update`` writes in place and allocates nothing big.
"""

from __future__ import annotations

from typing import Sequence

import mujoco
import numpy as np

from ..errors import InvalidInput
from ..robot import Robot

_AXES = "xyz"


def axis_rows(axes: str) -> np.ndarray:
    """Row indices of a mask such as ``"xy"`` (a non-empty subset of ``"xyz"``)."""
    if not isinstance(axes, str) or not axes or any(a not in _AXES for a in axes) or len(set(axes)) != len(axes):
        raise InvalidInput(f"axes must be a non-empty subset of 'xyz', got {axes!r}")
    return np.array(sorted(_AXES.index(a) for a in axes), dtype=int)


def finite_vector(value, size: int, what: str) -> np.ndarray:
    """``value`` as a float array of shape (size,), or InvalidInput naming ``what``."""
    arr = np.asarray(value, dtype=float)
    if arr.shape != (size,):
        raise InvalidInput(f"{what} must have shape ({size},), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InvalidInput(f"{what} contains NaN or inf: {arr}")
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


class Task:
    """Base class: ``dim`` rows of :math:`J\\dot q \\approx v` with a weight.

    Args:
        robot: the robot whose kinematics the task reads.
        dim: number of task rows.
        weight: cost weight of a soft task (scalar or one per row).
        hard: enforce the task as an equality constraint in the QP.

    Subclasses fill ``jacobian``, ``target_velocity`` and ``error`` in :meth:`update`.
    """

    name = "task"
    lm_damping = 0.0
    _priority = 0  # a class default, so every subclass has one without a constructor argument

    def __init__(self, robot: Robot, dim: int, weight=1.0, hard: bool = False):
        self.robot = robot
        self.dim = dim
        self.hard = bool(hard)
        self.weight = positive(weight, dim, f"{self.name} weight", allow_zero=True)
        self._allocate_jacobian()
        self.target_velocity = np.zeros(dim)
        self.error = np.zeros(dim)

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

    def update(self) -> None:
        """Refresh ``jacobian``, ``target_velocity`` and ``error`` from the robot's kinematics."""
        raise NotImplementedError

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
    dofs = []
    for name in joints:
        jid = robot.joint_id(name)
        start = int(robot.model.jnt_dofadr[jid])
        dofs.extend(range(start, start + _joint_dof_count(robot.model, jid)))
    if len(set(dofs)) != len(dofs):
        raise InvalidInput(f"a joint is named twice in {list(joints)}")
    return np.array(sorted(dofs), dtype=int)


def _joint_dof_count(model: mujoco.MjModel, jid: int) -> int:
    kind = int(model.jnt_type[jid])
    return {int(mujoco.mjtJoint.mjJNT_FREE): 6, int(mujoco.mjtJoint.mjJNT_BALL): 3}.get(kind, 1)


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
        super().__init__(robot, len(self.dofs), weight, hard=False)
        self.hard = False

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
        value = np.asarray(value, dtype=float)
        if value.shape != (self.dim, self.robot.nv):
            raise InvalidInput(f"{self.name} jacobian must have shape ({self.dim}, {self.robot.nv}), got {value.shape}")
        self._custom_jacobian = value

    @property
    def joint_space(self) -> bool:
        return self._custom_jacobian is None and type(self).jacobian is JointSpaceTask.jacobian
