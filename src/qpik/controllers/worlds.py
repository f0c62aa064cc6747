"""The worlds a closed form did not settle, each solved by the chosen QP solver.

One solver back-end serves every world: a world's problem is written into its arrays and
solved through :class:`~qpik.controllers.fallbacks.GuardedSolve` (taming, fallbacks,
infeasibility confirmed by a phase-1 problem), each world with its own guard (a solver
that failed in a world sits out that world's next steps only). A world that fails is
named: one world's typed error is raised as it is; N worlds' failures are gathered into
one :class:`~qpik.errors.WorldsFailed` after every other world is solved.
"""

from __future__ import annotations

from collections import namedtuple

import numpy as np

from ..controllers.labels import task_label
from ..errors import InfeasibleProblem, InvalidInput, QpikError, WorldsFailed
from ..solvers import make_backend
from ..controllers.fallbacks import GuardedSolve, copy_constraints


WorldQP = namedtuple("WorldQP", "H c A b lb ub G h rows")
WorldQP.__doc__ = "One world's QP as a solver sees it: H, c, A, b, lb, ub, G, h and a function giving its cost's rows."


class WorldSolver:
    """The solver ``solver`` for QPs of nv variables, meq equalities and mineq rows, world by
    world (see the module's description). Each world has a workspace of its own: an
    iterative solver warm-starts from that world's last answer, as its one-world run does,
    not from the world solved before it."""

    def __init__(self, solver: str, nv: int, meq: int, mineq: int, native: bool = True, **settings):
        self.name = solver
        self._make_backend = lambda: make_backend(solver, nv, meq, mineq, native=native, **settings)
        self.backend = self._make_backend()  # world 0's (and what any world's is: exact or not)
        self.exact = self.backend.exact
        self._guards: dict[int, GuardedSolve] = {}

    def guard(self, world: int) -> GuardedSolve:
        if world not in self._guards:
            self._guards[world] = GuardedSolve(self.backend if world == 0 else self._make_backend(), self.name)
        return self._guards[world]

    def solve(self, world: int, qp: WorldQP, hessian_changed: bool = True) -> np.ndarray:
        """The checked minimiser of ``qp`` (typed errors as GuardedSolve raises them)."""
        guard = self.guard(world)
        copy_constraints(qp, guard.backend)
        return guard.solve(qp.H, qp.c, hessian_changed=hessian_changed, rows=qp.rows)

    @property
    def fallbacks(self) -> int:
        """Steps a fallback solver solved, over all worlds."""
        return sum(guard.fallbacks for guard in self._guards.values())


def check_finite_velocities(tasks, c: np.ndarray, b: np.ndarray, world: int) -> None:
    """InvalidInput naming the tasks whose target velocity in ``world`` is not finite (K·e
    overflowed for a target ~1e308 away), when c or b is not: never solved, never returned."""
    if np.isfinite(c).all() and np.isfinite(b).all():
        return
    bad = [task_label(task) for task in tasks if not np.isfinite(task.target_velocities[world]).all()]
    raise InvalidInput(f"the target velocity of the {', '.join(bad) or 'cost'} is not finite (K·e overflowed): "
                       "check the target and the gain")


def solve_each(worlds, solve_world, qdots: np.ndarray, batched: bool, what: str,
               failures: dict[int, str] | None = None) -> None:
    """``qdots[w] = solve_world(w)`` for each world; failures as the module says (their
    velocity zero). ``failures``: a dict the failing worlds are gathered into (world →
    why) instead of raising, for a caller with more to solve first (the hierarchy's
    levels below)."""
    gathered = {} if failures is None else failures
    for w in worlds:
        w = int(w)
        try:
            qdots[w] = solve_world(w)
        except (InfeasibleProblem, QpikError) as exc:
            if not batched:
                raise
            qdots[w] = 0.0
            gathered[w] = f"{type(exc).__name__}: {exc}"
    if failures is None and gathered:
        raise WorldsFailed(gathered, qdots, what)
