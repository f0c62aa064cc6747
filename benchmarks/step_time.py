"""Per-step controller time, side by side in one run (ratios, since machines are noisy).

Each controller rolls out the same scenario ``--rounds`` times, in interleaved order
(round-robin), so slow phases of the machine hit every controller alike. The step
time covers the kinematics update and the controller's ``compute_velocity``.

    python benchmarks/step_time.py --robot arm --scenario seed-redundant
writes benchmarks/results/step_time_<scenario>.json and .md.
"""

from __future__ import annotations

import argparse
import gc
import platform
import sys
from pathlib import Path

import numpy as np

from qpik.app.progress import iterate, wanted
from qpik.app.runs import run
from qpik.io import write_json, write_text
from qpik.scenario import scenarios
from qpik.solvers import available_solvers

RESULTS = Path(__file__).resolve().parent / "results"


def timed_run(*args, **kwargs):
    """``qpik.app.runs.run`` with the garbage collector off, so no collector pause lands in a
    measured step."""
    gc.collect()
    gc.disable()
    try:
        return run(*args, **kwargs)
    finally:
        gc.enable()


def measure(robot: str, scenario: str, entries: list[tuple[str, str]], rounds: int) -> list[dict]:
    """Step times of each (controller, solver) over ``rounds`` interleaved rollouts; each
    row also keeps the summary of the controller's last rollout. A progress bar counts
    the rollouts (on a terminal; it draws between rollouts, never inside a timed step)."""
    times = {e: [] for e in entries}
    last_logs = {}
    order = [entry for _ in range(rounds) for entry in entries]
    for controller, solver in iterate(order, desc=f"{robot} / {scenario}", enabled=wanted(), unit="rollout"):
        _, log = timed_run(robot, scenario, controller, solver)
        times[(controller, solver)].append(log.step_time[1:])  # the first step sets up solvers
        last_logs[(controller, solver)] = log
    rows = []
    for (controller, solver), chunks in times.items():
        t = np.concatenate(chunks) * 1e6
        rows.append({"controller": controller, "solver": solver, "steps": int(t.size),
                     "median_us": float(np.median(t)), "p99_us": float(np.percentile(t, 99)),
                     "mean_us": float(np.mean(t)), "summary": last_logs[(controller, solver)].summary()})
    return rows


def to_markdown(robot: str, scenario: str, rows: list[dict], reference: str) -> str:
    ref = next(r for r in rows if r["controller"] == reference)
    lines = [f"Per-step controller time, {robot} / {scenario} (kinematics update + controller), "
             f"{rows[0]['steps']} steps each; ratio = median / median of `{reference}`.", "",
             "| controller | solver | median [µs] | p99 [µs] | ratio to " + reference + " |",
             "|---|---|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['controller']} | {r['solver']} | {r['median_us']:.1f} | {r['p99_us']:.1f} | "
                     f"{r['median_us'] / ref['median_us']:.2f} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robot", default="arm")
    parser.add_argument("--scenario", default="seed-redundant", choices=sorted(scenarios()))
    parser.add_argument("--solvers", default=",".join(available_solvers()))
    parser.add_argument("--classical", default="pinv,jt")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    solvers = [s for s in args.solvers.split(",") if s]
    classical = [c for c in args.classical.split(",") if c]
    rows = measure(args.robot, args.scenario, [("qp", s) for s in solvers] + [(c, "none") for c in classical],
                   args.rounds)
    reference = "pinv" if "pinv" in classical else rows[0]["controller"]
    md = to_markdown(args.robot, args.scenario, rows, reference)
    print(md)
    meta = {"python": sys.version.split()[0], "machine": platform.machine(), "processor": platform.processor(),
            "rounds": args.rounds}
    write_json(args.out / f"step_time_{args.scenario}.json",
               {"robot": args.robot, "scenario": args.scenario, "meta": meta, "rows": rows})
    write_text(args.out / f"step_time_{args.scenario}.md", md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
