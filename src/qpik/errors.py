"""Exception types raised by qpik.

Every error a user can provoke with bad input derives from :class:`QpikError`, so
the command line can turn it into one line on stderr and exit code 2. Each also
derives from the built-in type a Python user would expect (``ValueError`` for bad
input, ``RuntimeError`` for a numerical failure).
"""

from __future__ import annotations


class QpikError(Exception):
    """Base class of every error qpik raises on purpose."""


class InvalidInput(QpikError, ValueError):
    """An argument has the wrong shape, type, or a non-finite value."""


class UnknownName(QpikError, ValueError):
    """An unknown robot, scenario, solver, site, joint or task name."""


class ModelError(QpikError, ValueError):
    """A missing or malformed MJCF model, or one that lacks what qpik needs."""


class UnreachablePose(QpikError, ValueError):
    """A target pose lies outside the workspace (no admissible joint solution)."""


class InfeasibleProblem(QpikError, RuntimeError):
    """The constraints of a QP (hard tasks and limits) cannot all be met.

    ``variable`` is the index of the variable whose bounds cross, when that is the cause.
    """

    def __init__(self, message: str, variable: int | None = None):
        super().__init__(message)
        self.variable = variable


class SolverError(QpikError, RuntimeError):
    """A QP solver failed or returned a non-finite solution."""


class ConvergenceError(QpikError, RuntimeError):
    """An iterative method (Newton, Gauss-Newton, ...) did not converge."""


class DivergenceError(QpikError, RuntimeError):
    """A controller produced a non-finite command (e.g. at a singularity)."""


class GainWarning(UserWarning):
    """A feedback gain K with K·Δt > 1: the task's error overshoots every control step."""


class OutsideJointLimits(ModelError):
    """A configuration outside the model's joint ranges (at load, from ``qpos0`` or a
    keyframe, or given to :meth:`~qpik.Robot.set_q`).

    ``excess`` maps each joint outside its range to how far (joint units, > 0). Start
    outside on purpose with ``allow_outside_limits=True``: a
    :class:`~qpik.JointPositionLimit` then brings the joints back.
    """

    def __init__(self, message: str, excess: dict[str, float] | None = None):
        super().__init__(message)
        self.excess = dict(excess or {})


class MissingExtra(QpikError, ImportError):
    """An optional dependency is not installed; the message names the extra that brings it
    (``pip install -e ".[extra]"`` from qpik's clone)."""


class InvalidWorlds(InvalidInput):
    """Bad input in some worlds of a batch (a NaN target, a configuration outside the
    limits): ``worlds`` lists them, ascending. Nothing was written."""

    def __init__(self, message: str, worlds):
        import numpy as np

        super().__init__(message)
        self.worlds = np.asarray(worlds, dtype=np.int64)


class WorldsFailed(QpikError, RuntimeError):
    """Some worlds of a batched step have no answer; the others were solved.

    Raised *after* every healthy world is solved, so that one bad world (an infeasible
    box, a diverging law) never stops the thousands of others.

    Attributes:
        worlds: the failing world ids, ascending (``int64`` array).
        reasons: world id → the typed error of that world (its message says why).
        qdot: ``(N, nv)``: the healthy worlds' answers, and **zero** velocity in the
            failing worlds (a safe value: never NaN).
    """

    def __init__(self, reasons: dict, qdot, what: str = "batched step"):
        import numpy as np

        self.reasons = dict(sorted(reasons.items()))
        self.worlds = np.array(list(self.reasons), dtype=np.int64)
        self.qdot = qdot
        shown = "; ".join(f"world {w}: {why}" for w, why in list(self.reasons.items())[:5])
        more = f"; and {len(self.reasons) - 5} more" if len(self.reasons) > 5 else ""
        super().__init__(f"{what}: {len(self.reasons)} of {len(qdot)} worlds failed "
                         f"(their velocity set to zero, the others solved) — {shown}{more}")


class HostStepWarning(UserWarning):
    """A step of a device back-end (Warp) runs on the host: a task or limit has no device
    function (the message names it). The answers are the same; the step is slower."""


MAX_WORLDS_LISTED = 8


def listed(worlds) -> str:
    """``worlds`` for a message: the first few ids, and how many more."""
    worlds = [int(w) for w in worlds]
    shown = ", ".join(map(str, worlds[:MAX_WORLDS_LISTED]))
    return shown + (f" and {len(worlds) - MAX_WORLDS_LISTED} more" if len(worlds) > MAX_WORLDS_LISTED else "")
