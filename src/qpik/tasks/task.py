r"""The Task interface: linear relations :math:`J \dot q \approx v`, for one world or N.

A task measures, every step and in every world, an error e (what it wants to remove: its
units are metres, radians, ...) and its Jacobian J, and asks for the velocity
:math:`v = \dot x_d + K e` (the feed-forward :math:`\dot x_d` and the gains K). Every
controller reads the same three arrays: the QP enforces :math:`J\dot q = v` (``hard``) or
weighs :math:`\tfrac12 \|J\dot q - v\|_W^2`; the hierarchy and SNS order tasks by
``priority`` (0 the highest); the classical laws invert J.

One implementation for one robot and for thousands: the engine's arrays carry a leading
world axis, ``errors`` (N, dim), ``jacobians`` (N, dim, nv), ``target_velocities``
(N, dim). What a user reads are ``error``, ``jacobian`` and ``target_velocity``: the same
arrays for a :class:`qpik.batch.Robot`, their world 0 (views, as mink's shapes) for a
:class:`qpik.Robot`.

A task written as in mink needs its row count and two methods::

    class TipHeight(qpik.Task):
        dim = 1
        def compute_error(self, robot):     # (dim,): e = x_d − x
            return np.array([self.target[0] - robot.data.site_xpos[site, 2]])
        def compute_jacobian(self, robot):  # (dim, nv): J = ∂x/∂q
            ...

On N worlds such a task is evaluated world by world, on a one-world view of each
(:meth:`qpik.batch.Robot.world`); one that sets ``vectorized = True`` is given the robot
itself and returns (N, dim) and (N, dim, nv) (N = 1 for a :class:`qpik.Robot`), written
once over the world axis as the built-in tasks are.
"""

from __future__ import annotations

import math
import warnings

import numpy as np

from ..errors import GainWarning, InvalidInput
from .inputs import as_floats, feedback_gain, joint_dofs, positive, positive_scalar, world_values


def _row_count(dim, name: str) -> int:
    """A task's row count: an integer >= 1 (InvalidInput otherwise)."""
    if isinstance(dim, (bool, np.bool_)) or not isinstance(dim, (int, np.integer)) or dim < 1:
        raise InvalidInput(f"{name} needs its row count dim, an integer >= 1 (a class attribute or dim=...), "
                           f"got {dim!r}")
    return int(dim)


def _checked_rows(value, shape: tuple, name: str, method: str) -> np.ndarray:
    """What a user task's method returned, as finite floats of the promised shape."""
    rows = as_floats(value, f"{name}.{method}", "must return")
    if rows.shape != shape:
        raise InvalidInput(f"{name}.{method} must return shape {shape}, got {rows.shape}")
    if not math.isfinite(float(rows.sum())):
        raise InvalidInput(f"{name}.{method} returned NaN or inf")
    return rows


class Task:
    r"""Base class: ``dim`` rows of :math:`J\dot q \approx v` with a weight, in every world.

    The base class owns the gains K (checked against the controller's period:
    :meth:`attach`), the weights, ``hard``, ``priority`` and ``lm_damping`` (adaptive
    Levenberg–Marquardt: :math:`\tfrac12 \mu\, e^TWe\, \|\dot q\|^2` added to a soft
    task's cost), and :math:`v = \dot x_d + K e`. A subclass measures: :meth:`measure_rows`
    writes ``errors`` and ``jacobians`` (a built-in task), or ``compute_error`` and
    ``compute_jacobian`` return them (a user's task, as in mink). Every task answers both
    methods (a built-in one from its own rows, on its robot) and :meth:`measured`.

    Args:
        robot: the robot (one world, or a batch of N) whose kinematics the task reads.
        dim: number of task rows (default: the class attribute ``dim``).
        weight: cost weight of a soft task (scalar or one per row); a zero weight
            leaves a row out of the cost (a mask).
        hard: enforce the task as an equality constraint in the QP.
        gain: K (1/s), a scalar or one per row, >= 0; default ``None``: dead-beat,
            1/Δt of the controller the task is given to (mink's ``gain=1``).
        priority: level in a strict hierarchy (0 the highest).
        lm_damping: μ above (soft tasks).

    Raises:
        InvalidInput: no row count, a bad weight, gain, priority or ``lm_damping``, or a
            subclass that defines neither :meth:`measure_rows` nor both compute methods.
    """

    name = "task"
    dim: int | None = None
    vectorized = False  # a user's task that returns (N, ...) arrays itself (N = 1 for one robot)
    joint_space = False  # J is the fixed selection I[dofs] (a controller may use its diagonal)
    target: np.ndarray | None = None  # x_d, for a task that tracks one (set_target)
    _own_gain = None  # ``gain`` of a task without feedback (``gains`` None)
    _priority = 0

    def __init__(self, robot, dim: int | None = None, weight=1.0, hard: bool = False, *, gain=None,
                 priority: int = 0, lm_damping: float = 0.0):
        if type(self).name == Task.name:  # a user's subclass: messages name its class
            self.name = type(self).__name__
        self.robot = robot
        self.dim = _row_count(type(self).dim if dim is None else dim, self.name)
        self.hard = bool(hard)
        self.weight = positive(weight, self.dim, f"{self.name} weight", allow_zero=True)
        self.priority = priority
        self.lm_damping = positive_scalar(lm_damping, f"{self.name} lm_damping", allow_zero=True)
        n = robot.n
        # e, v and the feed-forward ẋ_d of every world
        self.errors, self.target_velocities, self.rates = (np.zeros((n, self.dim)) for _ in range(3))
        self._allocate_jacobians()
        self.error, self.target_velocity = robot.present(self.errors), robot.present(self.target_velocities)
        self.target_rate = robot.present(self.rates)
        self._present_jacobians()
        self._user_rows = self._computes_rows()
        self.gains = None  # (N, dim) K, at the operand's full shape; None: no feedback
        if self._user_rows or gain is not None:
            self.set_gain(feedback_gain(gain, self.dim, f"{self.name} gain"))

    def _allocate_jacobians(self) -> None:
        self.jacobians = np.zeros((self.robot.n, self.dim, self.robot.nv))

    def _present_jacobians(self) -> None:
        """``jacobian``: what a user reads of ``jacobians``."""
        self.jacobian = self.robot.present(self.jacobians)

    def _computes_rows(self) -> bool:
        """Whether the rows come from compute_error/compute_jacobian (no own ``measure_rows``)."""
        cls = type(self)
        if cls.measure_rows is not Task.measure_rows:
            return False
        missing = [m for m in ("compute_error", "compute_jacobian")
                   if getattr(cls, m, None) in (None, getattr(Task, m))]
        if missing:
            raise InvalidInput(f"{self.name} must define {' and '.join(m + '(robot)' for m in missing)} "
                               "(or a measure_rows() filling errors and jacobians)")
        return True

    def compute_error(self, robot) -> np.ndarray:
        """The error e = x_d − x on ``robot`` as a user reads it ((dim,) for one robot):
        a user's task defines it; a built-in task measures its rows on its own robot (a copy).

        Raises:
            InvalidInput: a robot other than the task's.
        """
        self._update_on(robot)
        return self.error.copy()

    def compute_jacobian(self, robot) -> np.ndarray:
        """The Jacobian J = ∂x/∂q ((dim, nv) for one robot), as :meth:`compute_error` the error.

        Raises:
            InvalidInput: a robot other than the task's.
        """
        self._update_on(robot)
        return np.array(self.jacobian, dtype=float)

    def _update_on(self, robot) -> None:
        if robot is not self.robot:
            raise InvalidInput(f"{self.name} evaluates its error and Jacobian on the robot it was built with")
        robot.ensure_kinematics()
        self.update()

    def measured(self, robot=None) -> np.ndarray:
        """The tracked x = x_d − e (a copy, as a user reads it) on the bound robot or, for a
        user's task, another robot of the same model (after its kinematics update): what a
        rollout's reference records.

        Raises:
            InvalidInput: the task has no target (``set_target``) to measure from.
        """
        if self.target is None:
            raise InvalidInput(f"{self.name} has no target to measure against: set_target(...) first, "
                               "or define measured(robot)")
        robot = robot or self.robot
        if robot is self.robot and robot.batched and not self.vectorized:
            self.measure_rows()  # world by world
            return self.target - self.error
        return self.target - self.compute_error(robot)

    # -- gains and the controller's period ------------------------------------------------
    def set_gain(self, gain: np.ndarray) -> None:
        """The gains K (dim,) of v = ẋ_d + K e (NaN rows: dead-beat, set by :meth:`attach`)."""
        self.gains = np.tile(gain, (self.robot.n, 1))
        self._gain_view = self.robot.present(self.gains)

    @property
    def gain(self):
        """K (1/s) of each row as the step uses it: a view of ``gains``, world 0's (dim,)
        for one robot, (N, dim) for a batch, so that a gain written in place
        (``task.gain[:] = 20.0``, a frame task's ``position_gain``) or set whole
        (``task.gain = 20.0``, checked) is the next step's. A task without feedback keeps
        what it sets here as its own (e.g. a gradient's k0; None if nothing)."""
        return self._own_gain if self.gains is None else self._gain_view

    @gain.setter
    def gain(self, value) -> None:
        if self.gains is None:
            self._own_gain = value
        else:
            self.gains[...] = feedback_gain(value, self.dim, f"{self.name} gain")

    def feedback_gains(self) -> np.ndarray | None:
        """K (1/s) of each row, or None for a task without feedback (a damping)."""
        return None if self.gains is None else self.gains[0]

    @property
    def needs_period(self) -> bool:
        """Whether a default (dead-beat) gain still waits for a controller's period."""
        return self.gains is not None and bool(np.isnan(self.gains).any())

    def attach(self, dt: float | None) -> None:
        """Called by a controller with its period Δt (None for a law without one).

        A gain left at its default becomes K = 1/Δt, dead-beat as mink's ``gain=1``. A met
        task's error follows e_{k+1} = (1 − KΔt) e_k: KΔt > 1 overshoots (a
        :class:`~qpik.errors.GainWarning`), KΔt > 2 grows (refused).

        Raises:
            InvalidInput: a gain with KΔt > 2.
        """
        if dt is None or self.gains is None:
            return
        if self.needs_period:
            self.gains[np.isnan(self.gains)] = 1.0 / dt  # in place: ``gain`` and its views see it
        worst = float(np.max(self.gains)) * dt * (1.0 - 1e-12)  # 1/Δt·Δt may round to 1 + 1 ulp
        largest = float(np.max(self.gains))
        if worst > 2.0:
            raise InvalidInput(f"{self.name}: gain {largest:g} 1/s with dt = {dt:g} s gives K·dt = {worst:.3g} > 2: "
                               f"the discrete error e(k+1) = (1 - K·dt) e(k) grows every step; use K <= {1.0 / dt:g} 1/s")
        if worst > 1.0:
            warnings.warn(f"{self.name}: gain {largest:g} 1/s with dt = {dt:g} s gives K·dt = {worst:.3g} > 1: the error "
                          f"overshoots, changing sign every step; K <= {1.0 / dt:g} 1/s converges without overshoot",
                          GainWarning, stacklevel=3)

    @property
    def priority(self) -> int:
        """Level in a strict hierarchy: 0 is the highest; equal priorities share a level."""
        return self._priority

    @priority.setter
    def priority(self, value) -> None:
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or value < 0:
            raise InvalidInput(f"{self.name} priority must be an integer >= 0 (0 the highest), got {value!r}")
        self._priority = int(value)

    # -- targets ----------------------------------------------------------------------------
    @property
    def target_dim(self) -> int:
        """Length of a target (``set_target``): ``dim`` unless a task says otherwise."""
        return self.dim

    def set_target(self, target, velocity=None) -> None:
        """Desired x_d (``target``: target_dim, or (N, target_dim)) and feed-forward ẋ_d
        (zero by default), for a task whose ``compute_error`` reads ``self.target``.

        Raises:
            InvalidInput: a wrong shape, NaN or inf (InvalidWorlds: in some worlds).
        """
        value = world_values(self.robot, target, (self.target_dim,), f"{self.name} target")
        rate = None if velocity is None else world_values(self.robot, velocity, (self.dim,),
                                                          f"{self.name} target velocity")
        if self.target is None:
            self.target = self.robot.present(np.array(value))
        else:
            self.target[...] = self.robot.present(value)
        self.rates[...] = 0.0 if rate is None else rate

    # -- every step -------------------------------------------------------------------------
    def update(self) -> None:
        """Refresh every world's ``errors``, ``jacobians`` and ``target_velocities`` from the
        robot's kinematics (current: a controller updates them first)."""
        self.measure_rows()
        self.track()

    def update_target_velocity(self) -> None:
        """``errors`` and ``target_velocities`` for a law that reads no Jacobian (the peers'
        problems): the same update (a task measures its Jacobian with its error)."""
        self.update()

    def measure_rows(self) -> None:
        """Write ``errors`` and ``jacobians``: a built-in task's own; here, from the user's
        ``compute_error`` and ``compute_jacobian`` (world by world unless ``vectorized``)."""
        robot, n, nv = self.robot, self.robot.n, self.robot.nv
        if not robot.batched or self.vectorized:
            shape = (n, self.dim) if self.vectorized else (self.dim,)
            self.errors[...] = _checked_rows(self.compute_error(robot), shape, self.name, "compute_error")
            self.jacobians[...] = _checked_rows(self.compute_jacobian(robot), shape + (nv,), self.name,
                                                "compute_jacobian")
            return
        self._measure_each_world()

    def _measure_each_world(self) -> None:
        """World by world, on a one-world view of each; while world w is measured
        ``self.target`` is its row (dim,), as the methods read it on one robot."""
        robot, nv, targets = self.robot, self.robot.nv, self.target
        try:
            for w in range(robot.n):
                world = robot.world(w)
                if targets is not None:
                    self.target = targets[w]
                self.errors[w] = _checked_rows(self.compute_error(world), (self.dim,), self.name, "compute_error")
                self.jacobians[w] = _checked_rows(self.compute_jacobian(world), (self.dim, nv), self.name,
                                                  "compute_jacobian")
        finally:
            self.target = targets

    def track(self) -> None:
        """v = ẋ_d + K e in every world (outputs by position: a keyword costs more per call)."""
        if self.gains is None:
            np.copyto(self.target_velocities, self.rates)
            return
        np.multiply(self.gains, self.errors, self.target_velocities)
        np.add(self.target_velocities, self.rates, self.target_velocities)

    def __repr__(self) -> str:
        return f"{type(self).__name__}(dim={self.dim}, hard={self.hard})"


class ScalarGain:
    """A mixin for a task with one gain K (1/s) for every row: ``gain`` reads it (NaN
    until a controller gives its period, when dead-beat) and sets it (a number >= 0)."""

    gain_label = "gain"  # the gain's name in messages

    def set_gain(self, gain: np.ndarray) -> None:
        self.gains = np.tile(gain, (self.robot.n, 1))

    @property
    def gain(self) -> float:
        return float(self.gains[0, 0])

    @gain.setter
    def gain(self, value) -> None:
        self.gains[...] = positive_scalar(value, self.gain_label, allow_zero=True)


class JointSpaceTask(Task):
    """A task whose Jacobian is the selection ``I[dofs]`` (posture, damping, gradients):
    a controller adds its weights to the Hessian's diagonal without reading J.

    ``jacobian`` is read-only. A subclass with its own J (a matrix assigned to
    ``jacobian`` before the task is given to a controller, or a ``jacobian`` property of
    its class) is a general task: ``joint_space`` is then False and every controller reads
    that J, so nothing silently assumes J = I.

    Args:
        robot: the robot.
        joints: joint names whose dofs the task covers (default: every hinge and slide
            joint; name a free or ball joint to include its dofs).
        weight: cost weight (scalar or one per covered dof).

    Raises:
        InvalidInput: no joint to act on; a J of the wrong shape, or assigned once a
            controller has the task.
    """

    _own_jacobian = False  # a J assigned to ``jacobian``
    _attached = False  # given to a controller (which reads whether J = I once)

    def __init__(self, robot, joints=None, weight=1.0, **options):
        self.dofs = joint_dofs(robot, joints)
        if len(self.dofs) == 0:
            raise InvalidInput(f"{self.name}: the model has no joint to act on (give joints=...)")
        super().__init__(robot, len(self.dofs), weight, **options)
        if type(self).jacobian is not JointSpaceTask.jacobian:  # the class's own J, read every update
            self.jacobians = np.zeros((robot.n, self.dim, robot.nv))
            self.update = self._update_reading_jacobian

    def _allocate_jacobians(self) -> None:
        selection = np.zeros((self.dim, self.robot.nv))
        selection[np.arange(self.dim), self.dofs] = 1.0
        # Read-only and shared by every world: the identity's rows cost no memory per world.
        self.jacobians = np.broadcast_to(selection, (self.robot.n, self.dim, self.robot.nv))

    def _present_jacobians(self) -> None:
        self._jacobian = self.robot.present(self.jacobians)

    @property
    def joint_space(self) -> bool:
        """Whether J is the selection ``I[dofs]`` (False once a subclass gives its own)."""
        return not self._own_jacobian and type(self).jacobian is JointSpaceTask.jacobian

    @property
    def jacobian(self) -> np.ndarray:
        """J as a user reads it: ``I[dofs]`` (read-only) unless a subclass gave its own."""
        return self._jacobian

    @jacobian.setter
    def jacobian(self, value) -> None:
        if self._attached:  # a controller put this task on its Hessian's diagonal
            raise InvalidInput(f"{self.name}: its Jacobian cannot change after the task was given to a "
                               "controller (which reads whether a task's J = I once); set it before")
        own = world_values(self.robot, value, (self.dim, self.robot.nv), f"{self.name} jacobian")
        self.jacobians = np.array(own)  # (N, dim, nv), the task's own
        self._own_jacobian = True
        self._present_jacobians()

    def attach(self, dt: float | None) -> None:
        self._attached = True
        super().attach(dt)

    def _update_reading_jacobian(self) -> None:
        """The class's update, ``jacobians`` first copied from its own ``jacobian`` (checked)."""
        np.copyto(self.jacobians, world_values(self.robot, self.jacobian, (self.dim, self.robot.nv),
                                               f"{self.name} jacobian"))
        type(self).update(self)

    def measure_rows(self) -> None:
        """``errors`` only (J is constant)."""
