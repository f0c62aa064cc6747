"""qpik.batch of this checkout beside another revision's, in one process: robot-steps per
second of both (their default thread count and one thread), block-interleaved with qpik's
serial loop (benchmarks/timing.py), on batch_throughput.py's problems.

The other revision's package is exported from git and imported under another name
(timing.import_revision), so that both run on the same machine at the same moments: a
before/after of a change to the batched engine measured in the same conditions. The
hexapod is skipped, with a message, while this checkout's ``qpik.batch`` has no
``EqualityTask``.

    python benchmarks/batch_revisions.py REVISION [--robots arm pusher hexapod]
                                          [--sizes 1024 4096 16384] [--repeats 3]

writes benchmarks/results/batch_revisions.{json,md}.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import batch_throughput as bt  # noqa: E402
from timing import Contestant, import_revision, interleave  # noqa: E402


class Run:
    """One batched problem on a given ``qpik.batch`` module (this checkout's or another's)."""

    failures = ()

    def __init__(self, lib, name: str, n: int, steps: int, nthread: int | None = None):
        options = {} if nthread is None else {"nthread": nthread}
        self.robots, tasks, limits, self.mover = bt.build(lib, name, n, **options)
        self.controller = lib.QPController(self.robots, tasks, limits, dt=bt.DT)
        self.offset, self.velocity = bt.circle(n, steps, bt.RADIUS[name], axes=(0, 2) if name == "pusher" else (0, 1))
        self.steps = steps

    def step(self, k: int) -> None:
        self.mover(self.offset[k], self.velocity[k])
        self.robots.integrate(self.controller.compute_velocity(), bt.DT)

    def after(self, k: int) -> None:
        pass


def measure(libs: dict, robot: str, n: int, repeats: int) -> dict:
    steps = bt.run_steps(n)
    contestants = []
    for label, lib in libs.items():
        contestants += [Contestant(label, lambda lib=lib: Run(lib, robot, n, steps)),
                        Contestant(f"{label} (1 thread)", lambda lib=lib: Run(lib, robot, n, steps, nthread=1))]
    contestants += [Contestant("serial", lambda: bt.SerialRun(robot, n, steps)),
                    Contestant("serial (1 robot)", lambda: bt.SerialRun(robot, n, steps, count=1, inner=bt.SERIAL_ROBOTS))]
    timing = interleave(contestants, repeats=repeats, block=max(1, steps // 8))
    robots = {"serial": min(n, bt.SERIAL_ROBOTS), "serial (1 robot)": bt.SERIAL_ROBOTS}
    per_robot = {c.label: c.repeat_medians_us / robots.get(c.label, n) for c in timing.contestants.values()}
    row = {"robot": robot, "n": n, "robot_steps_per_s": {k: float(np.median(1e6 / v)) for k, v in per_robot.items()}}
    first, second = libs
    for suffix in ("", " (1 thread)"):  # repeat by repeat: both revisions ran in the same moments
        ratios = per_robot[second + suffix] / per_robot[first + suffix]
        row[f"{first} / {second}{suffix}"] = {"median": float(np.median(ratios)), "min": float(ratios.min()),
                                              "max": float(ratios.max())}
    for label in per_robot:
        if not label.startswith("serial"):
            row[f"{label} vs serial"] = float(np.median(per_robot["serial"] / per_robot[label]))
            row[f"{label} vs serial (1 robot)"] = float(np.median(per_robot["serial (1 robot)"] / per_robot[label]))
    return row


def _ratio(ratio: dict) -> str:
    return f"{ratio['median']:.2f} ({ratio['min']:.2f}–{ratio['max']:.2f})"


def markdown(results: dict) -> str:
    first, second = results["labels"]
    lines = ["# qpik.batch: this checkout beside another revision", "",
             f"`{results['command']}` — {results['cpus']} CPUs, load average before {results['load_before']}, "
             f"after {results['load_after']}. Robot-steps/s (median over repeats); speed-ups are medians of "
             "per-repeat ratios, against qpik's serial loop over 32 robots and a warm one-robot loop; the "
             "two revisions' ratio is the median (range) of their per-repeat ratios.", "",
             "| robot | N | " + " | ".join(f"{x}, {y}" for x in (first, second) for y in ("default", "1 thread"))
             + f" | {first} / {second} | {first} / {second}, 1 thread | {first} vs serial loop | {first} vs 1 robot "
               f"| {second} vs serial loop | {second} vs 1 robot |",
             "|---" * 12 + "|"]
    for row in results["rows"]:
        rate = row["robot_steps_per_s"]
        cells = [f"{rate[label]:.3g}" for x in (first, second) for label in (x, f"{x} (1 thread)")]
        cells += [_ratio(row[f"{first} / {second}{suffix}"]) for suffix in ("", " (1 thread)")]
        cells += [f"{row[f'{x} vs {base}']:.1f}" for x in (first, second) for base in ("serial", "serial (1 robot)")]
        lines.append(f"| {row['robot']} | {row['n']} | " + " | ".join(cells) + " |")
    lines += ["", *(f"{why}." for why in results.get("skipped", {}).values())] if results.get("skipped") else []
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("revision", help="the other revision (a commit, a branch)")
    parser.add_argument("--robots", nargs="+", default=["arm", "pusher", "hexapod"], choices=["arm", "hexapod", "pusher"])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1024, 4096, 16384])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", default=str(bt.RESULTS))
    args = parser.parse_args()
    from qpik import batch

    folder = Path(tempfile.mkdtemp(prefix="qpik-revision-"))
    other = importlib.import_module(import_revision(HERE.parent, args.revision, folder) + ".batch")
    labels = ("this checkout", args.revision)
    libs = dict(zip(labels, (batch, other)))
    load = lambda: " ".join(f"{x:.2f}" for x in os.getloadavg())  # noqa: E731
    results = {"command": "python benchmarks/batch_revisions.py " + " ".join(sys.argv[1:]), "cpus": os.cpu_count(),
               "labels": labels, "load_before": load(), "rows": [], "skipped": {}}
    for robot in args.robots:
        skipped = bt.unbatched(robot)
        if skipped:
            print(skipped, file=sys.stderr, flush=True)
            results["skipped"][robot] = skipped
            continue
        for n in args.sizes:
            results["rows"].append(measure(libs, robot, n, args.repeats))
            print(json.dumps(results["rows"][-1]), file=sys.stderr, flush=True)
    results["load_after"] = load()
    from qpik.rollout.io import write_text

    out = Path(args.out)
    write_text(out / "batch_revisions.json", json.dumps(results, indent=1))
    write_text(out / "batch_revisions.md", markdown(results))
    print(markdown(results))


if __name__ == "__main__":
    main()
