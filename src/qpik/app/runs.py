"""Running scenarios: one controller (``qpik run``) or all of them side by side
(``qpik compare``), with their tables and output files. The peer libraries (mink,
placo) run as controllers too, when installed (:mod:`qpik.app.peers`)."""

from __future__ import annotations

from pathlib import Path
from typing import Callable, Sequence

from ..errors import InvalidInput, UnknownName
from ..io import write_json
from .peers import PEERS, PeerUnsupported, peer_controller, peer_installed, peer_solvers
from ..rollout import MODES, Rollout, RolloutLog
from ..rollout.log import run_status
from ..scenario import Setup, build_scenario, check_solver
from ..solvers import available_solvers

CLASSICAL_KINDS = ("pinv", "jt")
# Controllers a scenario may offer besides qp: a variant with hard tasks, the strict
# hierarchy and SNS (each run once, hqp and qp-hard with the first solver asked for).
HIERARCHY_KINDS = ("qp-hard", "hqp", "sns")
QP_KINDS = ("qp", "mink", "qp-hard", "hqp")  # the controllers that take a QP solver name

StepProgress = Callable[[int, int], None]


def start_run(robot: str | None = None, scenario: str | None = None, controller: str = "qp", solver: str = "daqp",
              mode: str = "kinematic", on_failure: str = "raise", setup: Setup | None = None,
              progress: StepProgress | None = None) -> tuple[Setup, Rollout]:
    """Build the scenario and one controller on it: the rollout, not yet advanced
    (arguments as :func:`run`)."""
    if mode not in MODES:
        raise InvalidInput(f"unknown mode {mode!r}; expected one of {', '.join(MODES)}")
    if controller in QP_KINDS:
        check_solver(solver)
    if setup is None:
        if scenario is None:
            raise InvalidInput("run() needs a scenario name or a setup")
        setup = build_scenario(scenario, robot)
    elif setup.rolled_out:
        raise InvalidInput(f"this setup of {setup.scenario!r} was already run: its robot and "
                           "references are at that run's final state. Build a fresh setup per run "
                           "(call the scenario's or arm_setup()'s constructor again)")
    known = [*setup.controller_kinds(), *PEERS]
    if controller not in known:
        raise UnknownName(f"unknown controller {controller!r} for {setup.scenario}; choose from {', '.join(known)}")
    setup.rolled_out = True
    ctrl = peer_controller(controller, setup, solver) if controller in PEERS else setup.controller(controller, solver)
    rollout = Rollout(ctrl, setup.reference, setup.duration, dt=setup.dt, mode=mode,
                      manipulability=setup.manipulability, manipulability_measure=setup.manipulability_measure,
                      joint_limits=setup.joint_limits, scenario=scenario or setup.scenario,
                      robot_name=setup.robot_name, on_failure=on_failure, closure=setup.closure,
                      speed_dofs=setup.plot_joints.dof_index, progress=progress, levels=setup.level_errors)
    return setup, rollout


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
            classical: Sequence[str] = HIERARCHY_KINDS + CLASSICAL_KINDS, peers: Sequence[str] = PEERS,
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
    logs, notes = [], []
    setup = None

    def step_progress(controller: str, solver: str) -> StepProgress | None:
        if progress is None:
            return None
        label = run_label(controller, solver)
        return lambda k, steps: progress(label, k, steps)

    for solver in solvers:
        setup, log = run(robot, scenario, "qp", solver, mode, on_failure="stop",
                         progress=step_progress("qp", solver))
        logs.append(log)
    for kind in classical:
        probe = build_scenario(scenario, robot)
        if kind not in probe.controller_kinds():
            continue
        solver = solvers[0] if kind in QP_KINDS else "none"
        setup, log = run(robot, scenario, kind, solver, mode, on_failure="stop", setup=probe,
                         progress=step_progress(kind, solver))
        logs.append(log)
    for kind in peers:
        if not peer_installed(kind):
            notes.append(f"{kind} not installed: skipped")
            continue
        for solver in peer_solvers(kind, solvers):
            try:
                setup, log = run(robot, scenario, kind, solver, mode, on_failure="stop",
                                 progress=step_progress(kind, solver))
            except PeerUnsupported as exc:
                notes.append(f"{kind} skipped: {exc}")
                break
            logs.append(log)
    return setup, logs, notes


_COLUMNS = (
    ("controller", "controller", "{}"),
    ("solver", "solver", "{}"),
    ("max_error", "max err [m]", "{:.2e}"),
    ("final_error", "final err [m]", "{:.2e}"),
    ("limit_violation_max", "limit viol.", "{:.2e}"),
    ("peak_joint_speed", "peak |q̇|", "{:.3g}"),
    ("manipulability_final", "manip. final", "{:.4f}"),
    ("step_time_median_us", "step med [µs]", "{:.1f}"),
    ("step_time_p99_us", "step p99 [µs]", "{:.1f}"),
)


def format_table(summaries: Sequence[dict], extra: Sequence[tuple[str, str, str]] = ()) -> str:
    """A plain-text table of summaries, one row per run; failed runs say why."""
    columns = list(_COLUMNS) + list(extra)
    for key, label, fmt in (("orientation_error_max", "orient. err [rad]", "{:.2e}"),
                            ("constraint_violation_max", "loop resid. [m]", "{:.2e}")):
        if any(key in s for s in summaries) and key not in [c[0] for c in columns]:
            columns.insert(4, (key, label, fmt))
    summaries = [_flatten_levels(s) for s in summaries]
    levelled = next((s for s in summaries if "level_names" in s), None)
    if levelled is not None:  # a task hierarchy: each level's error, then SNS's task scale
        for i, (name, unit) in enumerate(zip(levelled["level_names"], levelled["level_units"])):
            columns.insert(4 + i, (f"level_error_max[{i}]", f"L{i} {name} [{unit}]", "{:.2e}"))
    for key, label, fmt in (("task_scale_min", "task scale min", "{:.3f}"),
                            ("path_deviation_max", "off path [m]", "{:.2e}"),
                            ("completion_time", "done at [s]", "{:.3f}")):
        if any(key in s for s in summaries):
            columns.append((key, label, fmt))
    # Each row says whether its run went to the end: a stopped run's numbers cover only
    # the steps before it stopped.
    columns.append(("status", "run", "{}"))
    rows = [[label for _, label, _ in columns]]
    for s in summaries:
        s = {**s, "status": run_status(s)}
        rows.append([("never" if s[key] is None else fmt.format(s[key])) if key in s else "-"
                     for key, _, fmt in columns])
    widths = [max(len(r[i]) for r in rows) for i in range(len(columns))]
    text = {0, 1, len(columns) - 1}  # left-aligned: controller, solver, run
    lines = ["  ".join(cell.ljust(w) if i in text else cell.rjust(w) for i, (cell, w) in enumerate(zip(r, widths)))
             .rstrip() for r in rows]
    lines.insert(1, "  ".join("-" * w for w in widths))
    for s in summaries:
        if not s.get("completed", True):
            lines.append(f"note: {run_label(s['controller'], s['solver'])} {run_status(s)} (its numbers cover "
                         f"the steps before): {s.get('failure', '')}")
    return "\n".join(lines)


def _flatten_levels(summary: dict) -> dict:
    """The per-level list ``level_error_max`` as keys ``level_error_max[i]`` (table cells)."""
    flat = dict(summary)
    for i, value in enumerate(summary.get("level_error_max", [])):
        flat[f"level_error_max[{i}]"] = value
    return flat


def write_compare(out_dir: str | Path, robot: str, scenario: str, summaries: Sequence[dict], mode: str) -> Path:
    """Write ``compare.json`` (robot, scenario, mode and every run's summary) into ``out_dir``."""
    path = Path(out_dir) / "compare.json"
    write_json(path, {"robot": robot, "scenario": scenario, "mode": mode, "runs": list(summaries)})
    return path


def level_note(summaries: Sequence[dict], mode: str) -> str | None:
    """What the level columns measure beside ``max err``, where the two differ (physics mode):
    a line to print under the table, or None."""
    levelled = next((s for s in summaries if s.get("level_names")), None)
    if levelled is None or mode != "physics":
        return None
    columns = ", ".join(f"L{i} {name}" for i, name in enumerate(levelled["level_names"]))
    return (f"note: {columns}: each priority level's error on the controller's own model, at the "
            "configuration it commands; max err and final err: the simulated robot, which the servos "
            "move after the command (the gap is their lag)")
