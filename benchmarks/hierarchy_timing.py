"""Step time of the strict hierarchy and SNS against the single QP and the pseudoinverse
law, block-interleaved so that the machine's slow phases hit every controller alike.

Each controller runs its own copy of the scenario. The rollouts advance together in
blocks of ``--block`` steps: one block of each controller in turn, the order rotated
every block, the garbage collector off. A step's time is the kinematics update plus
``compute_velocity``, as in the rollouts (and, apart, the thread's CPU time for the same
steps). Each repeat starts fresh copies. Each row gives its median step time and its
tail, the 99th percentile over the median, on both clocks; the ratios are
per repeat (medians of the step times), reported as the median over the repeats with
their spread (min to max):

- ``sns / pinv``: SNS against the pseudoinverse law it extends;
- ``hqp per level / qp``: the hierarchy's step time divided by its number of levels,
  against the scenario's single QP (and against ``qp-hard`` where the scenario has it).

    python benchmarks/hierarchy_timing.py                      # all four scenarios
    python benchmarks/hierarchy_timing.py --scenarios three-tasks --repeats 5
writes benchmarks/results/hierarchy_timing.json and .md.
"""

from __future__ import annotations

import argparse
import gc
import platform
import sys
import time
from pathlib import Path

import numpy as np

from qpik.errors import QpikError
from qpik.io import write_json, write_text
from qpik.scenario import build_scenario

RESULTS = Path(__file__).resolve().parent / "results"
SCENARIOS = ("seed-redundant", "joint-limits", "too-fast", "three-tasks")
KINDS = ("pinv", "sns", "qp", "qp-hard", "hqp")


class Rollout:
    """One controller on its own copy of a scenario, advanced a block of steps at a time
    (kinematic mode, exactly the loop of qpik.rollout.simulate without its logging)."""

    def __init__(self, scenario: str, kind: str, solver: str):
        self.setup = build_scenario(scenario, "arm")
        self.kind = kind
        self.controller = self.setup.controller(kind, solver)
        self.robot, self.reference, self.dt = self.setup.robot, self.setup.reference, self.setup.dt
        self.steps = int(round(self.setup.duration / self.dt)) + 1
        self.stops = self.robot.joint_limits
        self.levels = getattr(self.controller, "level_count", 1)
        self.times: list[float] = []  # wall clock per step
        self.cpu_times: list[float] = []  # this thread's CPU time per step (preemption left out)
        self.k = 0
        self.failure = ""

    def advance(self, count: int) -> None:
        robot, controller, stops = self.robot, self.controller, self.stops
        for _ in range(min(count, self.steps - self.k) if not self.failure else 0):
            self.reference.apply(self.k * self.dt)
            cpu_start = time.thread_time()
            start = time.perf_counter()
            robot.update_kinematics()
            try:
                qdot = controller.compute_velocity()
            except QpikError as exc:  # e.g. qp-hard on too-fast: infeasible by design
                self.failure = f"{type(exc).__name__} at t = {self.k * self.dt:.3f} s"
                return
            end = time.perf_counter()
            self.cpu_times.append(time.thread_time() - cpu_start)
            self.times.append(end - start)
            robot.integrate(qdot, self.dt)
            robot.q[stops.qpos_index] = np.clip(robot.q[stops.qpos_index], stops.lower, stops.upper)
            self.k += 1


def measure(scenario: str, solver: str, block: int) -> dict[str, dict]:
    """One repeat: every controller the scenario offers, block-interleaved."""
    offered = build_scenario(scenario, "arm").controller_kinds()
    rollouts = [Rollout(scenario, kind, solver) for kind in KINDS if kind in offered]
    gc.collect()
    gc.disable()
    try:
        for b in range(-(-rollouts[0].steps // block)):
            shift = b % len(rollouts)
            for rollout in rollouts[shift:] + rollouts[:shift]:
                rollout.advance(block)
    finally:
        gc.enable()
    # The first step of each sets up its solvers: left out. A controller that failed
    # (an infeasible hard task) is left out of the table.
    return {r.kind: {"median_us": float(np.median(r.times[1:]) * 1e6),
                     "p99_us": float(np.percentile(r.times[1:], 99) * 1e6),
                     "cpu_median_us": float(np.median(r.cpu_times[1:]) * 1e6),
                     "cpu_p99_us": float(np.percentile(r.cpu_times[1:], 99) * 1e6), "levels": r.levels}
            for r in rollouts if not r.failure}


def ratios(rows: dict[str, dict]) -> dict[str, float]:
    out = {"sns / pinv": rows["sns"]["median_us"] / rows["pinv"]["median_us"]}
    per_level = rows["hqp"]["median_us"] / rows["hqp"]["levels"]
    out["hqp per level / qp"] = per_level / rows["qp"]["median_us"]
    if "qp-hard" in rows:
        out["hqp per level / qp-hard"] = per_level / rows["qp-hard"]["median_us"]
    return out


def to_markdown(results: dict, meta: dict) -> str:
    lines = [f"Step time (kinematics update + controller), block-interleaved in blocks of {meta['block']} "
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
    if args.repeats < 1 or args.block < 1:
        parser.error("--repeats and --block must be positive")
    results = {}
    for scenario in [s for s in args.scenarios.split(",") if s]:
        repeats = [measure(scenario, args.solver, args.block) for _ in range(args.repeats)]
        kinds = list(repeats[0])
        results[scenario] = {
            "median_us": {k: [r[k]["median_us"] for r in repeats] for k in kinds},
            **{field: {k: [r[k][field] for r in repeats] for k in kinds}
               for field in ("p99_us", "cpu_median_us", "cpu_p99_us")},
            "levels": {k: repeats[0][k]["levels"] for k in kinds},
            "ratios": {name: [ratios(r)[name] for r in repeats] for name in ratios(repeats[0])},
        }
    meta = {"python": sys.version.split()[0], "machine": platform.machine(), "processor": platform.processor(),
            "repeats": args.repeats, "block": args.block, "solver": args.solver}
    md = to_markdown(results, meta)
    print(md)
    write_json(args.out / "hierarchy_timing.json", {"meta": meta, "results": results})
    write_text(args.out / "hierarchy_timing.md", md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
