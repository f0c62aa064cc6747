"""QP solver back-ends, chosen by their qpsolvers name through a registry.

DAQP, OSQP and ProxQP are called through their own Python interfaces (persistent
workspaces, no per-call conversion); any other solver that qpsolvers knows runs through
``qpsolvers.solve_problem``. Adding a native back-end = one module + one
:func:`register_backend` line below.
"""

from __future__ import annotations

from typing import Callable

import qpsolvers

from ..errors import InvalidInput, UnknownName
from .base import BIG, QPBackend
from .daqp import DaqpBackend
from .osqp import OsqpBackend
from .proxqp import ProxqpBackend
from .qpsolvers_backend import QpsolversBackend

# Native back-ends by qpsolvers name: each takes (nv, meq, mineq, **settings).
NATIVE_BACKENDS: dict[str, Callable[..., QPBackend]] = {}

# Tolerances tight enough for the QP to reproduce the closed-form laws (≤ 1e-6) when a
# solver runs through qpsolvers.
QPSOLVERS_DEFAULTS: dict[str, dict] = {
    "proxqp": {"eps_abs": 1e-10, "eps_rel": 0.0},
    # raise_error=False: OSQP's own default is about to change (a PendingDeprecationWarning
    # every solve); the back-end reads the status itself.
    "osqp": {**{key: value for key, value in OsqpBackend.SETTINGS.items() if key != "warm_starting"},
             "raise_error": False},
}


def register_backend(name: str, factory: Callable[..., QPBackend]) -> None:
    """Make ``factory(nv, meq, mineq, **settings)`` the native back-end of solver ``name``."""
    NATIVE_BACKENDS[name] = factory


register_backend("daqp", DaqpBackend)
register_backend("osqp", OsqpBackend)
register_backend("proxqp", ProxqpBackend)


def available_solvers() -> list[str]:
    """Names of the QP solvers installed here (qpsolvers' names)."""
    return sorted(qpsolvers.available_solvers)


def make_backend(solver: str, nv: int, meq: int, mineq: int = 0, native: bool = True, **settings) -> QPBackend:
    """Back-end for a qpsolvers solver name, sized for nv variables, meq equalities and
    mineq general inequalities; ``native=False`` forces the qpsolvers path."""
    if not isinstance(solver, str) or solver not in qpsolvers.available_solvers:
        raise UnknownName(f"unknown or uninstalled QP solver {solver!r}; available: {', '.join(available_solvers())}")
    if nv < 1 or meq < 0 or mineq < 0:
        raise InvalidInput("a QP needs at least one variable")
    if native and solver in NATIVE_BACKENDS:
        return NATIVE_BACKENDS[solver](nv, meq, mineq, **settings)
    settings = {**QPSOLVERS_DEFAULTS.get(solver, {}), **settings}
    return QpsolversBackend(nv, meq, mineq, solver=solver, **settings)


__all__ = ["BIG", "NATIVE_BACKENDS", "QPBackend", "available_solvers", "make_backend", "register_backend"]
