"""Per-step controller time, side by side in one run (ratios, since machines are noisy).

Every controller runs the same scenario on its own copy, all advancing in turns of 50
steps with the order rotated, the garbage collector off, ``--repeats`` times
(:mod:`timing`). The timed step is what a user's loop writes: the task's target for the
step (``set_target`` with the reference's precomputed samples), ``compute_velocity``
(which refreshes the kinematics), ``robot.integrate``. Reported per controller: median and p99 of the step, whether the
p99 stays within 3 medians and within the 2 ms control period, and the ratio of its
median to the reference controller's with its range over the repeats.

    python benchmarks/step_time.py --robot arm --scenario seed-redundant [--repeats 5]
writes benchmarks/results/step_time_<scenario>.json and .md.
"""

from __future__ import annotations

import argparse
import platform
import sys
from pathlib import Path

from timing import P99_BOUND, Contestant, interleave, logged_run, scenario_run, timed_vs_logged

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository: tools (the results page)

from qpik.app.runs import run_label  # noqa: E402
from qpik.rollout.io import write_json, write_text  # noqa: E402
from qpik.scenario import scenarios  # noqa: E402
from qpik.solvers import available_solvers  # noqa: E402
from tools.results import refresh  # noqa: E402
from tools.tables import ratio_cell  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
CONTROL_PERIOD_US = 2000.0  # the scenarios' Δt: a step must fit in it to run in real time


def measure(robot: str, scenario: str, entries: list[tuple[str, str]], repeats: int = 3):
    """Interleaved step times of each (controller, solver); each row keeps the summary of
    the controller's logged rollout (run apart, untimed) and how far the last timed run's
    q strayed from it. Returns the rows and the :class:`timing.Timing`."""
    contestants = [Contestant(run_label(c, s), lambda c=c, s=s: scenario_run(robot, scenario, c, s))
                   for c, s in entries]
    timing = interleave(contestants, repeats=repeats)
    rows = []
    for (controller, solver), row in zip(entries, timing.rows()):
        log = logged_run(robot, scenario, controller, solver)
        rows.append({"controller": controller, "solver": solver, **row, "summary": log.summary().to_json(),
                     "timed_vs_logged_q": timed_vs_logged(timing.contestants[row["label"]].last_run, log)})
    return rows, timing


def to_markdown(robot: str, scenario: str, rows: list[dict], timing, reference: str) -> str:
    lines = [f"Per-step controller time, {robot} / {scenario} (timed step: set_target from the sampled "
             "reference, compute_velocity, robot.integrate), "
             f"{rows[0]['steps']} steps each over {timing.repeats} repeats, controllers interleaved in blocks "
             f"of {timing.block} steps; ratio = median / median of `{reference}`, median over the repeats "
             "(range).", "",
             f"| controller | solver | median [µs] | p99 [µs] | p99 / median (≤ {P99_BOUND:g}) | "
             f"p99 ≤ {CONTROL_PERIOD_US / 1000:g} ms | ratio to {reference} |",
             "|---|---|---:|---:|---:|:---:|---:|"]
    for r in rows:
        ratio = timing.ratio(r["label"], reference)
        holds = "yes" if r["p99_within_3_medians"] else "**no**"
        period = "yes" if r["p99_us"] <= CONTROL_PERIOD_US else "**no**"
        lines.append(f"| {r['controller']} | {r['solver']} | {r['median_us']:.1f} | {r['p99_us']:.1f} | "
                     f"{r['p99_over_median']:.2f} {holds} | {period} | {ratio_cell(ratio)} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robot", default="arm")
    parser.add_argument("--scenario", default="seed-redundant", choices=sorted(scenarios()))
    parser.add_argument("--solvers", default=",".join(available_solvers()))
    parser.add_argument("--classical", default="pinv,jt")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    if args.repeats < 3:
        parser.error("--repeats must be at least 3 (the spread of the ratios needs them)")
    solvers = [s for s in args.solvers.split(",") if s]
    classical = [c for c in args.classical.split(",") if c]
    rows, timing = measure(args.robot, args.scenario,
                           [("qp", s) for s in solvers] + [(c, "none") for c in classical], args.repeats)
    reference = "pinv" if "pinv" in classical else rows[0]["label"]
    md = to_markdown(args.robot, args.scenario, rows, timing, reference)
    print(md)
    meta = {"python": sys.version.split()[0], "machine": platform.machine(), "processor": platform.processor(),
            "repeats": args.repeats, "block": timing.block}
    ratios = [timing.ratio(r["label"], reference) for r in rows]
    write_json(args.out / f"step_time_{args.scenario}.json",
               {"robot": args.robot, "scenario": args.scenario, "meta": meta, "rows": rows, "ratios": ratios})
    write_text(args.out / f"step_time_{args.scenario}.md", md)
    return refresh(args.out)


if __name__ == "__main__":
    sys.exit(main())
