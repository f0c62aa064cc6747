"""A fast subset of the bundled robots' fuzz (benchmarks.fuzz.bundled, whose command line
is benchmarks/fuzz_bundled.py): the same random cases, a few dozen.

The promises are checked on cases hypothesis draws (derandomized, so every run checks
the same cases), and each defect the first full sweep found is pinned by the case that
showed it (each of these failed before the solver layer and the gain checks). Hangs and
slow steps are left to the benchmark (a test must not depend on the clock).
"""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from benchmarks.fuzz.bundled import MUTATIONS, run_case
from benchmarks.fuzz.bundled_sweep import sweep

FAST = settings(max_examples=12, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow])
seeds = st.integers(0, 10**6)


def _case(kind: str, seed: int, tmp_path: Path) -> dict:
    return run_case(kind, seed, tmp_path)


@FAST
@given(seed=seeds)
def test_a_mutated_model_is_rejected_with_a_typed_error_or_runs_cleanly(seed, tmp_path_factory):
    result = _case("model", seed, tmp_path_factory.mktemp("model"))
    assert not {"untyped", "nan", "crash"} & set(result["classes"]), result
    assert {"rejected", "ok", "typed"} & set(result["classes"]), result


@FAST
@given(kind=st.sampled_from(["arm", "hexapod", "physics"]), seed=seeds)
def test_no_rollout_ever_logs_nan_or_inf(kind, seed, tmp_path_factory):
    result = _case(kind, seed, tmp_path_factory.mktemp(kind))
    assert "nan" not in result["classes"], result


def test_every_mutation_of_a_bundled_scene_is_caught_or_harmless(tmp_path):
    """One case per mutation kind, each of the fuzz's mutations at least once."""
    seen = set()
    for seed in range(200):
        result = _case("model", seed, tmp_path)
        mutation = result["params"].get("mutation")
        if mutation in seen:
            continue
        seen.add(mutation)
        assert not {"untyped", "nan", "crash"} & set(result["classes"]), result
        must_reject = ("nan_range", "reversed_range", "malformed_xml", "missing_joint", "missing_site")
        # A keyframe is read only where a scenario starts from it: the hexapod's start at
        # "home"; the arm's scenarios set their own start, so a bad keyframe there is unused.
        if result["params"].get("robot") == "hexapod":
            must_reject += ("keyframe_outside", "keyframe_nan")
        if mutation in must_reject:
            assert "rejected" in result["classes"], result
        if len(seen) == len(MUTATIONS):
            break
    assert seen == set(MUTATIONS)


def test_the_sweep_kills_a_case_past_its_cap_and_goes_on_with_the_rest():
    results = sweep(["arm:1", "arm:3", "hexapod:0"], jobs=1, chunk=2, cap=0.001)
    assert {case: r["classes"] for case, r in results.items()} == \
        {"arm:1": ["hang"], "arm:3": ["hang"], "hexapod:0": ["hang"]}


# Defects of the solver layer (found by `python benchmarks/fuzz_bundled.py --seed 0`): each case fails today.

def test_daqp_keeps_the_limits_on_a_soft_hexapod_task(tmp_path):
    result = _case("hexapod", 24, tmp_path)
    assert not {"crossing", "speed"} & set(result["classes"]), result["details"]


def test_osqp_failures_are_typed_errors(tmp_path):
    result = _case("arm", 22, tmp_path)
    assert result["params"]["solver"] == "osqp"
    assert "untyped" not in result["classes"], result["details"]


def test_a_soft_hexapod_task_degrades_on_an_unreachable_target(tmp_path):
    result = _case("hexapod", 72, tmp_path)
    assert result["params"]["hard"] is False and result["params"]["target_kind"] != "reachable"
    assert "soft_bounded" in result["classes"], result["details"]


def test_a_soft_arm_task_degrades_on_a_target_far_outside_the_workspace(tmp_path):
    result = _case("arm", 12, tmp_path)
    assert result["params"]["hard"] is False and result["params"]["target_kind"] == "far"
    assert "soft_bounded" in result["classes"], result["details"]


def test_hexapod_loops_stay_closed_on_the_commanded_configuration(tmp_path):
    result = _case("hexapod", 124, tmp_path)
    assert result["params"]["gain_dt_max"] <= 1.0 and result["params"]["start_inside"]
    assert "loop" not in result["classes"], result["details"]


def test_a_gain_above_one_over_dt_is_rejected_or_warned_about(tmp_path):
    result = _case("arm", 11, tmp_path)
    assert result["params"]["gain_dt_max"] > 1.0
    assert "gain_unflagged" not in result["classes"], result


@pytest.mark.parametrize("seed", [24, 726])
def test_a_far_soft_hexapod_target_is_not_declared_infeasible(seed, tmp_path):
    """A target 1e8 m away puts a cost 1e9 times H's scale even once capped, and DAQP
    declared the (feasible) loops and box infeasible; the step now checks feasibility and
    re-solves (found by the full sweep at 2738452: 11 of 2,000 hexapod cases)."""
    result = _case("hexapod", seed, tmp_path)
    assert result["params"]["target_kind"] == "far" and result["params"]["start_inside"]
    assert result["params"]["solver"] == "daqp"
    assert "soft_bounded" in result["classes"], result["details"]
    assert not {"typed", "crossing", "speed", "loop"} & set(result["classes"]), result["details"]


def test_an_infeasible_start_still_names_the_binding_limits(tmp_path):
    """A slider started outside the range the case gives it: loops and limits have no
    common point (an exact solver confirms it, and the fuzz's LP), so the error stands,
    names them, and is the promise, not a soft task that raised instead of degrading."""
    result = _case("hexapod", 1803, tmp_path)
    assert not result["params"]["start_inside"]
    assert "InfeasibleProblem" in result["details"]["error"]
    assert "at its upper position limit" in result["details"]["error"]
    assert result["details"]["hard_part_infeasible"] and result["classes"] == ["typed"]
