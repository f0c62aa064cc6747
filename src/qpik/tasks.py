r"""Tasks: linear relations :math:`J \dot q \approx v` shared by every controller.

A task exposes, after :meth:`Task.update`, a Jacobian ``jacobian`` (dim x nv) and a
desired task velocity ``target_velocity`` (dim,). The QP controller either enforces
it (``hard=True``: :math:`J\dot q = v`) or adds the cost
:math:`\tfrac12 w \|J\dot q - v\|^2` (``hard=False``); the pseudoinverse controller
uses the same two arrays. Tracking tasks use the closed-loop inverse kinematics
velocity :math:`v = \dot x_d + K (x_d - x)`.

All arrays are preallocated: ``update`` writes in place and allocates nothing big.
"""

from __future__ import annotations

from typing import Protocol, Sequence

import mujoco
import numpy as np

from .errors import InvalidInput, ModelError, UnknownName
from .robot import Robot

_AXES = "xyz"


def _axis_rows(axes: str) -> np.ndarray:
    if not axes or any(a not in _AXES for a in axes) or len(set(axes)) != len(axes):
        raise InvalidInput(f"axes must be a non-empty subset of 'xyz', got {axes!r}")
    return np.array(sorted(_AXES.index(a) for a in axes), dtype=int)


def _finite_vector(value, size: int, what: str) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if arr.shape != (size,):
        raise InvalidInput(f"{what} must have shape ({size},), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InvalidInput(f"{what} contains NaN or inf: {arr}")
    return arr


def _positive(value, size: int, what: str, allow_zero: bool = False) -> np.ndarray:
    """A scalar (broadcast) or a (size,) vector of positive (or >= 0) finite values."""
    if np.ndim(value) == 0:
        arr = np.full(size, float(value))
    else:
        arr = _finite_vector(value, size, what)
    ok = arr >= 0 if allow_zero else arr > 0
    if not np.all(np.isfinite(arr)) or not np.all(ok):
        raise InvalidInput(f"{what} must be {'non-negative' if allow_zero else 'positive'} and finite, got {value}")
    return arr


class Task:
    """Base class: ``dim`` rows of :math:`J\\dot q \\approx v` with weight and priority.

    Args:
        robot: the robot whose kinematics the task reads.
        dim: number of task rows.
        weight: cost weight of a soft task (scalar or one per row).
        hard: enforce the task as an equality constraint in the QP.
    """

    name = "task"
    lm_damping = 0.0

    def __init__(self, robot: Robot, dim: int, weight=1.0, hard: bool = False):
        self.robot = robot
        self.dim = dim
        self.hard = bool(hard)
        self.weight = _positive(weight, dim, f"{self.name} weight", allow_zero=True)
        self.jacobian = np.zeros((dim, robot.nv))
        self.target_velocity = np.zeros(dim)

    def update(self) -> None:
        """Refresh ``jacobian`` and ``target_velocity`` from the robot's kinematics."""
        raise NotImplementedError

    def __repr__(self) -> str:
        return f"{type(self).__name__}(dim={self.dim}, hard={self.hard})"


class PositionTask(Task):
    """Track a site's position on selected world axes (the arm's task uses ``"xy"``).

    :math:`v = \\dot p_d + K (p_d - p)` on the masked rows. Targets are given in the
    masked coordinates (length ``len(axes)``).

    ``lm_damping`` μ adds μ w ‖e‖² ‖q̇‖²/2 to the cost of a soft task (adaptive
    Levenberg–Marquardt, as mink's ``lm_damping``): negligible while tracking, it
    calms the step when the target is out of reach and the error stays large.
    """

    name = "position task"

    def __init__(self, robot: Robot, site: str, axes: str = "xyz", gain=1.0, weight=1.0, hard: bool = False,
                 lm_damping: float = 0.0):
        self.rows = _axis_rows(axes)
        super().__init__(robot, len(self.rows), weight, hard)
        self.lm_damping = _positive(lm_damping, 1, "lm_damping", allow_zero=True)[0]
        self.site = site
        self.site_id = robot.site_id(site)
        self.gain = _positive(gain, self.dim, "position gain", allow_zero=True)
        self._model, self._data = robot.model, robot.data
        self._jacp = np.zeros((3, robot.nv))
        site_position = robot.data.site_xpos[self.site_id]
        # With contiguous axes ("xy", "xyz") the Jacobian and position are views that
        # MuJoCo's own arrays fill: no copies in the loop.
        self._views = bool(self.rows[-1] - self.rows[0] + 1 == self.dim)
        if self._views:
            rows = slice(int(self.rows[0]), int(self.rows[-1]) + 1)
            self.jacobian = self._jacp[rows]
            self.position = site_position[rows]
        else:
            self.position = site_position[self.rows]
        self.error = np.zeros(self.dim)
        self.target = site_position[self.rows].copy()
        self.target_rate = np.zeros(self.dim)

    def set_target(self, position, velocity=None) -> None:
        """Desired position (and feed-forward velocity) on the masked axes."""
        self.target[:] = _finite_vector(position, self.dim, "target position")
        self.target_rate[:] = 0.0 if velocity is None else _finite_vector(velocity, self.dim, "target velocity")

    def update(self) -> None:
        mujoco.mj_jacSite(self._model, self._data, self._jacp, None, self.site_id)
        if not self._views:
            self.jacobian[:] = self._jacp[self.rows]
        self.update_target_velocity()

    def update_target_velocity(self) -> None:
        """Error and v only (what a law without the Jacobian needs)."""
        if not self._views:
            self.position[:] = self._data.site_xpos[self.site_id][self.rows]
        np.subtract(self.target, self.position, out=self.error)
        np.multiply(self.gain, self.error, out=self.target_velocity)
        self.target_velocity += self.target_rate


def rotation_error(desired: np.ndarray, current: np.ndarray) -> np.ndarray:
    """World-frame rotation vector e with exp([e]) R_current = R_desired."""
    qd, qc, local = np.empty(4), np.empty(4), np.empty(3)
    mujoco.mju_mat2Quat(qd, np.ascontiguousarray(desired).ravel())
    mujoco.mju_mat2Quat(qc, np.ascontiguousarray(current).ravel())
    mujoco.mju_subQuat(local, qd, qc)  # qc * exp(local) = qd, local in the current frame
    return current @ local


class FrameTask(Task):
    """Track a site's pose: 3 position rows then 3 orientation rows (world frame).

    :math:`v = [\\dot p_d + K_p e_p;\\ \\omega_d + K_o e_o]`, with :math:`e_o` the
    rotation vector of :math:`R_d R^T`.
    """

    name = "frame task"

    def __init__(self, robot: Robot, site: str, position_gain=1.0, orientation_gain=1.0, weight=1.0, hard: bool = False,
                 lm_damping: float = 0.0):
        super().__init__(robot, 6, weight, hard)
        self.lm_damping = _positive(lm_damping, 1, "lm_damping", allow_zero=True)[0]
        self.site = site
        self.site_id = robot.site_id(site)
        self.position_gain = _positive(position_gain, 3, "position gain", allow_zero=True)
        self.orientation_gain = _positive(orientation_gain, 3, "orientation gain", allow_zero=True)
        self.target_position = robot.site_position(self.site_id).copy()
        self.target_rotation = robot.site_rotation(self.site_id).copy()
        self.target_linear_velocity = np.zeros(3)
        self.target_angular_velocity = np.zeros(3)
        self.position_error = np.zeros(3)
        self.orientation_error = np.zeros(3)

    def set_target(self, position, rotation, linear_velocity=None, angular_velocity=None) -> None:
        """Desired pose (world frame) and feed-forward twist."""
        self.target_position[:] = _finite_vector(position, 3, "target position")
        rot = np.asarray(rotation, dtype=float)
        if rot.shape != (3, 3) or not np.all(np.isfinite(rot)):
            raise InvalidInput(f"target rotation must be a finite 3x3 matrix, got shape {rot.shape}")
        if not np.allclose(rot @ rot.T, np.eye(3), atol=1e-6) or np.linalg.det(rot) < 0:
            raise InvalidInput("target rotation is not a rotation matrix")
        self.target_rotation[:] = rot
        self.target_linear_velocity[:] = 0.0 if linear_velocity is None else _finite_vector(linear_velocity, 3, "target linear velocity")
        self.target_angular_velocity[:] = 0.0 if angular_velocity is None else _finite_vector(angular_velocity, 3, "target angular velocity")

    def update(self) -> None:
        self.robot.site_jacobian(self.site_id, self.jacobian[:3], self.jacobian[3:])
        self.update_target_velocity()

    def update_target_velocity(self) -> None:
        """Errors and v only (what a law without the Jacobian needs)."""
        np.subtract(self.target_position, self.robot.site_position(self.site_id), out=self.position_error)
        self.orientation_error[:] = rotation_error(self.target_rotation, self.robot.site_rotation(self.site_id))
        self.target_velocity[:3] = self.target_linear_velocity + self.position_gain * self.position_error
        self.target_velocity[3:] = self.target_angular_velocity + self.orientation_gain * self.orientation_error

    @property
    def error(self) -> np.ndarray:
        return np.concatenate([self.position_error, self.orientation_error])


class ManipulabilityMeasure(Protocol):
    """A scalar measure m(q) of dexterity and its gradient over the dofs."""

    label: str

    def value(self, robot: Robot | None = None) -> float:
        """m(q) of the bound robot, or of another robot on the same model."""
        ...

    def gradient(self, out: np.ndarray) -> None: ...


class SigmaProxy:
    """The source's proxy σ(q) = ½ Σ_j sin² q_j over chosen joints (maximum at ±π/2).

    On the arm, with joints θ2 and θ3, σ = ½(sin²θ2 + sin²θ3);
    ∂σ/∂q_j = sin q_j cos q_j.
    """

    label = "sigma"

    def __init__(self, robot: Robot, joints: Sequence[str] = ("theta2", "theta3")):
        self.robot = robot
        self.qpos_index = np.array([robot.joint_qpos_index(j) for j in joints], dtype=int)
        self.dof_index = np.array([robot.joint_dof_index(j) for j in joints], dtype=int)

    def value(self, robot: Robot | None = None) -> float:
        s = np.sin((robot or self.robot).q[self.qpos_index])
        return 0.5 * float(s @ s)

    def gradient(self, out: np.ndarray) -> None:
        angles = self.robot.q[self.qpos_index]
        out[:] = 0.0
        out[self.dof_index] = 0.5 * np.sin(2.0 * angles)


class Yoshikawa:
    """Yoshikawa's measure w = √det(J Jᵀ) of a site's position Jacobian on masked rows.

    Masking matters on planar robots: the z row of the arm's Jacobian is zero, so
    det over all three rows would be 0. The gradient is a central difference over
    each dof, on a scratch MjData so the robot's own kinematics stay untouched
    (2 nv extra kinematics evaluations, documented cost).
    """

    label = "yoshikawa"

    def __init__(self, robot: Robot, site: str, axes: str = "xyz", step: float = 1e-6):
        self.robot = robot
        self.site_id = robot.site_id(site)
        self.rows = _axis_rows(axes)
        self.step = step
        self._scratch = mujoco.MjData(robot.model)
        self._jacp = np.zeros((3, robot.nv))
        self._dq = np.zeros(robot.nv)

    def _measure(self, data: mujoco.MjData) -> float:
        mujoco.mj_jacSite(self.robot.model, data, self._jacp, None, self.site_id)
        jac = self._jacp[self.rows]
        return float(np.sqrt(max(np.linalg.det(jac @ jac.T), 0.0)))

    def value(self, robot: Robot | None = None) -> float:
        return self._measure((robot or self.robot).data)

    def gradient(self, out: np.ndarray) -> None:
        model, scratch = self.robot.model, self._scratch
        for k in range(self.robot.nv):
            values = []
            for sign in (1.0, -1.0):
                scratch.qpos[:] = self.robot.q
                self._dq[:] = 0.0
                self._dq[k] = sign * self.step
                mujoco.mj_integratePos(model, scratch.qpos, self._dq, 1.0)
                mujoco.mj_kinematics(model, scratch)
                mujoco.mj_comPos(model, scratch)
                values.append(self._measure(scratch))
            out[k] = (values[0] - values[1]) / (2.0 * self.step)


class ManipulabilityTask(Task):
    """Posture task toward the manipulability gradient: cost ½ w ‖q̇ − k0 ∇m(q)‖².

    Written as a quadratic in q̇ with J = I (not as a bare linear term -w k0 ∇mᵀq̇,
    which with a tiny regulariser drives the null-space velocity to its bounds).
    With a hard primary task this is exactly the null-space law
    q̇ = J†v + (I − J†J) k0 ∇m.
    """

    name = "manipulability task"

    def __init__(self, robot: Robot, measure: ManipulabilityMeasure, gain: float = 5.0, weight=1.0):
        super().__init__(robot, robot.nv, weight, hard=False)
        if not np.isfinite(gain) or gain < 0:
            raise InvalidInput(f"manipulability gain must be finite and >= 0, got {gain}")
        self.measure = measure
        self.gain = float(gain)
        self.jacobian[:] = np.eye(robot.nv)
        self._grad = np.zeros(robot.nv)

    def update(self) -> None:
        self.measure.gradient(self._grad)
        np.multiply(self.gain, self._grad, out=self.target_velocity)


class PostureTask(Task):
    """Joint-space task toward a reference configuration: v = K (q_ref ⊖ q)."""

    name = "posture task"

    def __init__(self, robot: Robot, target=None, gain: float = 1.0, weight=1.0):
        super().__init__(robot, robot.nv, weight, hard=False)
        self.gain = float(gain)
        self.jacobian[:] = np.eye(robot.nv)
        self.target = robot.q.copy() if target is None else _finite_vector(target, robot.nq, "posture target")

    def update(self) -> None:
        mujoco.mj_differentiatePos(self.robot.model, self.target_velocity, 1.0, self.robot.q, self.target)
        self.target_velocity *= self.gain


class DampingTask(Task):
    """Regularisation ½ w ‖q̇‖²: with a hard primary task it yields the minimum-norm J†v."""

    name = "damping task"

    def __init__(self, robot: Robot, weight=1e-3):
        super().__init__(robot, robot.nv, weight, hard=False)
        self.jacobian[:] = np.eye(robot.nv)

    def update(self) -> None:
        pass


class LoopClosureTask(Task):
    """Closed kinematic chains: MuJoCo ``connect`` equalities as hard rows J_c q̇ = −K_c e_c.

    The residual e_c = p1 − p2 (the two anchor points in world) and its Jacobian
    J_c = J(p1) − J(p2) are computed from the kinematics update alone (``mj_jacSite`` /
    ``mj_jac``), without running MuJoCo's constraint pipeline.
    """

    name = "loop closure"

    def __init__(self, robot: Robot, equalities: Sequence[str] | None = None, gain: float = 1.0):
        model = robot.model
        if equalities is None:
            ids = list(range(model.neq))
        else:
            ids = []
            for name in equalities:
                eq = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_EQUALITY, name)
                if eq < 0:
                    raise UnknownName(f"unknown equality constraint {name!r}")
                ids.append(eq)
        if not ids:
            raise ModelError("the model has no equality constraints to close")
        for eq in ids:
            if model.eq_type[eq] != mujoco.mjtEq.mjEQ_CONNECT:
                raise ModelError(f"equality {eq} is not a 'connect' constraint")
        n = len(ids)
        super().__init__(robot, 3 * n, weight=1.0, hard=True)
        self.gain = float(gain)
        self.equalities = tuple(ids)  # model equality ids, in row order
        self._sites = all(model.eq_objtype[eq] == mujoco.mjtObj.mjOBJ_SITE for eq in ids)
        self._obj1 = np.array([model.eq_obj1id[eq] for eq in ids], dtype=int)
        self._obj2 = np.array([model.eq_obj2id[eq] for eq in ids], dtype=int)
        if not self._sites and any(model.eq_objtype[eq] == mujoco.mjtObj.mjOBJ_SITE for eq in ids):
            raise ModelError("mixing site- and body-based connect constraints is not supported")
        # Body-based connects: the anchors in each body's frame (MuJoCo's eq_data layout).
        self._anchor1 = np.array([model.eq_data[eq][0:3] for eq in ids])
        self._anchor2 = np.array([model.eq_data[eq][3:6] for eq in ids])
        self.error = np.zeros(self.dim)
        self._jac1 = np.zeros((n, 3, robot.nv))
        self._jac2 = np.zeros((n, 3, robot.nv))
        self._jac_rows = self.jacobian.reshape(n, 3, robot.nv)
        self._error_rows = self.error.reshape(n, 3)

    def _points(self, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray]:
        if self._sites:
            return data.site_xpos[self._obj1], data.site_xpos[self._obj2]
        p1 = data.xpos[self._obj1] + np.einsum("kij,kj->ki", data.xmat[self._obj1].reshape(-1, 3, 3), self._anchor1)
        p2 = data.xpos[self._obj2] + np.einsum("kij,kj->ki", data.xmat[self._obj2].reshape(-1, 3, 3), self._anchor2)
        return p1, p2

    def update(self) -> None:
        model, data = self.robot.model, self.robot.data
        p1, p2 = self._points(data)
        np.subtract(p1, p2, out=self._error_rows)
        if self._sites:
            for k in range(len(self._obj1)):
                mujoco.mj_jacSite(model, data, self._jac1[k], None, self._obj1[k])
                mujoco.mj_jacSite(model, data, self._jac2[k], None, self._obj2[k])
        else:
            for k in range(len(self._obj1)):
                mujoco.mj_jac(model, data, self._jac1[k], None, p1[k], self._obj1[k])
                mujoco.mj_jac(model, data, self._jac2[k], None, p2[k], self._obj2[k])
        np.subtract(self._jac1, self._jac2, out=self._jac_rows)
        np.multiply(-self.gain, self.error, out=self.target_velocity)

    def max_residual(self, robot: Robot | None = None) -> float:
        """Largest loop-closure gap (m) on the bound robot, or another of the same model."""
        p1, p2 = self._points((robot or self.robot).data)
        return float(np.max(np.linalg.norm(p1 - p2, axis=1)))
