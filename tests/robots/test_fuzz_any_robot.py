"""The any-robot fuzz's short version (benchmarks/fuzz_any_robot.py runs the full one):
300 seeded cases on generated and third-party models, every class of failure zero.

Also checks the harness itself: the LP tells a feasible step from an infeasible one, a
case past its time budget is a hang, and a repeat in another process gives the same q.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from qpik.fuzz import CLASSES, DEFECTS, run_case
from qpik.fuzz.checks import lp_feasible
from qpik.fuzz.sweep import run_workers, summarise, sweep

SHORT = 300


def test_the_lp_tells_feasible_from_infeasible_steps():
    A, b = np.array([[1.0, 1.0]]), np.array([1.0])
    box = np.array([-1.0, -1.0]), np.array([1.0, 1.0])
    no_rows = np.zeros((0, 2)), np.zeros(0)
    assert lp_feasible(A, b, *box, *no_rows, margin=True)
    assert not lp_feasible(A, np.array([2.0]), *box, *no_rows, margin=True)  # only at the corner
    assert lp_feasible(A, np.array([2.0]), *box, *no_rows, margin=False)
    contradictory = np.array([[1.0, 0.0], [1.0, 0.0]]), np.array([0.5, 0.6])
    assert not lp_feasible(*contradictory, *box, *no_rows, margin=False)


def test_a_case_past_its_budget_is_a_hang_and_the_rest_still_run():
    results = run_workers([0, 1], jobs=1, chunk=2, cap=1e-3)
    assert {seed: r["classes"] for seed, r in results.items()} == {0: ["hang"], 1: ["hang"]}


def test_a_case_repeated_in_another_process_gives_the_same_trajectory(tmp_path):
    here = {seed: run_case(seed, tmp_path) for seed in range(4)}
    there = run_workers(list(range(4)), jobs=1, chunk=4, cap=120.0)
    assert [here[s].get("q_hash") for s in range(4)] == [there[s].get("q_hash") for s in range(4)]


def test_the_short_any_robot_fuzz_finds_no_defect(tmp_path):
    results = sweep(list(range(SHORT)), jobs=2, chunk=50, cap=60.0, folder=tmp_path, repeat_every=30)
    summary = summarise(results)
    counts = summary["counts"]
    # The harness ran real rollouts: 175 of these 300 keep every promise (the rest stop
    # with a typed error an LP confirms, or refuse an injected invalid parameter).
    assert counts["cases"] == SHORT and counts.get("ok", 0) >= 0.4 * SHORT
    found = {key: counts.get(key, 0) for key in DEFECTS if counts.get(key, 0)}
    assert not found, (found, summary["sites"], {k: v[:2] for k, v in summary["examples"].items()})
    assert {key for key, _, _ in CLASSES} >= set(counts) - {"cases"}


def _children(pid: int) -> list[int]:
    """The sweep's worker processes among ``pid``'s children (an import may start a helper
    process of its own, e.g. ldconfig, before the sweep installs its SIGTERM handler)."""
    found = []
    for task in Path(f"/proc/{pid}/task").glob("*/children"):
        for child in task.read_text().split():
            try:
                command = Path(f"/proc/{child}/cmdline").read_bytes()
            except OSError:  # already gone
                continue
            if b"qpik.fuzz.sweep" in command:
                found.append(int(child))
    return found


@pytest.mark.skipif(not Path("/proc/self/task").exists(), reason="reads child processes from /proc")
def test_sigterm_ends_the_sweep_and_its_workers():
    script = "from qpik.fuzz.sweep import run_workers; run_workers(list(range(40)), 1, 40, 600.0)"
    parent = subprocess.Popen([sys.executable, "-c", script])
    children: list[int] = []
    try:
        deadline = time.monotonic() + 60
        while not children and time.monotonic() < deadline:
            time.sleep(0.1)
            children = _children(parent.pid)
        assert children, "no worker started"
        time.sleep(0.5)
        parent.send_signal(signal.SIGTERM)
        assert parent.wait(timeout=60) == 128 + signal.SIGTERM
        assert not [c for c in children if Path(f"/proc/{c}").exists()]  # reaped by the sweep, not left running
    finally:
        for pid in children:
            if Path(f"/proc/{pid}").exists():
                os.kill(pid, signal.SIGKILL)  # only when the test fails: the worker it started
        if parent.poll() is None:
            parent.kill()
            parent.wait()


def test_a_start_outside_the_ranges_is_refused_before_the_fuzz_opts_in(tmp_path, monkeypatch):
    """Case 4 starts some joints outside their ranges: set_q must first refuse it naming
    exactly those joints (OutsideJointLimits), then the case opts in. With the refusal
    switched off the fuzz reports the start as an invalid input accepted."""
    from qpik.robot import Robot

    result = run_case(4, tmp_path)
    assert result["params"]["allow_outside_limits"] and "ok" in result["classes"], result["details"]
    monkeypatch.setattr(Robot, "_check_inside", lambda self, q, what, remedy: None)
    result = run_case(4, tmp_path)
    assert "invalid_accepted" in result["classes"] and "accepted" in result["details"]["outside_start"]
