"""The `qpik` command: its contract (files, keys) and its handling of bad input."""

import json
import os
import signal
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
    with np.load(out / "log.npz") as log:
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
    (["run", "arm", "--scenario", "seed-primary", "--controller", "pinv", "--solver", "osqp"], "--solver applies"),
    (["run", "arm", "--scenario", "seed-primary", "--controller", "placo", "--solver", "daqp"], "--solver applies"),
    (["run", "arm", "--scenario", "seed-primary", "--video", "clip.avi.txt"], "unknown video format"),
    (["run", "robot9", "--scenario", "seed-primary"], "unknown robot"),
    (["run", "arm", "--scenario", "seed-primary", "--solver", "nosolver"], "solver"),
    (["run", "arm", "--scenario", "seed-primary", "--controller", "magic"], "unknown controller"),
    # The list names every controller the command takes, the peers included.
    (["run", "arm", "--scenario", "seed-primary", "--controller", "magic"], "pinv, jt, mink, placo"),
    (["run", "hexapod", "--scenario", "hexapod-circle", "--controller", "jt"], "sns, pinv, mink, placo"),
    (["compare", "arm", "--scenario", "seed-primary", "--solvers", "daqp,osqp,daqp"],
     "solvers listed more than once: daqp"),
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
    # A hard task that asks for more than the velocity limits allow: the path starts 0.14 m
    # from the end effector, so K e = 500 × 0.14 = 70 m/s at t = 0 (the joints allow 8 rad/s).
    import qpik.robots.arm.scenarios as scenarios

    out = tmp_path / "o"
    assert main(["run", "arm", "--scenario", "seed-primary", "--out", str(out)]) == 0  # feasible as shipped
    monkeypatch.setattr(scenarios, "SEED_PATH", ((0.6, 1.9), (1.5, 1.0)))
    out = tmp_path / "o2"
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


def _qpik(*args, **kwargs):
    """The command in a fresh interpreter (``python -m qpik``), as a user runs it."""
    env = {**os.environ, "MPLBACKEND": "Agg", **kwargs.pop("env", {})}
    return subprocess.run([sys.executable, "-m", "qpik", *args], capture_output=True, text=True, env=env, **kwargs)


def test_version_and_python_m():
    import qpik

    done = _qpik("--version")
    assert done.returncode == 0 and done.stdout.strip() == f"qpik {qpik.__version__}"


def test_help_imports_nothing_heavy():
    # `qpik --help` stays fast by importing no numerical library (measured: README); the
    # subcommands' help does, as it lists the installed solvers and the scenarios.
    probe = ("import sys\nfrom qpik.app.cli import main\ntry:\n    main(['--help'])\nexcept SystemExit:\n    pass\n"
             "print(sorted(m for m in ('mujoco', 'numpy', 'scipy', 'matplotlib', 'qpsolvers') if m in sys.modules))")
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert "usage: qpik" in done.stdout and done.stdout.strip().endswith("[]"), done.stdout
    sub = _qpik("run", "--help")
    assert sub.returncode == 0
    text = " ".join(sub.stdout.split())
    from qpik.solvers import available_solvers

    for name in (*available_solvers(), "seed-redundant", "hexapod-circle", "pinv", "placo", "(default: kinematic)"):
        assert name in text, name


def test_out_that_names_a_file_is_refused_before_any_work(tmp_path, capsys, monkeypatch):
    import qpik.app.runs as runs

    def must_not_run(*args, **kwargs):
        raise AssertionError("the run started before --out was checked")

    monkeypatch.setattr(runs, "run", must_not_run)
    monkeypatch.setattr(runs, "compare", must_not_run)
    target = tmp_path / "file.txt"
    target.write_text("mine")
    for argv in (["run", "arm", "--scenario", "seed-primary", "--out", str(target)],
                 ["compare", "arm", "--scenario", "seed-primary", "--out", str(target)],
                 ["run", "arm", "--scenario", "seed-primary", "--out", str(target / "below")],
                 ["calibrate", "--out", str(target)]):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and str(target) in err and "Traceback" not in err, err
    assert target.read_text() == "mine" and sorted(tmp_path.iterdir()) == [target]


def _unwritable_folder(tmp_path) -> Path:
    if os.geteuid() != 0:
        folder = tmp_path / "locked"
        folder.mkdir()
        folder.chmod(0o500)
        return folder
    try:  # root writes anywhere permissions allow: use a file system that refuses folders
        os.mkdir("/sys/qpik-probe")
    except OSError:
        return Path("/sys")
    os.rmdir("/sys/qpik-probe")
    pytest.skip("running as root and /sys accepts new folders: no unwritable folder to test with")


def test_out_in_an_unwritable_folder_is_refused_before_any_work(tmp_path, capsys, monkeypatch):
    import qpik.app.runs as runs

    monkeypatch.setattr(runs, "run", lambda *a, **k: pytest.fail("ran before --out was checked"))
    folder = _unwritable_folder(tmp_path)
    assert main(["run", "arm", "--scenario", "seed-primary", "--out", str(folder / "o")]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "cannot write" in err, err


PINV_RUN = ["run", "arm", "--controller", "pinv", "--scenario", "seed-primary", "--quiet"]


def test_output_replaces_an_earlier_output_folder_whole(tmp_path, capsys):
    """A second command into the same --out leaves its files only: the first run's figures
    do not survive beside the second one's summary (run, compare and calibrate alike)."""
    out = tmp_path / "existing"
    out.mkdir()  # an empty folder is taken
    assert main([*PINV_RUN, "--plot", "--out", str(out)]) == 0
    assert "error.png" in {p.name for p in out.iterdir()}
    assert main([*PINV_RUN, "--out", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["log.npz", "summary.json"]
    assert main(["compare", "arm", "--scenario", "seed-primary", "--solvers", "daqp", "--quiet",
                 "--out", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["compare.json"]
    assert main(["calibrate", "--quiet", "--plot", "--out", str(out)]) == 0
    assert main(["calibrate", "--quiet", "--out", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["calibration.json"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["existing"]  # nothing staged or set aside is left


def test_output_into_a_folder_qpik_did_not_write_is_refused(tmp_path, capsys):
    """Replacing whole a folder that is not an earlier output (``--out .``, a folder of
    notes) would delete what the user keeps there: refused before any work."""
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("kept")
    for argv in (PINV_RUN, ["calibrate", "--quiet"]):
        assert main([*argv, "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and "an existing folder qpik did not write" in err, err
    assert [p.name for p in out.iterdir()] == ["notes.txt"] and (out / "notes.txt").read_text() == "kept"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mine"]


CALIBRATE_BAD_INPUTS = [
    (["--seed", "-1", "--noise-um", "1"], "seed must be an integer ≥ 0"),
    # Noise so large the fit's candidate geometries cannot reach the poses: said as such,
    # not as the geometry's own check ("leg lengths must be positive") or an unreachable pose.
    (["--noise-um", "1e30", "--seed", "1"], "noise σ = 1e+30 µm is too large for the stroke model"),
    (["--noise-um", "1.5e5"], "noise σ = 150000 µm is too large for the stroke model"),
    (["--noise-um", "-3"], "finite standard deviation"),
]


@pytest.mark.parametrize("argv,fragment", CALIBRATE_BAD_INPUTS)
def test_bad_calibrate_input_is_one_line_and_exit_code_2(argv, fragment, tmp_path, capsys):
    assert main(["calibrate", *argv, "--quiet", "--out", str(tmp_path / "c")]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and fragment in err, err
    assert list(tmp_path.iterdir()) == []


def test_options_that_do_not_apply_to_calibrate_are_errors(tmp_path, capsys):
    for argv, fragment in ((["--repeats", "5"], "--noise-um"), (["--seed", "3"], "nothing random")):
        assert main(["calibrate", *argv, "--out", str(tmp_path / "c")]) == 2
        err = capsys.readouterr().err
        assert fragment in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "c").exists()
    # The same options where they apply.
    assert main(["calibrate", "--poses", "8", "--seed", "3", "--noise-um", "1", "--repeats", "3",
                 "--out", str(tmp_path / "c")]) == 0
    data = json.loads((tmp_path / "c" / "calibration.json").read_text())
    assert data["seed"] == 3 and data["repeats"] == 3 and len(data["poses"]) == 8


def _default_sigint():
    """In the child, before Python starts: SIGINT back to its default. A test run started in
    the background of a non-interactive shell inherits SIGINT ignored, and Python then
    never turns it into KeyboardInterrupt (a user's Ctrl-C reaches a foreground process)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def test_ctrl_c_stops_compare_within_a_solve_and_leaves_nothing(tmp_path):
    """SIGINT during `qpik compare` (OSQP installs its own SIGINT handler during each solve
    and swallows it): exit 130, no output, no staging folder left."""
    out = tmp_path / "X"
    proc = subprocess.Popen([sys.executable, "-m", "qpik", "compare", "hexapod", "--scenario", "hexapod-circle",
                             "--solvers", "osqp,daqp", "--out", str(out), "--plot"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "MPLBACKEND": "Agg"}, preexec_fn=_default_sigint)
    # Wait until the command is past its checks and working (the staging folder exists),
    # then interrupt it during the first run, qp with OSQP (~2000 solves).
    import time

    while not any(p.name.startswith(".qpik-partial-") for p in tmp_path.iterdir()):
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.05)
    time.sleep(0.3)
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 130, (proc.returncode, stdout, stderr)
    assert "interrupted" in stderr and "Traceback" not in stderr and "Solver interrupted" not in stdout + stderr
    assert list(tmp_path.iterdir()) == []  # no X, no compare.json, summary, figure, staging


def _start_and_signal(argv, folder: Path, ready, signum) -> tuple[int, str, str]:
    """Start ``qpik argv``, wait until ``ready(staging folder)`` holds, send ``signum``."""
    import time

    proc = subprocess.Popen([sys.executable, "-m", "qpik", *argv], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env={**os.environ, "MPLBACKEND": "Agg"}, preexec_fn=_default_sigint)
    while not any(p.name.startswith(".qpik-partial-") and ready(p) for p in folder.iterdir()):
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.05)
    time.sleep(0.3)
    proc.send_signal(signum)
    stdout, stderr = proc.communicate(timeout=120)
    return proc.returncode, stdout, stderr


def test_sigterm_stops_compare_like_ctrl_c_and_keeps_the_earlier_output(tmp_path):
    """SIGTERM (kill, a scheduler) during an OSQP solve: exit 143, one line, no staging
    folder, and the earlier output in --out left as it was (it is replaced only at the end)."""
    out = tmp_path / "X"
    out.mkdir()
    (out / "compare.json").write_text("{}")
    code, stdout, stderr = _start_and_signal(
        ["compare", "hexapod", "--scenario", "hexapod-circle", "--solvers", "osqp,daqp", "--out", str(out), "--plot"],
        tmp_path, lambda staging: True, signal.SIGTERM)
    assert code == 143, (code, stdout, stderr)
    assert stderr.strip() == "qpik: terminated; nothing written", stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["X"]
    assert [p.name for p in out.iterdir()] == ["compare.json"] and (out / "compare.json").read_text() == "{}"


def test_sigterm_while_rendering_the_video_leaves_no_half_video(tmp_path):
    """SIGTERM once the run is logged (its summary staged) and the video is being made:
    neither the video (staged beside its final path) nor the output folder is left."""
    pytest.importorskip("imageio_ffmpeg", reason="the [video] extra (imageio-ffmpeg) is not installed")
    probe = subprocess.run([sys.executable, "-c", "from qpik.app.video import prefer_headless_gl, probe_gl\n"
                            "prefer_headless_gl()\nprobe_gl()"], capture_output=True, text=True)
    if probe.returncode != 0:  # MuJoCo picks its GL back-end at import: probed in a fresh interpreter
        pytest.skip(f"no OpenGL back-end here: {probe.stderr.strip().splitlines()[-1:]}")
    code, stdout, stderr = _start_and_signal(
        ["run", "arm", "--scenario", "seed-primary", "--controller", "pinv", "--quiet",
         "--video", str(tmp_path / "clip.mp4"), "--out", str(tmp_path / "o")],
        tmp_path, lambda staging: (staging / "summary.json").exists(), signal.SIGTERM)
    assert code == 143 and "Traceback" not in stderr, (code, stdout, stderr)
    assert list(tmp_path.iterdir()) == []  # no clip.mp4, no .clip.mp4.* being written, no staging


OSQP_LOOP = """
import sys
from qpik.app.interrupt import InterruptGuard
statuses = []
try:
    with InterruptGuard():  # first, as in the CLI: NumPy's BLAS threads must start under it
        import numpy as np, scipy.sparse as sp, osqp
        rng = np.random.default_rng(0)
        n = 150
        M = rng.standard_normal((n, n))
        solver = osqp.OSQP()
        solver.setup(sp.csc_matrix(M @ M.T + np.eye(n)), rng.standard_normal(n), sp.csc_matrix(np.eye(n)),
                     -np.ones(n), np.ones(n), verbose=False, eps_abs=1e-12, eps_rel=1e-12, max_iter=100000)
        print("ready", flush=True)
        for _ in range(200000):
            statuses.append(solver.solve(raise_error=False).info.status)
    print("finished", len(statuses))
except KeyboardInterrupt:
    print("stopped after", len(statuses), "solves;", "interrupted" in statuses)
    sys.exit(130)
"""


def test_interrupt_guard_stops_a_loop_of_osqp_solves():
    """Almost all of this loop's time is inside OSQP's solve, where OSQP catches SIGINT
    (status "interrupted") and Python never sees it; with the guard the first SIGINT stops
    the loop, and OSQP never reports an interruption."""
    proc = subprocess.Popen([sys.executable, "-c", OSQP_LOOP], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=_default_sigint)
    assert proc.stdout.readline().strip() == "ready"
    import time

    time.sleep(0.5)
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 130, (stdout, stderr)
    assert stdout.strip().endswith("False"), stdout  # no solve saw the SIGINT


def test_physics_table_says_what_the_level_columns_measure_beside_max_err(tmp_path, capsys):
    """In physics mode "L0 path" (the controller's commanded configuration) and "max err"
    (the simulated robot) differ by the servos' lag; the table says which is which, and it
    is true: L0 is the kinematic run's error (the controller integrates its own command)."""
    argv = ["run", "arm", "--scenario", "seed-redundant", "--quiet"]
    assert main([*argv, "--mode", "physics", "--out", str(tmp_path / "p")]) == 0
    out = capsys.readouterr().out
    assert "note: L0 path, L1 sigma: each priority level's error on the controller's own model" in out
    assert main([*argv, "--out", str(tmp_path / "k")]) == 0
    assert "note: L0" not in capsys.readouterr().out  # kinematic: one robot, nothing to tell apart
    physics, kinematic = (json.loads((tmp_path / m / "summary.json").read_text()) for m in "pk")
    # The same integration of the same commands: equal to rounding (1e-9 relative of a 5e-6 m error).
    assert np.isclose(physics["level_error_max"][0], kinematic["max_error"], rtol=1e-9, atol=0)
    assert physics["max_error"] > 100 * physics["level_error_max"][0]
