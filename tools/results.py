"""docs/results.md, generated whole from the benchmarks' recordings (benchmarks/results/).

    python tools/results.py            # write docs/results.md
    python tools/results.py --check    # exit 1 where docs/results.md differs from the recordings

Each section is one table, rendered by :mod:`tools.tables` from the JSON its benchmark
wrote, under a line of fixed prose (what the table shows), the command that records it
and the machine the recording names. Re-run a benchmark, then this command; the prose
that discusses the numbers lives in docs/benchmarks.md and points at these tables.
"""

from __future__ import annotations

import argparse
import difflib
import json
import re
import sys
import textwrap
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Callable

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:  # run as a script: the repository's packages (tools, benchmarks)
    sys.path.insert(0, str(ROOT))

from tools import tables  # noqa: E402
from qpik.rollout.io import write_text  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"
PAGE = ROOT / "docs" / "results.md"
# Scripts renamed since a recording named them in its command.
RENAMED = {"benchmarks/fuzz.py ": "benchmarks/fuzz_bundled.py "}
RECOMPUTED_BY = "tests/robots/test_recorded_rows.py"
WIDTH = 90  # the prose's lines


@dataclass(frozen=True)
class Section:
    """One table of the page.

    Args:
        name: the table's stable name.
        title: its heading (GitHub makes the anchor other pages link to from it).
        render: the table from the results folder.
        sources: the JSON files it is rendered from, relative to the results folder.
        commands: the benchmark commands that record them, where a recording names none.
        about: what the table shows, in a sentence or two (no number of its own).
        recomputed: the tests recompute it on the installed versions and compare.
    """

    name: str
    title: str
    render: Callable[[Path], str]
    sources: tuple[str, ...]
    commands: tuple[str, ...]
    about: str
    recomputed: bool = False


SECTIONS = (
    Section("scenarios", "Every scenario, every controller", tables.scenarios_table,
            ("scenarios.json", "scenarios_chaotic.json"), ("python benchmarks/scenarios_table.py",),
            "The QP (DAQP) beside the classical laws, the strict hierarchy, SNS and the peers mink and placo on every "
            "named scenario, kinematic mode unless said (Δt = 2 ms). A 0 is below 1e−12 (rounding); a run that "
            "stopped gives the numbers of the steps before the stop; the chaotic row is a range over OpenBLAS "
            "kernels.", recomputed=True),
    Section("calibration", "Hexapod calibration", tables.calibration_table, ("calibration.json",),
            ("python benchmarks/calibration.py",),
            "`qpik calibrate` on the source's four seed poses: the leg-length errors identified by each method.",
            recomputed=True),
    Section("step-time", "Per-step controller time", tables.step_time_table,
            ("step_time_seed-redundant.json", "step_time_hexapod-circle.json"),
            ("python benchmarks/step_time.py --robot arm --scenario seed-redundant --repeats 3",
             "python benchmarks/step_time.py --robot hexapod --scenario hexapod-circle --classical pinv --repeats 3"),
            "A user's loop step (`set_target`, `compute_velocity`, `integrate`) per controller and solver, "
            "block-interleaved; the p99 leaves out each block's first step."),
    Section("hierarchy-timing", "Strict hierarchies and SNS", tables.hierarchy_timing_table,
            ("hierarchy_timing.json",), ("python benchmarks/hierarchy_timing.py --repeats 3",),
            "The hierarchy (a QP per level) and SNS against their one-level counterparts; medians, and the ratios' "
            "median and range over the repeats."),
    Section("peers-arm", "Beside mink and placo: the arm", partial(tables.peers_table, scenario="seed-redundant"),
            ("peers_seed-redundant.json",), ("python benchmarks/compare_peers.py --repeats 3 --solvers daqp",),
            "Every contestant's step through `qpik compare`'s mapping of the scenario (the peers' step holds that "
            "glue), and how far each ends from the QP."),
    Section("peers-joint-limits", "Beside mink and placo: the arm's limits binding",
            partial(tables.peers_table, scenario="joint-limits"), ("peers_joint-limits.json",),
            ("python benchmarks/compare_peers.py --repeats 3 --solvers daqp",),
            "As above, on the arm's joint-limits scenario, where narrowed ranges bind on most steps."),
    Section("peers-hexapod", "Beside mink and placo: the hexapod",
            partial(tables.peers_table, scenario="hexapod-circle"), ("peers_hexapod-circle.json",),
            ("python benchmarks/compare_peers.py --repeats 3 --solvers daqp",),
            "As above, on the hexapod's circle with its six loops closed."),
    Section("placo-solve", "placo's compiled solve", tables.placo_solve_table, ("placo_solve.json",),
            ("python benchmarks/placo_solve.py",),
            "qpik's whole step against placo's compiled `solve` alone, and with its kinematics update."),
    Section("third-party", "Beside mink on third-party models", tables.third_party_table, ("third_party.json",),
            ("python benchmarks/third_party.py --repeats 3",),
            "Each side's step exactly as its user writes it (no qpik call in mink's), on models from dm_control, "
            "gymnasium and generated chains; the final configurations where both solve the same QP."),
    Section("batch-throughput", "Many robots at once: qpik.batch", tables.batch_throughput_table,
            ("batch_throughput.json",), ("python benchmarks/batch_throughput.py --repeats 3",),
            "Robot-steps per second of the batched engine against qpik's serial controller stepped robot after "
            "robot (N robots, 32 robots, one robot) and mink-warp's constrained solve on Warp's CPU device; every "
            "world against the serial controller after 1 s."),
    Section("rollout-speed", "Whole rollouts", tables.rollout_speed_table, ("rollout_speed.json",),
            ("python benchmarks/rollout_speed.py --against f6b657f",),
            "Building, rolling out and logging a scenario, this tree against an older commit, both imported in "
            "one process."),
    Section("monte-carlo-arm", "Monte Carlo: the arm", partial(tables.monte_carlo_table, robot="arm"),
            ("monte_carlo_arm.json",), ("python benchmarks/monte_carlo.py",),
            "Random reachable targets, a quintic move in 1 s then held 0.5 s; success = final error ≤ 1e−3 m and "
            "no range or speed violation beyond 1e−6."),
    Section("monte-carlo-hexapod", "Monte Carlo: the hexapod", partial(tables.monte_carlo_table, robot="hexapod"),
            ("monte_carlo_hexapod.json",), ("python benchmarks/monte_carlo.py",),
            "Random reachable poses (as for the calibration), a straight move; hard = the pose task as an "
            "equality, soft = weighted with LM damping."),
    Section("sweep-arm", "The arm's workspace: qpik sweep", partial(tables.sweep_table, robot="arm"),
            ("sweep_arm/summary.json", "sweep_arm/timing.json"),
            ("qpik sweep arm --targets 100000",),
            "Random targets, starts and gains through the batched engine, the QP beside the pseudoinverse law "
            "([sweep.md](sweep.md)); the sweep's summary.json and timing.json are kept as its recording."),
    Section("fuzz", "Fuzz: the bundled robots", tables.fuzz_table, ("fuzz.json",),
            ("python benchmarks/fuzz_bundled.py",),
            "Random arm and hexapod set-ups, physics rollouts and mutated scenes; a case may fall in several "
            "classes, defects in bold (every failing case, with its command, in fuzz.json)."),
    Section("fuzz-any-robot", "Fuzz: any robot", tables.fuzz_any_robot_table, ("fuzz_any_robot.json",),
            ("python benchmarks/fuzz_any_robot.py",),
            "Random MJCF chains and trees and third-party models, every task, limit and controller for 25 steps, "
            "a typed error judged by an independent LP; defects in bold."),
)

INTRO = """# Results

Generated by `python tools/results.py` from the JSON the benchmarks wrote under
[benchmarks/results/](../benchmarks/results/): do not edit by hand. Each table names the
command that records it and the machine the recording names; timings differ from machine
to machine. What the tables show, and how they were measured, is discussed in
[benchmarks.md](benchmarks.md).
"""


def machine(data: dict) -> str:
    """The machine a recording names (Python, architecture, CPUs, package versions), or ""."""
    meta, host = data.get("meta") or {}, data.get("machine")
    host = host if isinstance(host, dict) else {"arch": host}
    python = meta.get("python") or host.get("python") or data.get("python")
    parts = [f"Python {python}" if python else "", meta.get("machine") or host.get("arch") or "",
             f"{host.get('cpus') or data.get('cpus')} CPUs" if host.get("cpus") or data.get("cpus") else "",
             f"MuJoCo {meta['mujoco']}" if meta.get("mujoco") else "",
             *(f"{name} {v}" for name, v in (meta.get("versions") or {}).items())]
    return ", ".join(p for p in parts if p)


def command(data: dict) -> str:
    """The command a recording names (scripts renamed since, under their new name), or ""."""
    recorded = (data.get("meta") or {}).get("command") or data.get("command") or ""
    for old, new in RENAMED.items():
        recorded = recorded.replace(old, new)
    return recorded.strip()


def provenance(section: Section, results: Path) -> list[str]:
    """Where a table comes from: its files, the commands and the machines they name."""
    data = [tables.recorded(results, source) for source in section.sources]
    commands = list(dict.fromkeys(command(d) for d in data if command(d))) or list(section.commands)
    machines = list(dict.fromkeys(machine(d) for d in data if machine(d)))
    files = ", ".join(f"[{source}](../benchmarks/results/{source})" for source in section.sources)
    lines = [f"Recorded by {' and '.join(f'`{c}`' for c in commands)} in {files}; "
             f"machine: {'; '.join(machines) if machines else 'not recorded'}."]
    if section.recomputed:
        lines.append(f"The tests recompute it on the installed versions (`{RECOMPUTED_BY}`) and compare every cell "
                     "to one unit in its last printed digit.")
    return lines


def anchor(title: str) -> str:
    """GitHub's anchor for a heading: lower case, punctuation dropped, spaces as hyphens."""
    return re.sub(r"[^\w\- ]", "", title.lower()).replace(" ", "-")


def _wrapped(text: str) -> str:
    return textwrap.fill(text, width=WIDTH, break_long_words=False, break_on_hyphens=False)


def render_page(results: Path = RESULTS) -> str:
    parts = [INTRO, "| table | |\n|---|---|"]
    parts[-1] += "".join(f"\n| [{s.title}](#{anchor(s.title)}) | `{s.name}` |" for s in SECTIONS) + "\n"
    for section in SECTIONS:
        prose = [_wrapped(section.about), "", *map(_wrapped, provenance(section, results))]
        parts.append("\n".join([f"## {section.title}", "", *prose, "", section.render(results).rstrip("\n")]) + "\n")
    return "\n".join(parts)


def refresh(out: Path) -> int:
    """After a benchmark wrote its recording into ``out``: the page generated again when
    ``out`` is the repository's results folder (else it is left as is, and this says so)."""
    if Path(out).resolve() != RESULTS.resolve():
        print(f"{PAGE.relative_to(ROOT)} left as is: {out} is not {RESULTS.relative_to(ROOT)}, whose recordings it "
              "shows")
        return 0
    return main([])


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="compare with the page instead of writing it; "
                                                             "exit 1 where they differ")
    parser.add_argument("--results", type=Path, default=RESULTS, help="the recordings' folder")
    parser.add_argument("--out", type=Path, default=PAGE, help="the page")
    args = parser.parse_args(argv)
    try:
        page = render_page(args.results)
    except (tables.MissingResult, json.JSONDecodeError, KeyError) as exc:
        print(f"cannot render the results: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 2
    if args.check:
        current = args.out.read_text() if args.out.exists() else ""
        diff = list(difflib.unified_diff(current.splitlines(), page.splitlines(), str(args.out), "rendered",
                                         lineterm="", n=0))
        print("\n".join(diff[:60]) if diff else f"{args.out} is what the recordings give")
        return 1 if diff else 0
    write_text(args.out, page)
    print(f"wrote {args.out} ({len(SECTIONS)} tables from {args.results})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
