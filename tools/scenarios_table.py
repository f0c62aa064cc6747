"""Every named scenario, qp (DAQP) beside the classical laws and the peers: the rows of
the scenarios table (recorded by ``python benchmarks/scenarios_table.py``, rendered on
docs/results.md by :mod:`tools.results`, recomputed by the tests).

A chaotic row (:data:`CHAOTIC`: its numbers depend on rounding, so on the CPU and the
BLAS kernel) is not given as one build's numbers: :func:`record_chaotic` runs it under
every OpenBLAS kernel this machine can load (``OPENBLAS_CORETYPE``, one subprocess
each), and the table prints the range over the recording.
"""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Sequence

from qpik.app.progress import iterate
from qpik.app.runs import compare, run, run_label
from qpik.rollout.io import write_json
from qpik.rollout.log import RunSummary
from qpik.scenario import build_scenario, scenarios

ROOT = Path(__file__).resolve().parents[1]  # the repository: tools/ is a package in it

PHYSICS = ("seed-redundant", "hexapod-circle")

# Below this an error, residual or violation is rounding (machine epsilon on metres and
# radians): exactly 0 on one CPU, 3e-16 on another. The table prints it as one class, 0.
ROUNDING = 1e-12

# Rows whose numbers depend on rounding: (scenario, mode, controller, solver), and why.
CHAOTIC = {
    ("hexapod-stroke-limits", "kinematic", "pinv", "none"):
        "the inverse-Jacobian law jams the mechanism (a slider held at its stop while the others "
        "move on; the strokes then admit no assembly for most steps), and where the platform "
        "ends up depends on rounding",
}
# The OpenBLAS kernels (OPENBLAS_CORETYPE) a chaotic row is run under; those this machine
# cannot load fall back to another and are counted once.
KERNELS = ("Haswell", "SkylakeX", "Zen", "Sandybridge")
# The summary attributes the table prints, with their format (the manipulability cell has two).
_METRICS = (("max_error", ".2e"), ("final_error", ".2e"), ("orientation_error_max", ".1e"),
            ("constraint_violation_max", ".1e"), ("limit_violation_max", ".2e"), ("peak_joint_speed", ".3g"),
            ("reversal_fraction", ".3f"), ("manipulability_mean", ".4f"), ("manipulability_final", ".4f"))


def format_cell(value: float | None, spec: str) -> str:
    """A number as the table prints it: "-" for none, "0" for rounding-level values."""
    if value is None:
        return "-"
    return "0" if abs(value) < ROUNDING else format(value, spec)


def _format_range(values, spec: str) -> str:
    """``lo–hi`` over the kernels (one value where they print alike)."""
    if any(v is None for v in values):
        return "-"
    low, high = format_cell(min(values), spec), format_cell(max(values), spec)
    return low if low == high else f"{low}–{high}"


def row_key(summary: RunSummary) -> tuple[str, str, str, str]:
    info = summary.info
    return info.scenario, info.mode, info.controller, info.solver


def chaotic_rows() -> list[dict]:
    """This process's run of every CHAOTIC row (summary.json records), with the OpenBLAS
    kernel it used."""
    from threadpoolctl import threadpool_info

    kernel = next((i.get("architecture") for i in threadpool_info() if i["internal_api"] == "openblas"), None)
    rows = []
    for scenario, mode, controller, solver in CHAOTIC:
        _, log = run(scenarios()[scenario].robot, scenario, controller, "daqp" if solver == "none" else solver, mode,
                     on_failure="stop")
        rows.append({**log.summary().to_json(), "kernel": kernel})
    return rows


def record_chaotic(path: Path) -> dict:
    """Run the CHAOTIC rows under each of KERNELS (a subprocess each) and record them in ``path``."""
    runs, kernels = [], []
    for kernel in KERNELS:
        path = os.pathsep.join(p for p in (str(ROOT), os.environ.get("PYTHONPATH")) if p)
        env = {**os.environ, "OPENBLAS_CORETYPE": kernel, "PYTHONPATH": path}
        done = subprocess.run([sys.executable, "-m", "tools.scenarios_table", "--chaotic-rows"], env=env,
                              capture_output=True, text=True, check=True)
        rows = json.loads(done.stdout.splitlines()[-1])
        if rows[0]["kernel"] in kernels:  # fell back to a kernel already run
            continue
        kernels.append(rows[0]["kernel"])
        runs += rows
    record = {"kernels": kernels, "why": {" / ".join(k): why for k, why in CHAOTIC.items()}, "runs": runs}
    write_json(path, record)
    return record


def load_chaotic(path: Path) -> dict:
    """The recording of :func:`record_chaotic`."""
    if not Path(path).exists():
        raise FileNotFoundError(f"{path} is missing: run python benchmarks/scenarios_table.py")
    return json.loads(Path(path).read_text())


def recorded_runs(chaotic: dict) -> list[tuple[str, RunSummary]]:
    """The recorded chaotic runs: each one's kernel and summary."""
    return [(r["kernel"], RunSummary.from_json({k: v for k, v in r.items() if k != "kernel"}))
            for r in chaotic["runs"]]


def compute_rows(progress: bool = False) -> list[RunSummary]:
    """The summaries of every row of the table: each scenario's comparison with DAQP, the
    physics runs of PHYSICS, and hexapod-position-only without its manipulability task."""
    rows = []
    for name, info in iterate(list(scenarios().items()), desc="scenarios", enabled=progress, unit="scenario"):
        _, logs, _ = compare(info.robot, name, ["daqp"])
        rows += [log.summary() for log in logs]
        if name in PHYSICS:
            rows.append(run(info.robot, name, "qp", "daqp", "physics")[1].summary())
        if name == "hexapod-position-only":  # the same run without the manipulability task
            summary = run(info.robot, name, "qp", "daqp", setup=build_scenario(name, k0=0.0))[1].summary()
            rows.append(dataclasses.replace(summary, info=dataclasses.replace(summary.info, controller="qp, k0 = 0")))
    return rows


def _cells(runs: Sequence[RunSummary]) -> list[str]:
    """A row's metric cells: one run's numbers, or the range over several (a chaotic row)."""
    cells = [_format_range([getattr(r, name) for r in runs], spec) for name, spec in _METRICS]
    return cells[:-2] + [f"{cells[-2]} / {cells[-1]}"]


def to_markdown(rows: Sequence[RunSummary], chaotic: dict | None = None) -> str:
    """The table; the CHAOTIC rows from ``chaotic`` (the record of record_chaotic) when given."""
    recorded = recorded_runs(chaotic) if chaotic is not None else []
    lines = ["| scenario | mode | controller | max error [m] | final error [m] | orientation error [rad] | "
             "loop residual [m] | limit violation | peak speed | reversals | manipulability (mean / final) | run |",
             "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---|"]
    for s in rows:
        ctrl = run_label(s.info.controller, s.info.solver)
        runs = [s]
        if chaotic is not None and row_key(s) in CHAOTIC:
            runs = [r for _, r in recorded if row_key(r) == row_key(s)]
            ctrl += f" (chaotic: range over {len(runs)} BLAS kernels)"
        status = sorted({r.status for r in runs})
        lines.append(f"| {s.info.scenario} | {s.info.mode} | {ctrl} | {' | '.join(_cells(runs))} | "
                     f"{'; '.join(status)} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":  # record_chaotic's child: one kernel's chaotic rows, as JSON
    if sys.argv[1:] == ["--chaotic-rows"]:
        print(json.dumps(chaotic_rows()))
