"""Whole rollouts per second (``qpik.app.runs.run``: scenario built, rolled out, logged),
optionally against the package at another git revision, interleaved in one process.

    python benchmarks/rollout_speed.py [--rounds 7] [--against f6b657f]

With ``--against REV`` the package at REV is exported (``git archive``) to a temporary
folder and imported under another name, so both versions run in this one process; each
round runs one rollout of every (version, scenario) pair, in an order rotated from round
to round, with the garbage collector off. Reported per pair: the median rollout time over
the rounds and rollouts per second; per scenario, the ratio of the two versions' rates,
median and range over the rounds (each round's ratio comes from rollouts run seconds
apart, so a burst of load moves both). The two versions' summaries must agree to 1e-12
on the keys both have (the step-time fields aside) or the comparison is refused.

writes benchmarks/results/rollout_speed.json and .md.
"""

from __future__ import annotations

import argparse
import gc
import importlib
import platform
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from qpik.io import write_json, write_text

RESULTS = Path(__file__).resolve().parent / "results"
REPO = Path(__file__).resolve().parents[1]
RUNS = (("arm", "seed-redundant"), ("hexapod", "hexapod-circle"))
TIMING_KEYS = ("step_time_median_us", "step_time_p99_us")


def import_revision(revision: str, folder: Path) -> str:
    """Import the package at git ``revision`` as ``qpik_<rev>``; return the module name."""
    name = "qpik_" + re.sub(r"\W", "_", revision)
    archive = subprocess.run(["git", "-C", str(REPO), "archive", revision, "src/qpik"], check=True,
                             capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(folder)], input=archive, check=True)
    package = folder / name
    (folder / "src" / "qpik").rename(package)
    # Module paths written as strings (the lazy exports, the robot registry) and absolute
    # imports name the package: point them at the copy.
    pattern = re.compile(r"""(["'])qpik\.|\bfrom qpik\b|\bimport qpik\b""")
    for path in package.rglob("*.py"):
        text = path.read_text()
        new = pattern.sub(lambda m: (m.group(1) + name + ".") if m.group(1) else m.group(0).replace("qpik", name),
                          text)
        if new != text:
            path.write_text(new)
    sys.path.insert(0, str(folder))
    importlib.import_module(name + ".app.runs")
    return name


def tree_label() -> str:
    """``this tree (abc1234)``, with ``+`` when the tree has uncommitted changes."""
    head = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    dirty = subprocess.run(["git", "-C", str(REPO), "status", "--porcelain", "src"], capture_output=True, text=True)
    return f"this tree ({head.stdout.strip() or 'no git'}{'+' if dirty.stdout.strip() else ''})"


def timed_rollout(runs_module, robot: str, scenario: str) -> tuple[float, dict]:
    gc.collect()
    gc.disable()
    try:
        start = time.perf_counter()
        _, log = runs_module.run(robot, scenario)
        elapsed = time.perf_counter() - start
    finally:
        gc.enable()
    summary = log.summary()  # a dict before the typed summary
    return elapsed, summary.to_json() if hasattr(summary, "to_json") else summary


def measure(versions: dict[str, object], rounds: int) -> dict:
    pairs = [(v, run) for run in RUNS for v in versions]
    times = {pair: [] for pair in pairs}
    summaries = {}
    for pair in pairs:  # warm-up: imports, first solver set-ups
        timed_rollout(versions[pair[0]], *pair[1])
    for r in range(rounds):
        order = pairs[r % len(pairs):] + pairs[: r % len(pairs)]
        for version, run in order:
            elapsed, summary = timed_rollout(versions[version], *run)
            times[(version, run)].append(elapsed)
            summaries[(version, run)] = {k: v for k, v in summary.items() if k not in TIMING_KEYS}
    rows = []
    for (version, (robot, scenario)), values in times.items():
        values = np.array(values)
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
            per_round = np.array(times[(old, run)]) / np.array(times[(new, run)])
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
            name = import_revision(args.against, Path(folder))
            versions[args.against] = importlib.import_module(name + ".app.runs")
        result = measure(versions, args.rounds)
    md = to_markdown(result, list(versions))
    print(md)
    meta = {"python": sys.version.split()[0], "machine": platform.machine(), "processor": platform.processor(),
            "rounds": args.rounds, "against": args.against}
    write_json(args.out / "rollout_speed.json", {"meta": meta, **result})
    write_text(args.out / "rollout_speed.md", md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
