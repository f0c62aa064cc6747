"""qpik's whole step against placo's compiled solve alone.

placo's step in ``compare_peers.py`` includes the Python glue every peer needs to be
given qpik's problem (targets retargeted, step bounds re-set, the state synced). Here the
glue is left out of placo's side: only its C++ ``KinematicsSolver.solve`` is timed, while
qpik's side is its whole step (kinematics update, tasks, limits, QP). The two run
block-interleaved on their own copies of the scenario (``timing.interleave``, gc off);
per repeat, the ratio qp step median / placo solve median.

    python benchmarks/placo_solve.py [--repeats 5] [--out benchmarks/results]

writes placo_solve.{json,md}.
"""

from __future__ import annotations

import argparse
import platform
import sys
import time
from pathlib import Path

import numpy as np

from qpik.app.peers import peer_installed
from qpik.app.runs import start_run
from qpik.io import write_json, write_text
from timing import Contender, interleave

RESULTS = Path(__file__).resolve().parent / "results"
CASES = (("arm", "seed-redundant"), ("hexapod", "hexapod-circle"))


class _TimedSolve:
    """placo's solver with its ``solve`` timed; every other attribute passed through."""

    def __init__(self, ik, times: list[float]):
        self._ik, self._times = ik, times

    def __getattr__(self, name):
        return getattr(self._ik, name)

    def solve(self, *args):
        start = time.perf_counter()
        result = self._ik.solve(*args)
        self._times.append(time.perf_counter() - start)
        return result


def measure(robot: str, scenario: str, repeats: int) -> dict:
    solve_times: list[list[float]] = []

    def placo_rollout():
        rollout = start_run(robot, scenario, "placo", "daqp", on_failure="stop")[1]
        solve_times.append([])
        rollout.controller.ik = _TimedSolve(rollout.controller.ik, solve_times[-1])
        return rollout

    contenders = [Contender("qp (daqp)", lambda: start_run(robot, scenario, "qp", "daqp", on_failure="stop")[1]),
                  Contender("placo", placo_rollout)]
    timing = interleave(contenders, repeats=repeats)
    qp_medians = timing.contenders["qp (daqp)"].repeat_medians_us
    solve_medians = np.array([np.median(t[1:]) * 1e6 for t in solve_times])  # the first sets placo up
    ratios = qp_medians / solve_medians
    return {"robot": robot, "scenario": scenario, "qp_step_median_us": [float(v) for v in qp_medians],
            "placo_solve_median_us": [float(v) for v in solve_medians],
            "placo_step_median_us": [float(v) for v in timing.contenders["placo"].repeat_medians_us],
            "ratio": {"median": float(np.median(ratios)), "min": float(ratios.min()), "max": float(ratios.max()),
                      "per_repeat": [float(r) for r in ratios]}}


def to_markdown(results: list[dict], repeats: int) -> str:
    lines = [f"qpik's whole step against placo's compiled `solve` alone, block-interleaved, gc off, {repeats} "
             "repeats (medians over the repeats' medians; the ratio's median and range).", "",
             "| robot / scenario | qp (daqp) step [µs] | placo step [µs] | placo solve [µs] | qp step / placo solve |",
             "|---|---:|---:|---:|---:|"]
    for r in results:
        ratio = r["ratio"]
        lines.append(f"| {r['robot']} / {r['scenario']} | {np.median(r['qp_step_median_us']):.1f} | "
                     f"{np.median(r['placo_step_median_us']):.1f} | {np.median(r['placo_solve_median_us']):.1f} | "
                     f"{ratio['median']:.2f} ({ratio['min']:.2f}–{ratio['max']:.2f}) |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    if args.repeats < 3:
        parser.error("--repeats must be at least 3 (the ratio's spread needs them)")
    if not peer_installed("placo"):
        parser.error("placo is not installed: pip install -e '.[peers]'")
    results = [measure(robot, scenario, args.repeats) for robot, scenario in CASES]
    meta = {"python": platform.python_version(), "machine": platform.machine(), "repeats": args.repeats}
    markdown = to_markdown(results, args.repeats)
    write_json(args.out / "placo_solve.json", {"meta": meta, "results": results})
    write_text(args.out / "placo_solve.md", markdown)
    print(markdown)
    return 0


if __name__ == "__main__":
    sys.exit(main())
