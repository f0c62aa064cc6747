"""The README against the code: its tables (qpik.app.readme_tables, whose command line is
benchmarks/readme_tables.py --check) and its Python examples (run as written).

The quick tables are recomputed here on the installed versions (the scenarios table takes
about 30 s): an edited number, or a change of the code that moves one, fails with the cell
named. Their numbers are compared to one unit in the last printed digit, rounding-level
values (below 1e-12) as one class: another CPU's rounding can flip a last digit, never
more on these well-conditioned runs. The chaotic row is a range over BLAS kernels,
compared with its recording. The recorded tables (timings, sweeps) are compared with the
JSON their benchmark wrote.
"""

import re
import subprocess
import sys
from pathlib import Path

import pytest

from qpik.app import readme_tables, scenarios_table

ROOT = Path(__file__).resolve().parents[1]
README_PATH = ROOT / "README.md"
RESULTS = ROOT / "benchmarks" / "results"
README = README_PATH.read_text()


@pytest.mark.parametrize("name", list(readme_tables.TABLES))
def test_readme_table_matches_the_code(name):
    problems = readme_tables.check([name], README_PATH, RESULTS)
    assert not problems, "\n".join(problems)


def test_the_check_names_an_edited_cell(tmp_path):
    """An edited README number fails the check, which names the row and the column."""
    readme = tmp_path / "README.md"
    block = readme_tables.read_block(README, "calibration")
    # One unit in the last printed digit is what another CPU's rounding may give: agreed.
    readme.write_text(readme_tables.write_block(README, "calibration", block.replace("| 1 | 2.1 |", "| 1 | 2.2 |", 1)))
    assert readme_tables.check(["calibration"], readme, RESULTS) == []
    edited = block.replace("| 1 | 2.1 |", "| 1 | 2.5 |", 1)
    assert edited != block
    readme.write_text(readme_tables.write_block(README, "calibration", edited))
    problems = readme_tables.check(["calibration"], readme, RESULTS)
    assert problems == ["calibration: row `qpik calibrate`, column 'condition number': README has 2.5, "
                        "the code gives 2.1"]
    # A recorded table: a timing edited in the README no longer matches its JSON.
    block = readme_tables.read_block(README, "step-time")
    first_row = block.splitlines()[2]
    cells = first_row.split("|")
    cells[3] = " 99.9 "
    readme.write_text(readme_tables.write_block(README, "step-time", block.replace(first_row, "|".join(cells))))
    problems = readme_tables.check(["step-time"], readme, RESULTS)
    assert len(problems) == 1 and "column 'median [µs]': README has 99.9" in problems[0]


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
    assert readme_tables.cells_agree(want, have) is agree
    assert readme_tables.cells_agree(have, want) is agree


def test_rounding_level_values_print_as_one_class():
    # 0 on one CPU, a few ε on another: the same cell (they printed `< 1e-12` and `0.00e+00`).
    assert {scenarios_table.format_cell(v, ".2e") for v in (0.0, 2.48e-16, -3e-16, 9.9e-13)} == {"0"}
    assert scenarios_table.format_cell(1.5e-12, ".2e") == "1.50e-12" and scenarios_table.format_cell(None, ".2e") == "-"


def test_chaotic_rows_are_ranges_over_kernels_and_stated_in_the_readme():
    record = scenarios_table.load_chaotic(RESULTS / "scenarios_chaotic.json")
    assert len(record["kernels"]) >= 2 and len(set(record["kernels"])) == len(record["kernels"])
    block = readme_tables.read_block(README, "scenarios")
    recorded = scenarios_table.recorded_runs(record)
    for key in scenarios_table.CHAOTIC:
        runs = [(kernel, s) for kernel, s in recorded if scenarios_table.row_key(s) == key]
        assert sorted(kernel for kernel, _ in runs) == sorted(record["kernels"])
        row = next(line for line in block.splitlines() if line.startswith(f"| {key[0]} | {key[1]} | {key[2]} (chaotic"))
        low, high = min(s.max_error for _, s in runs), max(s.max_error for _, s in runs)
        assert f"{low:.2e}–{high:.2e}" in row
    assert "is chaotic" in README


def test_a_stopped_run_is_flagged_in_its_row():
    """qp-hard on too-fast stops at 0.056 s (its hard task becomes infeasible within the
    speed limits): its row says so, in the table the script writes and in the README, so
    its short run's small errors do not read as the best result."""
    from qpik.app.runs import compare

    _, logs, _ = compare("arm", "too-fast", ["daqp"], classical=("qp-hard", "pinv"), peers=())
    table = scenarios_table.to_markdown([log.summary() for log in logs]).splitlines()
    flagged = {line.split("|")[3].strip(): line.split("|")[-2].strip() for line in table[2:]}
    assert flagged == {"qp (daqp)": "complete", "qp-hard (daqp)": "stopped at 0.056 s: infeasible",
                       "pinv": "complete"}
    block = readme_tables.read_block(README, "scenarios")
    row = next(line for line in block.splitlines() if line.startswith("| too-fast | kinematic | qp-hard"))
    assert row.split("|")[-2].strip() == "stopped at 0.056 s: infeasible"


PYTHON_BLOCKS = re.findall(r"```python\n(.*?)```", README, re.S)


@pytest.mark.parametrize("code", PYTHON_BLOCKS, ids=[f"example{i}" for i in range(len(PYTHON_BLOCKS))])
def test_readme_python_examples_run_and_print_what_they_achieved(code, tmp_path):
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip()


def test_the_api_example_prints_what_the_readme_says():
    code = PYTHON_BLOCKS[0]
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    claimed = re.search(r"prints `(.*?)`", README).group(1)
    assert done.stdout.strip() == claimed
