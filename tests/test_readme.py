"""The README against the code: its tables (benchmarks/readme_tables.py --check) and its
Python examples (run as written).

The quick tables are recomputed here on the installed versions (the scenarios table takes
about 30 s): an edited number, or a change of the code that moves one, fails with the cell
named. The recorded tables (timings, sweeps) are compared with the JSON their benchmark
wrote. One row is skipped, with its reason (readme_tables.SKIPPED).
"""

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

import readme_tables  # noqa: E402

README = (ROOT / "README.md").read_text()


@pytest.mark.parametrize("name", list(readme_tables.TABLES))
def test_readme_table_matches_the_code(name):
    problems = readme_tables.check([name])
    assert not problems, "\n".join(problems)


def test_the_check_names_an_edited_cell(tmp_path):
    """An edited README number fails the check, which names the row and the column."""
    readme = tmp_path / "README.md"
    block = readme_tables.read_block(README, "calibration")
    edited = block.replace("| 1 | 2.1 |", "| 1 | 2.2 |", 1)
    assert edited != block
    readme.write_text(readme_tables.write_block(README, "calibration", edited))
    problems = readme_tables.check(["calibration"], readme)
    assert problems == ["calibration: row `qpik calibrate`, column 'condition number': README has 2.2, "
                        "the code gives 2.1"]
    # A recorded table: a timing edited in the README no longer matches its JSON.
    block = readme_tables.read_block(README, "step-time")
    first_row = block.splitlines()[2]
    cells = first_row.split("|")
    cells[3] = " 99.9 "
    readme.write_text(readme_tables.write_block(README, "step-time", block.replace(first_row, "|".join(cells))))
    problems = readme_tables.check(["step-time"], readme)
    assert len(problems) == 1 and "column 'median [µs]': README has 99.9" in problems[0]


def test_skipped_cells_are_stated_in_the_readme():
    for (table, key), reason in readme_tables.SKIPPED.items():
        assert " / ".join(k for k in key if k != "kinematic") in README
        assert "chaotic" in reason and "is chaotic" in README


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
