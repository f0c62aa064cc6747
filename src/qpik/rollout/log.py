"""The log of one rollout (time series) and its typed summary, the record of ``summary.json``.

What a run is (:class:`RunInfo`) and why it stopped early (:class:`RunStop`) are made
once by the rollout and shared, not copied, by its log and its summary; the tables, the
figures and ``compare.json`` read the summary's attributes. ``summary.json`` is the
summary's :meth:`RunSummary.to_json`, whose keys are a public contract.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping

import numpy as np

from .io import write_json, write_npz

# Report series where small is bad (a task slowed down): summarised by their minimum.
_LOWER_IS_WORSE = ("task_scale",)

# How a stopped run's row names its cause, by the error that stopped it.
_STOP_CAUSES = {"InfeasibleProblem": "infeasible", "SolverError": "solver failed",
                "DivergenceError": "diverged"}

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


@dataclass(frozen=True)
class RunInfo:
    """What a run is: the names its summary, tables, legends and file names give it."""

    robot: str
    controller: str
    solver: str
    scenario: str
    mode: str
    dt: float
    manipulability_measure: str = "sigma"


@dataclass(frozen=True)
class RunStop:
    """Why a run ended before its last step: the error's message and type, and the time
    of the step that failed (its log holds the steps before)."""

    failure: str
    failure_kind: str = ""
    stopped_at: float | None = None

    def describe(self) -> str:
        """``stopped at 0.056 s: infeasible``: the cell a table gives a stopped run."""
        cause = _STOP_CAUSES.get(self.failure_kind, "failed")
        when = self.stopped_at
        return f"stopped at {when:.3f} s: {cause}" if when is not None else f"stopped: {cause}"


@dataclass(frozen=True)
class LevelLog:
    """Per-level errors of a task hierarchy (steps x levels), measured for any controller."""

    names: tuple[str, ...]
    units: tuple[str, ...]
    error: np.ndarray


@dataclass
class RolloutLog:
    """Time series of one rollout; :meth:`summary` gives its metrics (``summary.json``).

    ``q`` is the configuration at time ``t`` (measured on the plant in physics mode);
    ``q_commanded[k]`` is the configuration the controller asked for at step k,
    q ⊕ q̇Δt, reached (or not: end stops, servos) at t + Δt; NaN at the last step.
    """

    info: RunInfo
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
    speed_dofs: np.ndarray | None = None  # dofs whose speed peak_joint_speed reports (None: all)
    stop: RunStop | None = None  # set when the run stopped early: its log is partial
    levels: LevelLog | None = None
    # The controller's own per-step numbers (its ``report()``), e.g. SNS's task scale.
    report: dict[str, np.ndarray] = field(default_factory=dict)
    # Whole-run numbers the reference computes (e.g. when a path was completed).
    reference_summary: dict = field(default_factory=dict)
    # Per step, the excursion of the commanded configuration alone (q ⊕ q̇Δt before the
    # end stops; 0 where no command was made): what a controller asked for, without
    # what a physics plant added. Not part of the summary or the saved log.
    commanded_violation: np.ndarray | None = None
    q_commanded: np.ndarray | None = None

    @property
    def completed(self) -> bool:
        return self.stop is None

    @property
    def failure(self) -> str:
        """Why the run stopped early ("" when it completed)."""
        return "" if self.stop is None else self.stop.failure

    def summary(self) -> RunSummary:
        """The run's metrics (``summary.json`` is its :meth:`RunSummary.to_json`)."""
        return RunSummary.of(self)

    def arrays(self) -> dict[str, np.ndarray]:
        data = dict(t=self.t, q=self.q, qdot=self.qdot, x=self.x, x_des=self.x_des, error=self.error,
                    manipulability=self.manipulability, step_time=self.step_time,
                    limit_violation=self.limit_violation)
        if self.q_commanded is not None:
            data["q_commanded"] = self.q_commanded
        data.update(self.extras)
        if self.levels is not None:
            data["level_error"] = self.levels.error
        data.update(self.report)
        # The log says itself whether it is whole: a stopped run's is partial.
        data["completed"] = np.array(self.completed)
        stopped_at = None if self.stop is None else self.stop.stopped_at
        data["stopped_at"] = np.array(np.nan if stopped_at is None else stopped_at)
        return data

    def save(self, out_dir: str | Path) -> None:
        """Write ``summary.json`` and ``log.npz`` (each whole, or not at all); a stopped
        run's are marked partial (``completed`` false, ``stopped_at`` its time)."""
        out_dir = Path(out_dir)
        write_npz(out_dir / "log.npz", **self.arrays())
        write_json(out_dir / "summary.json", self.summary().to_json())


@dataclass(frozen=True)
class LevelSummary:
    """Each priority level's largest and final error (a task hierarchy's runs)."""

    names: tuple[str, ...]
    units: tuple[str, ...]
    error_max: tuple[float, ...]
    error_final: tuple[float, ...]


# summary.json's keys for the fields of RunInfo, then the metrics, in the file's order.
_INFO_KEYS = ("robot", "controller", "solver", "scenario", "mode", "dt")
_METRIC_KEYS = ("steps", "max_error", "rms_error", "final_error")
_MEASURE_KEYS = ("manipulability_min", "manipulability_mean", "manipulability_final", "limit_violation_max",
                 "peak_joint_speed", "reversal_fraction", "step_time_median_us", "step_time_p99_us")
_LEVEL_KEYS = ("level_names", "level_units", "level_error_max", "level_error_final")
_STOP_KEYS = ("failure", "failure_kind", "stopped_at", "partial")


def _floats(values) -> tuple[float, ...]:
    return tuple(float(v) for v in values)


def _report(report: Mapping[str, np.ndarray]) -> dict[str, float | tuple[float, ...]]:
    """A controller's per-step report summarised, by summary.json key: the minimum of a
    series where small is bad (per level too), the maximum of the others."""
    out: dict[str, float | tuple[float, ...]] = {}
    for name, series in report.items():
        if name in _LOWER_IS_WORSE:  # per level; the primary (level 0) also on its own
            out[f"{name}_min"] = float(np.min(series[:, 0] if series.ndim == 2 else series))
            if series.ndim == 2:
                out[f"level_{name}_min"] = _floats(np.min(series, axis=0))
        else:
            peak = np.max(series, axis=0)
            out[f"{name}_max"] = _floats(peak) if np.ndim(peak) else float(peak)
    return out


def _plain(value):
    """A summary value as JSON writes it (tuples as lists)."""
    return list(value) if isinstance(value, tuple) else value


@dataclass(frozen=True)
class RunSummary:
    """The metrics of one run, as typed attributes; :meth:`to_json` is ``summary.json``.

    Attributes:
        info: what the run is (robot, controller, solver, scenario, mode, dt).
        steps: steps logged (fewer than planned when the run stopped early).
        max_error, rms_error, final_error: the tracking error ‖x_d − x‖.
        manipulability_min, manipulability_mean, manipulability_final: the measure
            ``info.manipulability_measure`` over the run.
        limit_violation_max: the largest excursion beyond the joint ranges the
            controller was given (measured or commanded configuration).
        peak_joint_speed: the largest commanded joint speed (of the scenario's joints).
        reversal_fraction: the fraction of steps on which a joint reverses at speed.
        step_time_median_us, step_time_p99_us: the control step's time.
        q_final: the last configuration.
        series_max: the largest value of each further series the reference measures
            (``orientation_error``, ``constraint_violation``, ``path_deviation``), by name.
        levels: each priority level's errors (a task hierarchy's scenarios), or None.
        report: the controller's own numbers, by their summary.json key (SNS's
            ``task_scale_min``, the hierarchy's ``level_residual_max``).
        reference: the reference's whole-run numbers (``completion_time``, None: never).
        stop: why the run stopped early, or None when it completed.
    """

    info: RunInfo
    steps: int
    max_error: float
    rms_error: float
    final_error: float
    manipulability_min: float
    manipulability_mean: float
    manipulability_final: float
    limit_violation_max: float
    peak_joint_speed: float
    reversal_fraction: float
    step_time_median_us: float
    step_time_p99_us: float
    q_final: tuple[float, ...]
    series_max: Mapping[str, float] = field(default_factory=dict)
    levels: LevelSummary | None = None
    report: Mapping[str, float | tuple[float, ...]] = field(default_factory=dict)
    reference: Mapping[str, object] = field(default_factory=dict)
    stop: RunStop | None = None

    @classmethod
    def of(cls, log: RolloutLog) -> RunSummary:
        """The summary of a log's steps."""
        err, st = log.error, log.step_time * 1e6
        speeds = log.qdot if log.speed_dofs is None else log.qdot[:, log.speed_dofs]
        levels = None
        if log.levels is not None:
            levels = LevelSummary(tuple(log.levels.names), tuple(log.levels.units),
                                  _floats(np.max(log.levels.error, axis=0)), _floats(log.levels.error[-1]))
        return cls(info=log.info, steps=int(len(log.t)), max_error=float(np.max(err)),
                   rms_error=float(np.sqrt(np.mean(err**2))), final_error=float(err[-1]),
                   manipulability_min=float(np.min(log.manipulability)),
                   manipulability_mean=float(np.mean(log.manipulability)),
                   manipulability_final=float(log.manipulability[-1]),
                   limit_violation_max=float(np.max(log.limit_violation)),
                   peak_joint_speed=float(np.max(np.abs(speeds))), reversal_fraction=reversal_fraction(log.qdot),
                   step_time_median_us=float(np.median(st)), step_time_p99_us=float(np.percentile(st, 99)),
                   q_final=_floats(log.q[-1]),
                   series_max={name: float(np.max(series)) for name, series in log.extras.items()},
                   levels=levels, report=_report(log.report), reference=dict(log.reference_summary), stop=log.stop)

    @property
    def completed(self) -> bool:
        return self.stop is None

    @property
    def status(self) -> str:
        """``complete``, or where and why the run stopped: ``stopped at 0.056 s: infeasible``."""
        return "complete" if self.stop is None else self.stop.describe()

    @property
    def orientation_error_max(self) -> float | None:
        """The largest orientation error [rad] (pose tasks: the hexapod), or None."""
        return self.series_max.get("orientation_error")

    @property
    def constraint_violation_max(self) -> float | None:
        """The largest loop-closure residual [m] (closed chains), or None."""
        return self.series_max.get("constraint_violation")

    @property
    def path_deviation_max(self) -> float | None:
        """The largest distance off the path [m] (path references), or None."""
        return self.series_max.get("path_deviation")

    @property
    def task_scale_min(self) -> float | None:
        """SNS's smallest task scale of the primary level, or None (other controllers)."""
        return self.report.get("task_scale_min")

    @property
    def completion_time(self) -> float | None:
        """When a path reference's end was reached and held [s], or None (never, or no
        such reference: ``"completion_time" in reference`` tells them apart)."""
        return self.reference.get("completion_time")

    def to_json(self) -> dict:
        """The ``summary.json`` record (plain Python types, its keys in the file's order)."""
        info = self.info
        out = {key: getattr(info, key) for key in _INFO_KEYS}
        out.update({key: getattr(self, key) for key in _METRIC_KEYS})
        out["manipulability_measure"] = info.manipulability_measure
        out.update({key: getattr(self, key) for key in _MEASURE_KEYS})
        out["q_final"] = list(self.q_final)
        out["completed"] = self.completed
        out.update({f"{name}_max": value for name, value in self.series_max.items()})
        if self.levels is not None:
            levels = self.levels
            out.update(zip(_LEVEL_KEYS, (list(levels.names), list(levels.units), list(levels.error_max),
                                         list(levels.error_final))))
        out.update({key: _plain(value) for key, value in self.report.items()})
        out.update(self.reference)
        if self.stop is not None:
            out.update(zip(_STOP_KEYS, (self.stop.failure, self.stop.failure_kind, self.stop.stopped_at, True)))
        out["status"] = self.status
        return out

    @classmethod
    def from_json(cls, record: Mapping) -> RunSummary:
        """A summary read back from its ``summary.json`` record (or a run of
        ``compare.json``): :meth:`to_json` gives the same keys and values back (a key
        it does not know is kept in ``reference``)."""
        info = RunInfo(*(record[key] for key in _INFO_KEYS), manipulability_measure=record["manipulability_measure"])
        fixed = {key: record[key] for key in (*_METRIC_KEYS, *_MEASURE_KEYS)}
        levels = None
        if "level_names" in record:
            levels = LevelSummary(*(tuple(record[key]) for key in _LEVEL_KEYS))
        stop = None
        if not record["completed"]:
            stop = RunStop(record.get("failure", ""), record.get("failure_kind", ""), record.get("stopped_at"))
        series, report, reference = {}, {}, {}
        known = {*_INFO_KEYS, *fixed, "manipulability_measure", "q_final", "completed", *_LEVEL_KEYS, *_STOP_KEYS,
                 "status"}
        for key, value in record.items():
            if key in known:
                continue
            if key == "task_scale_min" or key.startswith("level_"):
                report[key] = tuple(value) if isinstance(value, list) else value
            elif key.endswith("_max") and isinstance(value, float):
                series[key[: -len("_max")]] = value
            else:
                reference[key] = value
        return cls(info=info, **fixed, q_final=tuple(record["q_final"]), series_max=series, levels=levels,
                   report=report, reference=reference, stop=stop)
