"""The results tables, each rendered from the JSON its benchmark wrote under
``benchmarks/results/`` (:mod:`tools.results` puts them on ``docs/results.md``), and the
comparison of a recomputed table with its recording.

Every renderer takes the results folder. The scenarios' and the calibration's rows are
recorded too (``benchmarks/scenarios_table.py``, ``benchmarks/calibration.py``); a test
recomputes them on the installed versions and compares every cell with the recording
(:func:`compare` with ``tolerant``: numbers to one unit in their last printed digit,
:func:`cells_agree`, as another CPU's rounding may flip it).
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Sequence

import numpy as np

from qpik.app.runs import run_label
from qpik.rollout.log import RunSummary

# A number in a cell: 6.79e-07, 0.188, 197, -1.5.
NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:e[-+]?\d+)?", re.I)
# Below this two values are the same rounding-level value (the tables print it as 0).
ROUNDING = 1e-12


class MissingResult(FileNotFoundError):
    """A table's recording is not in the results folder: its benchmark has not run."""


def _cells(line: str) -> list[str]:
    return [c.strip() for c in line.strip().strip("|").split("|")]


def parse_table(markdown: str) -> tuple[list[str], list[list[str]]]:
    lines = [line for line in markdown.splitlines() if line.strip().startswith("|")]
    if len(lines) < 2:
        raise ValueError(f"not a markdown table:\n{markdown}")
    return _cells(lines[0]), [_cells(line) for line in lines[2:]]


def _last_digit(number: str) -> float:
    """The unit of a printed number's last digit: 1e-9 for 6.79e-07, 0.001 for 0.188; an
    integer (from a 3-significant-digit format) is good to its third digit, at most 1;
    0 is exact."""
    mantissa, _, exponent = number.lower().partition("e")
    scale = 10.0 ** int(exponent or 0)
    if "." in mantissa:
        return scale * 10.0 ** -len(mantissa.split(".")[1])
    value = abs(float(mantissa))  # 0 is the rounding class: ROUNDING covers it
    return scale * min(1.0, 10.0 ** (len(str(int(value))) - 3)) if value else 0.0


def cells_agree(want: str, have: str) -> bool:
    """The same text around numbers that agree to one unit in the last printed digit (the
    coarser of the two), or are both rounding-level (within ROUNDING): what two CPUs that
    round differently print for one quantity."""
    if want == have:
        return True
    numbers_w, numbers_h = NUMBER.findall(want), NUMBER.findall(have)
    if NUMBER.sub("#", want) != NUMBER.sub("#", have) or len(numbers_w) != len(numbers_h):
        return False
    return all(abs(float(a) - float(b)) <= max(_last_digit(a), _last_digit(b)) * (1 + 1e-9) + ROUNDING
               for a, b in zip(numbers_w, numbers_h))


def compare(name: str, expected: str, actual: str, key_columns: int, tolerant: bool = False) -> list[str]:
    """Every cell where ``actual`` (the recording) differs from ``expected`` (the code),
    named; ``tolerant``: numbers compared with :func:`cells_agree` (a recomputed table)."""
    header, rows = parse_table(expected)
    header_r, rows_r = parse_table(actual)
    if header != header_r:
        return [f"{name}: header {header_r} in the recording, the code writes {header}"]
    problems = []
    keyed = {tuple(r[:key_columns]): r for r in rows_r}
    for row in rows:
        key = tuple(row[:key_columns])
        other = keyed.pop(key, None)
        if other is None:
            problems.append(f"{name}: row {' / '.join(key)} is missing from the recording")
            continue
        for column, (want, have) in enumerate(zip(row, other)):
            if not (cells_agree(want, have) if tolerant else want == have):
                problems.append(f"{name}: row {' / '.join(key)}, column '{header[column]}': recorded {have}, "
                                f"the code gives {want}")
    problems += [f"{name}: row {' / '.join(k)} is recorded but not produced" for k in keyed]
    return problems


# Renderers --------------------------------------------------------------------------
def ratio_cell(ratio: dict) -> str:
    """``0.42 (0.40–0.45)``: a ratio's median over the repeats and its range."""
    return f"{ratio['median']:.2f} ({ratio['min']:.2f}–{ratio['max']:.2f})"


def _label(controller: str, solver: str, robot: str = "") -> str:
    if controller == "pinv" and robot == "hexapod":
        return "pinv (inverse Jacobian)"
    return run_label(controller, solver)


def recorded(results: Path, name: str) -> dict:
    """The JSON a benchmark wrote (``name`` relative to the results folder)."""
    path = Path(results) / name
    if not path.exists():
        raise MissingResult(f"{path} is missing: run its benchmark first")
    return json.loads(path.read_text())


def step_time_table(results: Path) -> str:
    lines = ["| robot / scenario | controller | median [µs] | p99 [µs] | ratio to pinv |",
             "|---|---|---:|---:|---:|"]
    for scenario in ("seed-redundant", "hexapod-circle"):
        data = recorded(results, f"step_time_{scenario}.json")
        reference = next(r["median_us"] for r in data["rows"] if r["controller"] == "pinv")
        for r in data["rows"]:
            lines.append(f"| {data['robot']} / {scenario} | {_label(r['controller'], r['solver'], data['robot'])} | "
                         f"{r['median_us']:.1f} | {r['p99_us']:.1f} | {r['median_us'] / reference:.2f} |")
    return "\n".join(lines) + "\n"


def peers_table(results: Path, scenario: str) -> str:
    data = recorded(results, f"peers_{scenario}.json")
    summaries = [RunSummary.from_json(r["summary"]) for r in data["rows"]]
    loops = all(s.constraint_violation_max is not None for s in summaries)
    lines = [f"| {data['robot']} / {scenario} | median [µs] | p99 [µs] | max error [m] | "
             + ("loop residual [m] | " if loops else "") + "max \\|Δq_final\\| vs qp (daqp) |",
             "|---|---:|---:|---:|" + ("---:|" if loops else "") + "---:|"]
    for r, s in zip(data["rows"], summaries):
        dq = r["q_final_vs_qp_daqp"]
        loop = f"{s.constraint_violation_max:.1e} | " if loops else ""
        lines.append(f"| {_label(s.info.controller, s.info.solver, data['robot'])} | {r['median_us']:.1f} | "
                     f"{r['p99_us']:.1f} | {s.max_error:.2e} | {loop}{'0' if dq == 0 else f'{dq:.1e}'} |")
    return "\n".join(lines) + "\n"


def _violation(value: float, unit: str) -> str:
    return "0" if value == 0 else f"{value:.1e} {unit}"


def monte_carlo_table(results: Path, robot: str) -> str:
    data = recorded(results, f"monte_carlo_{robot}.json")
    hard = {(r["controller"], r["solver"]): r for r in data["results"]["hard"]}
    soft = {(r["controller"], r["solver"]): r for r in data["results"]["soft"]}
    speed_unit = "rad/s" if robot == "arm" else "m/s"
    range_unit = "rad" if robot == "arm" else "m"
    # Step times are left out: the sweep runs for hours beside other work; the timing
    # tables above measure them interleaved.
    lines = ["| controller | success, hard task | success, soft task | range violation max (hard / soft) | "
             "speed violation max (hard / soft) | max error p99 [m] (hard / soft) |",
             "|---|---:|---:|---:|---:|---:|"]
    for key, h in hard.items():
        s = soft[key]
        lines.append(
            f"| {_label(*key, robot)} | {100 * h['success_rate']:.1f} % | {100 * s['success_rate']:.1f} % | "
            f"{_violation(h['limit_violation_max'], range_unit)} / {_violation(s['limit_violation_max'], range_unit)} | "
            f"{_violation(h['speed_violation_max'], speed_unit)} / {_violation(s['speed_violation_max'], speed_unit)} | "
            f"{h['max_error_p99']:.1e} / {s['max_error_p99']:.1e} |")
    return "\n".join(lines) + "\n"


def third_party_table(results: Path) -> str:
    """qpik beside mink on the third-party and generated models (benchmarks/third_party.py)."""
    data = recorded(results, "third_party.json")
    lines = ["| problem | qpik [µs] | mink [µs] | qpik / mink (range) | the script's bound | "
             "max \\|q_qpik − q_mink\\| | qpik max error |",
             "|---|---:|---:|---:|---|---:|---:|"]
    for case in data["cases"]:
        rows = {row["label"]: row for row in case["timing"]["rows"]}
        ratio = case["timing"]["ratio"]
        run = case["runs"]["qpik"]
        if "distance_min" in run:  # different collision bounds: the trajectories differ by design
            difference = "(other bound)"
            error = f"{collision_gap(case):.1e} m inside d_min (mink: {collision_gap(case, 'mink'):.1e} m)"
        else:
            difference = f"{case['differences']['mink']['q_max_difference']:.0e}"
            error = f"{run['max_error']:.1e} m"
        bound = case["ratio_bound"]
        bound = "-" if bound is None else f"≤ {bound:.2f}: {'met' if ratio['median'] <= bound else '**missed**'}"
        lines.append(f"| {case['title']} | {rows['qpik']['median_us']:.1f} | {rows['mink']['median_us']:.1f} | "
                     f"{ratio['median']:.2f} ({ratio['min']:.2f}–{ratio['max']:.2f}) | {bound} | {difference} | "
                     f"{error} |")
    return "\n".join(lines) + "\n"


def collision_gap(case: dict, label: str = "qpik") -> float:
    """How far inside the minimum distance a contender's hand came (0 when never)."""
    run = case["runs"][label]
    return max(0.0, case["minimum_distance"] - run["distance_min"])


def _spread(values) -> str:
    values = sorted(values)
    middle = values[len(values) // 2] if len(values) % 2 else 0.5 * (values[len(values) // 2 - 1] + values[len(values) // 2])
    return f"{middle:.2f} ({values[0]:.2f}–{values[-1]:.2f})"


def hierarchy_timing_table(results: Path) -> str:
    """Strict hierarchies against their one-QP / one-pseudoinverse counterparts
    (benchmarks/hierarchy_timing.py): median step and the ratios over the repeats."""
    data = recorded(results, "hierarchy_timing.json")
    lines = ["| scenario | levels (hqp) | pinv [µs] | sns [µs] | qp [µs] | hqp [µs] | sns / pinv | hqp per level / qp |",
             "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for scenario, r in data["results"].items():
        median = {kind: sorted(v)[len(v) // 2] for kind, v in r["median_us"].items()}
        lines.append(f"| {scenario} | {r['levels']['hqp']} | {median['pinv']:.1f} | {median['sns']:.1f} | "
                     f"{median['qp']:.1f} | {median['hqp']:.1f} | {_spread(r['ratios']['sns / pinv'])} | "
                     f"{_spread(r['ratios']['hqp per level / qp'])} |")
    return "\n".join(lines) + "\n"


def rollout_speed_table(results: Path) -> str:
    """Whole rollouts of this tree against an older commit (benchmarks/rollout_speed.py)."""
    data = recorded(results, "rollout_speed.json")
    this = {(r["robot"], r["scenario"]): r for r in data["rows"] if r["version"].startswith("this tree")}
    old = {(r["robot"], r["scenario"]): r for r in data["rows"] if not r["version"].startswith("this tree")}
    lines = [f"| robot / scenario | this tree [ms] | {data['meta']['against']} [ms] | speed-up (range over rounds) |",
             "|---|---:|---:|---:|"]
    for s in data["speedups"]:
        key = (s["robot"], s["scenario"])
        lines.append(f"| {key[0]} / {key[1]} | {1e3 * this[key]['median_s']:.1f} | {1e3 * old[key]['median_s']:.1f} | "
                     f"{s['speedup_median']:.2f}× ({s['speedup_min']:.2f}–{s['speedup_max']:.2f}) |")
    return "\n".join(lines) + "\n"


def placo_solve_markdown(results: Sequence[dict], repeats: int) -> str:
    """benchmarks/placo_solve.py's table: qpik's whole step against placo's compiled work."""
    lines = [f"qpik's whole step (set_target, compute_velocity, integrate) against placo's compiled `solve` alone, and "
             f"against its compiled work per step (`update_kinematics` + `solve`); block-interleaved, gc off, "
             f"{repeats} repeats (medians over the repeats' medians; the ratios' median and range).", "",
             "| robot / scenario | qp (daqp) step [µs] | placo step [µs] | placo solve [µs] | "
             "placo kinematics + solve [µs] | qp step / placo solve | qp step / placo kinematics + solve |",
             "|---|---:|---:|---:|---:|---:|---:|"]
    for r in results:
        lines.append(f"| {r['robot']} / {r['scenario']} | {np.median(r['qp_step_median_us']):.1f} | "
                     f"{np.median(r['placo_step_median_us']):.1f} | {np.median(r['placo_solve_median_us']):.1f} | "
                     f"{np.median(r['placo_compiled_median_us']):.1f} | "
                     f"{ratio_cell(r['ratio'])} | {ratio_cell(r['compiled_ratio'])} |")
    return "\n".join(lines) + "\n"


def placo_solve_table(results: Path) -> str:
    """qpik's whole step against placo's compiled solve alone (benchmarks/placo_solve.py)."""
    data = recorded(results, "placo_solve.json")
    return "\n".join(placo_solve_markdown(data["results"], data["meta"]["repeats"]).splitlines()[2:]) + "\n"


def fuzz_table(results: Path) -> str:
    from benchmarks.fuzz.bundled_sweep import outcome_table

    return "\n".join(outcome_table(recorded(results, "fuzz.json")["counts"])) + "\n"


def fuzz_any_robot_table(results: Path) -> str:
    """The any-robot fuzz's cases per class (defects in bold; benchmarks/fuzz_any_robot.py);
    the N-world classes where the recording ran cases on N worlds (``--batched``)."""
    from benchmarks.fuzz.cases import CLASSES
    from benchmarks.fuzz.sweep import BATCH_CLASSES

    data = recorded(results, "fuzz_any_robot.json")
    counts = data["counts"]
    shown = [c for c in CLASSES if c[0] not in BATCH_CLASSES or data["meta"].get("batched_every")]
    lines = ["| class | cases |", "|---|---:|", f"| cases run | {counts['cases']} |"]
    lines += [f"| {'**' + label + '**' if bad else label} | {counts.get(key, 0)} |" for key, label, bad in shown]
    return "\n".join(lines) + "\n"


# The calibration table's commands: (method, how the README's user runs it).
CALIBRATION_COMMANDS = (("linear", "`qpik calibrate`"), ("gauss-newton", "`qpik calibrate --method gauss-newton`"),
                        ("lm", "`qpik calibrate --method lm` (SciPy, MINPACK)"))


def calibration_rows() -> list[dict]:
    """Each method's calibration on the source's seed poses, as the table needs it
    (about 2 s; recorded by benchmarks/calibration.py, recomputed by the tests).

    ``floor_pct`` is the rounding floor of the relative error: the strokes are computed
    to ε·L (every length of the hexapod is under L = 1 m), which the fit carries into the
    parameters amplified by its condition number κ, so errors below 100·κ·ε·L /
    |smallest deviation| percent are rounding, whose digits change with the BLAS kernel."""
    from qpik.robots.hexapod.calibration import calibrate

    rows = []
    for method, command in CALIBRATION_COMMANDS:
        result = calibrate(method)
        deviation = min(abs(v) for v in result.reference if v != 0)
        rows.append({"method": method, "command": command, "parameters": int(result.params.size),
                     "worst_relative_error_pct": float(max(v for v in result.relative_error_pct if v == v)),
                     "floor_pct": float(100 * result.ident.condition_number * np.finfo(float).eps / deviation),
                     "iterations": int(result.fit.iterations),
                     "condition_number": float(result.ident.condition_number)})
    return rows


def calibration_markdown(rows: Sequence[dict]) -> str:
    lines = ["| command | parameters | max relative error | iterations | condition number |",
             "|---|---|---:|---:|---:|"]
    for r in rows:
        worst, floor = r["worst_relative_error_pct"], r["floor_pct"]
        error = f"< {floor:.0e} %" if worst < floor else f"{worst:.2g} %"
        lines.append(f"| {r['command']} | {r['parameters']} leg lengths | {error} | {r['iterations']} | "
                     f"{r['condition_number']:.2g} |")
    return "\n".join(lines) + "\n"


def calibration_table(results: Path) -> str:
    return calibration_markdown(recorded(results, "calibration.json")["rows"])


def scenarios_table(results: Path) -> str:
    """Every named scenario's rows as benchmarks/scenarios_table.py recorded them, the
    chaotic rows as their range over the recorded BLAS kernels."""
    from .scenarios_table import load_chaotic, to_markdown

    runs = [RunSummary.from_json(r) for r in recorded(results, "scenarios.json")["runs"]]
    return to_markdown(runs, load_chaotic(Path(results) / "scenarios_chaotic.json"))


def _speedup(row: dict, against: str) -> str:
    ratio = row.get(f"speedup vs {against}")
    return "–" if ratio is None else f"{ratio['median']:.1f}× ({ratio['min']:.1f}–{ratio['max']:.1f})"


def batch_throughput_table(results: Path) -> str:
    """qpik.batch against qpik's serial loop and mink-warp (benchmarks/batch_throughput.py),
    at the batch sizes the README's claims are about."""
    data = recorded(results, "batch_throughput.json")
    lines = ["| robot | N | qpik.batch [robot-steps/s] | vs the serial loop (N robots) | vs 32 robots' loop | "
             "vs one robot's loop | vs mink-warp constrained | max \\|q_batch − q_serial\\| after 1 s [rad] |",
             "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for robot, table in data["throughput"].items():
        exact = data["accuracy"][robot]["max_q_difference"]
        for row in (r for r in table["rows"] if r["n"] >= 1024):
            lines.append(f"| {robot} | {row['n']} | {row['qpik.batch']['robot_steps_per_s']:.3g} | "
                         f"{_speedup(row, 'qpik serial (N robots)')} | {_speedup(row, 'qpik serial (32 robots)')} | "
                         f"{_speedup(row, 'qpik serial (1 robot)')} | "
                         f"{_speedup(row, 'mink-warp constrained')} | {exact:.1e} |")
    return "\n".join(lines) + "\n"


def sweep_table(results: Path, robot: str) -> str:
    from qpik.app.sweep.report import table

    return table(recorded(results, f"sweep_{robot}/summary.json"))
