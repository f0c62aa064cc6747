r"""The cost of a set of soft tasks, :math:`\tfrac12 \dot q^T H \dot q + c^T \dot q`:
:math:`H = \epsilon I + \sum W_i` (joint-space tasks, on the diagonal, once)
:math:`+ \sum J_i^TW_iJ_i + \sum \mu_i e_i^TW_ie_i\, I` (the others, each step),
:math:`c = -\sum J_i^TW_iv_i`. The Levenberg–Marquardt term (mink's ``lm_damping``)
grows with the error; past ``LM_RESCALE`` H and c are scaled down together (the same
minimiser) so that no solver sees overflowing numbers.
"""

from __future__ import annotations

from typing import Sequence

import mujoco
import numpy as np

from ..errors import InvalidInput
from ..limits.limit import as_slice
from ..tasks import Task
from .rows import Stack

LM_RESCALE = 1e6
# A far target's c is scaled down to at most this times H's scale before a solver sees it
# (see tame): the solvers' answers keep their digits. The closed form is tried only where
# the cap leaves c as it is, so both give the same minimiser.
COST_SCALE_CAP = 1e9
# Below this squared norm no entry of c can reach the cap (at least COST_SCALE_CAP).
UNCAPPED_NORM2 = COST_SCALE_CAP * COST_SCALE_CAP


def tame(c: np.ndarray, hessian_scale: float, cap: float = COST_SCALE_CAP) -> np.ndarray:
    """c scaled down to at most ``cap`` times ``max(1, hessian_scale)`` (c itself when
    it already is)."""
    scale = float(np.abs(c).max()) if c.size else 0.0
    bound = cap * max(1.0, hessian_scale)
    if scale <= bound:
        return c
    return c * (bound / scale)


def uncapped(c: np.ndarray, H: np.ndarray) -> bool:
    """Whether :func:`tame` leaves c as it is for the Hessian H (c·c decides it unless c is
    ~1e9 or more): only then may a closed form answer, or the solver's answer would differ."""
    return c.dot(c) <= UNCAPPED_NORM2 or tame(c, float(H.diagonal().max())) is c


class Cost:
    """H and c of the soft tasks ``soft`` (``diagonal``: the joint-space ones, ``general``:
    the others), ε = ``regularization``. ``H0`` is H's constant part; ``H`` and ``c`` the
    step's after :meth:`write` (H stays H0 when no task has its own Jacobian)."""

    def __init__(self, nv: int, soft: Sequence[Task], regularization: float, c: np.ndarray | None = None):
        self.diagonal = [task for task in soft if task.joint_space]
        self.general = [task for task in soft if not task.joint_space]
        self.H0 = np.eye(nv) * regularization
        dofs = [as_slice(task.dofs) for task in self.diagonal]
        for task, where in zip(self.diagonal, dofs):
            self.H0.reshape(-1)[:: nv + 1][where] += task.weight
        self.H = self.H0.copy()
        self.c = np.zeros(nv) if c is None else c
        self._diag = self.H.reshape(-1)[:: nv + 1]
        self._scratch = np.zeros(nv)
        plan = [(task, -task.weight, where) for task, where in zip(self.diagonal, dofs)]
        # A first joint-space task on every dof writes c itself (no zeroing, no scratch).
        self._first = plan.pop(0)[:2] if plan and isinstance(dofs[0], slice) and dofs[0] == slice(0, nv) else None
        self._plan = plan
        # H0 is diagonal: H = Σ JᵀWJ, written into H by MuJoCo's JᵀDJ (on these sizes its
        # call costs less than BLAS's through NumPy), plus H0's diagonal. One general task:
        # JᵀWJ (W None when it is all ones); several: RᵀR for their rows stacked, R = √W J
        # (one product instead of one per task, and no sum of nv x nv matrices).
        if len(self.general) == 1:
            task = self.general[0]
            self._single = (task, None if np.all(task.weight == 1.0) else task.weight)
            self._weighted = np.zeros(task.dim)
        else:
            self._single = None
            self._rows = Stack(nv, self.general, weighted=True)
        self._diag0 = np.diag(self.H0).copy()

    def write_diagonal(self) -> None:
        """c of the joint-space tasks alone."""
        c = self.c
        if self._first is not None:
            task, neg_weight = self._first
            np.multiply(neg_weight, task.target_velocity, c)
        else:
            c.fill(0.0)
        for task, neg_weight, dofs in self._plan:
            scratch = self._scratch[: task.dim]
            np.multiply(neg_weight, task.target_velocity, scratch)
            c[dofs] += scratch

    def write(self) -> None:
        """The step's H and c: c of every task, and H = H0 + Σ JᵀWJ + the LM terms."""
        self.write_diagonal()
        if not self.general:
            return
        H, c = self.H, self.c
        scratch = self._scratch
        if self._single is not None:
            task, weight = self._single
            jacobian, v = task.jacobian, task.target_velocity
            mujoco.mju_sqrMatTD(H, jacobian, weight)
            if weight is not None:
                v = np.multiply(weight, v, self._weighted)
        else:
            rows = self._rows
            rows.stack()
            jacobian, v = rows.J, rows.v  # (√W v)ᵀ(√W J) = vᵀWJ
            mujoco.mju_sqrMatTD(H, jacobian, None)
        v.dot(jacobian, scratch)  # array methods: less overhead than np.dot or @ on small arrays
        np.subtract(c, scratch, c)
        self._diag += self._diag0
        lm = self.levenberg_marquardt()
        if lm:
            self._diag += lm
        if lm > LM_RESCALE:
            scale = 1.0 / (1.0 + lm)
            H *= scale
            c *= scale

    def levenberg_marquardt(self) -> float:
        """Σ μ eᵀWe over the tasks with ``lm_damping``: the step's damping on every dof.

        Raises:
            InvalidInput: it overflows (a target absurdly far away).
        """
        total = 0.0
        for task in self.general:
            if task.lm_damping:
                error = task.error
                total += task.lm_damping * float(error.dot(task.weight * error))
        if total > LM_RESCALE and not np.isfinite(total):
            raise InvalidInput("a soft task's error is too large to weigh (its squared norm overflows): "
                               "check its target")
        return total
