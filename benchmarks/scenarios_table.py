"""Every named scenario, qp (DAQP) beside the classical laws and the peers: the README's results table.

    python benchmarks/scenarios_table.py           # run, write the table into README.md and results/
    python benchmarks/scenarios_table.py --check   # run, compare with README.md cell by cell

writes benchmarks/results/scenarios.md and scenarios.json (tracking numbers; the step
times in them are single runs — for timing use step_time.py / compare_peers.py) and the
README block ``<!-- table:scenarios -->``. ``--check`` exits 1, naming every cell where
the README differs from what the code gives on the installed versions (the cells of
readme_tables.SKIPPED excepted, with their reason). About 30 s.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from qpik.app.progress import iterate, wanted
from qpik.app.runs import compare, run
from qpik.io import write_json, write_text
from qpik.scenario import build_scenario, scenarios

RESULTS = Path(__file__).resolve().parent / "results"
PHYSICS = ("seed-redundant", "hexapod-circle")


# Below this an error, residual or violation is rounding (machine epsilon on metres and
# radians): its digits change with the build and the CPU, so the table does not print them.
ROUNDING = 1e-12


def _fmt(value, spec: str) -> str:
    if value is None:
        return "-"
    if value == 0.0:
        return format(0.0, spec)
    return f"< {ROUNDING:.0e}" if abs(value) < ROUNDING else format(value, spec)


def compute_rows(progress: bool = False) -> list[dict]:
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
            rows.append({**summary, "controller": "qp, k0 = 0"})
    return rows


def to_markdown(rows: list[dict]) -> str:
    lines = ["| scenario | mode | controller | max error [m] | final error [m] | orientation error [rad] | "
             "loop residual [m] | limit violation | peak speed | manipulability (mean / final) |",
             "|---|---|---|---:|---:|---:|---:|---:|---:|---:|"]
    for s in rows:
        ctrl = s["controller"] if s["solver"] == "none" else f"{s['controller']} ({s['solver']})"
        lines.append(f"| {s['scenario']} | {s['mode']} | {ctrl} | {_fmt(s['max_error'], '.2e')} | "
                     f"{_fmt(s['final_error'], '.2e')} | "
                     f"{_fmt(s.get('orientation_error_max'), '.1e')} | {_fmt(s.get('constraint_violation_max'), '.1e')} | "
                     f"{_fmt(s['limit_violation_max'], '.2e')} | {s['peak_joint_speed']:.3g} | "
                     f"{s['manipulability_mean']:.4f} / {s['manipulability_final']:.4f} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    import readme_tables

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=RESULTS)
    parser.add_argument("--check", action="store_true", help="compare with README.md instead of writing")
    parser.add_argument("--readme", type=Path, default=readme_tables.README)
    parser.add_argument("--quiet", "-q", action="store_true", help="no progress bar")
    args = parser.parse_args(argv)
    rows = compute_rows(progress=wanted(args.quiet))
    md = to_markdown(rows)
    if args.check:
        return _check(readme_tables, md, args.readme)
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
    skipped = [f"{' / '.join(k)} ({why})" for (t, k), why in readme_tables.SKIPPED.items() if t == "scenarios"]
    print(f"scenarios table: {'in step with the code' if not problems else f'{len(problems)} cell(s) differ'}; "
          f"not compared: {'; '.join(skipped)}")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    sys.exit(main())
