"""A run that stopped early says so in its own row (CLI table, compare.json), and its log is
still written, marked partial. too-fast's qp-hard is the real case: its hard position task
asks for more than the joints' speed limits allow from t = 0.056 s on, and DAQP declares
the QP infeasible there."""

import json

import numpy as np

from qpik.app.cli import EXIT_STOPPED, main
from qpik.app.runs import compare, format_table, run, write_compare

STOP = "stopped at 0.056 s: infeasible"


def test_the_stopped_row_is_flagged_in_the_table_and_in_compare_json(tmp_path):
    _, logs, _ = compare("arm", "too-fast", ["daqp"], classical=("qp-hard", "pinv"), peers=())
    summaries = [log.summary() for log in logs]
    by_controller = {s.info.controller: s for s in summaries}
    hard = by_controller["qp-hard"]
    assert not hard.completed and hard.stop.failure_kind == "InfeasibleProblem"
    assert hard.stop.stopped_at == 0.056 and hard.status == STOP
    assert hard.steps == 28  # the steps before t = 0.056 s, at Δt = 2 ms
    assert by_controller["qp"].status == "complete" and by_controller["qp"].stop is None
    # The CLI table: a `run` column on every row, the stop in the stopped run's own row.
    lines = format_table(summaries).splitlines()
    assert lines[0].split()[-1] == "run"
    rows = {line.split()[0]: line for line in lines[2:2 + len(summaries)]}
    assert rows["qp-hard"].endswith(STOP)
    assert rows["qp"].endswith("complete") and rows["pinv"].endswith("complete")
    # compare.json carries the same flag.
    written = json.loads(write_compare(tmp_path, "arm", "too-fast", summaries, "kinematic").read_text())
    flags = {r["controller"]: (r["completed"], r["status"], r.get("partial")) for r in written["runs"]}
    assert flags == {"qp": (True, "complete", None), "qp-hard": (False, STOP, True), "pinv": (True, "complete", None)}


def test_a_stopped_run_writes_its_partial_log_and_exits_1(tmp_path, capsys):
    out = tmp_path / "o"
    code = main(["run", "arm", "--scenario", "too-fast", "--controller", "qp-hard", "--out", str(out), "--quiet"])
    assert code == EXIT_STOPPED == 1
    captured = capsys.readouterr()
    assert STOP in captured.out  # the table's row
    assert len(captured.err.strip().splitlines()) == 1 and "partial" in captured.err and STOP in captured.err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["partial"] and not summary["completed"] and summary["stopped_at"] == 0.056
    assert summary["status"] == STOP and "InfeasibleProblem" in summary["failure"]
    with np.load(out / "log.npz") as log:
        completed, stopped_at, t, q = log["completed"], log["stopped_at"], log["t"], log["q"]
    assert not completed and stopped_at == 0.056
    # The steps before the stop, equal to an in-process run stopped the same way.
    _, reference = run("arm", "too-fast", "qp-hard", on_failure="stop")
    assert len(t) == 28 and t[-1] == 0.054
    np.testing.assert_array_equal(q, reference.q)


def test_a_complete_log_is_marked_complete(tmp_path):
    _, log = run("arm", "too-fast", "qp")
    log.save(tmp_path)
    with np.load(tmp_path / "log.npz") as saved:
        assert saved["completed"] and np.isnan(saved["stopped_at"])
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["completed"] and summary["status"] == "complete" and "stopped_at" not in summary
