"""Every named scenario, qp (DAQP) beside the classical laws and the peers: the README's results table.

    python benchmarks/scenarios_table.py           # run, write the table into README.md and results/
    python benchmarks/scenarios_table.py --check   # run, compare with README.md cell by cell

writes benchmarks/results/scenarios.md and scenarios.json (tracking numbers; the step
times in them are single runs — for timing use step_time.py / compare_peers.py) and the
README block ``<!-- table:scenarios -->``. ``--check`` exits 1, naming every cell where
the README differs from what the code gives on the installed versions (numbers compared
to one unit in their last printed digit, readme_tables.cells_agree). About 30 s.

A chaotic row (``CHAOTIC``: its numbers depend on rounding, so on the CPU and the BLAS
kernel) is not given as one build's numbers: the script runs it under every OpenBLAS
kernel this machine can load (``OPENBLAS_CORETYPE``, one subprocess each), records what
each gave in results/scenarios_chaotic.json and prints the range. ``--check`` compares
that row with the recording.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

from qpik.app.progress import iterate, wanted
from qpik.app.runs import compare, run
from qpik.io import write_json, write_text
from qpik.rollout.log import RunSummary
from qpik.scenario import build_scenario, scenarios

RESULTS = Path(__file__).resolve().parent / "results"
PHYSICS = ("seed-redundant", "hexapod-circle")


CHAOTIC_RECORD = RESULTS / "scenarios_chaotic.json"

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
# The summary keys the table prints, with their format (the manipulability cell has two).
_METRICS = (("max_error", ".2e"), ("final_error", ".2e"), ("orientation_error_max", ".1e"),
            ("constraint_violation_max", ".1e"), ("limit_violation_max", ".2e"), ("peak_joint_speed", ".3g"),
            ("reversal_fraction", ".3f"), ("manipulability_mean", ".4f"), ("manipulability_final", ".4f"))


def _fmt(value, spec: str) -> str:
    if value is None:
        return "-"
    return "0" if abs(value) < ROUNDING else format(value, spec)


def _fmt_range(values, spec: str) -> str:
    """``lo–hi`` over the kernels (one value where they print alike)."""
    if any(v is None for v in values):
        return "-"
    low, high = _fmt(min(values), spec), _fmt(max(values), spec)
    return low if low == high else f"{low}–{high}"


def row_key(summary: dict) -> tuple[str, str, str, str]:
    return summary["scenario"], summary["mode"], summary["controller"], summary["solver"]


def chaotic_rows() -> list[dict]:
    """This process's run of every CHAOTIC row, with the OpenBLAS kernel it used."""
    from threadpoolctl import threadpool_info

    from qpik.scenario import scenarios as registry

    kernel = next((i.get("architecture") for i in threadpool_info() if i["internal_api"] == "openblas"), None)
    rows = []
    for scenario, mode, controller, solver in CHAOTIC:
        _, log = run(registry()[scenario].robot, scenario, controller, "daqp" if solver == "none" else solver, mode,
                     on_failure="stop")
        rows.append({**log.summary().to_json(), "kernel": kernel})
    return rows


def record_chaotic(path: Path = CHAOTIC_RECORD) -> dict:
    """Run the CHAOTIC rows under each of KERNELS (a subprocess each) and record them."""
    runs, kernels = [], []
    for kernel in KERNELS:
        env = {**os.environ, "OPENBLAS_CORETYPE": kernel}
        done = subprocess.run([sys.executable, __file__, "--chaotic-rows"], env=env, capture_output=True,
                              text=True, check=True)
        rows = json.loads(done.stdout.splitlines()[-1])
        if rows[0]["kernel"] in kernels:  # fell back to a kernel already run
            continue
        kernels.append(rows[0]["kernel"])
        runs += rows
    record = {"kernels": kernels, "why": {" / ".join(k): why for k, why in CHAOTIC.items()}, "runs": runs}
    write_json(path, record)
    return record


def load_chaotic(path: Path = CHAOTIC_RECORD) -> dict:
    if not path.exists():
        raise FileNotFoundError(f"{path} is missing: run python benchmarks/scenarios_table.py")
    return json.loads(path.read_text())


def compute_rows(progress: bool = False) -> list[dict]:
    """The summaries of every row of the table: each scenario's comparison with DAQP, the
    physics runs of PHYSICS, and hexapod-position-only without its manipulability task."""
    rows = []
    for name, info in iterate(list(scenarios().items()), desc="scenarios", enabled=progress, unit="scenario"):
        _, logs, _ = compare(info.robot, name, ["daqp"])
        rows += [log.summary().to_json() for log in logs]
        if name in PHYSICS:
            rows.append(run(info.robot, name, "qp", "daqp", "physics")[1].summary().to_json())
        if name == "hexapod-position-only":  # the same run without the manipulability task
            summary = run(info.robot, name, "qp", "daqp", setup=build_scenario(name, k0=0.0))[1].summary().to_json()
            rows.append({**summary, "controller": "qp, k0 = 0"})
    return rows


def _cells(runs: list[dict]) -> list[str]:
    """A row's metric cells: one run's numbers, or the range over several (a chaotic row)."""
    cells = [_fmt_range([r.get(key) for r in runs], spec) for key, spec in _METRICS]
    return cells[:-2] + [f"{cells[-2]} / {cells[-1]}"]


def to_markdown(rows: list[dict], chaotic: dict | None = None) -> str:
    """The table; the CHAOTIC rows from ``chaotic`` (the record of record_chaotic) when given."""
    lines = ["| scenario | mode | controller | max error [m] | final error [m] | orientation error [rad] | "
             "loop residual [m] | limit violation | peak speed | reversals | manipulability (mean / final) | run |",
             "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---|"]
    for s in rows:
        ctrl = s["controller"] if s["solver"] == "none" else f"{s['controller']} ({s['solver']})"
        runs = [s]
        if chaotic is not None and row_key(s) in CHAOTIC:
            runs = [r for r in chaotic["runs"] if row_key(r) == row_key(s)]
            ctrl += f" (chaotic: range over {len(runs)} BLAS kernels)"
        status = sorted({RunSummary.from_json(r).status for r in runs})
        lines.append(f"| {s['scenario']} | {s['mode']} | {ctrl} | {' | '.join(_cells(runs))} | {'; '.join(status)} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    import readme_tables

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=RESULTS)
    parser.add_argument("--check", action="store_true", help="compare with README.md instead of writing")
    parser.add_argument("--readme", type=Path, default=readme_tables.README)
    parser.add_argument("--quiet", "-q", action="store_true", help="no progress bar")
    parser.add_argument("--chaotic-rows", action="store_true", help=argparse.SUPPRESS)  # record_chaotic's child
    args = parser.parse_args(argv)
    if args.chaotic_rows:
        print(json.dumps(chaotic_rows()))
        return 0
    rows = compute_rows(progress=wanted(args.quiet))
    if args.check:
        return _check(readme_tables, to_markdown(rows, load_chaotic()), args.readme)
    chaotic = record_chaotic(args.out / CHAOTIC_RECORD.name)
    md = to_markdown(rows, chaotic)
    print(md)
    write_json(args.out / "scenarios.json", {"runs": rows})
    write_text(args.out / "scenarios.md", md)
    readme_tables.update(["scenarios"], args.readme, rendered={"scenarios": md})
    print(f"wrote {args.out / 'scenarios.md'}, {args.out / 'scenarios.json'} and the table in {args.readme}")
    return 0


def _check(readme_tables, md: str, readme: Path) -> int:
    problems = readme_tables.check(["scenarios"], readme, rendered={"scenarios": md})
    for line in problems:
        print(line, file=sys.stderr)
    chaotic = [f"{' / '.join(k)} ({why})" for k, why in CHAOTIC.items()]
    print(f"scenarios table: {'in step with the code' if not problems else f'{len(problems)} cell(s) differ'}; "
          f"compared with its recorded range over BLAS kernels: {'; '.join(chaotic)}")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    sys.exit(main())
