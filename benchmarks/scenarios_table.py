"""Every named scenario, qp (DAQP) beside the classical laws: the README's results table.

    python benchmarks/scenarios_table.py
writes benchmarks/results/scenarios.md and scenarios.json (tracking numbers; the step
times in them are single runs — for timing use step_time.py / compare_peers.py).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from qpik.io import write_json, write_text
from qpik.app.runs import compare, run
from qpik.scenario import build_scenario, scenarios

RESULTS = Path(__file__).resolve().parent / "results"
PHYSICS = ("seed-redundant", "hexapod-circle")


def _fmt(value, spec: str) -> str:
    return "-" if value is None else format(value, spec)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    rows = []
    for name, info in scenarios().items():
        _, logs, _ = compare(info.robot, name, ["daqp"])
        rows += [log.summary() for log in logs]
        if name in PHYSICS:
            rows.append(run(info.robot, name, "qp", "daqp", "physics")[1].summary())
        if name == "hexapod-position-only":  # the same run without the manipulability task
            summary = run(info.robot, name, "qp", "daqp", setup=build_scenario(name, k0=0.0))[1].summary()
            rows.append({**summary, "controller": "qp, k0 = 0"})
    lines = ["| scenario | mode | controller | max error [m] | final error [m] | orientation error [rad] | "
             "loop residual [m] | limit violation | peak speed | manipulability (mean / final) |",
             "|---|---|---|---:|---:|---:|---:|---:|---:|---:|"]
    for s in rows:
        ctrl = s["controller"] if s["solver"] == "none" else f"{s['controller']} ({s['solver']})"
        lines.append(f"| {s['scenario']} | {s['mode']} | {ctrl} | {s['max_error']:.2e} | {s['final_error']:.2e} | "
                     f"{_fmt(s.get('orientation_error_max'), '.1e')} | {_fmt(s.get('constraint_violation_max'), '.1e')} | "
                     f"{s['limit_violation_max']:.2e} | {s['peak_joint_speed']:.3g} | "
                     f"{s['manipulability_mean']:.4f} / {s['manipulability_final']:.4f} |")
    md = "\n".join(lines) + "\n"
    print(md)
    write_json(args.out / "scenarios.json", {"runs": rows})
    write_text(args.out / "scenarios.md", md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
