"""QP solver back-ends, chosen by their qpsolvers name through a registry.

DAQP, OSQP and ProxQP are called through their own Python interfaces (persistent
workspaces, no per-call conversion); any other solver that qpsolvers knows runs through
``qpsolvers.solve_problem``. Adding a native back-end = one module + one
:func:`register_backend` line below.

Only DAQP is a dependency of qpik; OSQP, ProxQP, quadprog and qpsolvers come with the
``solvers`` extra (``pip install -e ".[solvers]"`` from a clone) and are imported only
when asked for.
"""

from __future__ import annotations

import importlib.util
from typing import Callable

from ..errors import InvalidInput, UnknownName
from .base import BIG, QPBackend
from .daqp import DaqpBackend
from .osqp import OsqpBackend
from .proxqp import ProxqpBackend

# Native back-ends by qpsolvers name: each takes (nv, meq, mineq, **settings).
NATIVE_BACKENDS: dict[str, Callable[..., QPBackend]] = {"daqp": DaqpBackend, "osqp": OsqpBackend,
                                                        "proxqp": ProxqpBackend}

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


# Native back-end -> the module its solver imports (installed or not, without importing it).
NATIVE_MODULES = {"daqp": "daqp", "osqp": "osqp", "proxqp": "proxsuite"}
SOLVERS_EXTRA = 'pip install -e ".[solvers]" from qpik\'s clone'


def _qpsolvers_names() -> list[str]:
    if importlib.util.find_spec("qpsolvers") is None:
        return []
    import qpsolvers

    return list(qpsolvers.available_solvers)


def available_solvers() -> list[str]:
    """Names of the QP solvers installed here (qpsolvers' names): the native back-ends whose
    module is installed, and every solver qpsolvers finds when qpsolvers is installed."""
    native = [name for name, module in NATIVE_MODULES.items() if importlib.util.find_spec(module) is not None]
    return sorted(set(native) | set(_qpsolvers_names()))


def make_backend(solver: str, nv: int, meq: int, mineq: int = 0, native: bool = True, **settings) -> QPBackend:
    """Back-end for a qpsolvers solver name, sized for nv variables, meq equalities and
    mineq general inequalities; ``native=False`` forces the qpsolvers path.

    Raises:
        UnknownName: a solver that is not installed here (the message names the extra).
        InvalidInput: no variable.
    """
    if not isinstance(solver, str) or solver not in available_solvers():
        raise UnknownName(f"unknown or uninstalled QP solver {solver!r}; available: {', '.join(available_solvers())} "
                          f"(the others: {SOLVERS_EXTRA})")
    if not native or solver not in NATIVE_BACKENDS:
        if solver not in _qpsolvers_names():
            raise UnknownName(f"solver {solver!r} through qpsolvers needs qpsolvers: {SOLVERS_EXTRA}")
    if nv < 1 or meq < 0 or mineq < 0:
        raise InvalidInput("a QP needs at least one variable")
    if native and solver in NATIVE_BACKENDS:
        return NATIVE_BACKENDS[solver](nv, meq, mineq, **settings)
    from .qpsolvers_backend import QpsolversBackend

    settings = {**QPSOLVERS_DEFAULTS.get(solver, {}), **settings}
    return QpsolversBackend(nv, meq, mineq, solver=solver, **settings)


__all__ = ["BIG", "NATIVE_BACKENDS", "QPBackend", "available_solvers", "make_backend", "register_backend"]
