r"""Manipulability measures and the task that climbs their gradient in the null space."""

from __future__ import annotations

import math
from typing import Protocol, Sequence

import mujoco
import numpy as np

from ...errors import DivergenceError, InvalidInput
from ..numerics import all_finite
from .inputs import as_index, positive_scalar
from .task import JointSpaceTask

_ROTATING = (int(mujoco.mjtJoint.mjJNT_BALL), int(mujoco.mjtJoint.mjJNT_FREE))


class ManipulabilityMeasure(Protocol):
    """A scalar measure m(q) of dexterity and its gradient over the dofs."""

    label: str

    def value(self, robot: Robot | None = None) -> float:
        """m(q) of the bound robot, or of another robot on the same model."""
        ...

    def gradient(self, out: np.ndarray) -> None:
        """∂m/∂q (nv,) at the bound robot's current kinematics, written into ``out``."""
        ...


class SigmaProxy:
    r"""The proxy :math:`\sigma(q) = \tfrac12 \sum_j \sin^2 q_j` over chosen hinge joints
    (maximum at :math:`\pm\pi/2`), :math:`\partial\sigma/\partial q_j = \sin q_j \cos q_j`.
    On the arm, with joints θ2 and θ3, σ = ½(sin²θ2 + sin²θ3), the source's measure.

    Args:
        robot: the robot (one world or N).
        joints: the hinge or slide joints it sums over (no default: which joints make a
            robot dexterous is the robot's own business).

    Raises:
        UnknownName: an unknown joint (the closest are listed).
        InvalidInput: no joint, the same joint twice, or a ball or free joint.
    """

    label = "sigma"

    def __init__(self, robot, joints: Sequence[str]):
        if isinstance(joints, str) or not len(joints):
            raise InvalidInput(f"SigmaProxy needs a list of joint names, got {joints!r}")
        if len(set(joints)) != len(joints):
            raise InvalidInput(f"a joint is named twice in {list(joints)}")
        ids = [robot.joint_id(j) for j in joints]
        rotating = [j for j, i in zip(joints, ids) if int(robot.model.jnt_type[i]) in _ROTATING]
        if rotating:
            raise InvalidInput(f"SigmaProxy sums sin² of scalar joints; {rotating} are ball or free joints")
        self.robot = robot
        self.joints = tuple(joints)
        self.qpos_index = np.array([robot.model.jnt_qposadr[i] for i in ids], dtype=int)
        self.dof_index = np.array([robot.model.jnt_dofadr[i] for i in ids], dtype=int)
        self._gradient = np.zeros((robot.n, robot.nv))  # zero off the measure's dofs
        self._angles = np.zeros((robot.n, len(ids)))

    def values(self, qpos: np.ndarray) -> np.ndarray:
        """σ of configurations (N, nq), (N,)."""
        s = np.sin(qpos[:, self.qpos_index])
        return 0.5 * np.einsum("ni,ni->n", s, s)

    def value(self, robot=None):
        """σ as a user reads it: of the bound robot or another of the same model."""
        robot = robot or self.robot
        return robot.present(self.values(robot.qpos))

    def gradient(self) -> np.ndarray:
        """∂σ/∂q (N, nv) of every world: ½ sin 2q_j on the measure's joints (an array of the
        measure's, overwritten by the next call)."""
        angles = self._angles
        np.take(self.robot.qpos, self.qpos_index, 1, angles)
        np.multiply(angles, 2.0, angles)
        np.sin(angles, angles)
        np.multiply(angles, 0.5, angles)
        self._gradient[:, self.dof_index] = angles
        return self._gradient


class Yoshikawa:
    r"""Yoshikawa's measure :math:`w = \sqrt{\det(J J^T)}` of a frame's Jacobian rows,
    with an analytic gradient.

    J stacks the translational rows ``axes`` and the rotational rows
    ``orientation_axes`` of the frame's Jacobian (world axes). Masking matters on planar
    robots: the z row of the arm's position Jacobian is zero, so det over all three rows
    would be 0.

    Gradient (Haviland & Corke 2023, "Manipulator Differential Kinematics" II): with
    :math:`A = JJ^T`, :math:`\partial w/\partial q_k = w\,\langle A^{-1}J,\ \partial J/\partial q_k\rangle`,
    and the kinematic Hessian follows from the Jacobian's columns alone. For dofs i, k on
    the frame's chain (dof order is chain order in MuJoCo), with :math:`\omega_i` the
    rotational column (zero for a slide) and :math:`c_i` the translational one,

    .. math::
        \frac{\partial c_i}{\partial q_k} = \omega_{\min(i,k)} \times c_{\max(i,k)},\qquad
        \frac{\partial \omega_i}{\partial q_k} = \begin{cases}\omega_k\times\omega_i & k \le i\\
        0 & k > i\end{cases}

    exact for hinge and slide joints and a free joint's translation. The three rotational
    dofs of a ball or free joint are MuJoCo's tangent directions (q ⊗ exp(h e_k), the
    body's own axes): each rotates all three axes of its joint, so within one such joint
    :math:`\partial c_i/\partial q_k = \omega_k \times c_i` (and likewise for ω) whatever
    the order. Dofs off the chain have zero columns and add nothing.

    With :math:`M = A^{-1}J` and the triple products :math:`\langle M_i, \omega_k \times c_i\rangle =
    \omega_k\cdot(c_i \times M_i)` and :math:`\langle M_i, \omega_i \times c_k\rangle =
    c_k\cdot(M_i \times \omega_i)` the double sum over i and k becomes one cumulative sum
    over i (started, for a ball or free joint's dofs, at the joint's first rotational dof):
    one Jacobian evaluation and O(nv) work per gradient, against 2 nv kinematics updates
    for central differences. :math:`A^{-1}` is written :math:`\mathrm{adj}(A)/w^2`, defined
    at a singularity too; the gradient is zero where w = 0 (it does not exist there).

    Args:
        robot: the robot.
        frame: name of the site, body or geom.
        frame_type: ``"site"``, ``"body"`` (its origin) or ``"geom"``.
        axes: translational rows, a subset of ``"xyz"``, or ``""`` for none.
        orientation_axes: rotational rows, a subset of ``"xyz"``, or ``""`` for none.

    Raises:
        UnknownName: no frame of that type has this name (the closest are listed).
        InvalidInput: bad masks, or no row at all.
    """

    label = "yoshikawa"

    def __init__(self, robot: Robot, frame: str, frame_type: str = "site", axes: str = "xyz",
                 orientation_axes: str = ""):
        self.robot = robot
        self.frame = robot.frame(frame, frame_type)
        self.position_rows = _optional_rows(axes, "axes")
        self.orientation_rows = _optional_rows(orientation_axes, "orientation_axes")
        self.dim = len(self.position_rows) + len(self.orientation_rows)
        if self.dim == 0:
            raise InvalidInput("Yoshikawa needs at least one row: give axes and/or orientation_axes")
        nv = robot.nv
        n = self._n_position = len(self.position_rows)
        # The Jacobian's columns in one array, [c; c; ω; ω] (12 x nv): rows 0:6 and 6:12
        # hold c and ω twice over, so that rows 1:4 and 2:5 of each are the cyclic shifts
        # a cross product needs (views), and rows 3:9 are [c; ω].
        self._columns = np.zeros((12, nv))
        self._c, self._omega = self._columns[3:6], self._columns[6:9]  # what MuJoCo fills
        self._m_position, self._m_orientation = np.zeros((6, nv)), np.zeros((6, nv))  # adj(A) J / w, doubled
        self._position_rows = _as_index(self.position_rows)
        self._orientation_rows = _as_index(self.orientation_rows)
        # J's rows: a view when they are one contiguous block of c or of ω.
        if n == self.dim and isinstance(self._position_rows, slice):
            self._jac, self._copy = self._c[self._position_rows], False
        elif n == 0 and isinstance(self._orientation_rows, slice):
            self._jac, self._copy = self._omega[self._orientation_rows], False
        else:
            self._jac, self._copy = np.zeros((self.dim, nv)), True
        self._terms, self._sums = np.zeros((6, nv)), np.zeros((6, nv))
        self._product, self._rotational = np.zeros((3, nv)), np.zeros((3, nv))
        self._total, self._sum = np.zeros(3), np.zeros(nv)
        self._weights = np.zeros((self.dim, nv))
        # Within a ball or free joint each rotational dof turns all three of the joint's
        # axes: for those dofs the sums below start at the joint's first rotational dof.
        start = np.arange(nv)
        model = robot.model
        for j in range(model.njnt):
            kind = int(model.jnt_type[j])
            if kind in _ROTATING:
                first = int(model.jnt_dofadr[j]) + (3 if kind == int(mujoco.mjtJoint.mjJNT_FREE) else 0)
                start[first:first + 3] = first
        self._start = start if np.any(start != np.arange(nv)) else None
        self._gathered = np.zeros((6, nv))

    def _fill(self, robot: Robot) -> None:
        """The frame's Jacobian columns (c, ω) and the measure's rows J, on ``robot``."""
        if robot is self.robot:
            self.frame.jacobian(self._c, self._omega)
        else:
            robot.frame_jacobian(self.frame, self._c, self._omega)
        if self._copy:
            n = self._n_position
            self._jac[:n] = self._c[self._position_rows]
            self._jac[n:] = self._omega[self._orientation_rows]

    def _measure(self) -> tuple[float, np.ndarray]:
        """w and adj(JJᵀ) of the rows in ``_jac``."""
        gram = self._jac @ self._jac.T
        adjugate = _adjugate(gram)
        det = float(gram[0] @ adjugate[:, 0]) if len(gram) <= 3 else float(np.linalg.det(gram))
        return float(np.sqrt(max(det, 0.0))), adjugate

    def value(self, robot: Robot | None = None) -> float:
        self._fill(robot or self.robot)
        return self._measure()[0]

    def gradient(self, out: np.ndarray) -> None:
        # Unbounded (no limits, a slide joint extending) the ascent grows w without end
        # until JJᵀ overflows: the task then reports a DivergenceError, not a RuntimeWarning per step.
        with np.errstate(over="ignore", invalid="ignore"):
            self._gradient(out)

    def _gradient(self, out: np.ndarray) -> None:
        self._fill(self.robot)
        w, adjugate = self._measure()
        if w == 0.0:
            out[:] = 0.0
            return
        columns, n = self._columns, self._n_position
        columns[0:3] = columns[3:6]
        columns[9:12] = columns[6:9]
        c2, omega2 = columns[0:6], columns[6:12]
        # M = A⁻¹J = adj(A) J / w²; ∂w/∂q_k = w ⟨M, ∂J/∂q_k⟩ = ⟨adj(A) J, ∂J/∂q_k⟩ / w.
        weights = np.matmul(adjugate, self._jac, out=self._weights)
        weights /= w
        terms = self._terms
        # ⟨M_i, ω_k × c_i⟩ = ω_k · (c_i × M_i) for k ≤ i, ⟨M_i, ω_i × c_k⟩ = c_k · (M_i × ω_i)
        # for k > i; rotational rows add ⟨Mr_i, ω_k × ω_i⟩ = ω_k · (ω_i × Mr_i) for k ≤ i.
        # terms = [ω_i × M_i (= −(M_i × ω_i)), paired with c_k; the ω_k terms]
        if n:
            mp = self._m_position
            mp[self._position_rows] = weights[:n]
            mp[3:] = mp[:3]
            self._cross(omega2, mp, terms[:3])
            self._cross(c2, mp, terms[3:])
        else:
            terms.fill(0.0)
        if n < self.dim:
            mr = self._m_orientation
            mr[self._orientation_rows] = weights[n:]
            mr[3:] = mr[:3]
            terms[3:] += self._cross(omega2, mr, self._rotational)
        # sums[:, k] = Σ_{i ≥ k} terms_i; Σ_{i < k} (M_i × ω_i) = total + sums[:3, k].
        sums = self._sums
        np.cumsum(terms[:, ::-1], axis=1, out=sums[:, ::-1])
        self._total[:] = sums[:3, 0]
        if self._start is not None:
            sums = np.take(sums, self._start, axis=1, out=self._gathered)
        np.einsum("ij,ij->j", columns[3:9], sums, out=out)
        out -= np.matmul(self._total, self._c, out=self._sum)

    def _cross(self, a: np.ndarray, b: np.ndarray, out: np.ndarray) -> np.ndarray:
        """Column-wise a × b of two doubled 6 x nv arrays, into ``out`` (3 x nv)."""
        np.multiply(a[1:4], b[2:5], out=out)
        out -= np.multiply(a[2:5], b[1:4], out=self._product)
        return out


def _as_index(rows: np.ndarray) -> slice | np.ndarray:
    """A slice for consecutive rows (views and plain copies), else the index array."""
    if len(rows) and rows[-1] - rows[0] + 1 == len(rows):
        return slice(int(rows[0]), int(rows[-1]) + 1)
    return rows


def _optional_rows(axes: str, what: str) -> np.ndarray:
    if not isinstance(axes, str) or any(a not in "xyz" for a in axes) or len(set(axes)) != len(axes):
        raise InvalidInput(f"{what} must be a subset of 'xyz' (or ''), got {axes!r}")
    return np.array(sorted("xyz".index(a) for a in axes), dtype=int)


def _adjugate(a: np.ndarray) -> np.ndarray:
    """adj(A) of a symmetric matrix of size 1 to 6 (det(A) A⁻¹, defined when A is singular)."""
    n = len(a)
    if n == 1:
        return np.ones((1, 1))
    if n == 2:
        (p, q), (_, r) = a.tolist()
        return np.array([[r, -q], [-q, p]])
    if n == 3:  # cofactors of [[p, q, r], [q, s, t], [r, t, u]], written out
        (p, q, r), (_, s, t), (_, _, u) = a.tolist()
        qt_rs, qr_pt, rt_qu = q * t - r * s, q * r - p * t, r * t - q * u
        return np.array([[s * u - t * t, rt_qu, qt_rs], [rt_qu, p * u - r * r, qr_pt], [qt_rs, qr_pt, p * s - q * q]])
    # Larger: cofactors through the SVD, adj(A) = det(A) A⁻¹ = V diag(Π_{j≠i} s_j) Uᵀ det(UVᵀ)
    u, s, vt = np.linalg.svd(a)
    products = np.array([np.prod(np.delete(s, i)) for i in range(n)])
    return np.linalg.det(u @ vt) * (vt.T * products) @ u.T


class ManipulabilityTask(JointSpaceTask):
    """Posture task toward the manipulability gradient: cost ½ w ‖q̇ − k0 ∇m(q)‖².

    Written as a quadratic in q̇ with J = I (not as a bare linear term -w k0 ∇mᵀq̇,
    which with a tiny regulariser drives the null-space velocity to its bounds).
    With a hard primary task this is exactly the null-space law
    q̇ = J†v + (I − J†J) k0 ∇m.

    Args:
        robot: the robot (one world or N).
        measure: the measure m whose gradient (over every dof) the task follows.
        gain: k0.
        weight: cost weight.
        joints: joints whose dofs the task covers (default: every hinge and slide joint).
    """

    name = "manipulability task"

    def __init__(self, robot, measure: ManipulabilityMeasure, gain: float = 5.0, weight=1.0,
                 joints: Sequence[str] | None = None):
        super().__init__(robot, joints, weight)
        self.measure = measure
        self.gain = gain
        self._dofs = as_index(self.dofs)

    @property
    def gain(self) -> float:
        return self._gain

    @gain.setter
    def gain(self, value) -> None:
        self._gain = positive_scalar(value, "manipulability gain", allow_zero=True)
        self._k = np.array(self._gain)

    def track(self) -> None:
        """v = k0 ∇m on the task's dofs, in every world."""
        gradient = self.measure.gradient()
        part = gradient[:, self._dofs] if isinstance(self._dofs, slice) else gradient.take(self._dofs, 1)
        np.multiply(part, self._k, self.target_velocities)
        if not all_finite(self.target_velocities):
            raise DivergenceError(f"{self.name}: the manipulability gradient overflowed (the configuration "
                                  "diverged, e.g. an unlimited joint extending): add joint limits")
