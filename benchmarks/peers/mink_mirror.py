r"""mink on the same problem as a :class:`qpik.QPController`: each qpik task and limit as
the mink object that expresses it, so both solve the same QP every step.

qpik's QP is written in the joint velocity :math:`\dot q`, mink's in the step
:math:`\Delta q = \dot q\,\Delta t`; multiplying qpik's cost by :math:`\Delta t^2` leaves the
minimiser unchanged, so (see :mod:`qpik.app.peers.problem` for the derivations):

- weights carry over as mink costs :math:`\sqrt w`, the regulariser ε as mink's
  ``damping``, a feedback gain K as mink's step gain :math:`\alpha = K\Delta t`;
- a moving target with feed-forward (qpik's :math:`v = \dot x_d + K e`) is given to mink
  shifted so that its error is exactly the step qpik asks for: a position (or CoM)
  target :math:`x_d + \dot x_d/K`; a pose target :math:`T\exp(u)` with
  :math:`u = (\Delta t/\alpha)[R^Tv_{lin};\ R^Tv_{ang}]` (mink's body-frame SE(3) error is
  then u and its log Jacobian drops out, :mod:`qpik.app.peers.mink_peer`);
- a target that does not move is given once, as it is; mink's pose error (the body-frame
  log) and qpik's (world rotation vector and position difference) agree to first order
  in the error, which a hard task keeps at ~1e-12;
- a :class:`~qpik.PositionTask` (every world axis, one weight) is mink's FrameTask with no
  orientation cost, its target rotation the frame's current one (so the log has no
  rotation part to couple into the position rows);
- a hard task goes into ``solve_ik(constraints=...)`` (mink's equalities
  :math:`J\Delta q = -\alpha e`, costs ignored);
- :class:`~qpik.JointPositionLimit` (without qpik's velocity damper) is
  ``ConfigurationLimit`` with the same gain and margin, :class:`~qpik.JointVelocityLimit`
  ``VelocityLimit``, :class:`~qpik.CollisionAvoidanceLimit` ``CollisionAvoidanceLimit``
  with the same pairs, gain, distances and relaxation. That last one is *not* the same
  constraint: mink bounds its variable :math:`\Delta q` by :math:`\gamma (d - d_s)/\Delta t`
  (qpik bounds :math:`\dot q` by that, i.e. :math:`\Delta q` by :math:`\gamma (d - d_s)`),
  and mink has no velocity damper; benchmarks/third_party.py measures what that does.

Every step mink re-reads q (``Configuration.update``), the moving targets are retargeted,
and ``mink.solve_ik`` builds the QP and hands it to qpsolvers with the tolerances qpik's
qpsolvers back-end uses. That is the exact mirror of the QP, for the logged comparisons;
its retargeting calls qpik (the task's own velocity), so it is not what a mink user
writes. :class:`MinkRun` is: the timed mink contestant of benchmarks/third_party.py, the
mirror's tasks and limits stepped with targets from plain arrays, ``solve_ik`` and
``integrate_inplace``, nothing of qpik's in the step.
"""

from __future__ import annotations

from typing import Collection, Sequence

import mink
import mujoco
import numpy as np

from qpik.app.peers.mink_peer import TaskRows, qpsolvers_settings, rplus
from qpik.app.peers.problem import PeerUnsupported
from qpik.errors import SolverError
from qpik.limits import CollisionAvoidanceLimit, JointPositionLimit, JointVelocityLimit
from qpik.robot import Robot
from qpik.tasks import ComTask, DampingTask, FrameTask, PositionTask, PostureTask

FREE = int(mujoco.mjtJoint.mjJNT_FREE)


def _one(values: np.ndarray, what: str) -> float:
    """The one value shared by every entry (mink has one gain per task, one cost per block)."""
    values = np.asarray(values, dtype=float)
    if np.ptp(values) > 0:
        raise PeerUnsupported(f"mink: {what} must be the same on every row, got {values}")
    return float(values[0])


def _pose(position: np.ndarray, rotation: np.ndarray) -> mink.SE3:
    wxyz_xyz = np.empty(7)
    mujoco.mju_mat2Quat(wxyz_xyz[:4], np.ascontiguousarray(rotation).reshape(9))
    wxyz_xyz[4:] = position
    return mink.SE3(wxyz_xyz)


def _joint_space_cost(robot: Robot, task, what: str) -> np.ndarray:
    """mink's (nv,) cost of a qpik joint-space task: √w on the task's dofs, which must be
    every dof but the free joint's (mink's posture and damping leave those out)."""
    model = robot.model
    free = {int(model.jnt_dofadr[j]) + k for j in range(model.njnt) if int(model.jnt_type[j]) == FREE
            for k in range(6)}
    if sorted(set(range(robot.nv)) - free) != sorted(int(d) for d in task.dofs):
        raise PeerUnsupported(f"mink: a {what} acts on every dof but a free joint's; this one on {task.dofs}")
    cost = np.zeros(robot.nv)
    cost[task.dofs] = np.sqrt(task.weight)
    return cost


class MinkMirror:
    """``mink.solve_ik`` on the problem of ``QPController(robot, tasks, limits, dt=dt)``.

    Args:
        robot: the robot whose ``q`` is read every step (the rollout integrates it).
        tasks: qpik tasks (frame, position, CoM, posture, damping; hard or soft).
        limits: qpik limits (joint position without damper, joint velocity, collision).
        dt: control period.
        solver: the qpsolvers name mink hands the QP to.
        regularization: qpik's ε (mink's ``damping``).
        moving: the tasks whose targets change during the run: retargeted every step.

    Raises:
        PeerUnsupported: a task or limit mink cannot express the same way.
    """

    kind = "mink"

    def __init__(self, robot: Robot, tasks: Sequence, limits: Sequence, dt: float, solver: str = "daqp",
                 regularization: float = 1e-12, moving: Collection = ()):
        self.robot = robot
        self.solver = solver
        self.dt = dt
        self.regularization = regularization
        self._settings = qpsolvers_settings(solver)
        self.configuration = mink.Configuration(robot.model, robot.q)
        self.tasks: list = []
        self.constraints: list = []
        self._retargets: list = []
        self.mink_task: dict[int, object] = {}  # id of a qpik task -> the mink task expressing it
        moving_ids = {id(task) for task in moving}
        for task in tasks:
            self._add_task(task, id(task) in moving_ids)
        self.limits = [self._limit(limit) for limit in limits]
        self.qdot = np.zeros(robot.nv)

    # Tasks -------------------------------------------------------------------------
    def _gain(self, gains: np.ndarray, what: str) -> float:
        alpha = _one(gains, f"the {what} gain") * self.dt
        if not 0.0 <= alpha <= 1.0:
            raise PeerUnsupported(f"mink: the {what} step gain K·Δt = {alpha:g} must lie in [0, 1]")
        return alpha

    def _place(self, task, mink_task) -> None:
        (self.constraints if task.hard else self.tasks).append(mink_task)

    def _add_task(self, task, moving: bool) -> None:
        if isinstance(task, FrameTask):
            self._frame_task(task, moving)
        elif isinstance(task, PositionTask):
            self._position_task(task)
        elif isinstance(task, ComTask):
            self._com_task(task, moving)
        elif isinstance(task, PostureTask):
            if moving:
                raise PeerUnsupported("mink: a moving posture target is not mapped")
            cost = _joint_space_cost(self.robot, task, "posture task")
            posture = mink.PostureTask(self.robot.model, cost=cost, gain=self._gain(np.array([task.gain]), "posture"))
            posture.set_target(task.target)
            self.tasks.append(posture)
        elif isinstance(task, DampingTask):
            self.tasks.append(mink.DampingTask(self.robot.model, _joint_space_cost(self.robot, task, "damping task")))
        else:
            raise PeerUnsupported(f"mink: no mapping for a {type(task).__name__}")

    def _frame_task(self, task: FrameTask, moving: bool) -> None:
        if task.dim != 6 or task.axes_frame != "world" or task.lm_damping:
            raise PeerUnsupported("mink: a frame task maps on all six world rows, without LM damping")
        alpha = self._gain(task.feedback_gains(), "frame task")
        costs = (1.0, 1.0) if task.hard else (np.sqrt(_one(task.weight[:3], "position weight")),
                                               np.sqrt(_one(task.weight[3:], "orientation weight")))
        frame = mink.FrameTask(task.frame.name, task.frame.type, position_cost=costs[0], orientation_cost=costs[1],
                               gain=alpha)
        self._place(task, frame)
        self.mink_task[id(task)] = frame
        if not moving:
            frame.set_target(_pose(task.target_position, task.target_rotation))
            return
        target = mink.SE3(np.array([1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]))
        step, scale = np.empty(6), self.dt / alpha
        name, kind, configuration, rotation = task.frame.name, task.frame.type, self.configuration, task.frame.rotation

        def retarget() -> None:
            # u = (Δt/α) [Rᵀ v_lin; Rᵀ v_ang] from qpik's own v (feed-forward + K e).
            task.update_target_velocity()
            v = task.target_velocity
            np.matmul(v[:3], rotation, out=step[:3])
            np.matmul(v[3:], rotation, out=step[3:])
            np.multiply(step, scale, out=step)
            pose = configuration.get_transform_frame_to_world(name, kind)
            rplus(pose.wxyz_xyz, step, target.wxyz_xyz)
            frame.set_target(target)

        self._retargets.append(retarget)

    def _position_task(self, task: PositionTask) -> None:
        if task.dim != 3 or task.axes_frame != "world" or task.lm_damping:
            raise PeerUnsupported("mink: a position task maps on all three world axes, without LM damping")
        gain = _one(task.gain, "position gain")
        alpha = self._gain(task.gain, "position task")
        cost = 1.0 if task.hard else np.sqrt(_one(task.weight, "position weight"))
        frame = mink.FrameTask(task.frame.name, task.frame.type, position_cost=cost, orientation_cost=0.0, gain=alpha)
        self._place(task, TaskRows(frame, np.arange(3)) if task.hard else frame)
        self.mink_task[id(task)] = frame
        name, kind, configuration = task.frame.name, task.frame.type, self.configuration

        def retarget() -> None:
            # The frame's current rotation, the translation x_d + ẋ_d/K.
            pose = configuration.get_transform_frame_to_world(name, kind)
            pose.wxyz_xyz[4:] = task.target + task.target_rate / gain
            frame.set_target(pose)

        self._retargets.append(retarget)

    def _com_task(self, task: ComTask, moving: bool) -> None:
        model = self.robot.model
        if task.dim != 3 or task.lm_damping or task.body not in (0, 1) or \
                model.body_subtreemass[1] != model.body_subtreemass[0]:
            raise PeerUnsupported("mink: its CoM task is body 1's subtree on all three axes (the whole model's "
                                  "CoM when every mass hangs below body 1)")
        gain = _one(task.gain, "CoM gain")
        com = mink.ComTask(cost=1.0 if task.hard else np.sqrt(_one(task.weight, "CoM weight")),
                           gain=self._gain(task.gain, "CoM task"))
        self._place(task, com)
        self.mink_task[id(task)] = com
        com.set_target(task.target + task.target_rate / gain)
        if moving:
            self._retargets.append(lambda: com.set_target(task.target + task.target_rate / gain))

    # Limits ------------------------------------------------------------------------
    def _limit(self, limit):
        model = self.robot.model
        if isinstance(limit, JointPositionLimit):
            if limit.influence > 0.0 or limit.limits is not self.robot.joint_limits:
                raise PeerUnsupported("mink: joint position limits map without the velocity damper, on the "
                                      "model's own ranges")
            return mink.ConfigurationLimit(model, gain=limit.gain, min_distance_from_limits=limit.margin)
        if isinstance(limit, JointVelocityLimit):
            speeds = {}
            for j in range(model.njnt):
                dofs = self.robot.joint_dofs(model.joint(j).name)
                bound = limit.max_velocity[dofs]
                if np.all(np.isfinite(bound)):
                    if int(model.jnt_type[j]) == FREE:
                        raise PeerUnsupported("mink: a speed bound on a free joint is not supported")
                    speeds[model.joint(j).name] = bound.copy()
                elif np.any(np.isfinite(bound)):
                    raise PeerUnsupported(f"mink: joint {model.joint(j).name} is bounded on some dofs only")
            return mink.VelocityLimit(model, speeds)
        if isinstance(limit, CollisionAvoidanceLimit):
            return mink.CollisionAvoidanceLimit(
                model, [([g1], [g2]) for g1, g2 in limit.pairs], gain=limit.gain,
                minimum_distance_from_collisions=limit.minimum_distance,
                collision_detection_distance=limit.detection_distance, bound_relaxation=limit.bound_relaxation)
        raise PeerUnsupported(f"mink: no mapping for a {type(limit).__name__}")

    # Step ----------------------------------------------------------------------------
    def compute_velocity(self) -> np.ndarray:
        """Sync mink's configuration, retarget the moving tasks, ``solve_ik``: q̇ = Δq/Δt."""
        self.configuration.update(self.robot.q)
        for retarget in self._retargets:
            retarget()
        try:
            self.qdot = mink.solve_ik(self.configuration, self.tasks, self.dt, self.solver, damping=self.regularization,
                                      limits=self.limits, constraints=self.constraints, **self._settings)
        except (mink.MinkError, ValueError) as exc:
            raise SolverError(f"mink ({self.solver}) failed: {type(exc).__name__}: {exc}") from None
        return self.qdot


# The timed contestant --------------------------------------------------------------
def shifted_pose(position, rotation, velocity, angular_velocity, gain: float) -> np.ndarray:
    """mink's ``wxyz_xyz`` targets (steps x 7) of a moving pose reference given as plain
    arrays: the pose shifted by its feed-forward twist over 1/K (p + ṗ/K, exp(ω/K) R),
    since mink has no feed-forward input and its gain α = KΔt removes the fraction α of
    the error per step. First-order equal to the mirror's exact target."""
    steps = len(position)
    out = np.empty((steps, 7))
    out[:, 4:] = position + velocity / gain
    body_rate = np.einsum("kji,kj->ki", rotation, angular_velocity) / gain  # Rᵀω/K: mju_quatIntegrate's frame
    for k in range(steps):
        mujoco.mju_mat2Quat(out[k, :4], np.ascontiguousarray(rotation[k]).reshape(9))
        mujoco.mju_quatIntegrate(out[k, :4], body_rate[k], 1.0)
    return out


class MinkRun:
    """mink on a mirrored problem, stepped as a mink user writes it (timing.Run).

    Timed step: each moving task's target for step k from its precomputed plain arrays in
    mink's types (a frame task's ``SE3`` from ``wxyz_xyz``; a position-only task's target
    from the frame's current pose with the translation replaced; the CoM's point),
    ``mink.solve_ik``, ``configuration.integrate_inplace`` (which updates the kinematics).

    Args:
        mirror: the :class:`MinkMirror` of the problem (built with no moving task: its
            retargets are not used).
        targets: per moving qpik task, the columns of its ``set_target`` arguments
            (steps x ...): position, rotation (frame tasks), velocity, angular velocity.
    """

    failures = (mink.MinkError, ValueError)  # qpsolvers raises ValueError subclasses

    def __init__(self, mirror: MinkMirror, targets: Sequence[tuple[object, list[np.ndarray]]], steps: int):
        self.mirror, self.steps = mirror, steps
        self.configuration = mirror.configuration
        self._solve = dict(tasks=mirror.tasks, dt=mirror.dt, solver=mirror.solver, damping=mirror.regularization,
                           limits=mirror.limits, constraints=mirror.constraints, **mirror._settings)
        self._setters = [self._setter(task, columns) for task, columns in targets]
        self.q = np.full((steps, self.configuration.model.nq), np.nan)

    def _setter(self, task, columns: list[np.ndarray]):
        target, steps = self.mirror.mink_task[id(task)], len(columns[0])
        if isinstance(task, FrameTask):
            zero = np.zeros((steps, 3))
            velocity, angular = (columns[2] if len(columns) > 2 else zero), (columns[3] if len(columns) > 3 else zero)
            poses = shifted_pose(columns[0], columns[1], velocity, angular, _one(task.feedback_gains(), "gain"))
            return lambda k: target.set_target(mink.SE3(poses[k]))
        gain = _one(task.gain, "gain")
        shifted = columns[0] + (columns[1] / gain if len(columns) > 1 else 0.0)
        if isinstance(task, ComTask):
            return lambda k: target.set_target(shifted[k])
        name, kind, configuration = task.frame.name, task.frame.type, self.configuration

        def position_target(k: int) -> None:
            pose = configuration.get_transform_frame_to_world(name, kind)
            pose.wxyz_xyz[4:] = shifted[k]
            target.set_target(pose)

        return position_target

    def step(self, k: int) -> None:
        for set_target in self._setters:
            set_target(k)
        velocity = mink.solve_ik(self.configuration, **self._solve)
        self.configuration.integrate_inplace(velocity, self.mirror.dt)

    def after(self, k: int) -> None:
        self.q[k] = self.configuration.q
