"""The any-robot fuzz's batched path (benchmarks/fuzz/batched.py; the full run:
``python benchmarks/fuzz_any_robot.py --batched 1``): a handful of cases on N = 4 worlds,
every world equal to its own one-world run; and the harness itself: the recipe builds the
case's own problem again, and a world made to differ (its q̇, its state, its error) is
caught.
"""

from __future__ import annotations

import hashlib
from types import SimpleNamespace

import numpy as np
import pytest

from benchmarks.fuzz import batched
from benchmarks.fuzz.cases import DT, STEPS, Case, run_case
from benchmarks.fuzz.sweep import _batch_site
from qpik.errors import WorldsFailed

# (seed, what it covers): every controller, the exact solvers, generated and third-party
# models, steps whose condition number makes 10·nv·ε·κ the tolerance (55, 137), a world
# that fails alone mid-run (67: InfeasibleProblem in world 1 at step 5, the others
# compared to the end), every world failing at step 0 (1), an invalid parameter
# refused at the same step of every world's build (3), the guard's capped ladder
# (8160: it stopped at cap 1e3 in one run, on a hard-row check that rounding decided, and
# at 1 in the other, q̇ 1.0 apart), and a closed form whose residual sits at its rounding,
# one run's kept and the other's sent to a solver that did worse (8850:
# tests/core/test_closed_form.py holds its step), and a robot 1e6 m out whose H is
# indefinite in floats, where DAQP fails and the retry answered a damped QP (3870:
# tests/core/test_solvers.py holds its step).
CASES = {5: "sns", 9: "qp/quadprog", 12: "pinv, ball_in_cup", 21: "hqp/daqp", 120: "qp/daqp, humanoid",
         137: "qp/daqp, κ ~ 1e12", 55: "pinv, κ ~ 5e6", 67: "qp/osqp, world 1 infeasible at step 5",
         1: "pinv, DivergenceError everywhere", 3: "sns, an invalid parameter refused",
         110: "hqp/quadprog, level 1's rows above dependent on its free dofs (κ inf)",
         8160: "qp/proxqp, the capped ladder",
         8850: "qp/quadprog, a soft row of terms 6e6 times its target",
         3870: "qp/daqp, H indefinite in floats: the retry in the row form"}


@pytest.mark.parametrize("seed", CASES)
def test_each_world_equals_its_own_one_world_run(tmp_path, seed):
    result = run_case(seed, tmp_path, batched=True)
    record = result["details"]["batched"]
    assert "batch_same" in result["classes"], record.get("difference", record)
    if seed == 67:
        assert record["failed"] == {"1": "InfeasibleProblem at step 5"} and record["steps"] == STEPS
    if seed in (55, 137, 110):
        assert record["conditioned_steps"] and record["max_gap"] > batched.TOLERANCE


@pytest.mark.parametrize("seed", [4360, 6430])
def test_a_step_its_data_does_not_determine_is_judged_by_its_minimum(tmp_path, seed):
    """4360 (qp/daqp, a cost only the 1e-12 regulariser makes definite, κ ~ 1e12) and 6430
    (hqp/daqp, level 2's rows above nearly dependent on its free dofs): 10·nv·ε·κ is past
    the cap, so a rounding moves q̇ by more than it; the worlds' answers are judged by what
    the data determines, the minimum (each level's cost, the hard rows, the limits)."""
    result = run_case(seed, tmp_path, batched=True)
    record = result["details"]["batched"]
    assert "batch_same_minimum" in result["classes"], record.get("difference", record)
    assert record["undetermined_steps"] and record["minimum_steps"] == record["undetermined_steps"]


def test_a_tolerance_solvers_levels_are_polished_to_one_minimum(tmp_path):
    """9430 (hqp/osqp): OSQP pinned level 1 (a frame task 1e6 m away) only to its
    tolerance, its two answers 0.036 apart, so level 2's rows above differed and its cost
    moved by up to 5e-4 relative (within what level 2's multipliers bound, the judge's
    moved minimum, tested below). Polished by the held-bounds iteration from OSQP's bounds,
    every level's answer is its minimiser: the worlds' costs agree to 1e-6 with no move."""
    result = run_case(9430, tmp_path, batched=True)
    record = result["details"]["batched"]
    assert "batch_same_minimum" in result["classes"], record.get("difference", record)
    assert "moved_minimum_steps" not in record and record["max_cost_gap"] <= batched.PROXQP_COST_TOLERANCE


def test_the_moved_minimum_is_the_levels_sensitivity_to_the_level_above():
    """Level 1: min ½‖q̇ − (1, 2, 0)‖² under q̇₀ + q̇₁ = d (level 0's row) and q̇₁ ≤ 0.5,
    its minimum W(d) = ½ ((d − 1.5)² + 1.5²), multiplier λ = 1.5 − d: from d = 1 to 1.1, W
    moves by −0.045, between −λ(1)·0.1 and −λ(1.1)·0.1. A point of the level's set that
    is no minimiser (q̇₂ = 0.1) leaves ∇f unbalanced: no bound."""
    def task(jacobian, velocity):
        return SimpleNamespace(jacobian=np.array(jacobian, dtype=float), target_velocity=np.array(velocity),
                               weight=1.0, hard=False)
    levels = [[task([[1.0, 1.0, 0.0]], [0.0])], [task(np.eye(3), [1.0, 2.0, 0.0])]]
    box = np.full(3, -np.inf), np.array([np.inf, 0.5, np.inf]), np.zeros((0, 3)), np.zeros(0)
    own, other = np.array([0.5, 0.5, 0.0]), np.array([0.6, 0.5, 0.0])
    low, high = batched._moved_minimum(levels, 1, other, own, *box)
    assert (low, high) == (pytest.approx(-0.05), pytest.approx(-0.04))
    assert low < 0.5 * (0.4**2 - 0.5**2) < high
    assert batched._moved_minimum(levels, 1, other + [0.0, 0.0, 0.1], own, *box) is None


@pytest.mark.parametrize("seed", [21, 120])
def test_the_recipe_builds_the_cases_own_problem(tmp_path, seed):
    """Replayed on a fresh robot at the case's start, the recipe's controller rolls out the
    case's own trajectory, bit for bit."""
    result = run_case(seed, tmp_path)
    case = Case(seed, tmp_path)
    case.build()
    robot = batched.support.one_robot(case.recipe.model, case.recipe.q)
    controller = case.recipe.replay(robot).get(case.controller)
    digest = hashlib.sha256()
    for _ in range(STEPS):
        robot.integrate(controller.compute_velocity(), DT)
        robot.update_kinematics()
        digest.update(robot.q.tobytes())
    assert result["classes"] == ["ok"] and digest.hexdigest() == result["q_hash"]


def _batch_steps(monkeypatch, change):
    """The batch's answers ((N, nv), the one-world runs' are (nv,)) passed through
    ``change(qdots, call)``, which may raise WorldsFailed instead."""
    step, calls = batched._step, []

    def changed(controller):
        qdot, error = step(controller)
        if qdot is None or qdot.ndim != 2:
            return qdot, error
        calls.append(1)
        try:
            return change(qdot, len(calls)), None
        except WorldsFailed as exc:
            return None, exc
    monkeypatch.setattr(batched, "_step", changed)


def test_a_world_whose_answer_is_off_by_1e_8_is_caught(tmp_path, monkeypatch):
    def nudged(qdots, call):
        qdots[2] *= 1.0 + 1e-8
        return qdots
    _batch_steps(monkeypatch, nudged)
    result = run_case(9, tmp_path, batched=True)
    difference = result["details"]["batched"]["difference"]
    assert "batch_differs" in result["classes"] and "ok" not in result["classes"]
    assert (difference["at"], difference["world"], difference["what"]) == ("step 0", 2, "qdot")
    assert 5e-9 < difference["gap"] < 1e-8


def test_a_world_given_another_worlds_state_is_caught(tmp_path, monkeypatch):
    build = batched._batch_robot

    def mixed(model, starts):
        return build(model, [starts[0], starts[1], starts[3], starts[3]])
    monkeypatch.setattr(batched, "_batch_robot", mixed)
    result = run_case(5, tmp_path, batched=True)
    difference = result["details"]["batched"]["difference"]
    assert "batch_differs" in result["classes"] and (difference["world"], difference["what"]) == (2, "qdot")


def test_a_world_failing_where_its_own_run_is_solved_is_caught(tmp_path, monkeypatch):
    def failed(qdots, call):
        if call == 4:
            qdots[1] = 0.0
            raise WorldsFailed({1: "InfeasibleProblem: made up"}, qdots)
        return qdots

    _batch_steps(monkeypatch, failed)
    result = run_case(9, tmp_path, batched=True)
    difference = result["details"]["batched"]["difference"]
    assert "batch_differs" in result["classes"]
    assert (difference["at"], difference["world"], difference["what"], difference["alone"]) == \
        ("step 3", 1, "error", "solved")


def test_an_ill_conditioned_step_still_catches_a_world_apart(tmp_path, monkeypatch):
    """Case 137's steps have κ ~ 1e12 (a cost only the 1e-12 regulariser makes definite):
    held to 10·nv·ε·κ, at most 1e-2, a world 10 % off is still caught."""
    def nudged(qdots, call):
        qdots[1] *= 1.1 if call == 3 else 1.0
        return qdots
    _batch_steps(monkeypatch, nudged)
    result = run_case(137, tmp_path, batched=True)
    difference = result["details"]["batched"]["difference"]
    assert "batch_differs" in result["classes"] and (difference["at"], difference["world"]) == ("step 2", 1)


def test_the_gap_of_answers_near_the_float_range_or_not_finite_warns_nothing():
    """(The suite runs with warnings as errors; in a case, a warning of the harness's own
    would count as the library's stray one.)"""
    huge = np.array([1e308, -1e308, 1.0])
    assert batched.gap(huge, -huge) == pytest.approx(2.0)
    assert batched.gap(np.array([np.inf, 1.0]), np.array([np.inf, 1.0 + 1e-6])) == pytest.approx(1e-6 / 2)
    assert batched.gap(np.array([np.inf, 1.0]), np.array([1.0, 1.0])) == np.inf
    assert batched.gap(np.array([np.nan, 1.0]), np.array([-np.inf, 1.0])) == np.inf
    assert batched.gap(np.array([3.0, 4.0]), np.zeros(2)) == 5.0
    result = {"params": {"controller": "pinv"}, "details": {"batched": {"difference": {"at": "step 3", "what": "qdot",
                                                                                       "gap": "inf"}}}}
    assert _batch_site(result) == "pinv step qdot inf"
    result["details"]["batched"]["difference"]["gap"] = 0.031
    assert _batch_site(result) == "pinv step qdot ~1e-2"


def test_the_active_systems_condition_sees_dependent_rows():
    """A QP's equality rows restricted to the dofs its answer leaves free: κ(H_F) and
    κ(C_F H_F⁻¹ C_Fᵀ); rows that depend on each other there (a dof they reach held at its
    bound) make it past 1/ε (its smallest singular value a rounding), however well conditioned the rows are over every dof."""
    hessian = np.diag([1.0, 1e-2, 1.0])
    rows = np.array([[1.0, 1.0, 0.0], [1.0, 1.0, 1.0]])  # dependent once dof 2 is held
    lower, upper = np.full(3, -1.0), np.full(3, 1.0)
    inside = batched._active_condition(hessian, rows, np.array([0.5, 0.2, 0.1]), lower, upper)
    scaled = rows / np.sqrt(np.diag(hessian))
    assert inside == pytest.approx(max(100.0, np.linalg.cond(scaled) ** 2))
    assert batched._active_condition(hessian, rows, np.array([0.5, 0.2, 1.0]), lower, upper) > 1 / batched.EPSILON
    assert batched._active_condition(hessian, rows[:0], np.zeros(3), lower, upper) == 1.0
