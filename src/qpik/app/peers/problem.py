r"""A scenario's QP, read off its :class:`~qpik.scenario.Setup` for a peer library.

qpik's QP (``qp.py``) is written in the joint velocity:

.. math::
    \min_{\dot q}\ \tfrac12 \sum_{\text{soft}} w_i \|J_i\dot q - v_i\|^2 + \tfrac12\epsilon\|\dot q\|^2
    \ \ \text{s.t.}\ \ J_h\dot q = v_h,\ \ q + \dot q\Delta t \in [q_{min} + m, q_{max} - m],
    \ \ |\dot q| \le \dot q_{max}

mink and placo solve for the step :math:`\Delta q = \dot q\,\Delta t` instead. Multiplying the
cost by :math:`\Delta t^2` leaves the minimiser unchanged, so every weight carries over as
it is: a task term becomes :math:`\tfrac12 w\|J\Delta q - \Delta t\,v\|^2`.

- Tracking, :math:`v = \dot p_d + K(p_d - p)`: :math:`\Delta t\,v = \alpha(p_t - p)` with
  the step gain :math:`\alpha = K\Delta t` and the shifted target
  :math:`p_t = p_d + \dot p_d / K`. A peer task that removes the fraction α of its error per
  step (mink's ``gain``; placo's tasks are dead-beat, α = 1) given :math:`p_t` therefore
  reproduces the closed-loop law with its feed-forward *exactly*; neither peer has a
  feed-forward input, and dropping it would leave a lag of :math:`\dot p_d/K` (up to
  ~1e-3 m on the arm's segment), which is why the target is shifted rather than the
  difference documented.
- Pose tracking (a :class:`~qpik.tasks.FrameTask`,
  :math:`v = [\dot p_d + K e_p;\ \omega_d + K e_o]` in the world frame): the same idea on
  SE(3). A peer whose error is the body-frame log :math:`\log(T^{-1}T_t)` gets the target
  :math:`T_t = T\exp(u)` with :math:`u = (\Delta t/\alpha)\,[R^T v_{lin};\ R^T v_{ang}]`
  (:meth:`PeerProblem.body_step`), so that its error is exactly u (see
  :mod:`qpik.app.peers.mink_peer` for why its log Jacobian then drops out).
- Loop closures (``connect`` equalities, hard :math:`J_c\dot q = -K_c e_c`): the peer's
  own equality rows with gain :math:`\alpha_c = K_c\Delta t`.
- Joint-space tasks (the σ gradient :math:`v = k_0\nabla\sigma`, posture, damping: J = I)
  and other soft tasks with their own Jacobian (the hexapod's platform-manipulability
  task: J = angular site Jacobian, :math:`v = k_0\nabla_\theta m`):
  :math:`\tfrac12 w\|J\Delta q - \Delta t\,v\|^2`.
- Limits: the same bounds on the same joints, pulled in by the QP's margin; the position
  limit's gain (fraction of the remaining distance one step may cover) carries over, and
  so does its velocity damper near a bound, which neither peer has (each gets it as
  extra inequalities computed by the scenario's own limit object).
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from ...errors import QpikError
from ...limits import JointPositionLimit, JointVelocityLimit
from ...robot import Robot
from ...scenario import Setup
from ...tasks import EqualityTask, FrameTask, PositionTask, Task

SCALAR_JOINTS = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
# JointPositionLimit's default margin: bounds pulled in so that q + q̇Δt never lands a
# rounding error outside the range (the QP's limits use it; the peers get the same).
POSITION_MARGIN = 1e-10
# QPController's default Hessian regulariser ε (scale-free: it maps unchanged to Δq).
REGULARIZATION = 1e-12


class PeerUnsupported(QpikError, ValueError):
    """A scenario uses something a peer library cannot express (yet)."""


@dataclass
class PeerProblem:
    """The pieces of a scenario's QP that a peer rebuilds with its own objects.

    Attributes:
        robot: the setup's robot, whose ``q`` the rollout integrates (read every step).
        dt: control period Δt.
        tracking: the tracked task (the reference's): a position or a frame task, hard or soft.
        step_gain: α = KΔt of the tracked task, in (0, 1].
        joint_space: the soft joint-space tasks (J = I[dofs], target velocity v).
        extra: the other soft tasks, each with its own Jacobian (e.g. platform manipulability).
        loops: the hard equality task (loop closures), if the robot is a closed chain.
        loop_gain: α_c = K_cΔt of the loop closures, in (0, 1] (0 without loops).
        position_limit: the scenario's joint position limit (its ranges, gain, damper).
        max_velocity: per-dof speed bound (nv,), inf where none.
    """

    robot: Robot
    dt: float
    tracking: PositionTask | FrameTask
    step_gain: float
    joint_space: tuple[Task, ...]
    extra: tuple[Task, ...]
    loops: EqualityTask | None
    loop_gain: float
    position_limit: JointPositionLimit
    max_velocity: np.ndarray

    def __post_init__(self) -> None:
        limits = self.position_limit.limits
        self.joint_names, self.lower, self.upper = limits.names, limits.lower, limits.upper
        self.limit_gain = self.position_limit.gain
        self.damper = self.position_limit.influence > 0.0
        # One world's box (1, nv), as the limit writes it (the peers run a one-world robot).
        self._low, self._high = np.empty((1, self.robot.nv)), np.empty((1, self.robot.nv))
        self._step = np.empty(6)

    @classmethod
    def from_setup(cls, setup: Setup, peer: str) -> PeerProblem:
        """Read the scenario's tasks and limits; raise :class:`PeerUnsupported` otherwise."""
        tracking = getattr(setup.reference, "task", None)
        if not isinstance(tracking, (PositionTask, FrameTask)) or tracking not in setup.qp_tasks:
            raise PeerUnsupported(f"{peer}: scenario {setup.scenario!r} tracks a {type(tracking).__name__} "
                                  "outside the QP, which the peer does not map")
        if tracking.axes_frame != "world" or (isinstance(tracking, FrameTask) and tracking.dim != 6):
            raise PeerUnsupported(f"{peer}: scenario {setup.scenario!r} tracks a masked frame task or one in the "
                                  "frame's own axes, which the peer mapping does not cover")
        others = [t for t in setup.qp_tasks if t is not tracking]
        loops = [t for t in others if isinstance(t, EqualityTask) and t.hard]
        joint_space = [t for t in others if t.joint_space]
        extra = [t for t in others if t not in loops and t not in joint_space]
        hard_extra = [type(t).__name__ for t in extra if t.hard]
        if hard_extra or len(loops) > 1:
            raise PeerUnsupported(f"{peer}: scenario {setup.scenario!r} has tasks the peer does not map: "
                                  f"{hard_extra or ['two equality tasks']}")
        step_gain = _step_gain(_gains(tracking), setup.dt, f"{peer}: the tracking gain")
        loop_gain = _step_gain(np.array([loops[0].gain]), setup.dt, f"{peer}: the loop gain") if loops else 0.0
        position_limits = [lim for lim in setup.limits if isinstance(lim, JointPositionLimit)]
        velocity_limits = [lim for lim in setup.limits if isinstance(lim, JointVelocityLimit)]
        if len(position_limits) != 1 or len(velocity_limits) > 1 or len(setup.limits) != 1 + len(velocity_limits):
            raise PeerUnsupported(f"{peer}: expected one joint position limit and at most one velocity limit")
        max_velocity = velocity_limits[0].max_velocity if velocity_limits else np.full(setup.robot.nv, np.inf)
        return cls(robot=setup.robot, dt=setup.dt, tracking=tracking, step_gain=step_gain,
                   joint_space=tuple(joint_space), extra=tuple(extra), loops=loops[0] if loops else None,
                   loop_gain=loop_gain, position_limit=position_limits[0], max_velocity=max_velocity.copy())

    @property
    def hard(self) -> bool:
        return self.tracking.hard

    @property
    def frame(self) -> bool:
        """Whether the tracked task is a 6-D pose task (else a position task)."""
        return isinstance(self.tracking, FrameTask)

    def shifted_target(self) -> np.ndarray:
        """p_t = p_d + ṗ_d / K on a position task's axes: the target whose error α(p_t − p) is Δt v."""
        task = self.tracking
        return task.target + task.target_rate / task.gain

    def body_step(self) -> np.ndarray:
        r"""u = (Δt/α) [Rᵀ v_lin; Rᵀ v_ang] (6,): the frame task's step in the frame's own axes.

        With the QP's :math:`v = [\dot p_d + K e_p;\ \omega_d + K e_o]` and α = KΔt this is
        :math:`u = [R^T(\dot p_d/K + e_p);\ R^T(\omega_d/K + e_o)]`: the current pose
        :math:`T` shifted by :math:`\exp(u)` is the target a body-frame SE(3) task needs.
        (The desired pose shifted by the feed-forward, :math:`T_d \oplus (\dot p_d, \omega_d)/K`,
        agrees only to first order: the log's coupling :math:`V(\theta)^{-1}` adds
        :math:`\sim\tfrac12\,\theta\times\rho` per step, a few 1e-9 m on the hexapod's circle.)
        Reads the robot's current kinematics.
        """
        task = self.tracking
        task.update_target_velocity()
        R = task.frame.rotation
        scale = self.dt / self.step_gain
        v, u = task.target_velocity, self._step
        np.matmul(v[:3], R, out=u[:3])  # vᵀR = (Rᵀv)ᵀ
        np.matmul(v[3:], R, out=u[3:])
        u *= scale
        return u

    def step_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Bounds on Δq of the limited joints at the current q, as the QP computes them.

        The scenario's own :class:`JointPositionLimit` fills them: the gain, the margin
        and, near a bound, the velocity damper (Faverjon–Tournassoud: the speed toward a
        bound closer than the influence distance ρ is at most ξ d / ρ).
        """
        low, high = self._low, self._high
        low.fill(-np.inf)
        high.fill(np.inf)
        self.position_limit.apply(self.dt, low, high)
        dofs = self.position_limit.limits.dof_index
        return self.dt * low[0, dofs], self.dt * high[0, dofs]

    def velocity_limited_joints(self) -> dict[str, float]:
        """{joint name: q̇max} for the scalar joints with a finite speed bound."""
        model = self.robot.model
        out = {}
        for j in range(model.njnt):
            vmax = self.max_velocity[model.jnt_dofadr[j]]
            if np.isfinite(vmax) and int(model.jnt_type[j]) in SCALAR_JOINTS:
                out[mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j)] = float(vmax)
        return out

    def loop_equalities(self) -> list[int]:
        """The ids of the model's equalities the hard equality task enforces."""
        return [] if self.loops is None else list(self.loops.equalities)

def _gains(task: PositionTask | FrameTask) -> np.ndarray:
    if isinstance(task, FrameTask):
        return np.concatenate([task.position_gain, task.orientation_gain])
    return task.gain


def _step_gain(gain: np.ndarray, dt: float, what: str) -> float:
    """α = KΔt, one K for every row (the peers' tasks have one gain), in (0, 1]."""
    if np.ptp(gain) > 0:
        raise PeerUnsupported(f"{what} must be the same on every axis, got {gain}")
    alpha = float(gain[0]) * dt
    if not 0.0 < alpha <= 1.0:
        raise PeerUnsupported(f"{what}: the step gain KΔt = {alpha:g} must lie in (0, 1]")
    return alpha
