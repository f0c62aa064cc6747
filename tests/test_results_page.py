"""docs/results.md is what ``python tools/results.py`` renders from the committed
recordings (benchmarks/results/*.json): the tables, their commands and machines, never
prose. Rendering reads JSON only (no benchmark runs), so the check costs well under 5 s;
whether the recordings still match the code is tests/robots/test_recorded_rows.py's."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

from tools import results

ROOT = Path(__file__).resolve().parents[1]


def test_the_page_is_what_the_recordings_give():
    page = results.render_page(results.RESULTS)
    assert page == results.PAGE.read_text(), "docs/results.md drifted: run python tools/results.py"


def test_every_recording_on_the_page_names_its_command_and_every_table_is_linked():
    page = results.PAGE.read_text()
    for section in results.SECTIONS:
        assert f"## {section.title}\n" in page
        assert f"(#{results.anchor(section.title)})" in page
        for source in section.sources:
            assert f"(../benchmarks/results/{source})" in page
            assert (results.RESULTS / source).is_file()
    recorded = [results.command(json.loads((results.RESULTS / s).read_text()))
                for section in results.SECTIONS for s in section.sources]
    scripts = {m for c in recorded + [c for s in results.SECTIONS for c in s.commands]
               for m in re.findall(r"benchmarks/\w+\.py", c)}
    assert scripts and all((ROOT / script).is_file() for script in scripts), scripts  # no renamed script left


def test_anchors_are_githubs():
    assert results.anchor("Beside mink and placo: the arm") == "beside-mink-and-placo-the-arm"
    assert results.anchor("Many robots at once: qpik.batch") == "many-robots-at-once-qpikbatch"
    assert results.anchor("placo's compiled solve") == "placos-compiled-solve"


def test_the_check_fails_on_a_drifted_page_and_names_the_line(tmp_path, capsys):
    page = tmp_path / "results.md"
    page.write_text(results.PAGE.read_text().replace("| seed-primary | kinematic | qp (daqp) | 6.79e-07",
                                                     "| seed-primary | kinematic | qp (daqp) | 6.80e-07", 1))
    assert results.main(["--check", "--out", str(page)]) == 1
    assert "6.80e-07" in capsys.readouterr().out
    assert results.main(["--out", str(page)]) == 0
    assert results.main(["--check", "--out", str(page)]) == 0


def test_a_missing_recording_is_one_line_and_exit_code_2(tmp_path):
    folder = tmp_path / "results"
    shutil.copytree(results.RESULTS, folder, ignore=shutil.ignore_patterns("*.npz", "*.png"))
    (folder / "third_party.json").unlink()
    done = subprocess.run([sys.executable, str(ROOT / "tools" / "results.py"), "--results", str(folder), "--out",
                           str(tmp_path / "page.md")], capture_output=True, text=True, cwd=tmp_path)
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [
        f"cannot render the results: MissingResult: {folder / 'third_party.json'} is missing: run its benchmark first"]
    assert not (tmp_path / "page.md").exists()
