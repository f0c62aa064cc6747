"""Running scenarios: one controller (``qpik run``) or all of them side by side
(``qpik compare``), with their tables and output files. The peer libraries (mink,
placo) run as controllers too, when installed (:mod:`qpik.app.peers`)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

from ..errors import InvalidInput, UnknownName
from ..rollout.io import write_json
from ..rollout import MODES, Rollout, RolloutLog
from ..rollout.log import RunSummary
from ..scenario import Setup, build_scenario, check_solver
from ..solvers import available_solvers
from .kinds import OFFERED_KINDS, PEER_KINDS, uses_solver
from .peers import PeerUnsupported, peer_controller, peer_installed, peer_solvers

StepProgress = Callable[[int, int], None]


def start_run(robot: str | None = None, scenario: str | None = None, controller: str = "qp", solver: str = "daqp",
              mode: str = "kinematic", on_failure: str = "raise", setup: Setup | None = None,
              progress: StepProgress | None = None) -> tuple[Setup, Rollout]:
    """Build the scenario and one controller on it: the rollout, not yet advanced
    (arguments as :func:`run`)."""
    if mode not in MODES:
        raise InvalidInput(f"unknown mode {mode!r}; expected one of {', '.join(MODES)}")
    if uses_solver(controller):
        check_solver(solver)
    if setup is None:
        if scenario is None:
            raise InvalidInput("run() needs a scenario name or a setup")
        setup = build_scenario(scenario, robot)
    elif setup.rolled_out:
        raise InvalidInput(f"this setup of {setup.scenario!r} was already run: its robot and "
                           "references are at that run's final state. Build a fresh setup per run "
                           "(call the scenario's or arm_setup()'s constructor again)")
    known = [*setup.controller_kinds(), *PEER_KINDS]
    if controller not in known:
        raise UnknownName(f"unknown controller {controller!r} for {setup.scenario}; choose from {', '.join(known)}")
    setup.rolled_out = True
    ctrl = peer_controller(controller, setup, solver) if controller in PEER_KINDS else setup.controller(controller, solver)
    return setup, setup.rollout(ctrl, mode=mode, on_failure=on_failure, progress=progress, scenario=scenario)


def run(robot: str | None = None, scenario: str | None = None, controller: str = "qp", solver: str = "daqp",
        mode: str = "kinematic", on_failure: str = "raise", setup: Setup | None = None,
        progress: StepProgress | None = None) -> tuple[Setup, RolloutLog]:
    """Roll one controller out on a scenario; returns the setup and the log.

    Args:
        robot: ``"arm"``, ``"hexapod"`` or an MJCF path (see :func:`qpik.build_scenario`);
            with ``setup``, only a label (default: the setup's robot).
        scenario: a registered scenario name; with ``setup``, only the log's label.
        controller: ``qp``, a controller the scenario offers (``qp-hard``, ``hqp``,
            ``sns``, ``pinv``, ``jt``) or a peer (``mink``, ``placo``).
        solver: the QP solver of ``qp``, ``qp-hard``, ``hqp`` and ``mink``.
        mode: ``kinematic`` or ``physics`` (see :func:`qpik.simulate`).
        on_failure: ``raise`` a controller failure, or ``stop`` the rollout and keep the log.
        setup: a fresh :class:`~qpik.scenario.Setup` to run instead of building the named
            scenario, e.g. ``arm_setup("mine", Circle(...), redundant=True)``. A setup
            holds the robot's state, so it runs once: a second run would start from the
            first one's final state, and is refused.
        progress: called as ``progress(k, steps)`` after each step.

    Raises:
        InvalidInput: a used setup, an unknown mode, neither scenario nor setup.
        UnknownName: unknown robot, scenario, controller or solver.
    """
    setup, rollout = start_run(robot, scenario, controller, solver, mode, on_failure, setup, progress)
    rollout.advance()
    return setup, rollout.log()


def run_label(controller: str, solver: str) -> str:
    """``qp (daqp)``, ``pinv``: how tables, legends and progress bars name a run."""
    return controller if solver in ("none", "", None) else f"{controller} ({solver})"


def compare(robot: str, scenario: str, solvers: Sequence[str] | None = None, mode: str = "kinematic",
            classical: Sequence[str] = OFFERED_KINDS, peers: Sequence[str] = PEER_KINDS,
            progress: Callable[[str, int, int], None] | None = None) -> tuple[Setup, list[RolloutLog], list[str]]:
    """qp with each solver, the other controllers the scenario offers among ``classical``
    (qp-hard, hqp, sns, pinv, jt), then the peers (mink with each solver, placo with its
    own), each on its own fresh setup of the scenario.

    A controller that fails mid-run (an infeasible QP, a singular pseudoinverse) is
    kept with ``completed = False`` and the reason, so the table can say why.
    ``progress(label, k, steps)`` is called after each step of each run.
    Returns the last setup, the logs and notes (e.g. skipped peers).

    Raises:
        InvalidInput: a solver listed twice. UnknownName: an unknown robot, scenario or solver.
    """
    solvers = list(solvers) if solvers else available_solvers()
    repeated = sorted({s for s in solvers if solvers.count(s) > 1})
    if repeated:  # each would run (and show) twice, the same run
        raise InvalidInput(f"solvers listed more than once: {', '.join(repeated)}")
    for solver in solvers:
        check_solver(solver)
    runs = _Comparison(robot, scenario, mode, progress)
    for solver in solvers:
        runs.run("qp", solver)
    for kind in classical:
        probe = build_scenario(scenario, robot)
        if kind in probe.controller_kinds():
            runs.run(kind, solvers[0] if uses_solver(kind) else "none", setup=probe)
    for kind in peers:
        runs.run_peer(kind, solvers)
    return runs.setup, runs.logs, runs.notes


class _Comparison:
    """The runs of one :func:`compare`: each run's log, the last setup, the notes."""

    def __init__(self, robot: str, scenario: str, mode: str, progress: Callable[[str, int, int], None] | None):
        self.robot, self.scenario, self.mode, self.progress = robot, scenario, mode, progress
        self.setup: Setup | None = None
        self.logs: list[RolloutLog] = []
        self.notes: list[str] = []

    def run(self, controller: str, solver: str, setup: Setup | None = None) -> None:
        self.setup, log = run(self.robot, self.scenario, controller, solver, self.mode, on_failure="stop",
                              setup=setup, progress=self._step_progress(run_label(controller, solver)))
        self.logs.append(log)

    def _step_progress(self, label: str) -> StepProgress | None:
        """``progress(label, k, steps)`` as a run's ``progress(k, steps)``."""
        progress = self.progress
        if progress is None:
            return None

        def step(k: int, steps: int) -> None:
            progress(label, k, steps)

        return step

    def run_peer(self, kind: str, solvers: Sequence[str]) -> None:
        if not peer_installed(kind):
            self.notes.append(f"{kind} not installed: skipped")
            return
        for solver in peer_solvers(kind, solvers):
            try:
                self.run(kind, solver)
            except PeerUnsupported as exc:
                self.notes.append(f"{kind} skipped: {exc}")
                return


@dataclass(frozen=True)
class Column:
    """A column of :func:`format_table`: its header and each run's cell."""

    label: str
    cell: Callable[[RunSummary], str]
    left: bool = False  # text, left-aligned


def _number(label: str, value: Callable[[RunSummary], float | None], spec: str) -> Column:
    """A column of numbers formatted with ``spec``; "-" where a run has none."""
    return Column(label, lambda s: "-" if (v := value(s)) is None else format(v, spec))


def _level_cell(summary: RunSummary, i: int) -> str:
    levels = summary.levels
    return "-" if levels is None or i >= len(levels.error_max) else format(levels.error_max[i], ".2e")


def _completion_cell(summary: RunSummary) -> str:
    """When the path was completed (a path reference's scenarios): "never", or "-"."""
    if "completion_time" not in summary.reference:
        return "-"
    time = summary.completion_time
    return "never" if time is None else format(time, ".3f")


def _columns(summaries: Sequence[RunSummary]) -> list[Column]:
    """The table's columns: those every run has, and those some runs have (each
    level's error, the loop residual, the orientation error, SNS's task scale, ...)."""
    columns = [Column("controller", lambda s: s.info.controller, left=True),
               Column("solver", lambda s: s.info.solver, left=True),
               _number("max err [m]", lambda s: s.max_error, ".2e"),
               _number("final err [m]", lambda s: s.final_error, ".2e")]
    levels = next((s.levels for s in summaries if s.levels is not None), None)
    if levels is not None:  # a task hierarchy: each level's error
        columns += [Column(f"L{i} {name} [{unit}]", lambda s, i=i: _level_cell(s, i))
                    for i, (name, unit) in enumerate(zip(levels.names, levels.units))]
    optional = [_number("loop resid. [m]", lambda s: s.constraint_violation_max, ".2e"),
                _number("orient. err [rad]", lambda s: s.orientation_error_max, ".2e")]
    columns += [c for c in optional if any(c.cell(s) != "-" for s in summaries)]
    columns += [_number("limit viol.", lambda s: s.limit_violation_max, ".2e"),
                _number("peak |q̇|", lambda s: s.peak_joint_speed, ".3g"),
                _number("manip. final", lambda s: s.manipulability_final, ".4f"),
                _number("step med [µs]", lambda s: s.step_time_median_us, ".1f"),
                _number("step p99 [µs]", lambda s: s.step_time_p99_us, ".1f")]
    optional = [_number("task scale min", lambda s: s.task_scale_min, ".3f"),
                _number("off path [m]", lambda s: s.path_deviation_max, ".2e"),
                Column("done at [s]", _completion_cell)]
    columns += [c for c in optional if any(c.cell(s) != "-" for s in summaries)]
    # Each row says whether its run went to the end: a stopped run's numbers cover only
    # the steps before it stopped.
    return columns + [Column("run", lambda s: s.status, left=True)]


def format_table(summaries: Sequence[RunSummary]) -> str:
    """A plain-text table of summaries, one row per run; failed runs say why."""
    columns = _columns(summaries)
    rows = [[c.label for c in columns]] + [[c.cell(s) for c in columns] for s in summaries]
    widths = [max(len(r[i]) for r in rows) for i in range(len(columns))]
    lines = ["  ".join(cell.ljust(w) if c.left else cell.rjust(w) for c, cell, w in zip(columns, r, widths)).rstrip()
             for r in rows]
    lines.insert(1, "  ".join("-" * w for w in widths))
    for s in summaries:
        if s.stop is not None:
            lines.append(f"note: {run_label(s.info.controller, s.info.solver)} {s.status} (its numbers cover "
                         f"the steps before): {s.stop.failure}")
    return "\n".join(lines)


def write_compare(out_dir: str | Path, robot: str, scenario: str, summaries: Sequence[RunSummary], mode: str) -> Path:
    """Write ``compare.json`` (robot, scenario, mode and every run's summary) into ``out_dir``."""
    path = Path(out_dir) / "compare.json"
    write_json(path, {"robot": robot, "scenario": scenario, "mode": mode, "runs": [s.to_json() for s in summaries]})
    return path


def level_note(summaries: Sequence[RunSummary], mode: str) -> str | None:
    """What the level columns measure beside ``max err``, where the two differ (physics mode):
    a line to print under the table, or None."""
    levels = next((s.levels for s in summaries if s.levels is not None and s.levels.names), None)
    if levels is None or mode != "physics":
        return None
    columns = ", ".join(f"L{i} {name}" for i, name in enumerate(levels.names))
    return (f"note: {columns}: each priority level's error on the controller's own model, at the "
            "configuration it commands; max err and final err: the simulated robot, which the servos "
            "move after the command (the gap is their lag)")
