r"""placo on qpik's scenarios: its KinematicsSolver on a URDF of the same robot.

placo (pinocchio + its own QP layer, eiquadprog) reads URDF. The arm has one kept next to
its MJCF (``scenes/arm.urdf``); any other model gets one generated from its compiled
MjModel (:func:`qpik.app.peers.urdf.mjcf_to_urdf`: same frames, axes, ranges; the hexapod's
platform on a ``floating`` joint, its legs open at the spherical joints). At construction
the tracked frame's pose is checked against MuJoCo's site. placo's variable is the step
Δq; its root free-flyer is always present and masked. The mapping (see
:mod:`qpik.app.peers.problem`):

- position task → ``PositionTask`` on the frame named like the site, axes masked with
  ``mask.set_axises`` (world frame), "hard" or "soft" with weight w. placo's tasks are
  dead-beat (``A Δq = target − p``): the target is :math:`p + \alpha(p_t - p)` with
  :math:`p_t = p_d + \dot p_d/K`, which is :math:`p_t` itself for α = KΔt = 1.
- frame task → a ``PositionTask`` and an ``OrientationTask`` on the site's frame, targets
  :math:`p + \Delta t\,v_{lin}` and :math:`\exp([\Delta t\,v_{ang}]_\times)R`: placo's rows
  :math:`J_p\Delta q = \text{target} - p` and
  :math:`J_\omega\Delta q = \log(R_t R^T)` (world frame, pinocchio's ``WORLD`` Jacobian)
  are then :math:`J\Delta q = \Delta t\,v`, the QP's rows, hard or soft (weights w_p, w_o).
- loop closures (the hard :class:`~qpik.tasks.EqualityTask`'s ``connect`` equalities between two sites) → one hard
  ``RelativePositionTask`` per loop, target 0 (placo's documented way to close a loop):
  :math:`\partial_q(R_1^T(p_2 - p_1))\Delta q = -R_1^T(p_2 - p_1)`. Dead-beat, so α_c = K_cΔt
  must be 1. It equals the QP's :math:`J_c\Delta q = -e_c` rotated by :math:`R_1^T` except
  for the term :math:`\dot R_1^T e_c`, of order |e_c| |ω|Δt (1e-7 m x 1e-4 rad here).
- σ (and any joint-space task) → a soft ``JointsTask`` of weight w on every joint whose
  target moves each step to :math:`q + \Delta t\,v`: cost :math:`w\|\Delta q - \Delta t\,v\|^2`
  over all joints, the QP's term exactly (placo's ManipulabilityTask is a different
  measure, and NaN on the planar arm whose z row is zero). Damping (v = 0) → a
  regularization task of weight w, which also covers free joints.
- the hexapod's platform-manipulability task (J = the site's angular Jacobian,
  :math:`v = k_0\nabla_\theta m`) → a soft ``OrientationTask`` on that site, weight w,
  target :math:`\exp([\Delta t\,v]_\times)R`: cost :math:`w\|J_\omega\Delta q - \Delta t\,v\|^2`.
- soft-task Levenberg–Marquardt damping μ (qpik's :math:`\tfrac12\mu\,e^T W e\|\dot q\|^2`)
  → a regularization task whose weight is set to :math:`\mu\,e^T W e` every step.
- joint bounds → placo's own joint limits (``q + Δq`` within the model's position limits),
  whose bounds are re-set every step to :math:`q + [l, h]` with the QP's own step bounds
  (:meth:`PeerProblem.step_bounds`: the scenario's ranges, gain, margin and velocity
  damper). placo's ``JointSpaceHalfSpacesConstraint`` would say the same, but it assumes
  the root is the only free joint (its A[:, 7:] must match Δq[6:]), which the hexapod's
  platform breaks; placo's joint limits only need every joint after the root to be
  scalar *or* the first one (then q[8:] and Δq[6:] align on the scalar joints): the URDF
  puts the platform first (urdfdom orders joints by name) and its six rows get ±1e10.
- speed bounds → ``set_velocity_limit`` per joint and ``enable_velocity_limits``, with
  ``dt`` = Δt (free joints: none).

placo's QP regulariser is set to the QP's ε (its default is 1e-8). ``solve(False)``
returns Δq without placo integrating its own state (the rollout integrates qpik's robot,
which placo re-reads next step); q̇ = Δq/Δt, with a free joint's linear part turned from
pinocchio's body frame to MuJoCo's world frame (:math:`\dot p = R\,v_{lin}`; both put the
angular velocity in the body frame).
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import placo

from ...errors import InfeasibleProblem, SolverError
from ...robots.hexapod.control import PlatformManipulabilityTask
from ...robots import BUNDLED
from ...scenario import Setup
from ...tasks import DampingTask
from ..kinds import KINDS
from .problem import REGULARIZATION, SCALAR_JOINTS, PeerProblem, PeerUnsupported
from .urdf import mjcf_to_urdf

URDF_SCENES = {"arm": BUNDLED["arm"][0].with_name("arm.urdf")}
_FREE = int(mujoco.mjtJoint.mjJNT_FREE)
_NO_BOUND = 1e10  # stands for "no bound" in placo's limit rows (eiquadprog wants finite numbers)


def _rotation(vector: np.ndarray) -> np.ndarray:
    """exp([vector]×) as a 3 x 3 matrix."""
    quat, R = np.empty(4), np.empty(9)
    angle = float(np.linalg.norm(vector))
    if angle > 0.0:
        mujoco.mju_axisAngle2Quat(quat, vector / angle, angle)
    else:
        quat[:] = (1.0, 0.0, 0.0, 0.0)
    mujoco.mju_quat2Mat(R, quat)
    return R.reshape(3, 3)


class _JointMap:
    """MuJoCo's qpos/qvel ↔ placo's q/Δq, joint by joint (names shared with the URDF).

    Scalar joints copy; a free joint's quaternion is reordered (MuJoCo w x y z, pinocchio
    x y z w) and its linear velocity rotated to the world frame.
    """

    def __init__(self, model: mujoco.MjModel, wrapper: placo.RobotWrapper):
        names = [model.joint(j).name for j in range(model.njnt)]
        missing = sorted(set(names) - set(wrapper.joint_names()))
        if missing:
            raise PeerUnsupported(f"placo: the URDF lacks joints {missing}")
        scalar = [j for j in range(model.njnt) if int(model.jnt_type[j]) in SCALAR_JOINTS]
        self.free = [j for j in range(model.njnt) if int(model.jnt_type[j]) == _FREE]
        if len(scalar) + len(self.free) != model.njnt:
            raise PeerUnsupported("placo: only hinge, slide and free joints are mapped")
        self.names = [names[j] for j in scalar]
        self.qpos = np.array([model.jnt_qposadr[j] for j in scalar], dtype=int)
        self.dofs = np.array([model.jnt_dofadr[j] for j in scalar], dtype=int)
        self.placo_q = np.array([wrapper.get_joint_offset(n) for n in self.names], dtype=int)
        self.placo_v = np.array([wrapper.get_joint_v_offset(n) for n in self.names], dtype=int)
        # (MuJoCo qpos adr, dof adr, body, placo q offset, placo v offset) per free joint.
        self.free_map = [(int(model.jnt_qposadr[j]), int(model.jnt_dofadr[j]), int(model.jnt_bodyid[j]),
                          wrapper.get_joint_offset(names[j]), wrapper.get_joint_v_offset(names[j]))
                         for j in self.free]
        if len(self.free_map) > 1 or (self.free_map and self.free_map[0][3] != 7):
            raise PeerUnsupported("placo: one free joint, first after the root, is all placo's joint "
                                  "limits can keep aligned")

    def to_placo(self, qpos: np.ndarray, q: np.ndarray) -> None:
        q[self.placo_q] = qpos[self.qpos]
        for adr, _, _, off, _ in self.free_map:
            q[off:off + 3] = qpos[adr:adr + 3]
            q[off + 3:off + 6] = qpos[adr + 4:adr + 7]
            q[off + 6] = qpos[adr + 3]

    def to_mujoco(self, step: np.ndarray, data: mujoco.MjData, qvel: np.ndarray) -> None:
        qvel[self.dofs] = step[self.placo_v]
        for _, dof, body, _, voff in self.free_map:
            qvel[dof:dof + 3] = data.xmat[body].reshape(3, 3) @ step[voff:voff + 3]
            qvel[dof + 3:dof + 6] = step[voff + 3:voff + 6]


class PlacoController:
    """placo's KinematicsSolver as a qpik controller (``kind = "placo"``).

    Args:
        setup: the scenario; its robot's ``q`` is read every step.
        urdf: a URDF of the setup's robot (default: the bundled one of the same name, else
            one generated from the MuJoCo model).
    """

    kind = "placo"
    solver = KINDS["placo"].own_solver

    def __init__(self, setup: Setup, urdf: str | Path | None = None):
        self.problem = problem = PeerProblem.from_setup(setup, "placo")
        self.robot = robot = setup.robot
        self.dt = setup.dt
        urdf = urdf or URDF_SCENES.get(setup.robot_name)
        if urdf is not None:
            self.wrapper = placo.RobotWrapper(str(urdf), placo.Flags.ignore_collisions)
        else:
            text = mjcf_to_urdf(robot.model, robot.velocity_limits, setup.robot_name)
            self.wrapper = placo.RobotWrapper(str(BUNDLED[setup.robot_name][0].parent if setup.robot_name in BUNDLED else Path.cwd()), placo.Flags.ignore_collisions, text)
        self.joints = _JointMap(robot.model, self.wrapper)
        self._state_q = self.wrapper.state.q  # placo's own vector (it keeps its storage), written in place
        self.ik = ik = placo.KinematicsSolver(self.wrapper)
        ik.mask_fbase(True)
        ik.dt = self.dt
        ik.problem.regularization = REGULARIZATION  # placo's default is 1e-8, the QP's ε 1e-12
        self._limits(problem)
        self._tracking(problem)
        self._loops(problem)
        self._soft_tasks(problem)
        self.qdot = np.zeros(robot.nv)
        self._check_urdf()

    # Construction ------------------------------------------------------------------

    def _limits(self, problem: PeerProblem) -> None:
        """Joint bounds through placo's own limits, re-set per step; speed bounds."""
        model = self.wrapper.model
        self._lower, self._upper = model.lowerPositionLimit, model.upperPositionLimit  # writable views
        for _, _, _, off, voff in self.joints.free_map:
            self._lower[off:off + 7], self._upper[off:off + 7] = -_NO_BOUND, _NO_BOUND
            model.velocityLimit[voff:voff + 6] = _NO_BOUND
        self._limited = np.array([self.wrapper.get_joint_offset(n) for n in problem.joint_names], dtype=int)
        for name, vmax in problem.velocity_limited_joints().items():
            self.wrapper.set_velocity_limit(name, vmax)
        self.ik.enable_joint_limits(True)
        self.ik.enable_velocity_limits(True)

    def _tracking(self, problem: PeerProblem) -> None:
        task = problem.tracking
        if task.frame.type == "geom":
            raise PeerUnsupported("placo: a geom frame has no URDF link; track a site or a body")
        self._frame = task.frame.name  # the URDF link of that site or body
        priority = "hard" if problem.hard else "soft"
        self.orientation = None
        if problem.frame:
            weights = _scalar(task.weight[:3], "position weight"), _scalar(task.weight[3:], "orientation weight")
            self.position = self.ik.add_position_task(self._frame, np.zeros(3))
            self.position.configure("position", priority, weights[0])
            self.orientation = self.ik.add_orientation_task(self._frame, np.eye(3))
            self.orientation.configure("orientation", priority, weights[1])
            self._rows = np.arange(3)
        else:
            self._rows = task.rows
            self.position = self.ik.add_position_task(self._frame, np.zeros(3))
            self.position.configure("position", priority, _scalar(task.weight, "position task"))
            self.position.mask.set_axises("".join("xyz"[r] for r in task.rows))
        self._lm = None
        if not problem.hard and task.lm_damping:
            # Its weight is set per step with set_weight (placo 0.10's RegularizationTask
            # ignores a later configure(); the magnitude given here multiplies, so 1).
            self._lm = self.ik.add_regularization_task(1.0)
        self._target = np.zeros(3)

    def _loops(self, problem: PeerProblem) -> None:
        self.loop_tasks = []
        if problem.loops is None:
            return
        if problem.loop_gain != 1.0:
            raise PeerUnsupported(f"placo: its loop tasks are dead-beat, K_cΔt = {problem.loop_gain:g} must be 1")
        model = self.robot.model
        for eq in problem.loop_equalities():
            if model.eq_type[eq] != mujoco.mjtEq.mjEQ_CONNECT or model.eq_objtype[eq] != mujoco.mjtObj.mjOBJ_SITE:
                raise PeerUnsupported("placo: only site-to-site connect equalities are mapped")
            a, b = (mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_SITE, int(s))
                    for s in (model.eq_obj1id[eq], model.eq_obj2id[eq]))
            closure = self.ik.add_relative_position_task(a, b, np.zeros(3))
            closure.configure(f"loop {a}-{b}", "hard", 1.0)
            self.loop_tasks.append(closure)

    def _soft_tasks(self, problem: PeerProblem) -> None:
        self._joint_tasks, self._orientation_tasks = [], []
        for k, task in enumerate(problem.joint_space):
            weight = _scalar(task.weight, type(task).__name__)
            if isinstance(task, DampingTask):
                self.ik.add_regularization_task(weight)
                continue
            if self.joints.free:
                raise PeerUnsupported(f"placo: a {type(task).__name__} on a robot with a free joint is not mapped")
            if not np.array_equal(task.dofs, np.arange(self.robot.nv)):
                raise PeerUnsupported(f"placo: a {type(task).__name__} on some of the joints only is not mapped")
            joints = self.ik.add_joints_task()
            joints.configure(f"joint space {k}", "soft", weight)
            self._joint_tasks.append((joints, task))
        for k, task in enumerate(problem.extra):
            if not isinstance(task, PlatformManipulabilityTask):
                raise PeerUnsupported(f"placo: the {type(task).__name__} is not mapped")
            site = mujoco.mj_id2name(self.robot.model, mujoco.mjtObj.mjOBJ_SITE, task.model.center_site)
            orientation = self.ik.add_orientation_task(site, np.eye(3))
            orientation.configure(f"angular {k}", "soft", _scalar(task.weight, type(task).__name__))
            self._orientation_tasks.append((orientation, task, site))

    # Per step ----------------------------------------------------------------------

    def _sync(self) -> None:
        self.joints.to_placo(self.robot.q, self._state_q)
        self.wrapper.update_kinematics()

    def _check_urdf(self) -> None:
        """The URDF must place the frame where MuJoCo places the site."""
        self._sync()
        pose = self.wrapper.get_T_world_frame(self._frame)
        frame = self.problem.tracking.frame
        if not (np.allclose(pose[:3, 3], frame.position, atol=1e-9)
                and np.allclose(pose[:3, :3], frame.rotation, atol=1e-9)):
            raise PeerUnsupported(f"placo: the URDF's {self._frame!r} is at {pose[:3, 3]}, "
                                  f"MuJoCo's {frame.type} at {frame.position}")

    def _retarget(self) -> None:
        problem, dt = self.problem, self.dt
        task = problem.tracking
        current = self.wrapper.get_T_world_frame(self._frame)
        if problem.frame:
            task.update_target_velocity()
            v = task.target_velocity
            self.position.target_world = current[:3, 3] + dt * v[:3]
            self.orientation.R_world_frame = _rotation(dt * v[3:]) @ current[:3, :3]
        else:
            rows, target = self._rows, self._target
            target[rows] = problem.shifted_target()
            if problem.step_gain != 1.0:
                target[rows] = current[rows, 3] + problem.step_gain * (target[rows] - current[rows, 3])
            self.position.target_world = target
            if self._lm is not None:
                task.update_target_velocity()
        if self._lm is not None:
            error = task.error
            self._lm.set_weight(task.lm_damping * float(error @ (task.weight * error)))

    def compute_velocity(self) -> np.ndarray:
        """Sync placo's state, retarget its tasks, solve: q̇ = Δq/Δt."""
        self._sync()
        problem, dt, joints = self.problem, self.dt, self.joints
        self._retarget()
        low, high = problem.step_bounds()
        q_limited = self._state_q[self._limited]
        self._upper[self._limited] = q_limited + high
        self._lower[self._limited] = q_limited + low
        if self._joint_tasks:
            q = self._state_q[joints.placo_q]
            for placo_task, task in self._joint_tasks:
                task.update()
                for name, value in zip(joints.names, q + dt * task.target_velocity[joints.dofs]):
                    placo_task.set_joint(name, value)
        for orientation, task, site in self._orientation_tasks:
            task.update()
            R = self.wrapper.get_T_world_frame(site)[:3, :3]
            orientation.R_world_frame = _rotation(dt * task.target_velocity) @ R
        try:
            step = self.ik.solve(False)
        except RuntimeError as exc:  # placo's QPError
            message = str(exc)
            raise (InfeasibleProblem if "nfeasible" in message else SolverError)(f"placo: {message}") from None
        joints.to_mujoco(step, self.robot.data, self.qdot)
        self.qdot /= dt
        return self.qdot


def _scalar(weight: np.ndarray, what: str) -> float:
    """placo weighs a task with one number."""
    if np.ptp(weight) > 0:
        raise PeerUnsupported(f"placo: {what} needs one weight for all its rows, got {weight}")
    return float(weight[0])
