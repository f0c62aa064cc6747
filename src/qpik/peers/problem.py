r"""A scenario's QP, read off its :class:`~qpik.scenarios.Setup` for a peer library.

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
- Joint-space tasks (the σ gradient :math:`v = k_0\nabla\sigma`, posture, damping: J = I):
  :math:`\tfrac12 w\|\Delta q - \Delta t\,v\|^2`.
- Limits: the same bounds on the same joints, pulled in by the QP's margin; the position
  limit's gain (fraction of the remaining distance one step may cover) carries over, and
  so does its velocity damper near a bound, which neither peer has (each gets it as
  extra inequalities computed by the scenario's own limit object).
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from ..errors import QpikError
from ..limits import JointPositionLimit, JointVelocityLimit
from ..robot import Robot
from ..scenarios import Setup
from ..tasks import DampingTask, ManipulabilityTask, PositionTask, PostureTask, Task

SCALAR_JOINTS = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
JOINT_SPACE_TASKS = (ManipulabilityTask, PostureTask, DampingTask)
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
        position: the tracked position task (the reference's), hard or soft.
        step_gain: α = KΔt of the position task, in (0, 1].
        joint_space: the other tasks, all joint-space (J = I, target velocity v).
        position_limit: the scenario's joint position limit (its ranges, gain, damper).
        max_velocity: per-dof speed bound (nv,), inf where none.
    """

    robot: Robot
    dt: float
    position: PositionTask
    step_gain: float
    joint_space: tuple[Task, ...]
    position_limit: JointPositionLimit
    max_velocity: np.ndarray

    def __post_init__(self) -> None:
        limits = self.position_limit.limits
        self.joint_names, self.lower, self.upper = limits.names, limits.lower, limits.upper
        self.limit_gain = self.position_limit.gain
        self.damper = self.position_limit.influence > 0.0
        self._low, self._high = np.empty(self.robot.nv), np.empty(self.robot.nv)

    @classmethod
    def from_setup(cls, setup: Setup, peer: str) -> PeerProblem:
        """Read the scenario's tasks and limits; raise :class:`PeerUnsupported` otherwise."""
        position = getattr(setup.reference, "task", None)
        if not isinstance(position, PositionTask):
            raise PeerUnsupported(f"{peer}: scenario {setup.scenario!r} tracks a "
                                  f"{type(position).__name__}, which the {peer} peer does not map yet")
        others = [t for t in setup.qp_tasks if t is not position]
        unsupported = [type(t).__name__ for t in others if not isinstance(t, JOINT_SPACE_TASKS)]
        if unsupported or position not in setup.qp_tasks:
            raise PeerUnsupported(f"{peer}: scenario {setup.scenario!r} has tasks the peer does not map: "
                                  f"{unsupported or ['tracked task outside the QP']}")
        gain = position.gain
        if np.ptp(gain) > 0:
            raise PeerUnsupported(f"{peer}: the position gain must be the same on every axis, got {gain}")
        step_gain = float(gain[0]) * setup.dt
        if not 0.0 < step_gain <= 1.0:
            raise PeerUnsupported(f"{peer}: the step gain KΔt = {step_gain:g} must lie in (0, 1]")
        position_limits = [lim for lim in setup.limits if isinstance(lim, JointPositionLimit)]
        velocity_limits = [lim for lim in setup.limits if isinstance(lim, JointVelocityLimit)]
        if len(position_limits) != 1 or len(velocity_limits) > 1 or len(setup.limits) != 1 + len(velocity_limits):
            raise PeerUnsupported(f"{peer}: expected one joint position limit and at most one velocity limit")
        max_velocity = velocity_limits[0].max_velocity if velocity_limits else np.full(setup.robot.nv, np.inf)
        return cls(robot=setup.robot, dt=setup.dt, position=position, step_gain=step_gain,
                   joint_space=tuple(others), position_limit=position_limits[0], max_velocity=max_velocity.copy())

    @property
    def hard(self) -> bool:
        return self.position.hard

    def shifted_target(self) -> np.ndarray:
        """p_t = p_d + ṗ_d / K on the task's axes: the target whose error α(p_t − p) is Δt v."""
        task = self.position
        return task.target + task.target_rate / task.gain

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
        return self.dt * low[dofs], self.dt * high[dofs]

    def velocity_limited_joints(self) -> dict[str, float]:
        """{joint name: q̇max} for the scalar joints with a finite speed bound."""
        model = self.robot.model
        out = {}
        for j in range(model.njnt):
            vmax = self.max_velocity[model.jnt_dofadr[j]]
            if np.isfinite(vmax) and int(model.jnt_type[j]) in SCALAR_JOINTS:
                out[mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j)] = float(vmax)
        return out
