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

from benchmarks.fuzz.cases import CLASSES, DEFECTS, run_case
from benchmarks.fuzz.checks import lp_feasible
from benchmarks.fuzz.sweep import PROXQP_COST_TOLERANCE, run_workers, same_run, summarise, sweep
from qpik.rollout.io import write_json

ROOT = Path(__file__).resolve().parents[2]

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


def test_the_lp_asks_of_a_point_what_a_controller_promises():
    """A row of entries 1e8 on dofs the box holds at 1e6 rad/s: a difference of two
    doubles near 1e6 moves in steps of 1.2e-10, so 1e8 (x0 − x1) misses 1 by 1e-3 at
    every floating-point point (summed exactly), far from the hard rows' promise of
    1e-9 (1 + |b|), and no solver can return a point meeting it; with the entries 1 it
    can. Asked of the point in exact arithmetic, the answer is the same under every
    BLAS kernel (a kernel's FMA once made A @ x round onto 1)."""
    box = np.array([1e6, -np.inf]), np.array([2e6, np.inf])
    no_rows = np.zeros((0, 2)), np.zeros(0)
    assert not lp_feasible(np.array([[1e8, -1e8]]), np.array([1.0]), *box, *no_rows, margin=True)
    assert lp_feasible(np.array([[1.0, -1.0]]), np.array([1.0]), *box, *no_rows, margin=True)
    # The smallest point is the one checked: a free dof the LP could put anywhere stays near 0.
    free = np.array([-np.inf, -np.inf]), np.array([np.inf, np.inf])
    assert lp_feasible(np.array([[1e8, 0.0]]), np.array([1.0]), *free, *no_rows, margin=True)
    # Two hard tasks on one motion whose targets (1e9) agree to 1e-12 relative, rounding:
    # one point meets both as the promise counts (|Ax − b| relative to |b|), however far
    # apart they are in absolute terms (1e-3, beyond HiGHS's own 1e-7).
    dependent = np.array([[1.0, 1.0], [2.0, 2.0]])
    assert lp_feasible(dependent, np.array([1e9, 2e9 + 1e-3]), *free, *no_rows, margin=True)
    assert not lp_feasible(dependent, np.array([1e9, 2e9 * (1 + 1e-8)]), *free, *no_rows, margin=True)
    assert lp_feasible(dependent, np.array([1e9, 2e9 * (1 + 1e-8)]), *free, *no_rows, margin=False)


@pytest.mark.parametrize("seed, classes", [(661, ["ok"]), (2728, ["ok"]), (7431, ["ok"]), (9123, ["typed"]),
                                           (5579, ["typed"]), (7286, ["typed"]), (4966, ["ok"])])
def test_the_steps_the_solvers_called_infeasible_on_a_stretched_robot(tmp_path, seed, classes):
    """The last full sweep's typed errors on steps an LP found feasible: hard rows of
    1e6–1e10 beside joint ranges 1e-3 wide. Three are solved in the hard rows' null
    space; the fourth (a row of entries 1e6 that only points 3e6 rad/s away meet) cannot
    be met to the promised 1e-9 in floating point, and its typed error stands. 5579 and
    7286: dependent hard rows of |b| ~ 1e9 that disagree by 3e-9–7e-9 relative, a
    SolverError that says so, neither feasible to the promise nor infeasible to phase 1.
    4966: a hierarchy's lowest level, whose rows above mix a far position and a near pose,
    met the pose rows 9e-6 off their scale, which a norm-wise check alone let pass."""
    assert run_case(seed, tmp_path)["classes"] == classes


def test_an_active_set_solve_that_cycles_stops_at_its_cap(tmp_path, monkeypatch):
    """Case 3586 (53 dofs, a cost whose smallest curvature is 1e-12): DAQP cycled to
    10,000 iterations on every step before the damped retry solved it in about 40; it now
    stops at its cap, 10 nv + 100 (nv the step's dofs, also for the reduction to the hard
    rows' null space, which has fewer variables), give or take a few iterations (DAQP
    0.11 reported 640 against a cap of 630)."""
    import daqp

    iterations = []
    solve = daqp.solve

    def counted(*args, **kwargs):
        answer = solve(*args, **kwargs)
        iterations.append((answer[3]["iterations"], len(args[1])))
        return answer

    monkeypatch.setattr(daqp, "solve", counted)
    assert run_case(3586, tmp_path)["classes"] == ["ok"]
    nv = max(variables for _, variables in iterations)
    assert iterations and all(count <= 1.1 * (10 * nv + 100) for count, _ in iterations)


def test_a_step_is_timed_in_cpu_time(tmp_path, monkeypatch):
    """A step that waits 0.15 s (a busy machine) is no hang; one that computes for 0.15 s
    of CPU time is."""
    from benchmarks.fuzz import cases

    def slowed(pause):
        build = cases.Case.build

        def build_slow(case):
            build(case)
            step = case.controller.compute_velocity

            def slow_step():
                pause()
                return step()

            case.controller.compute_velocity = slow_step
        return build_slow

    def compute():
        started = time.process_time()
        while time.process_time() - started < 0.15:
            pass

    seed = next(s for s in range(50) if run_case(s, tmp_path)["classes"] == ["ok"])
    monkeypatch.setattr(cases.Case, "build", slowed(lambda: time.sleep(0.15)))
    assert run_case(seed, tmp_path)["classes"] == ["ok"]
    monkeypatch.setattr(cases.Case, "build", slowed(compute))
    assert "hang" in run_case(seed, tmp_path)["classes"]


def test_a_proxqp_repeat_is_judged_by_its_promises_not_its_argmin():
    """Two ProxQP runs whose q ends 1e-3 apart (a cost whose smallest curvature is 1e-12)
    but whose every answer costs the same are the same run; a cost that differs, or a
    run that stops elsewhere, is not. Any other solver must repeat bit for bit."""
    first = {"classes": ["ok"], "q_hash": "a", "step_costs": [[1.0, 2.0], [0.5, 4.0]], "details": {}}
    same = {"classes": ["ok"], "q_hash": "b", "step_costs": [[1.0, 2.0 + 1e-12], [0.5, 4.0]], "details": {}}
    costlier = {"classes": ["ok"], "q_hash": "b", "step_costs": [[1.0, 2.0 + 1e-3], [0.5, 4.0]], "details": {}}
    shorter = {"classes": ["ok"], "q_hash": "b", "step_costs": [[1.0, 2.0]], "details": {}}
    assert same_run(first, same) and first["details"]["proxqp_cost_gap"] <= PROXQP_COST_TOLERANCE
    assert not same_run(first, costlier) and not same_run(first, shorter)
    other_solver = {"classes": ["ok"], "q_hash": "a", "details": {}}
    assert same_run(other_solver, dict(other_solver)) and not same_run(other_solver, {**other_solver, "q_hash": "b"})


def test_a_proxqp_case_replayed_in_another_process_keeps_its_promises(tmp_path):
    """Case 5560 (ProxQP, a cost whose smallest curvature is 1e-12) ended 1.9e-3 apart in
    q between processes; replayed on the first run's configurations, every answer costs
    the same."""
    first = run_case(5560, tmp_path)
    assert len(first["q_steps"]) == len(first["step_costs"]) == 25
    write_json(tmp_path / "replays.json", {"5560": first["q_steps"]})
    again = run_workers([5560], jobs=1, chunk=1, cap=120.0, replays=tmp_path / "replays.json")[5560]
    assert again["q_steps"] == first["q_steps"]
    assert same_run(first, again), first["details"].get("proxqp_cost_gap")


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
            if b"benchmarks.fuzz.pool" in command:
                found.append(int(child))
    return found


@pytest.mark.skipif(not Path("/proc/self/task").exists(), reason="reads child processes from /proc")
def test_sigterm_ends_the_sweep_and_its_workers(tmp_path):
    """Run as a script would, from another folder with only the repository on its path:
    its workers start, and SIGTERM ends them with it."""
    script = "from benchmarks.fuzz.sweep import run_workers; run_workers(list(range(40)), 1, 40, 600.0)"
    parent = subprocess.Popen([sys.executable, "-c", script], cwd=tmp_path,
                              env={**os.environ, "PYTHONPATH": str(ROOT)})
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
