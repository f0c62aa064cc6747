r"""The cost of a set of soft tasks in every world, :math:`\tfrac12 \dot q^T H \dot q + c^T \dot q`:
:math:`H = \epsilon I + \sum W_i` (joint-space tasks, on the diagonal, once)
:math:`+ \sum J_i^TW_iJ_i + \sum \mu_i e_i^TW_ie_i\, I` (the others, each step),
:math:`c = -\sum J_i^TW_iv_i`. The Levenberg–Marquardt term (mink's ``lm_damping``)
grows with the error; past ``LM_RESCALE`` H and c are scaled down together (the same
minimiser) so that no solver sees overflowing numbers.

Without a task of its own Jacobian, H is a constant diagonal: the cost keeps its inverse
(``inverse_diagonal``, (N, nv)) and no matrix.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ...errors import InvalidInput
from ..numerics import everywhere, weighted_gram
from ..tasks import Task
from ..tasks.inputs import as_index
from .rows import Stack

LM_RESCALE = 1e6
# A far target's c is scaled down to at most this times H's scale before a solver sees it
# (see tame): the solvers' answers keep their digits. The closed form is tried only where
# the cap leaves c as it is, so both give the same minimiser.
COST_SCALE_CAP = 1e9
# Below this squared norm no entry of c can reach the cap (at least COST_SCALE_CAP).
UNCAPPED_NORM2 = COST_SCALE_CAP * COST_SCALE_CAP


def tame(c: np.ndarray, hessian_scale: float, cap: float = COST_SCALE_CAP) -> np.ndarray:
    """One world's c scaled down to at most ``cap`` times ``max(1, hessian_scale)`` (c itself
    when it already is)."""
    scale = float(np.abs(c).max()) if c.size else 0.0
    bound = cap * max(1.0, hessian_scale)
    if scale <= bound:
        return c
    return c * (bound / scale)


class Cost:
    """H and c of the soft tasks ``soft`` in every world, ε = ``regularization``.

    Attributes:
        diagonal: the joint-space tasks (on H's diagonal, read once).
        general: the others (JᵀWJ every step).
        H: (N, nv, nv) after :meth:`write`, or None when H is the constant diagonal whose
            inverse is ``inverse_diagonal`` (N, nv).
        c: (N, nv) after :meth:`write`.
        scale: (N,) H's largest diagonal entry (what the cost cap is relative to).
    """

    def __init__(self, robot, soft: Sequence[Task], regularization: float):
        n, nv = robot.n, robot.nv
        self.diagonal = [task for task in soft if task.joint_space]
        self.general = [task for task in soft if not task.joint_space]
        diagonal0 = np.full(nv, float(regularization))
        for task in self.diagonal:
            diagonal0[task.dofs] += task.weight
        self.diagonal0 = np.tile(diagonal0, (n, 1))
        self.c = np.zeros((n, nv))
        # c of the joint-space tasks: −w v on their dofs (a first task on every dof writes c).
        self._linear = [(task, np.tile(-task.weight, (n, 1)), as_index(task.dofs)) for task in self.diagonal]
        self._first_writes = bool(self._linear) and isinstance(self._linear[0][2], slice) and \
            self._linear[0][2] == slice(0, nv)
        self._scratch = np.zeros((n, nv))
        if self.general:
            self.H = np.zeros((n, nv, nv))
            self._rows = Stack(robot, self.general, weighted=True)  # (√W J, √W v): H = RᵀR, c = −Rᵀr
            self._lm = [(task, task.lm_damping * task.weight) for task in self.general if task.lm_damping]
            self.inverse_diagonal = None
            self.scale = np.zeros(n)
        else:
            self.H, self._lm = None, []
            self.inverse_diagonal = 1.0 / self.diagonal0
            self.scale = self.diagonal0.max(axis=1)

    def write(self) -> None:
        """The step's c (and H where it changes), in every world."""
        self._write_linear()
        if self.H is None:
            return
        rows = self._rows
        rows.stack()
        weighted_gram(rows.J, None, self.H)
        np.einsum("nij,ni->nj", rows.J, rows.v, out=self._scratch)
        self.c -= self._scratch
        lm = self.levenberg_marquardt()
        diagonal = np.einsum("nii->ni", self.H)  # a writable view of every world's diagonal
        diagonal += self.diagonal0 + lm[:, None]
        self.scale = diagonal.max(axis=1)
        big = lm > LM_RESCALE
        if big.any():  # the same minimiser, numbers a solver can take
            factor = 1.0 / (1.0 + lm[big])
            self.H[big] *= factor[:, None, None]
            self.c[big] *= factor[:, None]
            self.scale[big] *= factor

    def _write_linear(self) -> None:
        c = self.c
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
        total = np.zeros(len(self.c))
        for task, weight in self._lm:
            total += np.einsum("ni,i,ni->n", task.errors, weight, task.errors)
        if not np.isfinite(total).all():
            raise InvalidInput("a soft task's error is too large to weigh (its squared norm overflows): "
                               "check its target")
        return total

    def uncapped(self) -> np.ndarray:
        """(N,) whether :func:`tame` leaves each world's c as it is: only there may a closed
        form answer, or the solver's answer would differ."""
        c = self.c
        if np.vdot(c, c) <= UNCAPPED_NORM2:  # the usual step: every world's c is small
            return everywhere(len(c))
        small = np.einsum("ni,ni->n", c, c) <= UNCAPPED_NORM2
        return small | (np.abs(c).max(axis=1) <= COST_SCALE_CAP * np.maximum(1.0, self.scale))

    def world_hessian(self, w: int) -> np.ndarray:
        """World ``w``'s H as a matrix (a copy where H is kept as its diagonal)."""
        return np.diag(self.diagonal0[w]) if self.H is None else self.H[w]
