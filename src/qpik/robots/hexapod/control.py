r"""Control of the hexapod on its full MuJoCo coordinates, and its classical comparator.

The QP controller works on all 24 dofs (6 sliders, 12 universal-joint hinges, the
platform's free joint): the platform task, the six ``connect`` loop closures as hard
equalities (an :class:`~qpik.tasks.EqualityTask` on MuJoCo's own constraint rows) :math:`J_c\dot q = -K_c e_c`, stroke and hinge limits as bounds. The
classical law works on the strokes only:

- 6-D task: :math:`\dot q_s = J_{inv}(p, R)\,[\dot p_d + K e_p;\ \omega_d + K e_o]`
  (the hexapod is square for a pose task, so the inverse Jacobian is the CLIK law);
- position only: the platform twist is the pseudoinverse solution of the position
  task, :math:`[I\ 0]^\dagger = [I; 0]`, plus the null-space term
  :math:`(I - [I;0][I\ 0])\,[0; k_0\nabla_\theta m]`, i.e. ω = k0 ∇θ m; then
  :math:`\dot q_s = J_{inv}\,[v; \omega]`.

The classical law moves the sliders; the platform and the passive joints follow, as on
the machine: its rollout closes the loops by forward kinematics after each step
(:class:`StrokeDrivenClosure`).

The hexapod's manipulability (see :meth:`qpik.robots.hexapod.kinematics.Hexapod.manipulability`): the
inverse condition number of the forward Jacobian with its angular rows scaled by the
platform radius (0.1 m). Its gradient with respect to the platform orientation is a
central difference over three small rotations.
"""

from __future__ import annotations

import mujoco
import numpy as np

from ...errors import ConvergenceError, DivergenceError
from .kinematics import N_LEGS, Hexapod
from .rotations import matrices_from_rotvecs
from .scene import assembly_qpos
from ...robot import Robot
from ...rollout.references import Reference, ReferenceRun
from ...numerics import rotation_error
from ...tasks import EqualityTask, FrameTask, PositionTask, Task
from ...trajectories import sample_many

CHARACTERISTIC_LENGTH = 0.1  # m, the platform radius: makes rotations commensurate
_GRADIENT_STEP = 1e-5  # rad
# exp(+h e_k), exp(−h e_k) for k = x, y, z: the central differences' rotations (6, 3, 3).
_SMALL_ROTATIONS = matrices_from_rotvecs(np.repeat(np.eye(3), 2, axis=0) * np.tile([1.0, -1.0], 3)[:, None]
                                         * _GRADIENT_STEP)


class HexapodModel:
    """The hexapod's analytic kinematics bound to its MuJoCo scene (index maps, pose I/O)."""

    def __init__(self, robot: Robot, hexapod: Hexapod | None = None):
        self.robot = robot
        self.hexapod = Hexapod() if hexapod is None else hexapod
        n = range(1, N_LEGS + 1)
        self.slider_qpos = np.array([robot.joint_qpos_index(f"slider{i}") for i in n])
        self.slider_dofs = np.array([robot.joint_dof_index(f"slider{i}") for i in n])
        self.hinge_qpos = np.array([[robot.joint_qpos_index(f"u{i}_a"), robot.joint_qpos_index(f"u{i}_b")] for i in n])
        self.platform_qpos = robot.joint_qpos_index("platform")
        # Where each entry of hexapod_scene.assembly_qpos goes in this robot's q.
        self.assembly_index = np.concatenate([np.column_stack([self.slider_qpos, self.hinge_qpos]).ravel(),
                                              self.platform_qpos + np.arange(7)])
        self.center_site = robot.site_id("platform_center")
        self.loop_names = tuple(f"loop{i}" for i in n)
        g = self.hexapod.geometry
        self._side = g.leg_side
        self._scale = np.repeat([1.0, 1.0 / CHARACTERISTIC_LENGTH], 3)
        self._common_axis = bool(np.all(g.slider_axes == g.slider_axes[0]))

    def strokes(self, robot: Robot | None = None) -> np.ndarray:
        return (robot or self.robot).q[self.slider_qpos]

    def platform_pose(self, robot: Robot | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Platform position and rotation from the site (valid after a kinematics update)."""
        robot = robot or self.robot
        return robot.site_position(self.center_site).copy(), robot.site_rotation(self.center_site).copy()

    def scaled_inverse_jacobian(self, position: np.ndarray, R: np.ndarray) -> np.ndarray:
        """Jinv diag(I, I/c) at a pose, or at a batch of rotations R (B, 3, 3) -> (B, 6, 6)
        with one position (3,) or one per rotation (B, 3).

        The hot-path twin of :meth:`Hexapod.inverse_jacobian` (tested against it): the
        strokes come from IK on each leg's side, q = s·d + side·√disc, since every slider
        runs along +x; NaN rows where a leg cannot reach.
        """
        g = self.hexapod.geometry
        r = np.matmul(g.platform_points, np.swapaxes(R, -1, -2))  # (..., 6, 3)
        d = np.expand_dims(position, -2) + r - g.slider_origins  # one position, or one per rotation
        sd = d @ g.slider_axes[0] if self._common_axis else np.einsum("ij,...ij->...i", g.slider_axes, d)
        disc = sd * sd - (np.einsum("...ij,...ij->...i", d, d) - g.leg_lengths**2)
        q = sd + self._side * np.sqrt(np.maximum(disc, 0.0))
        L = d - q[..., None] * g.slider_axes
        rows = np.empty(L.shape[:-1] + (6,))
        rows[..., :3] = L
        # r x L, written out: np.cross costs ~10x more on 6 x 3 arrays.
        rows[..., 3] = r[..., 1] * L[..., 2] - r[..., 2] * L[..., 1]
        rows[..., 4] = r[..., 2] * L[..., 0] - r[..., 0] * L[..., 2]
        rows[..., 5] = r[..., 0] * L[..., 1] - r[..., 1] * L[..., 0]
        along = np.einsum("...ij,ij->...i", L, g.slider_axes)
        rows *= self._scale / np.where(disc >= 0, along, np.nan)[..., None]
        return rows

    def manipulability(self, position: np.ndarray, R: np.ndarray) -> float | np.ndarray:
        """σmin/σmax of the scaled forward Jacobian (0 where IK fails); batched over R (and
        over positions (B, 3), if given one per rotation)."""
        scaled = self.scaled_inverse_jacobian(position, R)
        bad = ~np.all(np.isfinite(scaled), axis=(-2, -1))
        sigma = np.linalg.svd(np.where(bad[..., None, None], 1.0, scaled), compute_uv=False)
        ratio = np.where(bad, 0.0, sigma[..., -1] / sigma[..., 0])
        return float(ratio) if ratio.ndim == 0 else ratio

    def manipulability_gradient(self, position: np.ndarray, R: np.ndarray) -> np.ndarray:
        """∂m/∂θ (3,) for world-frame rotations R ← exp([θ]) R: central differences,
        the six perturbed poses evaluated as one batch."""
        values = self.manipulability(position, _SMALL_ROTATIONS @ R)
        return (values[0::2] - values[1::2]) / (2 * _GRADIENT_STEP)

    def manipulability_of(self, robot: Robot) -> float:
        """The logged measure, on any robot of this model (e.g. the physics plant)."""
        return self.manipulability(*self.platform_pose(robot))


class PlatformManipulability:
    """The hexapod's logged manipulability measure (:meth:`HexapodModel.manipulability`
    at the platform pose): callable on a robot, and, in a rollout, the platform pose
    copied per step and the measure evaluated for every step in one batch afterwards."""

    def __init__(self, model: HexapodModel):
        self.model = model

    def __call__(self, robot: Robot) -> float:
        return self.model.manipulability_of(robot)

    def start(self, plant: Robot, steps: int) -> _PlatformPoses:
        return _PlatformPoses(self.model, plant, steps)


class _PlatformPoses:
    """The platform pose of each step of a rollout; the measure of all of them at the end."""

    def __init__(self, model: HexapodModel, plant: Robot, steps: int):
        self.model = model
        self._position = plant.data.site_xpos[model.center_site]  # views into the plant's data
        self._rotation = plant.data.site_xmat[model.center_site]
        self.positions = np.empty((steps, 3))
        self.rotations = np.empty((steps, 9))

    def record(self, k: int) -> None:
        self.positions[k] = self._position
        self.rotations[k] = self._rotation

    def values(self, count: int) -> np.ndarray:
        if count == 0:
            return np.empty(0)
        return np.asarray(self.model.manipulability(self.positions[:count], self.rotations[:count].reshape(-1, 3, 3)))


class PlatformManipulabilityTask(Task):
    """Turn the platform toward higher manipulability: ½ w ‖ω − k0 ∇θ m‖².

    J is the platform's angular Jacobian (3 x nv); with a hard position task and the
    loop closures, the platform's three rotational freedoms are exactly this task's.
    """

    name = "platform manipulability task"

    def __init__(self, model: HexapodModel, gain: float = 1.0, weight=1.0):
        super().__init__(model.robot, 3, weight, hard=False)
        self.model = model
        self.gain = float(gain)

    def measure_rows(self) -> None:
        self.robot.site_jacobian(self.model.center_site, None, self.jacobians[0])

    def track(self) -> None:
        position, R = self.model.platform_pose()
        self.target_velocities[0] = self.gain * self.model.manipulability_gradient(position, R)


class HexapodClassicalController:
    """CLIK on the strokes with the analytic inverse Jacobian (and null-space gradient).

    Reads the platform pose and the task targets from the same task object as the QP:
    a :class:`FrameTask` (6-D law) or a :class:`PositionTask` on ``platform_center``
    (position-only law with ω = k0 ∇θ m). Returns q̇ with the stroke rates filled and
    zeros elsewhere: ``actuated_only`` tells the rollout to close the loops.
    """

    kind = "pinv"
    solver = "none"
    actuated_only = True

    def __init__(self, model: HexapodModel, task: FrameTask | PositionTask, k0: float = 0.0):
        self.model = model
        self.robot = model.robot
        self.task = task
        self.k0 = float(k0)
        self.qdot = np.zeros(model.robot.nv)
        self._twist = np.zeros(6)
        self._unscale = 1.0 / model._scale

    def compute_velocity(self) -> np.ndarray:
        position, R = self.model.platform_pose()
        task = self.task
        task.update_target_velocity()
        if isinstance(task, FrameTask):
            self._twist[:] = task.target_velocity
        else:
            self._twist[:3] = task.target_velocity
            self._twist[3:] = self.k0 * self.model.manipulability_gradient(position, R) if self.k0 else 0.0
        jinv = self.model.scaled_inverse_jacobian(position, R) * self._unscale
        strokes = jinv @ self._twist
        if not np.all(np.isfinite(strokes)):
            raise DivergenceError("inverse Jacobian undefined at this pose (outside the workspace)")
        self.qdot[self.model.slider_dofs] = strokes
        return self.qdot


class StrokeDrivenClosure:
    """The classical law's mechanism: after the strokes moved, the platform and hinges follow.

    Forward kinematics from the current pose (Newton with a short continuation, so it
    follows the assembly branch the mechanism is on) places the platform, then the
    universal joints. If the new
    strokes admit no assembly (a slider held at its end stop while the others move on),
    the mechanism jams: it stays where it was, as position-controlled drives fighting a
    closed chain would.
    """

    def __init__(self, model: HexapodModel):
        self.model = model
        self.jams = 0
        self._last = model.robot.q.copy()

    def __call__(self, robot: Robot) -> None:
        model = self.model
        q = robot.q[model.slider_qpos]
        position, R = model.platform_pose(robot)
        try:
            p, Rn = model.hexapod.forward_kinematics(q, initial=(position, R), steps=4)
        except (ConvergenceError, ValueError):
            self.jams += 1
            robot.q[:] = self._last
            robot.update_kinematics()
            return
        robot.q[model.assembly_index] = assembly_qpos(model.hexapod, q, p, Rn)
        robot.update_kinematics()
        self._last[:] = robot.q


class PlatformReference(Reference):
    """Feeds a pose trajectory to the platform task; measures pose error and loops."""

    def __init__(self, model: HexapodModel, task: FrameTask | PositionTask, trajectory, loops: EqualityTask):
        self.model = model
        self.task = task
        self.trajectory = trajectory
        self.loops = loops
        self._desired_rotation = np.eye(3)

    def apply(self, t: float) -> None:
        p, v, R, omega = self.trajectory.sample_pose(t)
        self._desired_rotation = R
        if isinstance(self.task, FrameTask):
            self.task.set_target(p, R, v, omega)
        else:
            self.task.set_target(p, v)

    def desired(self) -> np.ndarray:
        return self.task.target_position if isinstance(self.task, FrameTask) else self.task.target

    def measure(self, robot: Robot) -> dict:
        position, R = self.model.platform_pose(robot)
        sample = {"x": position}
        if isinstance(self.task, FrameTask):
            sample["orientation_error"] = float(np.linalg.norm(rotation_error(self._desired_rotation[None], R[None])[0]))
        sample["constraint_violation"] = self.loop_residual(robot)
        return sample

    def loop_residual(self, robot: Robot) -> float:
        """The largest loop-closure gap (m): between the two anchor sites of each site
        ``connect`` (what the rollout's run evaluates after the run, the same bits), else
        MuJoCo's own constraint residual."""
        model = robot.model
        loops = self.loops.equalities
        if all(model.eq_objtype[eq] == mujoco.mjtObj.mjOBJ_SITE for eq in loops):
            sites = robot.data.site_xpos
            gaps = sites[[model.eq_obj1id[eq] for eq in loops]] - sites[[model.eq_obj2id[eq] for eq in loops]]
            return float(np.max(np.linalg.norm(gaps, axis=1)))
        return self.loops.max_residual(robot)

    def start(self, plant: Robot, times: np.ndarray) -> ReferenceRun:
        return _PlatformRun(self, plant, times)


class _PlatformRun(ReferenceRun):
    """The pose trajectory sampled once; per step a target set and the platform pose and
    loop anchors copied; orientation errors and loop residuals evaluated after the run
    (the same bits as :meth:`PlatformReference.measure`, tested)."""

    def __init__(self, reference: PlatformReference, plant: Robot, times: np.ndarray):
        super().__init__(reference, plant, times)
        self.task = reference.task
        self.frame = isinstance(self.task, FrameTask)
        trajectory = reference.trajectory
        if hasattr(trajectory, "sample_pose_many"):
            self.positions, self.velocities, self.rotations, self.angular = trajectory.sample_pose_many(times)
        else:
            self.positions, self.velocities = sample_many(trajectory, times)
            poses = [trajectory.sample_pose(t) for t in times]
            self.rotations = np.array([pose[2] for pose in poses], dtype=float).reshape(-1, 3, 3)
            self.angular = np.array([pose[3] for pose in poses], dtype=float).reshape(-1, 3)
        data, model = plant.data, plant.model
        center = reference.model.center_site
        self._position, self._rotation = data.site_xpos[center], data.site_xmat[center]  # views
        self._sites = data.site_xpos
        steps = len(times)
        self._x = np.empty((steps, 3))
        self._measured_rotations = np.empty((steps, 9))
        # Site-based loop closures: their anchors are sites, copied per step; otherwise
        # (body anchors) the residual is computed per step.
        loops = reference.loops.equalities
        self._site_loops = all(model.eq_objtype[eq] == mujoco.mjtObj.mjOBJ_SITE for eq in loops)
        self._anchor1 = np.array([model.eq_obj1id[eq] for eq in loops], dtype=int)
        self._anchor2 = np.array([model.eq_obj2id[eq] for eq in loops], dtype=int)
        self._site_positions = np.empty((steps,) + self._sites.shape) if self._site_loops else None
        self._residuals = np.empty(steps)

    def apply(self, k: int) -> None:
        if self.frame:
            self.task.set_target(self.positions[k], self.rotations[k], self.velocities[k], self.angular[k])
        else:
            self.task.set_target(self.positions[k], self.velocities[k])

    def record(self, k: int) -> None:
        self._x[k] = self._position
        if self.frame:
            self._measured_rotations[k] = self._rotation
        if self._site_loops:
            self._site_positions[k] = self._sites
        else:
            self._residuals[k] = self.reference.loops.max_residual(self.plant)

    def results(self, count: int) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        extras = {}
        if self.frame:
            extras["orientation_error"] = _rotation_error_norms(self.rotations[:count],
                                                                self._measured_rotations[:count].reshape(-1, 3, 3))
        if self._site_loops:
            sites = self._site_positions[:count]
            gaps = sites[:, self._anchor1] - sites[:, self._anchor2]
            extras["constraint_violation"] = np.max(np.linalg.norm(gaps, axis=2), axis=1) if count else np.empty(0)
        else:
            extras["constraint_violation"] = self._residuals[:count]
        return self._x[:count], self.positions[:count], extras


def _rotation_error_norms(desired: np.ndarray, current: np.ndarray) -> np.ndarray:
    """‖rotation_error(desired[i], current[i])‖ for each i (n, 3, 3): row by row, as a step
    measures it (one world: MuJoCo's routines), then the norms of all rows at once."""
    world = np.array([rotation_error(desired[i:i + 1], current[i:i + 1])[0] for i in range(len(desired))])
    world = world.reshape(-1, 3, 1)
    # The norm as np.linalg.norm takes it, sqrt(x·x), with x·x as a batched dot product.
    return np.sqrt(np.matmul(np.swapaxes(world, 1, 2), world)[:, 0, 0])
