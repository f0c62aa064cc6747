r"""mink on qpik's scenarios: its FrameTask, limits and ``solve_ik``, one call per step.

The mapping (see :mod:`qpik.peers.problem` for why each one is exact):

- position task → ``mink.FrameTask`` on the same site, ``gain`` α = KΔt (1.0 for
  K = 500, Δt = 2 ms), target translation :math:`p_d + \dot p_d/K` on the task's axes and
  the site's current rotation (so the SE(3) error has no rotation part to couple into the
  position rows), ``orientation_cost = 0``. Soft: ``position_cost`` = √w on the task's axes,
  0 elsewhere, and ``lm_damping`` = μ/α² (mink's term is μ‖α e‖², qpik's μ‖e‖²; they
  agree up to the feed-forward share of mink's error, so only while the target moves).
  Hard: the task's rows of the same FrameTask as an equality in
  ``solve_ik(constraints=...)`` (mink's constraints ignore costs, hence the row subset).
  mink's FrameTask works in the site frame; on the planar arm the site's z axis stays the
  world's, so its x, y rows span the world x, y rows.
- σ (and any joint-space task) → :class:`JointSpaceTask`, residual √w(Δq − Δt v).
- limits → ``ConfigurationLimit`` on a model copy whose ``jnt_range`` are the scenario's
  (tightened) ranges, with the QP's gain and margin; ``VelocityLimit`` with the scene's
  speed bounds; with the scenario's velocity damper near a bound,
  :class:`DampedConfigurationLimit`.
- ``damping`` = the QP's regulariser; the QP solver named, with the tolerances qpik's own
  back-end asks of it.

Per step mink re-reads q (``Configuration.update``), builds the QP with NumPy and hands
it to ``qpsolvers`` — the cost this comparison measures.
"""

from __future__ import annotations

import copy
import warnings

import mink
import mujoco
import numpy as np
from qpsolvers.warnings import SparseConversionWarning

from ..errors import SolverError
from ..scenarios import Setup, check_solver
from ..solvers import make_backend
from ..tasks import Task
from .problem import POSITION_MARGIN, REGULARIZATION, PeerProblem, PeerUnsupported

# qpsolvers warns once that mink's dense matrices are converted for sparse solvers (OSQP):
# that conversion is part of mink's per-step cost, measured here, not news for the user.
# Its warning on an OSQP failure repeats what the SolverError below reports.
warnings.filterwarnings("ignore", category=SparseConversionWarning)
warnings.filterwarnings("ignore", message="OSQP exited with status", module="qpsolvers")


class JointSpaceTask(mink.Task):
    r"""A qpik joint-space task (J = I, target velocity v, weight w) as a mink task.

    mink minimises :math:`\tfrac12\|c \odot (J\Delta q + \alpha e)\|^2`; with J = I, α = 1,
    :math:`e = -\Delta t\,v` and :math:`c = \sqrt w` this is
    :math:`\tfrac12 w\|\Delta q - \Delta t\,v\|^2 = \Delta t^2\,\tfrac12 w\|\dot q - v\|^2`,
    the QP's term (for σ: :math:`v = k_0\nabla\sigma`). The qpik task computes v from the
    robot's q, which is the configuration mink holds.
    """

    def __init__(self, task: Task, dt: float):
        super().__init__(cost=np.sqrt(task.weight), gain=1.0)
        self.task = task
        self.dt = dt
        self._identity = np.eye(task.dim)

    def compute_error(self, configuration: mink.Configuration) -> np.ndarray:
        self.task.update()
        return -self.dt * self.task.target_velocity

    def compute_jacobian(self, configuration: mink.Configuration) -> np.ndarray:
        return self._identity


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
        dofs = list(problem.position_limit.limits.dof_index)
        if sorted(dofs) != sorted(self.indices):
            raise PeerUnsupported("mink: the model's limited joints differ from the scenario's")
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
        speeds = problem.velocity_limited_joints()
        if speeds:
            self.limits.append(mink.VelocityLimit(model, speeds))
        position = problem.position
        self._site = position.site
        self._axes = 4 + position.rows  # translation entries of mink's wxyz_xyz pose
        weight = np.zeros(3)
        weight[position.rows] = position.weight
        self.frame = mink.FrameTask(position.site, "site", position_cost=np.sqrt(weight), orientation_cost=0.0,
                                    gain=problem.step_gain, lm_damping=position.lm_damping / problem.step_gain**2)
        joint_tasks = [JointSpaceTask(task, self.dt) for task in problem.joint_space]
        if problem.hard:
            self.tasks, self.constraints = joint_tasks, [TaskRows(self.frame, position.rows)]
        else:
            self.tasks, self.constraints = [self.frame, *joint_tasks], []
        self.qdot = np.zeros(setup.robot.nv)

    def compute_velocity(self) -> np.ndarray:
        """Sync mink's configuration, retarget the frame task, ``solve_ik``: q̇ = Δq/Δt."""
        configuration = self.configuration
        configuration.update(self.robot.q)
        target = configuration.get_transform_frame_to_world(self._site, "site")
        target.wxyz_xyz[self._axes] = self.problem.shifted_target()
        self.frame.set_target(target)
        try:
            self.qdot = mink.solve_ik(configuration, self.tasks, self.dt, self.solver, damping=REGULARIZATION,
                                      limits=self.limits, constraints=self.constraints, **self._settings)
        except (mink.MinkError, ValueError) as exc:  # qpsolvers raises ValueError subclasses
            # NoSolutionFound covers an infeasible QP and a solver failure alike.
            raise SolverError(f"mink ({self.solver}) failed: {type(exc).__name__}: {exc}") from None
        if not np.all(np.isfinite(self.qdot)):
            raise SolverError(f"mink ({self.solver}) returned a non-finite velocity")
        return self.qdot
