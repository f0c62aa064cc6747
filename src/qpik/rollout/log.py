"""The log of one rollout: time series, and the summary metrics computed from them."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..io import write_json, write_npz


# Report series where small is bad (a task slowed down): summarised by their minimum.
_LOWER_IS_WORSE = ("task_scale",)

# How a stopped run's row names its cause, by the error that stopped it.
_STOP_CAUSES = {"InfeasibleProblem": "infeasible", "SolverError": "solver failed",
                "DivergenceError": "diverged"}


def run_status(summary: dict) -> str:
    """``complete``, or where and why the run stopped: ``stopped at 0.056 s: infeasible``
    (the cell a table gives a run, from its summary)."""
    if summary.get("completed", True):
        return "complete"
    cause = _STOP_CAUSES.get(summary.get("failure_kind", ""), "failed")
    when = summary.get("stopped_at")
    return f"stopped at {when:.3f} s: {cause}" if when is not None else f"stopped: {cause}"


# A joint "reverses" on a step when its commanded velocity changes sign with at least this
# magnitude (rad/s or m/s) on both sides: chatter, not a joint turning round smoothly.
REVERSAL_SPEED = 1.0


def reversal_fraction(qdot: np.ndarray, speed: float = REVERSAL_SPEED) -> float:
    """The fraction of steps (after the first) on which any joint's velocity changes sign
    with magnitude above ``speed`` before and after."""
    if len(qdot) < 2:
        return 0.0
    before, after = qdot[:-1], qdot[1:]
    flips = (before * after < 0.0) & (np.abs(before) > speed) & (np.abs(after) > speed)
    return float(np.mean(flips.any(axis=1)))


@dataclass
class RolloutLog:
    """Time series of one rollout; ``summary()`` gives the metrics of ``summary.json``.

    ``q`` is the configuration at time ``t`` (measured on the plant in physics mode);
    ``q_commanded[k]`` is the configuration the controller asked for at step k,
    q ⊕ q̇Δt, reached (or not: end stops, servos) at t + Δt; NaN at the last step.
    """

    robot: str
    controller: str
    solver: str
    scenario: str
    mode: str
    dt: float
    t: np.ndarray
    q: np.ndarray
    qdot: np.ndarray
    x: np.ndarray
    x_des: np.ndarray
    error: np.ndarray
    manipulability: np.ndarray
    step_time: np.ndarray
    limit_violation: np.ndarray
    extras: dict[str, np.ndarray] = field(default_factory=dict)
    manipulability_measure: str = "sigma"
    speed_dofs: np.ndarray | None = None  # dofs whose speed peak_joint_speed reports (None: all)
    completed: bool = True
    failure: str = ""
    # A run that stopped early: the time of the step that failed and the error's type.
    # Its log holds the steps before it (a partial log, marked so in summary and npz).
    stopped_at: float | None = None
    failure_kind: str = ""
    # Per-level errors of a task hierarchy (steps x levels), measured for any controller.
    level_error: np.ndarray | None = None
    level_names: tuple[str, ...] = ()
    level_units: tuple[str, ...] = ()
    # The controller's own per-step numbers (its ``report()``), e.g. SNS's task scale.
    report: dict[str, np.ndarray] = field(default_factory=dict)
    # Whole-run numbers the reference computes (e.g. when a path was completed).
    summary_extras: dict = field(default_factory=dict)
    # Per step, the excursion of the commanded configuration alone (q ⊕ q̇Δt before the
    # end stops; 0 where no command was made): what a controller asked for, without
    # what a physics plant added. Not part of the summary or the saved log.
    commanded_violation: np.ndarray | None = None
    q_commanded: np.ndarray | None = None

    def summary(self) -> dict:
        """The summary.json record (plain Python types)."""
        err = self.error
        st = self.step_time * 1e6
        out = {
            "robot": self.robot,
            "controller": self.controller,
            "solver": self.solver,
            "scenario": self.scenario,
            "mode": self.mode,
            "dt": self.dt,
            "steps": int(len(self.t)),
            "max_error": float(np.max(err)),
            "rms_error": float(np.sqrt(np.mean(err**2))),
            "final_error": float(err[-1]),
            "manipulability_measure": self.manipulability_measure,
            "manipulability_min": float(np.min(self.manipulability)),
            "manipulability_mean": float(np.mean(self.manipulability)),
            "manipulability_final": float(self.manipulability[-1]),
            "limit_violation_max": float(np.max(self.limit_violation)),
            "peak_joint_speed": float(np.max(np.abs(self.qdot if self.speed_dofs is None
                                                     else self.qdot[:, self.speed_dofs]))),
            "reversal_fraction": reversal_fraction(self.qdot),
            "step_time_median_us": float(np.median(st)),
            "step_time_p99_us": float(np.percentile(st, 99)),
            "q_final": [float(v) for v in self.q[-1]],
            "completed": self.completed,
        }
        for name, series in self.extras.items():
            out[f"{name}_max"] = float(np.max(series))
        if self.level_error is not None:
            out["level_names"] = list(self.level_names)
            out["level_units"] = list(self.level_units)
            out["level_error_max"] = [float(v) for v in np.max(self.level_error, axis=0)]
            out["level_error_final"] = [float(v) for v in self.level_error[-1]]
        for name, series in self.report.items():
            if name in _LOWER_IS_WORSE:  # per level; the primary (level 0) also on its own
                out[f"{name}_min"] = float(np.min(series[:, 0] if series.ndim == 2 else series))
                if series.ndim == 2:
                    out[f"level_{name}_min"] = [float(v) for v in np.min(series, axis=0)]
            else:
                peak = np.max(series, axis=0)
                out[f"{name}_max"] = [float(v) for v in peak] if np.ndim(peak) else float(peak)
        out.update(self.summary_extras)
        if not self.completed:
            out.update(failure=self.failure, failure_kind=self.failure_kind, stopped_at=self.stopped_at,
                       partial=True)
        out["status"] = run_status(out)
        return out

    def arrays(self) -> dict[str, np.ndarray]:
        data = dict(t=self.t, q=self.q, qdot=self.qdot, x=self.x, x_des=self.x_des, error=self.error,
                    manipulability=self.manipulability, step_time=self.step_time,
                    limit_violation=self.limit_violation)
        if self.q_commanded is not None:
            data["q_commanded"] = self.q_commanded
        data.update(self.extras)
        if self.level_error is not None:
            data["level_error"] = self.level_error
        data.update(self.report)
        # The log says itself whether it is whole: a stopped run's is partial.
        data["completed"] = np.array(self.completed)
        data["stopped_at"] = np.array(np.nan if self.stopped_at is None else self.stopped_at)
        return data

    def save(self, out_dir: str | Path) -> None:
        """Write ``summary.json`` and ``log.npz`` (each whole, or not at all); a stopped
        run's are marked partial (``completed`` false, ``stopped_at`` its time)."""
        out_dir = Path(out_dir)
        write_npz(out_dir / "log.npz", **self.arrays())
        write_json(out_dir / "summary.json", self.summary())
