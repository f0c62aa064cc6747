"""The batched engine's errors (each a :class:`~qpik.errors.QpikError`)."""

from __future__ import annotations

import numpy as np

from ..errors import InvalidInput, QpikError


class NotBatched(QpikError, NotImplementedError):
    """A task, limit or model feature the batched engine does not run yet (it runs in the
    serial :mod:`qpik` controllers)."""


class WorldsFailed(QpikError, RuntimeError):
    """Some worlds of a batched step have no answer; the others were solved.

    Raised by a batched controller *after* every healthy world is solved, so that one
    bad world (a NaN target, an infeasible box) never stops the thousands of others.

    Attributes:
        worlds: the failing world ids, ascending (``int64`` array).
        reasons: world id → why it failed (one line).
        qdot: ``(N, nv)``: the healthy worlds' answers, and **zero** velocity in the
            failing worlds (a safe value: never NaN).
    """

    def __init__(self, reasons: dict[int, str], qdot: np.ndarray, what: str = "batched step"):
        self.reasons = dict(sorted(reasons.items()))
        self.worlds = np.array(list(self.reasons), dtype=np.int64)
        self.qdot = qdot
        shown = "; ".join(f"world {w}: {why}" for w, why in list(self.reasons.items())[:5])
        more = f"; and {len(self.reasons) - 5} more" if len(self.reasons) > 5 else ""
        super().__init__(f"{what}: {len(self.reasons)} of {len(qdot)} worlds failed "
                         f"(their velocity set to zero, the others solved) — {shown}{more}")


class InvalidWorlds(InvalidInput):
    """Bad input in some worlds (a configuration outside the limits, NaN): ``worlds`` lists
    them, ascending."""

    def __init__(self, message: str, worlds):
        super().__init__(message)
        self.worlds = np.asarray(worlds, dtype=np.int64)


class HostStepWarning(UserWarning):
    """``QPController.step`` on a device back-end runs on the host: a task or limit has
    no device kernel (the message names it). The answers are the same; the step is
    slower (the tasks' rows cross between device and host)."""
