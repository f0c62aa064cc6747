"""qpik beside the peers: per-step time and tracking of qp, the classical law, mink, placo.

On the arm's ``seed-redundant`` and the hexapod's ``hexapod-circle`` (platform pose task,
six loop closures, stroke limits): qp with each solver, the classical law (pinv), mink
with each solver and placo each run the scenario on their own copy, advancing side by
side in blocks of 50 steps with the order rotated, ``--repeats`` times
(:mod:`timing`), so the ratios of medians come from one run on one machine state; each
ratio is the median over the repeats with its range. A peer that cannot map a scenario
is listed with its reason instead.

    python benchmarks/compare_peers.py [--repeats 5] [--solvers daqp,osqp,proxqp,quadprog]

writes benchmarks/results/peers_<scenario>.json and .md: median / p99 step time (and
whether p99 ≤ 3 medians), tracking error (and, on the hexapod, the largest loop-closure
residual), final-q agreement with qp (daqp), the ratios qp(daqp)/mink(daqp),
qp(osqp)/mink(osqp), qp(daqp)/pinv, qp(daqp)/placo and whether each bound holds.
"""

from __future__ import annotations

import argparse
import platform
import sys
from pathlib import Path

import numpy as np
from step_time import RESULTS, measure
from timing import P99_BOUND

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository: tools (the results page)

from qpik.app.peers import PEERS, PLACO_SOLVER, PeerUnsupported, peer_controller, peer_installed, peer_solvers  # noqa: E402
from qpik.app.runs import run_label  # noqa: E402
from qpik.rollout.io import write_json, write_text  # noqa: E402
from qpik.rollout import RunSummary  # noqa: E402
from qpik.scenario import build_scenario, scenarios  # noqa: E402
from qpik.solvers import available_solvers  # noqa: E402
from tools.results import refresh  # noqa: E402
from tools.tables import ratio_cell  # noqa: E402

# (robot, scenario, {ratio: bound}): the one engine's serial step at most 0.35 of mink's on
# the arm's seed-redundant step, 0.5 where the limits bind on most steps (joint-limits, where
# the classical law, blind to limits, is no yardstick) and on the hexapod.
RUNS = (("arm", "seed-redundant", {"qp(daqp) / mink(daqp)": 0.35}),
        ("arm", "joint-limits", {"qp(daqp) / mink(daqp)": 0.5, "qp(daqp) / pinv": None}),
        ("hexapod", "hexapod-circle", {"qp(daqp) / mink(daqp)": 0.5}))
TRACKING = 1e-3  # max error every controller must keep
# (label, numerator, denominator, bound or None): the must-show ratios of medians (a
# scenario's own bounds in RUNS take precedence).
RATIOS = (
    ("qp(daqp) / mink(daqp)", ("qp", "daqp"), ("mink", "daqp"), 0.5),
    ("qp(osqp) / mink(osqp)", ("qp", "osqp"), ("mink", "osqp"), 0.25),
    ("qp(daqp) / pinv", ("qp", "daqp"), ("pinv", "none"), 1.5),
    ("qp(daqp) / placo", ("qp", "daqp"), ("placo", PLACO_SOLVER), None),
)


def entries_for(robot: str, scenario: str, solvers: list[str]) -> tuple[list[tuple[str, str]], list[str]]:
    """Every controller that can run the scenario, and a note for each that cannot."""
    entries = [("qp", s) for s in solvers] + [("pinv", "none")]
    notes = []
    for kind in PEERS:
        if not peer_installed(kind):
            notes.append(f"{kind} not installed: skipped")
            continue
        try:
            peer_controller(kind, build_scenario(scenario, robot), peer_solvers(kind, solvers)[0])
        except PeerUnsupported as exc:
            notes.append(f"{kind} skipped: {exc}")
            continue
        entries += [(kind, s) for s in peer_solvers(kind, solvers)]
    return entries, notes


def ratios(rows: list[dict], timing, bounds: dict) -> list[dict]:
    present = {(r["controller"], r["solver"]) for r in rows}
    out = []
    for label, num, den, bound in RATIOS:
        bound = bounds.get(label, bound)
        if num in present and den in present:
            ratio = timing.ratio(run_label(*num), run_label(*den))
            out.append({"ratio": label, "value": ratio["median"], "min": ratio["min"], "max": ratio["max"],
                        "pooled": ratio["pooled"], "bound": bound,
                        "holds": None if bound is None else bool(ratio["median"] <= bound)})
    return out


def agreement(rows: list[dict]) -> None:
    """Each row's largest |q_final − q_final of qp(daqp)| (the same problem: same motion)."""
    q_final = [np.array(RunSummary.from_json(r["summary"]).q_final) for r in rows]
    ref = next(q for r, q in zip(rows, q_final) if (r["controller"], r["solver"]) == ("qp", "daqp"))
    for r, q in zip(rows, q_final):
        r["q_final_vs_qp_daqp"] = float(np.max(np.abs(q - ref)))


def to_markdown(robot: str, scenario: str, rows: list[dict], checks: list[dict], notes: list[str],
                repeats: int) -> str:
    summaries = [RunSummary.from_json(r["summary"]) for r in rows]
    loops = all(s.constraint_violation_max is not None for s in summaries)
    lines = [f"### {robot} / {scenario}", "",
             f"Per-step time (kinematics update + controller), {rows[0]['steps']} steps per controller over "
             f"{repeats} repeats, controllers interleaved in blocks of 50 steps; tracking from the last repeat; "
             "Δq_final = max |q_final − q_final of qp (daqp)|.", "",
             f"| controller | solver | median [µs] | p99 [µs] | p99 ≤ {P99_BOUND:g}× median | max error [m] | "
             "tracks (≤ 1e-3) | limit viol. | " + ("loop resid. [m] | " if loops else "") + "Δq_final |",
             "|---|---|---:|---:|:---:|---:|:---:|---:|" + ("---:|" if loops else "") + "---:|"]
    for r, s in zip(rows, summaries):
        tracks = "yes" if s.completed and s.max_error <= TRACKING else f"no: {s.stop.failure if s.stop else 'error'}"
        loop = f"{s.constraint_violation_max:.1e} | " if loops else ""
        p99 = f"{r['p99_over_median']:.2f} " + ("yes" if r["p99_within_3_medians"] else "**no**")
        lines.append(f"| {r['controller']} | {r['solver']} | {r['median_us']:.1f} | {r['p99_us']:.1f} | {p99} | "
                     f"{s.max_error:.2e} | {tracks} | {s.limit_violation_max:.1e} | {loop}"
                     f"{r['q_final_vs_qp_daqp']:.1e} |")
    lines += ["", "| ratio of medians | median over repeats (range) | bound | holds |", "|---|---:|---:|:---:|"]
    for c in checks:
        bound = "-" if c["bound"] is None else f"≤ {c['bound']}"
        holds = "-" if c["holds"] is None else ("yes" if c["holds"] else "**no**")
        lines.append(f"| {c['ratio']} | {ratio_cell({'median': c['value'], 'min': c['min'], 'max': c['max']})} | "
                     f"{bound} | {holds} |")
    lines += [""] + [f"- {n}" for n in notes]
    return "\n".join(lines).rstrip() + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--solvers", default=",".join(available_solvers()))
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    solvers = [s for s in args.solvers.split(",") if s]
    meta = {"python": sys.version.split()[0], "machine": platform.machine(), "processor": platform.processor(),
            "repeats": args.repeats, "block": 50}
    for robot, scenario, bounds in RUNS:
        if scenario not in scenarios():
            print(f"{scenario}: no such scenario here, skipped")
            continue
        entries, notes = entries_for(robot, scenario, solvers)
        rows, timing = measure(robot, scenario, entries, args.repeats)
        agreement(rows)
        checks = ratios(rows, timing, bounds)
        md = to_markdown(robot, scenario, rows, checks, notes, args.repeats)
        print(md)
        write_json(args.out / f"peers_{scenario}.json", {"robot": robot, "scenario": scenario, "meta": meta,
                                                          "rows": rows, "ratios": checks, "notes": notes})
        write_text(args.out / f"peers_{scenario}.md", md)
    return refresh(args.out)


if __name__ == "__main__":
    sys.exit(main())
