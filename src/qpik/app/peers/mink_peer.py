r"""mink on qpik's scenarios: its FrameTask, EqualityConstraintTask, limits and ``solve_ik``.

The mapping (see :mod:`qpik.app.peers.problem` for why each one is exact):

- position task → ``mink.FrameTask`` on the same frame (site, body or geom), ``gain`` α = KΔt (1.0 for
  K = 500, Δt = 2 ms), target translation :math:`p_d + \dot p_d/K` on the task's axes and
  the site's current rotation (so the SE(3) error has no rotation part to couple into the
  position rows: mink's log Jacobian is then the identity), ``orientation_cost = 0``.
  Hard: the task's rows of the same FrameTask as an equality in
  ``solve_ik(constraints=...)`` (mink's constraints ignore costs, hence the row subset).
  mink's FrameTask works in the site frame; its position rows are the world rows rotated
  by :math:`R^T`, the same equalities (and on the planar arm, whose site z axis stays the
  world's, its x, y rows span the world x, y rows).
- frame task (the hexapod's platform pose) → ``mink.FrameTask`` with ``gain`` α and the
  target :math:`T_t = T\exp(u)`, :math:`u = (\Delta t/\alpha)[R^T v_{lin};\ R^T v_{ang}]`
  (:meth:`PeerProblem.body_step`). Why this is the QP's row: mink's error is the body
  twist :math:`e = \log(T^{-1}T_t) = u` and its Jacobian
  :math:`J = -J_{log}(T_t^{-1}T)\,J_b` with :math:`J_b = [R^T J_p;\ R^T J_r]` (MuJoCo's site
  Jacobian in the site frame) and :math:`J_{log}(\exp(-u)) = J_r^{-1}(-u) = J_l^{-1}(u)`.
  Its row :math:`J\Delta q = -\alpha e` reads :math:`J_l^{-1}(u)J_b\Delta q = \alpha u`, i.e.
  :math:`J_b\Delta q = \alpha J_l(u)u = \alpha u` (:math:`u` is an eigenvector of
  :math:`J_l(u)`, eigenvalue 1): :math:`[J_p; J_r]\Delta q = \Delta t\,v`, the QP's six rows.
  Hard: the FrameTask itself in ``constraints``; an invertible 6 x 6 factor does not
  change an equality's solutions, so this is exact. Soft: ``position_cost`` √w_p,
  ``orientation_cost`` √w_o, and mink weighs the QP's residual r through
  :math:`J_l^{-1}(u) = I - \tfrac12\mathrm{ad}_u + O(|u|^2)`: exact while the task is met
  (r = 0), different by O(|u|) ≈ the pose error where a limit stops the task.
- soft-task Levenberg–Marquardt damping μ → ``lm_damping`` = μ/α² (mink's term is
  μ‖α e‖², qpik's μ‖e‖²; they agree up to the feed-forward share of mink's error, so only
  while the target moves). On ``hexapod-stroke-limits`` this share dominates the
  difference (per step ~4e-5 m/s, ~5e-8 m/s with the QP's own LM weight).
- loop closures (the hard :class:`~qpik.tasks.EqualityTask`) → ``mink.EqualityConstraintTask`` on the same equalities,
  ``gain`` α_c = K_cΔt, in ``constraints``. mink reads MuJoCo's constraint rows
  (``efc_pos`` = p1 − p2, ``efc_J`` = J(p1) − J(p2), which ``Configuration.update`` fills
  with ``mj_makeConstraint``): the QP's e_c and J_c, so its row
  :math:`J_c\Delta q = -\alpha_c e_c` is :math:`J_c\dot q = -K_c e_c`.
- σ, damping and any other soft qpik task (the platform-manipulability task's J is the
  site's angular Jacobian) → :class:`QpikTask`, residual √w(JΔq − Δt v).
- limits → ``ConfigurationLimit`` on a model copy whose ``jnt_range`` are the scenario's
  (tightened) ranges, with the QP's gain and margin (mink skips free joints, as the QP
  does); ``VelocityLimit`` with the scene's speed bounds; with the scenario's velocity
  damper near a bound, :class:`DampedConfigurationLimit`.
- ``damping`` = the QP's regulariser; the QP solver named, with the tolerances qpik's own
  back-end asks of it.

Numerics: mink's SE(3) log Jacobian (``lie.se3._getQ``) evaluates
:math:`(1 - \theta^2/2 - \cos\theta)/\theta^4` in closed form down to θ² = machine ε; at
the rotation steps of a 2 ms control loop (θ ~ 1e-4 rad) it cancels, and
:math:`J_{log}(\exp(-u))\,u` misses u by ~1e-16 |ρ|/θ² (6e-13 at θ = 1e-4): one mink step
equals the QP's to ~1e-10 m/s rather than 1e-15.

mink returns a velocity in the tangent space of the full MuJoCo configuration (its
``Configuration`` is the same model), which the rollout integrates with
``mj_integratePos`` as it does the QP's (the free joint's angular part in the body frame
for both, since both take MuJoCo's Jacobians).

Per step mink re-reads q (``Configuration.update``: kinematics and, with equalities, the
constraint rows), builds the QP with NumPy and hands it to ``qpsolvers`` — the cost this
comparison measures.
"""

from __future__ import annotations

import copy
import warnings

import mink
import mujoco
import numpy as np
from qpsolvers.warnings import SparseConversionWarning

from ...errors import SolverError
from ...scenario import Setup, check_solver
from ...solvers import make_backend
from ...tasks import Task
from .problem import POSITION_MARGIN, REGULARIZATION, PeerProblem, PeerUnsupported

# qpsolvers warns once that mink's dense matrices are converted for sparse solvers (OSQP):
# that conversion is part of mink's per-step cost, measured here, not news for the user.
# Its warning on an OSQP failure repeats what the SolverError below reports.
warnings.filterwarnings("ignore", category=SparseConversionWarning)
warnings.filterwarnings("ignore", message="OSQP exited with status", module="qpsolvers")


class QpikTask(mink.Task):
    r"""A soft qpik task (Jacobian J, target velocity v, weight w) as a mink task.

    mink minimises :math:`\tfrac12\|c \odot (J\Delta q + \alpha e)\|^2`; with α = 1,
    :math:`e = -\Delta t\,v` and :math:`c = \sqrt w` this is
    :math:`\tfrac12 w\|J\Delta q - \Delta t\,v\|^2 = \Delta t^2\,\tfrac12 w\|J\dot q - v\|^2`,
    the QP's term (σ: J = I, :math:`v = k_0\nabla\sigma`; platform manipulability: J the
    site's angular Jacobian, :math:`v = k_0\nabla_\theta m`). The qpik task computes J and
    v from the robot's q, which is the configuration mink holds.
    """

    def __init__(self, task: Task, dt: float):
        super().__init__(cost=np.sqrt(task.weight), gain=1.0)
        self.task = task
        self.dt = dt

    def compute_error(self, configuration: mink.Configuration) -> np.ndarray:
        self.task.update()
        return -self.dt * self.task.target_velocity

    def compute_jacobian(self, configuration: mink.Configuration) -> np.ndarray:
        # Filled by the update in compute_error, which mink's compute_qp_residual calls first.
        return self.task.jacobian


def _check_limited_joints(limit: mink.ConfigurationLimit, problem: PeerProblem) -> None:
    """mink limits every limited scalar joint of its model: they must be the scenario's."""
    if sorted(problem.position_limit.limits.dof_index) != sorted(limit.indices):
        raise PeerUnsupported("mink: the model's limited joints differ from the scenario's")


class DampedConfigurationLimit(mink.ConfigurationLimit):
    r"""mink's ConfigurationLimit, its bounds also obeying the scenario's velocity damper.

    mink has no damper. Near a bound the QP's own bound on the step
    (:meth:`PeerProblem.step_bounds`: :math:`\Delta q \le \Delta t\,\xi d/\rho` toward a
    bound closer than ρ) is tighter than mink's :math:`\text{gain}\cdot d`; the right-hand
    side h takes the smaller of the two. Tightening mink's rows rather than adding rows
    keeps G free of duplicate rows, which ProxQP at tight tolerances reports as a failure.
    """

    def __init__(self, model: mujoco.MjModel, problem: PeerProblem):
        super().__init__(model, gain=problem.limit_gain, min_distance_from_limits=POSITION_MARGIN)
        _check_limited_joints(self, problem)
        dofs = list(problem.position_limit.limits.dof_index)
        self.problem = problem
        self._order = np.array([dofs.index(i) for i in self.indices])

    def compute_qp_inequalities(self, configuration: mink.Configuration, dt: float) -> mink.Constraint:
        constraint = super().compute_qp_inequalities(configuration, dt)
        low, high = self.problem.step_bounds()
        n = len(self._order)
        np.minimum(constraint.h[:n], high[self._order], out=constraint.h[:n])
        np.minimum(constraint.h[n:], -low[self._order], out=constraint.h[n:])
        return constraint


class TaskRows(mink.Task):
    """Selected rows of another mink task: a masked task as a hard constraint."""

    def __init__(self, task: mink.Task, rows: np.ndarray):
        super().__init__(cost=np.ones(len(rows)), gain=task.gain)
        self.task = task
        self.rows = rows

    def compute_error(self, configuration: mink.Configuration) -> np.ndarray:
        return self.task.compute_error(configuration)[self.rows]

    def compute_jacobian(self, configuration: mink.Configuration) -> np.ndarray:
        return self.task.compute_jacobian(configuration)[self.rows]


def qpsolvers_settings(solver: str) -> dict:
    """The keyword arguments qpik's qpsolvers back-end passes for ``solver`` (its
    tolerances), so that mink's QP is solved to the accuracy qpik's is."""
    return dict(make_backend(solver, 1, 0, native=False)._settings)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a × b of two 3-vectors, written out (np.cross costs ~10x more on 3-vectors)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def rplus(pose: np.ndarray, u: np.ndarray, out: np.ndarray) -> np.ndarray:
    r"""``out`` = T exp(u) as mink's wxyz_xyz, u = [ρ; θ] a body twist (mink's order).

    Rotation :math:`q \otimes \exp(\theta)` (``mju_quatIntegrate`` multiplies on the right),
    translation :math:`p + R\,V(\theta)\rho` with
    :math:`V(\theta) = I + \frac{1-\cos\theta}{\theta^2}[\theta]_\times
    + \frac{\theta-\sin\theta}{\theta^3}[\theta]_\times^2`, series below 1e-3 rad.
    ``mink.SE3 @ mink.SE3.exp`` computes the same at ~2.5x the cost, which would be charged to mink.
    """
    rho, theta = u[:3], u[3:]
    angle2 = float(theta @ theta)
    if angle2 < 1e-6:
        a, b = 0.5 - angle2 / 24.0, 1.0 / 6.0 - angle2 / 120.0
    else:
        angle = np.sqrt(angle2)
        a, b = (1.0 - np.cos(angle)) / angle2, (angle - np.sin(angle)) / (angle2 * angle)
    cross = _cross(theta, rho)
    local = rho + a * cross + b * _cross(theta, cross)
    out[:4] = pose[:4]
    mujoco.mju_quatIntegrate(out[:4], theta, 1.0)
    mujoco.mju_rotVecQuat(out[4:], local, pose[:4])
    out[4:] += pose[4:]
    return out


def _block_cost(weight: np.ndarray, block: str) -> float:
    """mink's FrameTask cost of a block (position or orientation): √w, one w per block,
    since mink weighs the site-frame rows and only a uniform weight is frame-free."""
    if np.ptp(weight) > 0:
        raise PeerUnsupported(f"mink: the frame task's {block} weight must be the same on every axis, got {weight}")
    return float(np.sqrt(weight[0]))


class MinkController:
    """mink's differential IK as a qpik controller (``kind = "mink"``).

    Args:
        setup: the scenario; its robot's ``q`` is read every step.
        solver: a qpsolvers name, passed to ``mink.solve_ik``.
    """

    kind = "mink"

    def __init__(self, setup: Setup, solver: str = "daqp"):
        self.solver = check_solver(solver)
        self.problem = problem = PeerProblem.from_setup(setup, "mink")
        self.robot = setup.robot
        self.dt = setup.dt
        self._settings = qpsolvers_settings(solver)
        model = copy.deepcopy(setup.robot.model)
        for name, lo, hi in zip(problem.joint_names, problem.lower, problem.upper):
            model.jnt_range[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)] = (lo, hi)
        self.configuration = mink.Configuration(model, setup.robot.q)
        if problem.damper:
            self.limits = [DampedConfigurationLimit(model, problem)]
        else:
            self.limits = [mink.ConfigurationLimit(model, gain=problem.limit_gain,
                                                   min_distance_from_limits=POSITION_MARGIN)]
            _check_limited_joints(self.limits[0], problem)
        speeds = problem.velocity_limited_joints()
        if speeds:
            self.limits.append(mink.VelocityLimit(model, speeds))
        tracking = problem.tracking
        self._frame = (tracking.frame.name, tracking.frame.type)
        lm_damping = tracking.lm_damping / problem.step_gain**2
        if problem.frame:
            costs = (1.0, 1.0) if problem.hard else (_block_cost(tracking.weight[:3], "position"),
                                                     _block_cost(tracking.weight[3:], "orientation"))
            self.frame = mink.FrameTask(*self._frame, position_cost=costs[0], orientation_cost=costs[1],
                                        gain=problem.step_gain, lm_damping=lm_damping)
            hard_rows = self.frame
            self._target = mink.SE3(np.array([1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]))
        else:
            self._axes = 4 + tracking.rows  # translation entries of mink's wxyz_xyz pose
            weight = np.zeros(3)
            weight[tracking.rows] = tracking.weight
            self.frame = mink.FrameTask(*self._frame, position_cost=np.sqrt(weight), orientation_cost=0.0,
                                        gain=problem.step_gain, lm_damping=lm_damping)
            hard_rows = TaskRows(self.frame, tracking.rows)
        soft = [QpikTask(task, self.dt) for task in (*problem.joint_space, *problem.extra)]
        if problem.hard:
            self.tasks, self.constraints = soft, [hard_rows]
        else:
            self.tasks, self.constraints = [self.frame, *soft], []
        if problem.loops is not None:
            # cost is unused: mink's constraints are equalities J Δq = −α e, costs ignored.
            self.loops = mink.EqualityConstraintTask(model, cost=1.0, equalities=problem.loop_equalities(),
                                                     gain=problem.loop_gain)
            self.constraints.append(self.loops)
        self.qdot = np.zeros(setup.robot.nv)

    def _retarget(self) -> None:
        """The frame task's target for this step (see the module docstring)."""
        configuration = self.configuration
        pose = configuration.get_transform_frame_to_world(*self._frame)
        if self.problem.frame:
            rplus(pose.wxyz_xyz, self.problem.body_step(), self._target.wxyz_xyz)
            self.frame.set_target(self._target)
        else:
            pose.wxyz_xyz[self._axes] = self.problem.shifted_target()
            self.frame.set_target(pose)

    def compute_velocity(self) -> np.ndarray:
        """Sync mink's configuration, retarget the frame task, ``solve_ik``: q̇ = Δq/Δt."""
        self.configuration.update(self.robot.q)
        self._retarget()
        try:
            self.qdot = mink.solve_ik(self.configuration, self.tasks, self.dt, self.solver, damping=REGULARIZATION,
                                      limits=self.limits, constraints=self.constraints, **self._settings)
        except (mink.MinkError, ValueError) as exc:  # qpsolvers raises ValueError subclasses
            # NoSolutionFound covers an infeasible QP and a solver failure alike.
            raise SolverError(f"mink ({self.solver}) failed: {type(exc).__name__}: {exc}") from None
        if not np.all(np.isfinite(self.qdot)):
            raise SolverError(f"mink ({self.solver}) returned a non-finite velocity")
        return self.qdot
