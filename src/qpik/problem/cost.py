r"""The cost of a set of soft tasks in every world, :math:`\tfrac12 \dot q^T H \dot q + c^T \dot q`,
kept as rows: :math:`H = D + R_1^TR_1`, :math:`c = c_0 - R_1^Tr_1`, where :math:`R_1, r_1`
are the tasks of their own Jacobian, their rows scaled by √w, D is the diagonal
:math:`\epsilon + \sum w_i` (joint-space tasks, read once) :math:`+ \sum \mu_i e_i^TW_ie_i`
(the Levenberg–Marquardt term, mink's ``lm_damping``) and :math:`c_0 = -\sum w_i v_i` the
joint-space tasks' linear term. The closed form reads the rows; a solver gets one world's
H, formed when it asks. Past ``LM_RESCALE`` the solver's H and c are scaled down together
(the same minimiser) so that no solver sees overflowing numbers.

The hard rows follow :math:`R_1` in the same arrays (``R``, ``rhs``), as the closed form
takes them.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ..errors import InvalidInput
from ..numerics import everywhere, norm, vecmat
from ..tasks import Task
from ..tasks.inputs import as_index
from .rows import Stack

LM_RESCALE = 1e6
# A far target's c is scaled down to at most this times H's scale before a solver sees it
# (see tame): the solvers' answers keep their digits. The closed form is tried only where
# the cap leaves c as it is, so both give the same minimiser.
COST_SCALE_CAP = 1e9



def tame(c: np.ndarray, hessian_scale: float, cap: float = COST_SCALE_CAP) -> np.ndarray:
    """One world's c scaled down to at most ``cap`` times ``max(1, hessian_scale)`` (c itself
    when it already is)."""
    scale = float(np.abs(c).max()) if c.size else 0.0
    bound = cap * max(1.0, hessian_scale)
    if scale <= bound:
        return c
    return c * (bound / scale)


class Cost:
    """The cost of the soft tasks ``soft`` (ε = ``regularization``) in every world, and the
    hard rows after its own.

    Args:
        hard: hard tasks, their rows stacked after the soft ones (the QP's).
        spare_rows: rows after those, written by the owner each step (a hierarchy level's
            equalities).

    Attributes:
        diagonal, general: the joint-space tasks (in D), the others (rows of R₁).
        R, rhs: (N, soft_rows + hard rows, nv), (N, soft_rows + hard rows) after :meth:`write`;
            ``A``, ``b``: views of their hard rows; ``hard_task_rows``: (task, its rows of A).
        damping, dinv: (N, nv) D and D⁻¹.
        linear: (N, nv) c₀, or None without joint-space tasks.
        c: (N, nv) the QP's c (scaled with H where the damping is past ``LM_RESCALE``).
    """

    def __init__(self, robot, soft: Sequence[Task], regularization: float, hard: Sequence[Task] = (),
                 spare_rows: int = 0):
        n, nv = robot.n, robot.nv
        self.diagonal = [task for task in soft if task.joint_space]
        self.general = [task for task in soft if not task.joint_space]
        diagonal0 = np.full(nv, float(regularization))
        for task in self.diagonal:
            diagonal0[task.dofs] += task.weight
        self.diagonal0 = np.tile(diagonal0, (n, 1))
        self.damping, self.dinv = self.diagonal0, 1.0 / self.diagonal0
        # c₀ of the joint-space tasks: −w v on their dofs (a first task on every dof writes c₀).
        self._linear = [(task, np.tile(-task.weight, (n, 1)), as_index(task.dofs)) for task in self.diagonal]
        self._first_writes = bool(self._linear) and isinstance(self._linear[0][2], slice) and \
            self._linear[0][2] == slice(0, nv)
        self.linear = np.zeros((n, nv)) if self._linear else None
        self._scratch = np.zeros((n, nv))
        self.rows = Stack(robot, self.general + list(hard), weighted=True, spare_rows=spare_rows)
        self.soft_rows = self.rows.dim - sum(task.dim for task in hard)
        self.R, self.rhs = self.rows.J, self.rows.v
        self.A, self.b = self.R[:, self.soft_rows:], self.rhs[:, self.soft_rows:]
        self._soft = self.R[:, :self.soft_rows], self.rhs[:, :self.soft_rows]  # R₁, r₁ (views)
        self.hard_task_rows = [(task, slice(rows.start - self.soft_rows, rows.stop - self.soft_rows))
                               for task, rows in self.rows.task_rows if task.hard]  # (task, its rows of A)
        self.c = np.zeros((n, nv)) if self.soft_rows or self.linear is None else self.linear
        self._lm = [(task, task.lm_damping * task.weight) for task in self.general if task.lm_damping]
        self.factor = np.ones(n)  # H and c's scale for the solver (below 1 past LM_RESCALE)
        self._rescaled = False  # whether some world's factor is below 1

    def write(self) -> None:
        """The step's rows, D and c, in every world."""
        self._write_linear()
        self.rows.stack()
        if self._lm:
            lm = self.levenberg_marquardt()
            self.damping = self.diagonal0 + lm[:, None]
            self.dinv = 1.0 / self.damping
            big = lm > LM_RESCALE
            self._rescaled = bool(big.any())
            self.factor = np.where(big, 1.0 / (1.0 + lm), 1.0) if self._rescaled else np.ones(len(lm))
        if self.soft_rows:
            R1, r1 = self._soft
            vecmat(r1, R1, self.c)
            if self.linear is None:
                np.negative(self.c, self.c)
            else:
                np.subtract(self.linear, self.c, self.c)
            if self._rescaled:  # the same minimiser, numbers a solver can take
                self.c *= self.factor[:, None]

    def _write_linear(self) -> None:
        c = self.linear
        if c is None:
            return
        if not self._first_writes:
            c.fill(0.0)
        for k, (task, neg_weight, dofs) in enumerate(self._linear):
            if k == 0 and self._first_writes:
                np.multiply(neg_weight, task.target_velocities, c)
            else:
                scratch = self._scratch[:, :task.dim]
                np.multiply(neg_weight, task.target_velocities, scratch)
                c[:, dofs] += scratch

    def levenberg_marquardt(self) -> np.ndarray:
        """Σ μ eᵀWe over the tasks with ``lm_damping``, per world (N,): the step's damping
        on every dof.

        Raises:
            InvalidInput: it overflows (a target absurdly far away).
        """
        total = np.zeros(len(self.diagonal0))
        for task, weight in self._lm:
            total += np.einsum("ni,i,ni->n", task.errors, weight, task.errors)
        if not np.isfinite(total).all():
            raise InvalidInput("a soft task's error is too large to weigh (its squared norm overflows): "
                               "check its target")
        return total

    def scale(self) -> np.ndarray:
        """(N,) H's largest diagonal entry, as the solver sees H (what the cost cap is
        relative to)."""
        R1 = self._soft[0]
        return (self.damping + np.einsum("nij,nij->nj", R1, R1)).max(axis=1) * self.factor

    def uncapped(self) -> np.ndarray:
        """(N,) whether :func:`tame` leaves each world's c as it is: only there may a closed
        form answer, or the solver's answer would differ."""
        c = self.c
        if norm(c) <= COST_SCALE_CAP:  # the usual step: no entry of c can reach the cap
            return everywhere(len(c))
        small = np.einsum("ni,ni->n", c, c) <= COST_SCALE_CAP * COST_SCALE_CAP
        return small | (np.abs(c).max(axis=1) <= COST_SCALE_CAP * np.maximum(1.0, self.scale()))

    def world_rows(self, w: int) -> tuple:
        """World ``w``'s cost as rows (R₁, r₁, D, c₀), unscaled: H and c over the solver's factor."""
        linear = np.zeros(self.R.shape[2]) if self.linear is None else self.linear[w]
        return self._soft[0][w], self._soft[1][w], self.damping[w], linear

    def world_hessian(self, w: int) -> np.ndarray:
        """World ``w``'s H as the solver sees it (a new matrix)."""
        R1 = self.R[w, :self.soft_rows]
        H = R1.T @ R1
        H.flat[:: H.shape[0] + 1] += self.damping[w]
        return H * self.factor[w] if self.factor[w] != 1.0 else H
