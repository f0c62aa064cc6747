r"""The QP back-end interface.

Every back-end solves

.. math::
    \min_x \tfrac12 x^T H x + c^T x \quad\text{s.t.}\quad A x = b,\; lb \le x \le ub

with fixed sizes (nv variables, meq equalities) decided once. The controller writes the
problem straight into the back-end's own arrays, laid out as the solver wants them.
"""

from __future__ import annotations

import numpy as np

from ..errors import InfeasibleProblem, SolverError

BIG = 1e30  # DAQP's and OSQP's stand-in for an absent bound


class QPBackend:
    """Base class: one solver instance per controller, sized at construction.

    The controller writes the problem straight into the back-end's own arrays
    ``A`` (meq x nv), ``b`` (meq), ``lb`` and ``ub`` (nv; ±inf for no bound), laid
    out as the solver wants them, then calls :meth:`solve` with H and c.
    """

    name = "qp"
    exact_bounds = False  # interior-point/ADMM solvers meet bounds only to a tolerance

    def __init__(self, nv: int, meq: int):
        self.nv = nv
        self.meq = meq
        self.A = np.zeros((meq, nv))
        self.b = np.zeros(meq)
        self.lb = np.full(nv, -np.inf)
        self.ub = np.full(nv, np.inf)

    def solve(self, H: np.ndarray, c: np.ndarray, hessian_changed: bool = True) -> np.ndarray:
        """Solve with the arrays as written; ``hessian_changed=False`` lets a
        workspace keep its factorised H from the previous step."""
        raise NotImplementedError

    def _fail(self, status: str, infeasible: bool) -> None:
        if infeasible:
            raise InfeasibleProblem(
                f"QP infeasible ({self.name}: {status}): the hard tasks and limits cannot all be met"
            )
        raise SolverError(f"QP solver {self.name} failed: {status}")
