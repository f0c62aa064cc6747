r"""placo on qpik's scenarios: its KinematicsSolver on a URDF of the same robot.

placo (pinocchio + its own QP layer, eiquadprog) reads URDF, so each robot it runs on has
one kept next to its MJCF (``scenes/arm.urdf``); at construction the end effector's
position is checked against MuJoCo's. Its variable is the step Δq (a floating base is
always present and masked). The mapping (see :mod:`qpik.peers.problem`):

- position task → ``PositionTask`` on the frame named like the site, axes masked with
  ``mask.set_axises`` (world frame), "hard" or "soft" with weight w. placo's tasks are
  dead-beat (``A Δq = target − p``): the target is :math:`p + \alpha(p_t - p)` with
  :math:`p_t = p_d + \dot p_d/K`, which is :math:`p_t` itself for α = KΔt = 1.
- σ (and any joint-space task) → a soft ``JointsTask`` of weight w on every joint whose
  target moves each step to :math:`q + \Delta t\,v`: cost :math:`w\|\Delta q - \Delta t\,v\|^2`
  over all joints, the QP's term exactly (placo's ManipulabilityTask is a different
  measure, and NaN on the planar arm whose z row is zero).
- soft-task Levenberg–Marquardt damping μ (qpik's :math:`\tfrac12\mu w\|e\|^2\|\dot q\|^2`)
  → a regularization task whose weight is set to :math:`\mu w\|e\|^2` every step.
- joint bounds → a ``JointSpaceHalfSpacesConstraint`` :math:`q + \Delta q \le q + h`,
  :math:`-(q + \Delta q) \le -(q + l)` with the QP's own step bounds [l, h]
  (:meth:`PeerProblem.step_bounds`: the scenario's ranges, gain, margin and velocity damper)
  re-set every step. placo's ``enable_joint_limits`` is the special case gain 1 on the
  URDF's ranges without a damper, so it cannot carry the scenarios' bounds.
- speed bounds → ``set_velocity_limit`` per joint and ``enable_velocity_limits``, with
  ``dt`` = Δt.

placo's QP regulariser is set to the QP's ε (its default is 1e-8). ``solve(False)``
returns Δq without placo integrating its own state (the rollout integrates qpik's robot,
which placo re-reads next step); q̇ = Δq/Δt.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import placo

from ..errors import InfeasibleProblem, SolverError
from ..robot import SCENES_DIR
from ..scenarios import Setup
from . import PLACO_SOLVER
from .problem import REGULARIZATION, SCALAR_JOINTS, PeerProblem, PeerUnsupported

URDF_SCENES = {"arm": SCENES_DIR / "arm.urdf"}


class PlacoController:
    """placo's KinematicsSolver as a qpik controller (``kind = "placo"``).

    Args:
        setup: the scenario; its robot's ``q`` is read every step.
        urdf: the URDF of the setup's robot (default: the bundled one of the same name).
    """

    kind = "placo"
    solver = PLACO_SOLVER

    def __init__(self, setup: Setup, urdf: str | Path | None = None):
        self.problem = problem = PeerProblem.from_setup(setup, "placo")
        if urdf is None and setup.robot_name not in URDF_SCENES:
            raise PeerUnsupported(f"placo: no URDF for robot {setup.robot_name!r}")
        self.robot = robot = setup.robot
        self.dt = setup.dt
        self.wrapper = placo.RobotWrapper(str(urdf or URDF_SCENES[setup.robot_name]), placo.Flags.ignore_collisions)
        model = robot.model
        if any(int(model.jnt_type[j]) not in SCALAR_JOINTS for j in range(model.njnt)):
            raise PeerUnsupported("placo: only hinge and slide joints are mapped")
        names = [model.joint(j).name for j in range(model.njnt)]
        missing = sorted(set(names) - set(self.wrapper.joint_names()))
        if missing:
            raise PeerUnsupported(f"placo: the URDF lacks joints {missing}")
        self._names = names
        self._qpos = np.array([model.jnt_qposadr[j] for j in range(model.njnt)])
        self._dofs = np.array([model.jnt_dofadr[j] for j in range(model.njnt)])
        self._placo_q = np.array([self.wrapper.get_joint_offset(n) for n in names])
        self._placo_v = np.array([self.wrapper.get_joint_v_offset(n) for n in names])
        for name, vmax in problem.velocity_limited_joints().items():
            self.wrapper.set_velocity_limit(name, vmax)

        self.ik = ik = placo.KinematicsSolver(self.wrapper)
        ik.mask_fbase(True)
        ik.dt = self.dt
        ik.problem.regularization = REGULARIZATION  # placo's default is 1e-8, the QP's ε 1e-12
        ik.enable_velocity_limits(True)
        # Joint bounds as half-spaces A(q + Δq) ≤ b, b re-set each step: [I; −I] on the limited joints.
        limited = np.array([self.wrapper.get_joint_offset(n) for n in problem.joint_names])
        n = len(limited)
        rows = np.zeros((2 * n, self.wrapper.model.nq))
        rows[np.arange(n), limited] = 1.0
        rows[n + np.arange(n), limited] = -1.0
        self._limited = limited
        self.joint_bounds = ik.add_joint_space_half_spaces_constraint(rows, np.zeros(2 * n))
        self.joint_bounds.configure("joint bounds", "hard", 1.0)
        position = problem.position
        self._frame = position.site
        self._rows = position.rows
        self._weight = _scalar(position.weight, "position task")
        self.position = ik.add_position_task(self._frame, np.zeros(3))
        self.position.configure("position", "hard" if problem.hard else "soft", self._weight)
        self.position.mask.set_axises("".join("xyz"[r] for r in position.rows))
        self._joint_tasks = []
        for k, task in enumerate(problem.joint_space):
            joints = ik.add_joints_task()
            joints.configure(f"joint space {k}", "soft", _scalar(task.weight, type(task).__name__))
            self._joint_tasks.append((joints, task))
        self._lm = None
        if not problem.hard and position.lm_damping:
            # Its weight is set per step with set_weight (placo 0.10's RegularizationTask
            # ignores a later configure(); the magnitude given here multiplies, so 1).
            self._lm = ik.add_regularization_task(1.0)
        self._target = np.zeros(3)
        # Views into placo's own vectors (they keep their storage), written in place.
        self._state_q = self.wrapper.state.q
        self._bounds_upper, self._bounds_lower = self.joint_bounds.b[:n], self.joint_bounds.b[n:]
        self.qdot = np.zeros(robot.nv)
        self._check_urdf()

    def _sync(self) -> None:
        self._state_q[self._placo_q] = self.robot.q[self._qpos]
        self.wrapper.update_kinematics()

    def _check_urdf(self) -> None:
        """The URDF must place the frame where MuJoCo places the site."""
        self._sync()
        placo_p = self.wrapper.get_T_world_frame(self._frame)[:3, 3]
        mujoco_p = self.robot.site_position(self.problem.position.site_id)
        if not np.allclose(placo_p, mujoco_p, atol=1e-9):
            raise PeerUnsupported(f"placo: the URDF's {self._frame!r} is at {placo_p}, MuJoCo's site at {mujoco_p}")

    def compute_velocity(self) -> np.ndarray:
        """Sync placo's state, retarget its tasks, solve: q̇ = Δq/Δt."""
        self._sync()
        problem, rows, dt = self.problem, self._rows, self.dt
        target = self._target
        target[rows] = problem.shifted_target()
        if problem.step_gain != 1.0 or self._lm is not None:
            current = self.wrapper.get_T_world_frame(self._frame)[:3, 3]
            target[rows] = current[rows] + problem.step_gain * (target[rows] - current[rows])
            if self._lm is not None:
                error = problem.position.target - current[rows]
                self._lm.set_weight(problem.position.lm_damping * self._weight * float(error @ error))
        self.position.target_world = target
        low, high = problem.step_bounds()
        q_limited = self._state_q[self._limited]
        np.add(q_limited, high, out=self._bounds_upper)
        np.add(q_limited, low, out=self._bounds_lower)
        self._bounds_lower *= -1.0
        q = self._state_q[self._placo_q]
        for joints, task in self._joint_tasks:
            task.update()
            for name, value in zip(self._names, q + dt * task.target_velocity[self._dofs]):
                joints.set_joint(name, value)
        try:
            step = self.ik.solve(False)
        except RuntimeError as exc:  # placo's QPError
            message = str(exc)
            raise (InfeasibleProblem if "nfeasible" in message else SolverError)(f"placo: {message}") from None
        self.qdot[self._dofs] = step[self._placo_v] / dt  # placo's dofs: floating base first
        return self.qdot


def _scalar(weight: np.ndarray, what: str) -> float:
    """placo weighs a task with one number."""
    if np.ptp(weight) > 0:
        raise PeerUnsupported(f"placo: {what} needs one weight for all its rows, got {weight}")
    return float(weight[0])
