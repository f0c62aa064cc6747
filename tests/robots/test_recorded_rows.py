"""The recorded scenario rows and calibration rows against the code: recomputed here on
the installed versions (about 30 s and 2 s) and compared, cell by cell, with what
benchmarks/scenarios_table.py and benchmarks/calibration.py recorded under
benchmarks/results/ (the tables of docs/results.md).

Numbers are compared to one unit in their last printed digit, rounding-level values
(below 1e-12) as one class: another CPU's rounding can flip a last digit, never more on
these well-conditioned runs. The chaotic row is a range over BLAS kernels, compared with
its recording. A change of the code that moves a printed number fails here, naming the
cell; a change that should move it is recorded again by its benchmark.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from qpik.app.progress import wanted
from tools import scenarios_table, tables

RESULTS = Path(__file__).resolve().parents[2] / "benchmarks" / "results"


def test_every_scenario_row_is_the_recorded_one():
    rows = scenarios_table.compute_rows(progress=wanted())
    computed = scenarios_table.to_markdown(rows, scenarios_table.load_chaotic(RESULTS / "scenarios_chaotic.json"))
    problems = tables.compare("scenarios", computed, tables.scenarios_table(RESULTS), key_columns=3, tolerant=True)
    assert not problems, "\n".join(problems)


def test_every_calibration_row_is_the_recorded_one():
    computed = tables.calibration_markdown(tables.calibration_rows())
    problems = tables.compare("calibration", computed, tables.calibration_table(RESULTS), key_columns=1,
                              tolerant=True)
    assert not problems, "\n".join(problems)


def test_the_comparison_names_an_edited_cell():
    """One unit in the last printed digit is what another CPU's rounding may give: agreed;
    more is named by row and column."""
    recorded = tables.calibration_table(RESULTS)
    assert "| 1 | 2.1 |" in recorded
    nearby = recorded.replace("| 1 | 2.1 |", "| 1 | 2.2 |", 1)
    assert tables.compare("calibration", recorded, nearby, key_columns=1, tolerant=True) == []
    edited = recorded.replace("| 1 | 2.1 |", "| 1 | 2.5 |", 1)
    assert tables.compare("calibration", recorded, edited, key_columns=1, tolerant=True) == [
        "calibration: row `qpik calibrate`, column 'condition number': recorded 2.5, the code gives 2.1"]
    missing = "\n".join(line for line in recorded.splitlines() if "gauss-newton" not in line)
    assert tables.compare("calibration", recorded, missing, key_columns=1, tolerant=True) == [
        "calibration: row `qpik calibrate --method gauss-newton` is missing from the recording"]


@pytest.mark.parametrize("want, have, agree", [
    ("6.79e-07", "6.79e-07", True),
    ("6.79e-07", "6.80e-07", True),              # a last digit flipped by rounding
    ("6.79e-07", "6.81e-07", False),
    ("0", "0", True),
    ("0", "3.1e-13", True),                      # rounding-level: one class
    ("0", "2.1e-07", False),
    ("0.0507 / 0.0420", "0.0507 / 0.0421", True),
    ("0.0507 / 0.0420", "0.0507 / 0.0423", False),
    ("197", "198", True), ("8", "9", False), ("1.25", "1.26", True),
    ("complete", "stopped at 0.056 s: infeasible", False),
    ("stopped at 0.056 s: infeasible", "stopped at 0.056 s: diverged", False),
])
def test_numbers_agree_to_their_last_printed_digit(want, have, agree):
    assert tables.cells_agree(want, have) is agree
    assert tables.cells_agree(have, want) is agree


def test_rounding_level_values_print_as_one_class():
    # 0 on one CPU, a few ε on another: the same cell (they printed `< 1e-12` and `0.00e+00`).
    assert {scenarios_table.format_cell(v, ".2e") for v in (0.0, 2.48e-16, -3e-16, 9.9e-13)} == {"0"}
    assert scenarios_table.format_cell(1.5e-12, ".2e") == "1.50e-12"
    assert scenarios_table.format_cell(None, ".2e") == "-"


def test_chaotic_rows_are_ranges_over_the_recorded_kernels():
    record = scenarios_table.load_chaotic(RESULTS / "scenarios_chaotic.json")
    assert len(record["kernels"]) >= 2 and len(set(record["kernels"])) == len(record["kernels"])
    table = tables.scenarios_table(RESULTS)
    recorded = scenarios_table.recorded_runs(record)
    for key in scenarios_table.CHAOTIC:
        runs = [(kernel, s) for kernel, s in recorded if scenarios_table.row_key(s) == key]
        assert sorted(kernel for kernel, _ in runs) == sorted(record["kernels"])
        row = next(line for line in table.splitlines() if line.startswith(f"| {key[0]} | {key[1]} | {key[2]} (chaotic"))
        low, high = min(s.max_error for _, s in runs), max(s.max_error for _, s in runs)
        assert f"{low:.2e}–{high:.2e}" in row


def test_a_stopped_run_is_flagged_in_its_row():
    """qp-hard on too-fast stops at 0.056 s (its hard task becomes infeasible within the
    speed limits): its row says so, in the table the code writes and in the recording,
    so its short run's small errors do not read as the best result."""
    from qpik.app.runs import compare

    _, logs, _ = compare("arm", "too-fast", ["daqp"], classical=("qp-hard", "pinv"), peers=())
    table = scenarios_table.to_markdown([log.summary() for log in logs]).splitlines()
    flagged = {line.split("|")[3].strip(): line.split("|")[-2].strip() for line in table[2:]}
    assert flagged == {"qp (daqp)": "complete", "qp-hard (daqp)": "stopped at 0.056 s: infeasible",
                       "pinv": "complete"}
    row = next(line for line in tables.scenarios_table(RESULTS).splitlines()
               if line.startswith("| too-fast | kinematic | qp-hard"))
    assert row.split("|")[-2].strip() == "stopped at 0.056 s: infeasible"
