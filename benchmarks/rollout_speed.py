"""Whole rollouts per second (``qpik.app.runs.run``: scenario built, rolled out, logged),
optionally against the package at another git revision, interleaved in one process.

    python benchmarks/rollout_speed.py [--rounds 7] [--against f6b657f]

With ``--against REV`` the package at REV is exported (``git archive``) to a temporary
folder and imported under another name, so both versions run in this one process; each
round runs one rollout of every (version, scenario) pair, in an order rotated from round
to round, with the garbage collector off (the timing harness, :mod:`timing`, with one
rollout per step; a first rollout of each pair warms it up). Reported per pair: the median rollout time over
the rounds and rollouts per second; per scenario, the ratio of the two versions' rates,
median and range over the rounds (each round's ratio comes from rollouts run seconds
apart, so a burst of load moves both). The two versions' summaries must agree to 1e-12
on the keys both have (the step-time fields aside) or the comparison is refused.

writes benchmarks/results/rollout_speed.json and .md.
"""

from __future__ import annotations

import argparse
import importlib
import platform
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from timing import Contestant, import_revision, interleave

from qpik.rollout.io import write_json, write_text

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository: tools (the results page)

from tools.results import refresh  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
REPO = Path(__file__).resolve().parents[1]
RUNS = (("arm", "seed-redundant"), ("hexapod", "hexapod-circle"))
TIMING_KEYS = ("step_time_median_us", "step_time_p99_us")


def tree_label() -> str:
    """``this tree (abc1234)``, with ``+`` when the tree has uncommitted changes."""
    head = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    dirty = subprocess.run(["git", "-C", str(REPO), "status", "--porcelain", "src"], capture_output=True, text=True)
    return f"this tree ({head.stdout.strip() or 'no git'}{'+' if dirty.stdout.strip() else ''})"


class Rollouts:
    """A contestant whose step is one whole rollout (``run(robot, scenario)`` of a version's
    ``qpik.app.runs``), ``rounds`` of them after a first that warms it up; the summary of
    the last is kept (a dict, the step times aside)."""

    failures = ()

    def __init__(self, runs_module, robot: str, scenario: str, rounds: int):
        self.runs, self.robot, self.scenario, self.steps = runs_module, robot, scenario, rounds + 1
        self.summary: dict = {}

    def step(self, k: int) -> None:
        self._log = self.runs.run(self.robot, self.scenario)[1]

    def after(self, k: int) -> None:
        summary = self._log.summary()  # a dict before the typed summary
        summary = summary.to_json() if hasattr(summary, "to_json") else summary
        self.summary = {key: value for key, value in summary.items() if key not in TIMING_KEYS}


def measure(versions: dict[str, object], rounds: int) -> dict:
    """Every (version, scenario) pair's rollouts, interleaved one rollout at a time (the
    order rotated every round) by the benchmarks' timing harness."""
    pairs = {f"{version}: {robot} / {scenario}": (version, (robot, scenario)) for robot, scenario in RUNS
             for version in versions}
    timing = interleave([Contestant(label, lambda v=v, run=run: Rollouts(versions[v], *run, rounds))
                         for label, (v, run) in pairs.items()], repeats=1, block=1)
    times = {pair: timing.contestants[label].step_times[0] for label, pair in pairs.items()}
    summaries = {pair: timing.contestants[label].last_run.summary for label, pair in pairs.items()}
    rows = []
    for (version, (robot, scenario)), values in times.items():
        rows.append({"version": version, "robot": robot, "scenario": scenario, "rounds": rounds,
                     "median_s": float(np.median(values)), "min_s": float(values.min()), "max_s": float(values.max()),
                     "rollouts_per_s": float(1.0 / np.median(values))})
    ratios = []
    names = list(versions)
    if len(names) == 2:
        new, old = names
        for run in RUNS:
            mismatch = _summary_mismatch(summaries[(new, run)], summaries[(old, run)])
            if mismatch:
                raise SystemExit(f"{run}: the two versions' summaries differ ({mismatch}); not a like-for-like "
                                 "comparison")
            per_round = times[(old, run)] / times[(new, run)]
            ratios.append({"robot": run[0], "scenario": run[1], "speedup_median": float(np.median(per_round)),
                           "speedup_min": float(per_round.min()), "speedup_max": float(per_round.max())})
    return {"rows": rows, "speedups": ratios}


def _summary_mismatch(new: dict, old: dict) -> str:
    """The first key both summaries have whose values differ by more than 1e-12 (numbers,
    lists of numbers; a newer version may add keys: only the shared ones are compared)."""
    for key in sorted(set(new) & set(old)):
        a, b = new[key], old[key]
        if isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool):
            if abs(a - b) > 1e-12 * max(1.0, abs(b)):
                return f"{key}: {a} vs {b}"
        elif isinstance(a, list) and isinstance(b, list) and len(a) == len(b) and \
                all(isinstance(x, (int, float)) for x in a + b):
            if max((abs(x - y) for x, y in zip(a, b)), default=0.0) > 1e-12:
                return f"{key} differs"
        elif a != b:
            return f"{key}: {a!r} vs {b!r}"
    return ""


def to_markdown(result: dict, names: list[str]) -> str:
    lines = ["Whole rollouts (`qpik.app.runs.run`: build, roll out, log), garbage collector off, "
             f"{result['rows'][0]['rounds']} interleaved rounds.", "",
             "| version | robot / scenario | median [ms] | range [ms] | rollouts/s |", "|---|---|---:|---:|---:|"]
    for r in result["rows"]:
        lines.append(f"| {r['version']} | {r['robot']} / {r['scenario']} | {r['median_s'] * 1e3:.1f} | "
                     f"{r['min_s'] * 1e3:.1f}–{r['max_s'] * 1e3:.1f} | {r['rollouts_per_s']:.2f} |")
    if result["speedups"]:
        lines += ["", f"| robot / scenario | rollouts/s, {names[0]} ÷ {names[1]} (median) | range over rounds |",
                  "|---|---:|---:|"]
        for s in result["speedups"]:
            lines.append(f"| {s['robot']} / {s['scenario']} | {s['speedup_median']:.2f} | "
                         f"{s['speedup_min']:.2f}–{s['speedup_max']:.2f} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--against", help="a git revision to compare with (e.g. main)")
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    versions = {tree_label(): importlib.import_module("qpik.app.runs")}
    with tempfile.TemporaryDirectory() as folder:
        if args.against:
            name = import_revision(REPO, args.against, Path(folder))
            versions[args.against] = importlib.import_module(name + ".app.runs")
        result = measure(versions, args.rounds)
    md = to_markdown(result, list(versions))
    print(md)
    meta = {"python": sys.version.split()[0], "machine": platform.machine(), "processor": platform.processor(),
            "rounds": args.rounds, "against": args.against}
    write_json(args.out / "rollout_speed.json", {"meta": meta, **result})
    write_text(args.out / "rollout_speed.md", md)
    return refresh(args.out)


if __name__ == "__main__":
    sys.exit(main())
