"""qpik's whole step against placo's compiled solve alone.

placo's step in ``compare_peers.py`` includes the Python glue every peer needs to be
given qpik's problem (targets retargeted, step bounds re-set, the state synced). Here the
glue is left out of placo's side: its C++ ``KinematicsSolver.solve`` is timed, and with it
its C++ ``RobotWrapper.update_kinematics`` (once a step: like qpik's step, which includes
its kinematics update), while qpik's side is its whole step as its user writes it
(``set_target``, ``compute_velocity`` with the kinematics refresh, tasks, limits, QP,
``robot.integrate``). The two run block-interleaved on their own copies of the scenario
(``timing.interleave``, gc off); per repeat, the ratios of qp's step median to placo's
solve median and to its kinematics + solve median.

    python benchmarks/placo_solve.py [--repeats 5] [--out benchmarks/results]

writes placo_solve.{json,md}.
"""

from __future__ import annotations

import argparse
import platform
import sys
from pathlib import Path

import numpy as np

from qpik.app.peers import peer_installed
from qpik.rollout.io import write_json, write_text
from timing import Contestant, MethodTimer, interleave, scenario_run, spread

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository: tools (the results page)

from tools.results import refresh  # noqa: E402
from tools.tables import placo_solve_markdown  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
CASES = (("arm", "seed-redundant"), ("hexapod", "hexapod-circle"))


def measure(robot: str, scenario: str, repeats: int) -> dict:
    solve_times: list[list[float]] = []
    kinematics_times: list[list[float]] = []

    def placo_run():
        run = scenario_run(robot, scenario, "placo", "daqp")
        solve_times.append([])
        kinematics_times.append([])
        controller = run.controller
        controller.ik = MethodTimer(controller.ik, "solve", solve_times[-1])
        controller.wrapper = MethodTimer(controller.wrapper, "update_kinematics", kinematics_times[-1])
        return run

    contestants = [Contestant("qp (daqp)", lambda: scenario_run(robot, scenario, "qp", "daqp")),
                   Contestant("placo", placo_run)]
    timing = interleave(contestants, repeats=repeats)
    qp_medians = timing.contestants["qp (daqp)"].repeat_medians_us
    solve_medians = np.array([np.median(t[1:]) * 1e6 for t in solve_times])  # the first sets placo up
    # placo's compiled work per step: its kinematics update (once a step) and its solve.
    # (one more kinematics update than solves: the set-up's check of the URDF, first)
    compiled_medians = np.array([np.median(np.add(k[len(k) - len(t) + 1:], t[1:])) * 1e6
                                 for k, t in zip(kinematics_times, solve_times)])
    ratios = qp_medians / solve_medians
    compiled_ratios = qp_medians / compiled_medians
    return {"robot": robot, "scenario": scenario, "qp_step_median_us": [float(v) for v in qp_medians],
            "placo_solve_median_us": [float(v) for v in solve_medians],
            "placo_compiled_median_us": [float(v) for v in compiled_medians],
            "placo_step_median_us": [float(v) for v in timing.contestants["placo"].repeat_medians_us],
            "ratio": spread(ratios), "compiled_ratio": spread(compiled_ratios)}


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
    markdown = placo_solve_markdown(results, args.repeats)
    write_json(args.out / "placo_solve.json", {"meta": meta, "results": results})
    write_text(args.out / "placo_solve.md", markdown)
    print(markdown)
    return refresh(args.out)


if __name__ == "__main__":
    sys.exit(main())
