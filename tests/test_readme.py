"""The README as a front page: its size, its two commands up front, its examples run as
printed (and docs/usage.md's), its headline numbers those of the recordings they link
to, every link and figure it shows present."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from tools import results

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()
USAGE = (ROOT / "docs" / "usage.md").read_text()
RECORDINGS = ROOT / "benchmarks" / "results"
MAIN_JOB = ('python3 -m venv .venv && . .venv/bin/activate && pip install -c constraints.txt -e ".[peers]" && '
            "qpik compare arm --scenario seed-redundant --plot --out out/seed-redundant")
TESTS = ('python3 -m venv .venv && . .venv/bin/activate && pip install -c constraints.txt -e ".[test,peers]" && '
         "python -m pytest -q -n 2")


def test_the_readme_is_a_front_page():
    assert len(README.encode()) <= 12_000
    first = README.splitlines()[:25]
    assert MAIN_JOB in first and TESTS in first
    ci = next(line for line in README.splitlines() if "`.ci/run`" in line)
    assert "ruff check" in ci + README and ".ci/blas_kernel.py" in README
    # Nothing about how the project was made: a reader cannot use it.
    assert not re.search(r"this round|was lent|no GPU was|session|issue \d", README, re.I)


def _run(code: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=cwd)


def _examples(text: str) -> list[tuple[str, str | None]]:
    """Each python block and what the text right after it says it prints, if it says."""
    found = []
    for match in re.finditer(r"```python\n(.*?)```\s*\n(prints `(.*?)`)?", text, re.S):
        found.append((match.group(1), match.group(3)))
    return found


EXAMPLES = [(f"README-{i}", code, claim) for i, (code, claim) in enumerate(_examples(README))] + \
           [(f"usage-{i}", code, claim) for i, (code, claim) in enumerate(_examples(USAGE))]


@pytest.mark.parametrize("code, claim", [e[1:] for e in EXAMPLES], ids=[e[0] for e in EXAMPLES])
def test_the_examples_run_and_print_what_they_achieved(code, claim, tmp_path):
    done = _run(code, tmp_path)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip()
    if claim is not None:
        assert done.stdout.strip() == claim


def test_the_readme_shows_the_serial_and_the_batched_example():
    (serial, said), (batched, said_batched) = _examples(README)
    assert "QPController(robot" in serial and said.startswith("end effector at")
    assert "batch.QPController(robots" in batched and said_batched.startswith("farthest arm")


def _recorded(name: str) -> dict:
    return json.loads((RECORDINGS / name).read_text())


def _step_time() -> str:
    rows = _recorded("step_time_seed-redundant.json")["rows"]
    return f"{next(r['median_us'] for r in rows if (r['controller'], r['solver']) == ('qp', 'daqp')):.1f} µs"


def _beside_mink() -> str:
    case = next(c for c in _recorded("third_party.json")["cases"] if c["title"].startswith("Kinova Jaco"))
    return f"{case['timing']['ratio']['median']:.2f} ×"


def _batch() -> str:
    rows = _recorded("batch_throughput.json")["throughput"]["arm"]["rows"]
    return f"{next(r for r in rows if r['n'] == 1024)['speedup vs qpik serial (N robots)']['median']:.1f} ×"


def _joint_limits() -> str:
    runs = _recorded("scenarios.json")["runs"]
    pinv = next(r for r in runs if (r["scenario"], r["controller"]) == ("joint-limits", "pinv"))
    assert all(r["limit_violation_max"] == 0 for r in runs
               if r["scenario"] == "joint-limits" and r["controller"] in ("qp", "hqp", "sns"))
    return f"{pinv['limit_violation_max']:.2f} rad"


def _fuzz() -> str:
    from benchmarks.fuzz.cases import DEFECTS

    counts = _recorded("fuzz_any_robot.json")["counts"]
    defects = sum(counts.get(key, 0) for key in DEFECTS)
    return f"{counts['cases']} cases, {defects} defect{'' if defects == 1 else 's'}"


# A headline's table (its anchor on docs/results.md) -> its number as the recording gives it.
HEADLINES = {"per-step-controller-time": _step_time, "beside-mink-on-third-party-models": _beside_mink,
             "many-robots-at-once-qpikbatch": _batch, "every-scenario-every-controller": _joint_limits,
             "fuzz-any-robot": _fuzz}


def test_at_most_five_headline_numbers_each_the_recordings_and_linked_to_its_table():
    section = README[README.index("## Headline numbers"):README.index("\n## ", README.index("## Headline numbers") + 3)]
    items = re.findall(r"^- \*\*(.+?)\*\*(.*?)(?=^- |\Z)", section, re.M | re.S)
    assert 1 <= len(items) <= 5
    anchors = {results.anchor(s.title) for s in results.SECTIONS}
    for number, text in items:
        linked = re.findall(r"\(docs/results\.md#([\w-]+)\)", text)
        assert len(linked) == 1 and linked[0] in anchors, text
        assert number == HEADLINES[linked[0]](), (linked[0], number)


def test_every_link_and_figure_is_there():
    for page, text in ((ROOT / "README.md", README), (ROOT / "docs" / "usage.md", USAGE)):
        for target in re.findall(r"\]\(([^)#\s]+)(?:#[\w-]+)?\)", text):
            if not target.startswith("http"):
                assert (page.parent / target).exists(), (page.name, target)
    for gif in ("docs/figures/joint-limits.gif", "docs/figures/hexapod-stroke-limits.gif"):
        assert f"]({gif})" in README and (ROOT / gif).stat().st_size > 0
    anchors = {results.anchor(s.title) for s in results.SECTIONS}
    for page in [ROOT / "README.md", *ROOT.joinpath("docs").glob("*.md")]:
        for anchor in re.findall(r"results\.md#([\w-]+)", page.read_text()):
            assert anchor in anchors, (page.name, anchor)
