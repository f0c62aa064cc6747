"""The controllers a run can name, in one registry: the command line's choices and help,
``run`` and ``compare``, the peers, the palette's colours and the benchmarks read it.

A scenario offers ``qp`` and, of the others, those it builds (:meth:`qpik.Setup.controller_kinds`);
the peers (mink, placo) run on any scenario they can map. Importing this module costs
nothing (the command line reads it before any heavy import).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class ControllerKind:
    """One controller as runs name it.

    Attributes:
        name: the ``--controller`` value, the summary's ``controller``.
        description: what it is, for the command line's help.
        colour: its ``#rrggbb`` colour in every figure and video (matplotlib's tab10).
        uses_solver: whether it takes a QP solver name (``--solver``).
        peer: a peer library, run through :mod:`qpik.app.peers`.
        own_solver: the solver a peer always uses (placo's own), if any.
    """

    name: str
    description: str
    colour: str
    uses_solver: bool = False
    peer: bool = False
    own_solver: str | None = None


# In the order of the help text, of `qpik compare`'s runs and of its table.
KINDS: dict[str, ControllerKind] = {kind.name: kind for kind in (
    ControllerKind("qp", "qpik's QP", "#1f77b4", uses_solver=True),
    ControllerKind("qp-hard", "the scenario's QP with its top level hard, where it offers one", "#17becf",
                   uses_solver=True),
    ControllerKind("hqp", "strict task hierarchy", "#9467bd", uses_solver=True),
    ControllerKind("sns", "saturation in the null space", "#2ca02c"),
    ControllerKind("pinv", "pseudoinverse CLIK + null space", "#d62728"),
    ControllerKind("jt", "Jacobian transpose; arm only", "#8c564b"),
    ControllerKind("mink", "the peer library mink", "#ff7f0e", uses_solver=True, peer=True),
    ControllerKind("placo", "the peer library placo, with its own eiquadprog", "#e377c2", peer=True,
                   own_solver="eiquadprog"),
)}

# The kinds that take a QP solver name.
SOLVER_KINDS = tuple(name for name, kind in KINDS.items() if kind.uses_solver)
# The peer libraries.
PEER_KINDS = tuple(name for name, kind in KINDS.items() if kind.peer)
# What `qpik compare` runs after qp, where the scenario offers it (each once, a QP
# solver's kind with the first solver asked for).
OFFERED_KINDS = tuple(name for name, kind in KINDS.items() if name != "qp" and not kind.peer)


def uses_solver(name: str) -> bool:
    """Whether controller ``name`` takes a QP solver name (False for an unknown name)."""
    kind = KINDS.get(name)
    return kind is not None and kind.uses_solver
