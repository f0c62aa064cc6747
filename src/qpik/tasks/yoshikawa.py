r"""Yoshikawa's manipulability measure and its analytic gradient, in every world."""

from __future__ import annotations

import mujoco
import numpy as np

from ..errors import DivergenceError, InvalidInput
from ..numerics import all_finite
from .inputs import as_index, optional_rows
from .manipulability import _ROTATING, OVERFLOWED

# Jacobian columns smaller than this (their norm over every world) cannot overflow the
# gradient's products (the fifth power of J's entries at most, summed over a few dofs).
TAME = 1e50


class Yoshikawa:
    r"""Yoshikawa's measure :math:`w = \sqrt{\det(J J^T)}` of a frame's Jacobian rows,
    with an analytic gradient, in every world.

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
    over i (started, for a ball or free joint's dofs, at the joint's first rotational dof),
    taken in every world at once along the dof axis: one Jacobian evaluation and O(nv)
    work per world, against 2 nv kinematics updates for central differences.
    :math:`A^{-1}` is written :math:`\mathrm{adj}(A)/w^2`, defined at a singularity too;
    the gradient is zero in a world where w = 0 (it does not exist there).

    Args:
        robot: the robot (one world or N).
        frame: name of the site, body or geom.
        frame_type: ``"site"``, ``"body"`` (its origin) or ``"geom"``.
        axes: translational rows, a subset of ``"xyz"``, or ``""`` for none.
        orientation_axes: rotational rows, a subset of ``"xyz"``, or ``""`` for none.

    Raises:
        UnknownName: no frame of that type has this name (the closest are listed).
        InvalidInput: bad masks, or no row at all.
    """

    label = "yoshikawa"

    def __init__(self, robot, frame: str, frame_type: str = "site", axes: str = "xyz", orientation_axes: str = ""):
        self.robot = robot
        self.frame = robot.frame(frame, frame_type)
        self.axes, self.orientation_axes = axes, orientation_axes
        self.position_rows = optional_rows(axes, "axes")
        self.orientation_rows = optional_rows(orientation_axes, "orientation_axes")
        self.dim = len(self.position_rows) + len(self.orientation_rows)
        if self.dim == 0:
            raise InvalidInput("Yoshikawa needs at least one row: give axes and/or orientation_axes")
        n, nv = robot.n, robot.nv
        p = self._n_position = len(self.position_rows)
        # Each world's Jacobian columns in one array, [c; c; ω; ω] (12 x nv): rows 0:6 and
        # 6:12 hold c and ω twice over, so that rows 1:4 and 2:5 of each are the cyclic
        # shifts a cross product needs (views), and rows 3:9 are [c; ω].
        self._columns = np.zeros((n, 12, nv))
        self._c, self._omega = self._columns[:, 3:6], self._columns[:, 6:9]  # what MuJoCo fills
        self._position_rows, self._orientation_rows = as_index(self.position_rows), as_index(self.orientation_rows)
        # J's rows: a view when they are one contiguous block of c or of ω.
        self._copy = False
        if p == self.dim and isinstance(self._position_rows, slice):
            self._jac = self._c[:, self._position_rows]
        elif p == 0 and isinstance(self._orientation_rows, slice):
            self._jac = self._omega[:, self._orientation_rows]
        else:
            self._jac, self._copy = np.zeros((n, self.dim, nv)), True
        self._jac_t = self._jac.transpose(0, 2, 1)  # Jᵀ (a view)
        self._gram = _Gram(n, self.dim)
        self._w = np.zeros((n, 1, 1))
        self._weights = np.zeros((n, self.dim, nv))  # adj(A) J / w
        self._gradient = np.zeros((n, nv))
        self._contraction = _Contraction(robot.model, self._columns, self._weights, p, self._position_rows,
                                         self._orientation_rows)

    def _fill(self) -> None:
        """Every world's Jacobian columns (c, ω) and the measure's rows J."""
        self.frame.jacobians(self._c, self._omega)
        if self._copy:
            p = self._n_position
            self._jac[:, :p] = self._c[:, self._position_rows]
            self._jac[:, p:] = self._omega[:, self._orientation_rows]

    def _measure(self) -> np.ndarray:
        """w (N, 1, 1) of the rows in ``_jac``, adj(JJᵀ) left in ``_gram.adjugate``."""
        det = self._gram(self._jac, self._jac_t)
        np.maximum(det, 0.0, self._w)
        return np.sqrt(self._w, self._w)

    def value(self, robot=None):
        """w as a user reads it (a number for one robot, (N,) for N worlds), on the bound
        robot or another robot of the same model (after its kinematics update)."""
        if robot is not None and robot is not self.robot:
            return Yoshikawa(robot, self.frame.name, self.frame.type, self.axes, self.orientation_axes).value()
        self._fill()
        with np.errstate(over="ignore", invalid="ignore"):
            return self.robot.present(self._measure()[:, 0, 0].copy())

    def gradient(self) -> np.ndarray:
        """∂w/∂q (N, nv) of every world at the current kinematics (an array of the
        measure's, overwritten by the next call).

        Raises:
            DivergenceError: it overflowed in some world (the ascent grew w without end:
                no limits, a slide joint extending).
        """
        self._fill()
        # Below TAME no product of the gradient (at most the fifth power of J's entries)
        # can overflow; above it (a diverged configuration) overflow is reported as a
        # DivergenceError below, not as a RuntimeWarning per step.
        if mujoco.mju_norm(self._columns.reshape(-1)) <= TAME:
            self._gradients()
        else:
            with np.errstate(over="ignore", invalid="ignore"):
                self._gradients()
        if not all_finite(self._gradient):
            raise DivergenceError(f"{self.label}: {OVERFLOWED}")
        return self._gradient

    def _gradients(self) -> None:
        w = self._measure()
        singular = w == 0.0
        # M = A⁻¹J = adj(A) J / w²; ∂w/∂q_k = w ⟨M, ∂J/∂q_k⟩ = ⟨adj(A) J, ∂J/∂q_k⟩ / w.
        weights = np.matmul(self._gram.adjugate, self._jac, self._weights)
        any_singular = singular.any()
        np.divide(weights, np.where(singular, 1.0, w) if any_singular else w, weights)
        self._contraction(self._gradient)
        if any_singular:  # no gradient where w = 0
            self._gradient[singular[:, 0, 0]] = 0.0


class _Contraction:
    r""":math:`\langle W, \partial J/\partial q_k\rangle` for every dof k in every world, from
    the Jacobian's columns (``columns``, [c; c; ω; ω], (N, 12, nv)) and W (``weights``,
    the measure's rows: translational ``position_rows`` of c, then rotational
    ``orientation_rows`` of ω): the cumulative sum of :class:`Yoshikawa`'s description.
    Every view it takes is taken once, here."""

    def __init__(self, model: mujoco.MjModel, columns: np.ndarray, weights: np.ndarray, p: int, position_rows,
                 orientation_rows):
        n, nv = columns.shape[0], columns.shape[2]
        self._doubling = [(columns[:, 0:3], columns[:, 3:6]), (columns[:, 9:12], columns[:, 6:9])]
        c2, omega2 = columns[:, 0:6], columns[:, 6:12]
        self._c, self._c_omega = columns[:, 3:6], columns[:, 3:9]
        terms = self._terms = np.zeros((n, 6, nv))
        self._product = np.zeros((n, 3, nv))
        # W's translational and rotational rows, each doubled as the columns are.
        position, orientation = np.zeros((n, 6, nv)), np.zeros((n, 6, nv))
        self._rows = []  # (doubled, its rows, W's rows, the upper half, the lower half)
        # terms = [ω_i × W_i (= −(W_i × ω_i)), paired with c_k; c_i × W_i (+ ω_i × Wr_i), the ω_k terms]
        self._crosses = []
        if p:
            self._rows.append((position, position_rows, weights[:, :p], position[:, 3:], position[:, :3]))
            self._crosses += [self._cross_views(omega2, position, terms[:, :3], None),
                              self._cross_views(c2, position, terms[:, 3:], None)]
        if weights.shape[1] > p:
            self._rows.append((orientation, orientation_rows, weights[:, p:], orientation[:, 3:], orientation[:, :3]))
            self._crosses.append(self._cross_views(omega2, orientation, np.zeros((n, 3, nv)), terms[:, 3:]))
        self._empty = not p
        self._sums = np.zeros((n, 6, nv))
        self._reversed_terms, self._reversed_sums = terms[:, :, ::-1], self._sums[:, :, ::-1]
        self._start = _sum_starts(model)
        self._gathered = np.zeros((n, 6, nv)) if self._start is not None else self._sums
        self._total, self._last = np.zeros((n, 1, 3)), np.zeros((n, 1, nv))
        self._total_row, self._first_sums, self._last_row = self._total[:, 0], self._sums[:, :3, 0], self._last[:, 0]
        self._paired = np.zeros((n, 6, nv))

    @staticmethod
    def _cross_views(a: np.ndarray, b: np.ndarray, out: np.ndarray, add_to: np.ndarray | None):
        """The views of the column-wise a × b of two doubled (N, 6, nv) arrays into ``out``
        (N, 3, nv), then added to ``add_to`` if given."""
        return a[:, 1:4], b[:, 2:5], a[:, 2:5], b[:, 1:4], out, add_to

    def __call__(self, out: np.ndarray) -> np.ndarray:
        """Write ⟨W, ∂J/∂q_k⟩ (N, nv) into ``out``."""
        for destination, source in self._doubling:
            np.copyto(destination, source)
        for doubled, rows, source, upper, lower in self._rows:
            doubled[:, rows] = source
            np.copyto(upper, lower)
        if self._empty:
            self._terms.fill(0.0)
        product = self._product
        for a1, b2, a2, b1, cross, add_to in self._crosses:
            np.multiply(a1, b2, cross)
            np.subtract(cross, np.multiply(a2, b1, product), cross)
            if add_to is not None:
                np.add(add_to, cross, add_to)
        # sums[:, :, k] = Σ_{i ≥ k} terms_i; Σ_{i < k} (W_i × ω_i) = total + sums[:, :3, k].
        np.add.accumulate(self._reversed_terms, 2, out=self._reversed_sums)
        np.copyto(self._total_row, self._first_sums)
        sums = self._sums if self._start is None else np.take(self._sums, self._start, 2, self._gathered)
        # out_k = Σ_i [c; ω]_ik sums_ik − total · c_k
        np.add.reduce(np.multiply(self._c_omega, sums, self._paired), 1, None, out)
        np.matmul(self._total, self._c, self._last)
        np.subtract(out, self._last_row, out)
        return out


def _sum_starts(model: mujoco.MjModel) -> np.ndarray | None:
    """Where each dof's cumulative sum starts (None: at the dof itself, for every dof).

    Within a ball or free joint each rotational dof turns all three of the joint's axes:
    for those dofs the sums start at the joint's first rotational dof."""
    start = np.arange(model.nv)
    for j in range(model.njnt):
        kind = int(model.jnt_type[j])
        if kind in _ROTATING:
            first = int(model.jnt_dofadr[j]) + (3 if kind == int(mujoco.mjtJoint.mjJNT_FREE) else 0)
            start[first:first + 3] = first
    return start if np.any(start != np.arange(model.nv)) else None


class _Gram:
    r"""A = JJᵀ (N, m, m) of every world, det(A) and its adjugate adj(A) = det(A) A⁻¹, defined
    when A is singular too: from the SVD A = U diag(s) Vᵀ, adj(A) = V diag(Π_{j≠i} s_j) Uᵀ
    det(UVᵀ). A world whose A overflowed gets NaN (the others are decomposed as usual)."""

    def __init__(self, n: int, m: int):
        self.gram, self.adjugate, self._det = np.zeros((n, m, m)), np.zeros((n, m, m)), np.zeros((n, 1, 1))
        self._others = [np.delete(np.arange(m), i) for i in range(m)]  # the singular values each product takes

    def __call__(self, J: np.ndarray, Jt: np.ndarray) -> np.ndarray:
        """A = J Jᵀ and its adjugate (``adjugate``); returns det(A) (N, 1, 1)."""
        gram = np.matmul(J, Jt, self.gram)
        overflowed = None if all_finite(gram) else ~np.isfinite(gram).all(axis=(1, 2))
        if overflowed is not None:
            gram = np.where(overflowed[:, None, None], 0.0, gram)
        u, s, vt = np.linalg.svd(gram)
        products = np.stack([s[:, others].prod(axis=1) for others in self._others], axis=1)
        products *= np.linalg.det(np.matmul(u, vt))[:, None]
        np.matmul(vt.transpose(0, 2, 1) * products[:, None, :], u.transpose(0, 2, 1), self.adjugate)
        self._det[:, 0, 0] = np.linalg.det(gram)
        if overflowed is not None:
            self._det[overflowed], self.adjugate[overflowed] = np.nan, np.nan
        return self._det
