"""`qpik sweep`: small sweeps in-process, stopped and resumed, and on a local Ray cluster,
all giving the same summary.json; chunks written whole and keyed by what they depend on;
bad input refused before anything is written."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from qpik.app.cli import main
from qpik.app.sweep.chunks import CHUNK_FOLDER, Chunk, plan, read_chunk, write_chunk
from qpik.app.sweep.report import outcomes
from qpik.app.sweep.studies import ported, study

TARGETS, CHUNK = 240, 40  # 6 ranges x 2 controllers, a few seconds in all
# The QP beside the pseudoinverse law; beside the soft QP until the engine has the batched
# pseudoinverse law (batch.PseudoinverseController).
OTHER = "pinv" if ported("arm", "pinv") else "qp-soft"
PAIR = ["qp", OTHER]
# Short rollouts: 0.2 s to the target, held 0.1 s (150 steps).
ARGS = ["sweep", "arm", "--targets", str(TARGETS), "--chunk", str(CHUNK), "--seed", "5", "--move", "0.2",
        "--hold", "0.1", "--controllers", ",".join(PAIR), "--quiet"]
HEXAPOD = pytest.mark.skipif(not ported("hexapod", "qp"), reason="the hexapod's sweep needs the engine's batched "
                                                                  "EqualityTask (not exported by qpik.batch yet)")
SHORT = dict(move=0.2, hold=0.1)


def _default_sigint():
    """In the child: SIGINT back to its default (a background shell starts it ignored)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> Path:
    """An uninterrupted in-process sweep."""
    out = tmp_path_factory.mktemp("sweep") / "ref"
    assert main([*ARGS, "--out", str(out)]) == 0
    return out


def _summary(folder: Path) -> dict:
    return json.loads((folder / "summary.json").read_text())


def test_an_in_process_sweep_writes_its_summary_table_chunks_and_maps(reference):
    summary = _summary(reference)
    assert summary["targets"] == TARGETS and summary["robot"] == "arm" and summary["seed"] == 5
    assert list(summary["controllers"]) == PAIR
    qp, other = summary["controllers"]["qp"], summary["controllers"][OTHER]
    # The QP never crosses a limit; the pseudoinverse law does on some of these targets.
    assert qp["range_violation"] == {"worlds": 0, "max": 0.0} and qp["speed_violation"]["max"] <= 1e-9
    if OTHER == "pinv":
        assert other["range_violation"]["worlds"] > 0
    else:
        assert other["range_violation"]["worlds"] == 0 and other["speed_violation"]["max"] <= 1e-9
    assert qp["within_limits_rate"] == 1.0 and qp["stopped"] == qp["stop_reasons"]["infeasible"]
    chunks = sorted((reference / CHUNK_FOLDER).iterdir())
    assert len(chunks) == 2 * TARGETS // CHUNK
    # The aggregates are those of the chunks' worlds.
    worlds = [read_chunk(reference, c) for c in plan("arm", 5, TARGETS, CHUNK, PAIR, **SHORT)]
    reached = np.concatenate([outcomes(w)["reached"] for w in worlds[0::2]])
    assert qp["reach_rate"] == reached.mean() and len(reached) == TARGETS
    assert (reference / "table.md").read_text().count("\n| ") == 3  # header, qp, the other
    if OTHER == "pinv":  # the QP and the law compared world by world, on one map
        comparison = summary["comparisons"]["qp vs pinv"]
        assert sum(comparison[k] for k in ("both_succeed", "only_qp_succeeds", "only_pinv_succeeds",
                                           "both_fail")) == TARGETS
        assert (reference / "workspace-qp-vs-pinv.png").stat().st_size > 10_000
    else:  # two QPs: a map each
        assert all((reference / f"workspace-{name}.png").stat().st_size > 10_000 for name in PAIR)
    timing = json.loads((reference / "timing.json").read_text())
    assert timing["chunks_computed"] == 12 and timing["runner"] == "in-process"
    assert "wall_s" not in summary and "load_average" not in summary  # timings apart


def _start(argv) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "qpik", *argv], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env={**os.environ, "MPLBACKEND": "Agg"}, preexec_fn=_default_sigint)


def _stop_after_chunks(argv, out: Path, count: int, signum) -> tuple[int, str]:
    proc = _start(argv)
    while len(list((out / CHUNK_FOLDER).glob("*.npz")) if (out / CHUNK_FOLDER).is_dir() else []) < count:
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.05)
    proc.send_signal(signum)
    _, stderr = proc.communicate(timeout=120)
    return proc.returncode, stderr


@pytest.mark.parametrize("signum, code, word", [(signal.SIGINT, 130, "interrupted"),
                                                 (signal.SIGTERM, 143, "terminated")])
def test_a_stopped_sweep_keeps_whole_chunks_and_resumes_to_the_same_summary(reference, tmp_path, signum, code, word):
    out = tmp_path / "s"
    rc, stderr = _stop_after_chunks([*ARGS, "--out", str(out)], out, 3, signum)
    assert rc == code, stderr
    assert len(stderr.strip().splitlines()) == 1 and word in stderr and "resumes" in stderr
    assert sorted(p.name for p in out.iterdir()) == [CHUNK_FOLDER]  # no summary, no staging
    kept = {p.name: p.stat().st_mtime_ns for p in (out / CHUNK_FOLDER).iterdir()}
    assert not [name for name in kept if name.startswith(".")]  # no temporary file left
    assert 3 <= len(kept) < 12, sorted(kept)
    chunks = plan("arm", 5, TARGETS, CHUNK, PAIR, **SHORT)
    assert sum(read_chunk(out, c) is not None for c in chunks) == len(kept)  # each whole and readable
    assert main([*ARGS, "--out", str(out)]) == 0
    timing = json.loads((out / "timing.json").read_text())
    assert timing["chunks_computed"] == 12 - len(kept)  # the finished ones were not recomputed
    assert all((out / CHUNK_FOLDER / name).stat().st_mtime_ns == mtime for name, mtime in kept.items())
    assert (out / "summary.json").read_bytes() == (reference / "summary.json").read_bytes()


def test_a_changed_parameter_never_reuses_a_chunk(tmp_path, monkeypatch):
    chunk = Chunk("arm", 5, 0, 40, "qp")
    others = [Chunk("arm", 6, 0, 40, "qp"), Chunk("arm", 5, 0, 41, "qp"), Chunk("arm", 5, 0, 40, "pinv"),
              Chunk("arm", 5, 0, 40, "qp", hold=0.4), Chunk("arm", 5, 0, 40, "qp", move=0.9)]
    assert len({c.path(tmp_path) for c in [chunk, *others]}) == 6
    write_chunk(tmp_path, chunk, {"x": np.arange(3.0)})
    assert read_chunk(tmp_path, chunk)["x"].tolist() == [0.0, 1.0, 2.0]
    assert all(read_chunk(tmp_path, c) is None for c in others)
    from qpik.app.sweep import chunks as module

    # A file whose stored key is not the chunk's (a study redefined, the file renamed by hand)
    # is not taken.
    path = chunk.path(tmp_path)
    monkeypatch.setattr(module, "STUDY_VERSION", module.STUDY_VERSION + 1)
    assert chunk.path(tmp_path) != path and read_chunk(tmp_path, chunk) is None
    path.rename(chunk.path(tmp_path))
    assert read_chunk(tmp_path, chunk) is None
    # Other code (an edited qpik, another MuJoCo): other files.
    monkeypatch.setattr(module, "STUDY_VERSION", module.STUDY_VERSION - 1)
    write_chunk(tmp_path, chunk, {"x": np.arange(3.0)})
    monkeypatch.setattr(module, "code_fingerprint", lambda: "0123456789abcdef")
    assert read_chunk(tmp_path, chunk) is None


def test_a_world_has_the_same_sample_whatever_the_chunk_size():
    arm = study("arm")
    whole = arm.samples(9, 0, 600)
    parts = [arm.samples(9, a, b) for a, b in ((0, 100), (100, 257), (257, 600))]
    for key, value in whole.items():
        np.testing.assert_array_equal(np.concatenate([p[key] for p in parts]), value)
    assert not np.array_equal(arm.samples(10, 0, 600)["target"], whole["target"])
    lim = arm.limits
    q = whole["start_q"][:, lim.qpos_index]
    assert (q >= lim.lower).all() and (q <= lim.upper).all()  # starts inside the joint ranges
    assert (whole["gain"] >= 50.0).all() and (whole["gain"] <= 500.0).all()


def test_ray_local_cluster_gives_the_same_summary(reference, tmp_path):
    pytest.importorskip("ray", reason="the ray extra is not installed")
    out = tmp_path / "r"
    # Other chunk boundaries too: a world's sample and result depend on its id alone.
    argv = [*ARGS, "--out", str(out), "--ray", "auto", "--workers", "2"]
    argv[argv.index("--chunk") + 1] = "60"
    assert main(argv) == 0
    assert (out / "summary.json").read_bytes() == (reference / "summary.json").read_bytes()
    timing = json.loads((out / "timing.json").read_text())
    assert timing["runner"] == "ray" and timing["chunks_computed"] == 8
    assert all(row["latency_s"] >= row["compute_s"] for row in timing["per_chunk"])


@HEXAPOD
def test_hexapod_sweep_keeps_the_loops_closed_and_the_limits(tmp_path):
    out = tmp_path / "h"
    assert main(["sweep", "hexapod", "--targets", "6", "--move", "0.3", "--hold", "0.2", "--quiet",
                 "--out", str(out)]) == 0
    summary = _summary(out)
    qp = summary["controllers"]["qp"]
    assert qp["range_violation"]["worlds"] == 0 and qp["speed_violation"]["max"] <= 1e-9
    assert qp["loop_residual_m"]["max"] < 1e-5
    # Every QP run that finished reached its pose; one stops only where the fast segment
    # asks for more than the limits allow (its hard QP infeasible).
    assert qp["reach_rate"] * 6 + qp["stopped"] == 6 and qp["stopped"] == qp["stop_reasons"]["infeasible"]
    if ported("hexapod", "pinv"):
        assert summary["controllers"]["pinv"]["loop_residual_m"]["max"] < 1e-5


@pytest.mark.parametrize("argv, fragment", [
    (["--targets", "0"], "positive integer"),
    (["--targets", "10", "--controllers", "qp,mink"], "unknown controller"),
    (["--targets", "10", "--controllers", "qp,qp"], "named twice"),
    (["--targets", "10", "--workers", "2"], "--workers applies to --ray only"),
    (["--targets", "10", "--chunk", "-3"], "positive integer"),
    (["--targets", "10", "--hold", "nan"], "duration"),
])
def test_bad_input_is_one_line_exit_2_and_nothing_written(tmp_path, capsys, argv, fragment):
    out = tmp_path / "o"
    assert main(["sweep", "arm", *argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert fragment in err and len(err.strip().splitlines()) == 1
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("robot, controllers", [("arm", "qp,pinv"), ("hexapod", None)])
def test_a_controller_the_engine_does_not_batch_yet_is_refused_before_anything_is_written(tmp_path, capsys, robot,
                                                                                          controllers):
    if ported(robot, "pinv" if controllers else "qp"):
        pytest.skip("the engine batches it: nothing to refuse")
    given = ["--controllers", controllers] if controllers else []
    assert main(["sweep", robot, "--targets", "10", *given, "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "not ported to the engine" in err and len(err.strip().splitlines()) == 1
    assert list(tmp_path.iterdir()) == []


def test_the_default_controllers_are_those_the_engine_runs():
    from qpik.app.sweep.command import chosen_controllers

    assert chosen_controllers("arm", None) == (["qp", "pinv"] if ported("arm", "pinv") else ["qp"])
    assert chosen_controllers("arm", ["qp-soft"]) == ["qp-soft"]


def test_an_output_folder_of_something_else_is_refused(tmp_path, capsys):
    (tmp_path / "notes.txt").write_text("mine")
    assert main(["sweep", "arm", "--targets", "10", "--out", str(tmp_path)]) == 2
    assert "something else" in capsys.readouterr().err
    assert [p.name for p in tmp_path.iterdir()] == ["notes.txt"]
    assert main(["sweep", "arm", "--targets", "10", "--out", str(tmp_path / "notes.txt")]) == 2
    assert "existing file" in capsys.readouterr().err
    assert main(["sweep", "ur5", "--targets", "10", "--out", str(tmp_path / "x")]) == 2
    assert "invalid choice" in capsys.readouterr().err and not (tmp_path / "x").exists()


def test_ray_missing_is_one_line_naming_the_extra(tmp_path, run_without_modules):
    out = tmp_path / "o"
    code = (f"import sys; from qpik.app.cli import main; "
            f"sys.exit(main(['sweep', 'arm', '--targets', '10', '--ray', 'auto', '--out', {str(out)!r}]))")
    proc = run_without_modules(code, ("ray",), timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.strip().count("\n") == 0 and '.[ray]' in proc.stderr, proc.stderr
    assert not out.exists()
