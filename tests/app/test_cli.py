"""The `qpik` command: its contract (files, keys) and its handling of bad input."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from qpik.app.cli import main

SUMMARY_KEYS = {
    "robot", "controller", "solver", "scenario", "mode", "dt", "steps", "max_error", "rms_error",
    "final_error", "manipulability_min", "manipulability_mean", "manipulability_final",
    "limit_violation_max", "peak_joint_speed", "step_time_median_us", "step_time_p99_us", "q_final",
}
LOG_KEYS = {"t", "q", "qdot", "x", "x_des", "error", "manipulability", "step_time"}


def test_scenarios_lists_the_contract_names(capsys):
    assert main(["scenarios"]) == 0
    out = capsys.readouterr().out
    for name in ("seed-primary", "seed-redundant", "joint-limits", "unreachable"):
        assert name in out


def test_run_writes_summary_log_and_figures(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["run", "arm", "--controller", "pinv", "--scenario", "seed-primary", "--out", str(out), "--plot"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert SUMMARY_KEYS <= set(summary)
    assert summary["controller"] == "pinv" and summary["scenario"] == "seed-primary"
    assert summary["max_error"] <= 1e-5 and summary["limit_violation_max"] == 0.0
    log = np.load(out / "log.npz")
    assert LOG_KEYS <= set(log.files)
    assert log["q"].shape == (summary["steps"], 4)
    np.testing.assert_allclose(log["q"][-1], summary["q_final"])
    for fig in ("path.png", "joints.png", "velocities.png", "error.png", "manipulability.png"):
        assert (out / fig).stat().st_size > 10_000
    assert "pinv" in capsys.readouterr().out
    assert not [p for p in out.iterdir() if p.name.startswith(".")]  # no temporary left


def test_compare_runs_qp_and_pinv_side_by_side(tmp_path, capsys):
    out = tmp_path / "cmp"
    assert main(["compare", "arm", "--scenario", "seed-redundant", "--solvers", "daqp,quadprog", "--out", str(out)]) == 0
    data = json.loads((out / "compare.json").read_text())
    assert data["robot"] == "arm" and data["scenario"] == "seed-redundant"
    runs = {(r["controller"], r["solver"]): r for r in data["runs"]}
    assert {("qp", "daqp"), ("qp", "quadprog"), ("pinv", "none")} <= set(runs)
    for run in data["runs"]:
        assert SUMMARY_KEYS <= set(run)
    np.testing.assert_allclose(runs[("qp", "daqp")]["q_final"], runs[("pinv", "none")]["q_final"], atol=1e-3)
    table = capsys.readouterr().out
    assert "quadprog" in table and "pinv" in table


BAD_INPUTS = [
    (["run", "arm", "--scenario", "no-such-scenario"], "unknown scenario"),
    (["run", "robot9", "--scenario", "seed-primary"], "unknown robot"),
    (["run", "arm", "--scenario", "seed-primary", "--solver", "nosolver"], "solver"),
    (["run", "arm", "--scenario", "seed-primary", "--controller", "magic"], "unknown controller"),
    (["run", "arm", "--scenario", "seed-primary", "--mode", "dream"], "invalid choice"),
    (["run", "/nonexistent/arm.xml", "--scenario", "seed-primary"], "not found"),
    (["compare", "arm", "--scenario", "seed-primary", "--solvers", "daqp,bogus"], "solver"),
    (["frobnicate"], "invalid choice"),
]


@pytest.mark.parametrize("argv,fragment", BAD_INPUTS)
def test_bad_input_is_one_line_and_exit_code_2(argv, fragment, tmp_path, capsys):
    assert main(argv + (["--out", str(tmp_path / "o")] if argv[0] in ("run", "compare") else [])) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    assert fragment in err
    assert "Traceback" not in err
    assert not (tmp_path / "o").exists()  # nothing written


def test_malformed_mjcf_is_a_clear_error(tmp_path, capsys):
    bad = tmp_path / "bad.xml"
    bad.write_text("<mujoco><worldbody><body></mujoco>")
    assert main(["run", str(bad), "--scenario", "seed-primary", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "cannot load MJCF" in err and len(err.strip().splitlines()) == 1
    # A well-formed model without the arm's names is refused by name.
    other = tmp_path / "other.xml"
    other.write_text('<mujoco><compiler angle="radian"/><worldbody><body><joint type="hinge"/>'
                     '<geom size="0.1"/></body></worldbody></mujoco>')
    assert main(["run", str(other), "--scenario", "seed-primary", "--out", str(tmp_path / "o")]) == 2
    assert "unknown" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_infeasible_hard_task_fails_cleanly_without_output(tmp_path, capsys, monkeypatch):
    # A hard task that asks for more than the velocity limits allow: the QP is infeasible.
    import qpik.robots.arm.scenarios as scenarios

    monkeypatch.setattr(scenarios, "ARM_GAIN", 5e5)
    monkeypatch.setattr(scenarios, "SEED_PATH", ((0.6, 1.9), (1.5, 1.0)))
    out = tmp_path / "o"
    assert main(["run", "arm", "--scenario", "seed-primary", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "infeasible" in err and "t = 0.000 s" in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_console_script_entry_point(tmp_path):
    exe = Path(sys.executable).with_name("qpik")
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "qpik.app.cli"]
    env = {**os.environ, "MPLBACKEND": "Agg"}
    ok = subprocess.run(cmd + ["scenarios"], capture_output=True, text=True, env=env, cwd=tmp_path)
    assert ok.returncode == 0 and "seed-redundant" in ok.stdout
    bad = subprocess.run(cmd + ["run", "arm", "--scenario", "nope"], capture_output=True, text=True, env=env, cwd=tmp_path)
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1 and "Traceback" not in bad.stderr
