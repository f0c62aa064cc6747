"""What only the batch front end raises (the errors it shares with one robot live in
:mod:`qpik.errors`: :class:`~qpik.errors.WorldsFailed`, :class:`~qpik.errors.InvalidWorlds`)."""

from __future__ import annotations

from ..errors import QpikError


class NotBatched(QpikError, NotImplementedError):
    """A model feature a batch back-end cannot compute for N worlds yet (an equality type
    without rows on the CPU back-end, a model MuJoCo Warp cannot load); the message says
    which, and what runs it (one world: :class:`qpik.Robot`)."""
