"""SNS's step time by what the step had to do: the steps grouped by the number of joints
each level saturated and by which levels were scaled, each group's median against the
pseudoinverse law's median step, so that a ratio can be told apart into the cost of the
levels themselves (steps where nothing saturates) and that of the saturation passes.

SNS and pinv run block-interleaved (:mod:`timing`: the step is set_target,
compute_velocity, integrate), on the thread's CPU time (time.thread_time: the scheduler's
slices to other processes left out); each SNS step's pattern is read after it, untimed.

    python benchmarks/sns_step_patterns.py                      # joint-limits, three-tasks
    python benchmarks/sns_step_patterns.py --scenarios too-fast --repeats 5
writes benchmarks/results/sns_step_patterns.json and .md.
"""

from __future__ import annotations

import argparse
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

from hierarchy_timing import RESULTS
from qpik.rollout.io import write_json, write_text
from timing import Contestant, interleave, scenario_run


class PatternRun:
    """SNS's run, each step's saturation pattern read after it (untimed)."""

    def __init__(self, scenario: str):
        self.run = scenario_run("arm", scenario, "sns", "daqp")
        self.steps, self.failures, self.patterns = self.run.steps, self.run.failures, []

    def step(self, k: int) -> None:
        self.run.step(k)

    def after(self, k: int) -> None:
        self.run.after(k)
        controller = self.run.controller
        self.patterns.append((tuple(int(n) for n in controller.saturated),
                              tuple(bool(s < 1.0) for s in controller.task_scale)))


def measure(scenario: str, block: int, repeats: int) -> tuple[list[float], dict[tuple, list[float]]]:
    """pinv's median step per repeat [µs, CPU] and SNS's step times by pattern, pooled."""
    runs: list[PatternRun] = []

    def sns_run() -> PatternRun:
        runs.append(PatternRun(scenario))
        return runs[-1]

    timing = interleave([Contestant("pinv", lambda: scenario_run("arm", scenario, "pinv", "daqp")),
                         Contestant("sns", sns_run)], repeats=repeats, block=block, cpu=True)
    groups = defaultdict(list)
    for run, seconds in zip(runs, timing.contestants["sns"].cpu_times):
        for pattern, value in zip(run.patterns[1:], seconds):  # the first step sets up
            groups[pattern].append(value * 1e6)
    return [float(np.median(t) * 1e6) for t in timing.contestants["pinv"].cpu_times], groups


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenarios", default="joint-limits,three-tasks")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--block", type=int, default=50)
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    if args.repeats < 1 or args.block < 1:
        parser.error("--repeats and --block must be positive")
    results, lines = {}, [f"SNS step time [µs, CPU] by pattern, block-interleaved with pinv in blocks of "
                          f"{args.block} steps, {args.repeats} repeats pooled; ratio: the group's median over pinv's "
                          "median step.", "",
                          "| scenario | joints saturated per level | levels scaled | steps | median [µs] | / pinv |",
                          "|---|---|---|---:|---:|---:|"]
    for scenario in [s for s in args.scenarios.split(",") if s]:
        pinv_medians, pooled = measure(scenario, args.block, args.repeats)
        pinv_median = float(np.median(pinv_medians))
        rows = []
        for (saturated, scaled), times in sorted(pooled.items(), key=lambda item: -len(item[1])):
            median = float(np.median(times))
            rows.append({"saturated": list(saturated), "scaled": list(scaled), "steps": len(times) // args.repeats,
                         "median_us": median, "ratio_to_pinv": median / pinv_median})
            named = ", ".join(f"L{k}" for k, s in enumerate(scaled) if s) or "none"
            lines.append(f"| {scenario} | {', '.join(map(str, saturated))} | {named} | {len(times) // args.repeats} | "
                         f"{median:.1f} | {median / pinv_median:.2f} |")
        lines.append(f"| {scenario} | pinv's median step | | | {pinv_median:.1f} | 1.00 |")
        results[scenario] = {"pinv_median_us": pinv_median, "patterns": rows}
    md = "\n".join(lines) + "\n"
    print(md)
    write_json(args.out / "sns_step_patterns.json", {"meta": {"python": sys.version.split()[0], "repeats": args.repeats,
                                                              "block": args.block}, "results": results})
    write_text(args.out / "sns_step_patterns.md", md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
