"""Step time of the strict hierarchy and SNS against the single QP and the pseudoinverse
law, block-interleaved so that the machine's slow phases hit every controller alike.

Each controller runs its own copy of the scenario; all advance together in blocks of
``--block`` steps, the order rotated every block, the garbage collector off
(:mod:`timing`). A step's time is what a user's loop writes: the task's target for the
step (from the reference's precomputed samples), ``compute_velocity`` (which refreshes
the kinematics), ``robot.integrate`` (and, apart, the thread's CPU time for the same
steps). Each repeat starts fresh copies. Each row gives its median step time and its
tail, the 99th percentile over the median, on both clocks; the ratios are per repeat
(medians of the step times), reported as the median over the repeats with their spread
(min to max):

- ``sns / pinv``: SNS against the pseudoinverse law it extends;
- ``hqp per level / qp``: the hierarchy's step time divided by its number of levels,
  against the scenario's single QP (and against ``qp-hard`` where the scenario has it).

    python benchmarks/hierarchy_timing.py                      # all four scenarios
    python benchmarks/hierarchy_timing.py --scenarios three-tasks --repeats 5
writes benchmarks/results/hierarchy_timing.json and .md.
"""

from __future__ import annotations

import argparse
import platform
import sys
from pathlib import Path

import numpy as np

from qpik.rollout.io import write_json, write_text
from qpik.scenario import build_scenario
from timing import Contestant, interleave, scenario_run

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository: tools (the results page)

from tools.results import refresh  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
SCENARIOS = ("seed-redundant", "joint-limits", "too-fast", "three-tasks")
KINDS = ("pinv", "sns", "qp", "qp-hard", "hqp")


def measure(scenario: str, solver: str, block: int, repeats: int) -> dict:
    """Every controller the scenario offers, block-interleaved; per repeat each one's
    median and p99 on both clocks. A controller that failed (an infeasible hard task,
    e.g. qp-hard on too-fast) is left out."""
    offered = build_scenario(scenario, "arm").controller_kinds()
    kinds = [kind for kind in KINDS if kind in offered]
    contestants = [Contestant(kind, lambda kind=kind: scenario_run("arm", scenario, kind, solver)) for kind in kinds]
    timing = interleave(contestants, repeats=repeats, block=block, cpu=True)
    out = {"median_us": {}, "p99_us": {}, "cpu_median_us": {}, "cpu_p99_us": {}, "levels": {}}
    for kind in kinds:
        result = timing.contestants[kind]
        if any(result.failures):
            continue
        for name, times in (("", result.step_times), ("cpu_", result.cpu_times)):
            out[f"{name}median_us"][kind] = [float(np.median(t) * 1e6) for t in times]
            out[f"{name}p99_us"][kind] = [float(np.percentile(t, 99) * 1e6) for t in times]
        out["levels"][kind] = getattr(result.last_run.controller, "level_count", 1)
    per_repeat = [{kind: {"median_us": out["median_us"][kind][r], "levels": out["levels"][kind]}
                   for kind in out["levels"]} for r in range(repeats)]
    out["ratios"] = {name: [ratios(r)[name] for r in per_repeat] for name in ratios(per_repeat[0])}
    return out


def ratios(rows: dict[str, dict]) -> dict[str, float]:
    out = {"sns / pinv": rows["sns"]["median_us"] / rows["pinv"]["median_us"]}
    per_level = rows["hqp"]["median_us"] / rows["hqp"]["levels"]
    out["hqp per level / qp"] = per_level / rows["qp"]["median_us"]
    if "qp-hard" in rows:
        out["hqp per level / qp-hard"] = per_level / rows["qp-hard"]["median_us"]
    return out


def to_markdown(results: dict, meta: dict) -> str:
    lines = [f"Step time (set_target, compute_velocity, integrate), block-interleaved in blocks of {meta['block']} "
             f"steps, order rotated each block, gc off; {meta['repeats']} repeats, solver {meta['solver']}. "
             "Medians per repeat; the tail, 99th percentile over median, on the wall clock (which counts the "
             "steps in which the scheduler ran another process, ~4 ms each on a shared machine) and on the "
             "thread's CPU time (which does not); ratios: median over the repeats [min, max].", "",
             "| scenario | controller | levels | median step [µs] per repeat | p99 / median, wall | "
             "p99 / median, CPU |", "|---|---|---:|---|---|---|"]
    for scenario, result in results.items():
        for kind, times in result["median_us"].items():
            wall = [p99 / t for p99, t in zip(result["p99_us"][kind], times)]
            cpu = [p99 / t for p99, t in zip(result["cpu_p99_us"][kind], result["cpu_median_us"][kind])]
            cells = [", ".join(f"{t:.1f}" for t in times), ", ".join(f"{x:.2f}" for x in wall),
                     ", ".join(f"{x:.2f}" for x in cpu)]
            lines.append(f"| {scenario} | {kind} | {result['levels'][kind]} | " + " | ".join(cells) + " |")
    lines += ["", "| scenario | ratio | median | spread |", "|---|---|---:|---|"]
    for scenario, result in results.items():
        for name, values in result["ratios"].items():
            lines.append(f"| {scenario} | {name} | {np.median(values):.2f} | {min(values):.2f} – {max(values):.2f} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenarios", default=",".join(SCENARIOS))
    parser.add_argument("--solver", default="daqp")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--block", type=int, default=50)
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    if args.repeats < 3 or args.block < 1:
        parser.error("--repeats must be at least 3 (the ratios' spread needs them) and --block positive")
    results = {}
    for scenario in [s for s in args.scenarios.split(",") if s]:
        results[scenario] = measure(scenario, args.solver, args.block, args.repeats)
    meta = {"python": sys.version.split()[0], "machine": platform.machine(), "processor": platform.processor(),
            "repeats": args.repeats, "block": args.block, "solver": args.solver}
    md = to_markdown(results, meta)
    print(md)
    write_json(args.out / "hierarchy_timing.json", {"meta": meta, "results": results})
    write_text(args.out / "hierarchy_timing.md", md)
    return refresh(args.out)


if __name__ == "__main__":
    sys.exit(main())
