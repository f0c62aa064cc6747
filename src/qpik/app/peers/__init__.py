"""Peer libraries on qpik's scenarios: mink and placo as controllers of a rollout.

Each peer controller has ``kind``, ``solver``, ``robot`` (the scenario's robot, whose q the
rollout integrates) and ``compute_velocity()``, so :func:`qpik.rollout.simulate` rolls it
out exactly like qpik's own controllers: same reference, Δt, integration and limit
measurement. Every step a peer re-reads q into its own model (mink's Configuration,
placo's RobotWrapper), retargets its tasks from the scenario's task targets and solves
its own QP. How each maps the scenario's problem: :mod:`qpik.app.peers.problem`,
:mod:`qpik.app.peers.mink_peer`, :mod:`qpik.app.peers.placo_peer`.

The peers are optional (the ``[peers]`` extra); this module imports them only when asked.
"""

from __future__ import annotations

import importlib.util
from typing import Sequence

from ...errors import UnknownName
from ...scenario import Setup
from ..kinds import KINDS, PEER_KINDS
from .problem import PeerUnsupported

PEERS = PEER_KINDS
PLACO_SOLVER = KINDS["placo"].own_solver  # placo's built-in QP solver


def peer_installed(kind: str) -> bool:
    """Whether the peer library ``kind`` can be imported."""
    return importlib.util.find_spec(kind) is not None


def peer_solvers(kind: str, solvers: Sequence[str]) -> list[str]:
    """The solvers a peer runs with: mink each qpsolvers name asked for, placo its own."""
    own = KINDS[kind].own_solver
    return list(solvers) if own is None else [own]


def peer_controller(kind: str, setup: Setup, solver: str = "daqp"):
    """A peer controller on ``setup`` (raises :class:`PeerUnsupported` if it cannot map it)."""
    if kind == "mink":
        from .mink_peer import MinkController

        return MinkController(setup, solver)
    if kind == "placo":
        from .placo_peer import PlacoController

        return PlacoController(setup)
    raise UnknownName(f"unknown peer {kind!r}; known: {', '.join(PEERS)}")


__all__ = ["PEERS", "PLACO_SOLVER", "PeerUnsupported", "peer_controller", "peer_installed", "peer_solvers"]
