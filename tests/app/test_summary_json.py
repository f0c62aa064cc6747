"""summary.json is a public contract: the typed summary writes the same keys, in the same
order, with the same values as before it (the files under tests/data/summary_json were
written by ``qpik run`` at c57b646, when the summary was a dict built key by key).

Covered: a run stopped early (too-fast's qp-hard: the failure keys, a path reference's
``completion_time`` null and ``path_deviation_max``, one level), SNS on three levels (its
task scale, per level too) and the hexapod's strict hierarchy (the orientation and loop
columns, the hierarchy's per-level residual). Step times are the machine's: only their
type is compared; the other numbers to 1e-6 relative (another CPU's rounding), the rest
exactly.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from qpik.app.cli import main
from qpik.rollout import RunSummary

RECORDED = Path(__file__).resolve().parents[1] / "data" / "summary_json"
RUNS = {
    "arm-too-fast-qp-hard": ["run", "arm", "--scenario", "too-fast", "--controller", "qp-hard"],
    "arm-three-tasks-sns": ["run", "arm", "--scenario", "three-tasks", "--controller", "sns"],
    "hexapod-circle-hqp": ["run", "hexapod", "--scenario", "hexapod-circle", "--controller", "hqp"],
}
TIMES = ("step_time_median_us", "step_time_p99_us")


def _same(key: str, want, have) -> bool:
    if key in TIMES:
        return isinstance(have, float)
    if key == "failure":  # the error's type and time; the rest is the controller's own message
        return have.split(":")[0] == want.split(":")[0]
    if isinstance(want, list):
        return len(want) == len(have) and all(_same("", w, h) for w, h in zip(want, have))
    if isinstance(want, float) and not isinstance(have, bool):
        return have == pytest.approx(want, rel=1e-6, abs=1e-12)
    return type(have) is type(want) and have == want


@pytest.mark.parametrize("name", list(RUNS))
def test_summary_json_keeps_its_keys_order_and_values(name, tmp_path):
    out = tmp_path / name
    main([*RUNS[name], "--out", str(out), "--quiet"])  # exit 1 for the stopped run: its log is partial
    have = json.loads((out / "summary.json").read_text())
    want = json.loads((RECORDED / f"{name}.json").read_text())
    assert list(have) == list(want)
    different = {key: (want[key], have[key]) for key in want if not _same(key, want[key], have[key])}
    assert not different


@pytest.mark.parametrize("name", list(RUNS))
def test_the_typed_summary_reads_a_record_back_whole(name):
    """from_json then to_json gives the record back, keys in order (what tables read from
    compare.json and the benchmarks' JSON)."""
    record = json.loads((RECORDED / f"{name}.json").read_text())
    summary = RunSummary.from_json(record)
    assert summary.to_json() == record and list(summary.to_json()) == list(record)
    assert summary.info.controller == record["controller"] and summary.status == record["status"]
    assert summary.levels.error_max == tuple(record["level_error_max"])
