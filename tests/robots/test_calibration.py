"""Hexapod calibration (docs/calibration.md): the source's linear identification, Gauss–Newton / LM,
noise and spread, identifiability of extended parameter sets, and the `qpik calibrate` command."""

from __future__ import annotations

import json

import numpy as np
import pytest

from qpik.robots.hexapod.calibration import (
    MIN_MANIPULABILITY, POSE_BOX_POSITION_M, POSE_BOX_RPY_DEG, SEED_POSES, UM, ParameterSet,
    StrokeModel, calibrate, sample_poses,
)
from qpik.app.cli import main
from qpik.errors import InvalidInput, UnreachablePose
from qpik.robots.hexapod.kinematics import Hexapod, HexapodGeometry, rotation_from_rpy

JSON_KEYS = {"method", "poses", "dl_imposed_um", "dl_estimated_um", "relative_error_pct",
             "residual_rms_um", "condition_number", "iterations", "rank", "covariance_std_um", "dl_std_um"}


# The source's procedure and the non-linear solvers ----------------------------------
def test_linear_on_seed_poses_has_the_source_accuracy():
    result = calibrate("linear")
    assert result.fit.iterations == 1
    np.testing.assert_allclose(result.imposed / UM, [50, -20, -50, 20, 10, -10])
    assert np.all(result.relative_error_pct <= 0.1)
    assert np.max(result.relative_error_pct) > 1e-4  # a first-order model: not exact


@pytest.mark.parametrize("method", ["gauss-newton", "lm"])
def test_iterative_methods_recover_the_imposed_errors(method):
    result = calibrate(method)
    assert np.all(result.relative_error_pct <= 1e-4)
    assert 2 <= result.fit.iterations <= 20
    assert result.fit.residual_rms < 1e-15  # metres: the model is exact without noise


def test_linear_jacobian_entries_match_finite_differences_of_ik():
    hexapod, h = Hexapod(), 1e-7
    for pose in SEED_POSES:
        R = rotation_from_rpy(pose[3:])
        analytic = hexapod.stroke_sensitivity_to_leg_length(pose[:3], R)
        for i in range(6):
            dl = np.zeros(6)
            dl[i] = h
            plus = Hexapod(hexapod.geometry.with_leg_length_errors(dl)).inverse_kinematics(pose[:3], pose[3:])
            minus = Hexapod(hexapod.geometry.with_leg_length_errors(-dl)).inverse_kinematics(pose[:3], pose[3:])
            fd = (plus - minus) / (2 * h)
            assert fd[i] == pytest.approx(analytic[i], rel=1e-6)
            assert np.allclose(np.delete(fd, i), 0.0)  # each stroke depends on its own leg only


def test_identification_jacobian_of_every_group_matches_finite_differences():
    params = ParameterSet.parse("full+zeros")
    model = StrokeModel(HexapodGeometry.default(), params, SEED_POSES)
    theta = params.imposed()
    J, h = model.jacobian(theta), 1e-7
    fd = np.column_stack([(model.strokes(theta + h * e) - model.strokes(theta - h * e)).ravel() / (2 * h)
                          for e in np.eye(params.size)])
    np.testing.assert_allclose(J, fd, atol=1e-6)


# Random poses, noise and spread ----------------------------------------------------
@pytest.mark.parametrize("seed", [0, 1, 2, 3, 4])
def test_thirty_random_poses_with_one_micron_noise_stay_within_two_microns(seed):
    result = calibrate("gauss-newton", 30, noise_um=1.0, seed=seed)
    assert len(result.poses) == 30
    assert np.max(np.abs(result.fit.theta - result.imposed)) < 2 * UM
    assert 0.7 * UM < result.fit.residual_rms < 1.3 * UM  # the noise level, not a model error


def test_sampled_poses_are_reachable_well_conditioned_and_seeded():
    nominal = HexapodGeometry.default()
    true = ParameterSet.parse("full").geometry(nominal, ParameterSet.parse("full").imposed())
    poses, attempts = sample_poses(25, np.random.default_rng(7), [nominal, true])
    assert poses.shape == (25, 6) and attempts >= 25
    assert np.all(np.abs(poses[:, :3] - nominal.home_position) <= POSE_BOX_POSITION_M)
    assert np.all(np.abs(poses[:, 3:]) <= POSE_BOX_RPY_DEG)
    for g in (nominal, true):
        hexapod = Hexapod(g)
        for pose in poses:
            assert hexapod.manipulability(pose[:3], rotation_from_rpy(pose[3:])) >= MIN_MANIPULABILITY
    again, _ = sample_poses(25, np.random.default_rng(7), [nominal, true])
    np.testing.assert_array_equal(poses, again)


def test_covariance_spread_agrees_with_monte_carlo():
    result = calibrate("linear", 30, noise_um=1.0, seed=3, repeats=80)
    ratio = result.monte_carlo_std / result.covariance_std
    assert np.all((ratio > 0.7) & (ratio < 1.3)), ratio
    # Under noise the estimate scatters about the imposed errors (bias ≪ spread).
    bias = np.abs(result.monte_carlo.mean(axis=0) - result.imposed)
    assert np.all(bias < 4 * result.covariance_std / np.sqrt(80))


# Identifiability ------------------------------------------------------------------
def test_slider_offsets_and_encoder_zeros_are_not_separable():
    result = calibrate("gauss-newton", params="legs+offsets+zeros")
    ident = result.ident
    assert (ident.rank, result.params.size) == (12, 18)
    assert ident.fixed == [f"c{i}" for i in range(1, 7)]
    assert ident.null_vectors() == [{f"q0_{i}": 1.0, f"c{i}": 1.0} for i in range(1, 7)]
    assert ident.singular_values[12] < 1e-12 * ident.singular_values[0]
    # Only q0 − c is observable; it is recovered exactly, with the zeros fixed at 0.
    split = result.params.split(result.imposed)
    np.testing.assert_allclose(result.params.split(result.fit.theta)["offsets"],
                               split["offsets"] - split["zeros"], atol=1e-15)
    assert np.all(result.relative_error_pct[ident.free] <= 1e-4)


def test_leg_lengths_and_offsets_are_identifiable_together():
    result = calibrate("gauss-newton", params="legs+offsets")
    assert result.ident.rank == 12 and not result.ident.fixed
    assert result.ident.condition_number < 1e3
    assert np.all(result.relative_error_pct <= 1e-4)


def test_platform_points_need_rotations_and_enough_poses():
    # Many tilted poses: all 30 parameters identified.
    tilted = calibrate("gauss-newton", 30, params="full", seed=1)
    assert tilted.ident.rank == 30 and np.all(tilted.relative_error_pct <= 1e-4)
    # Pure translations: b_ix enters the strokes exactly as −q0_i (x of P_i − S0_i).
    rng = np.random.default_rng(0)
    home = HexapodGeometry.default().home_position
    shifted = np.column_stack([home + rng.uniform(-1, 1, (30, 3)) * [0.05, 0.04, 0.02], np.zeros((30, 3))])
    flat = calibrate("gauss-newton", shifted, params="full")
    assert flat.ident.rank == 24
    assert flat.ident.fixed == [f"b{i}x" for i in range(1, 7)]
    assert flat.ident.null_vectors() == [{f"q0_{i}": 1.0, f"b{i}x": 1.0} for i in range(1, 7)]
    # The four seed poses give four strokes per leg for five parameters per leg.
    assert calibrate("linear", params="full").ident.rank == 24


# Input validation -----------------------------------------------------------------
@pytest.mark.parametrize("kwargs, error", [
    ({"noise_um": -1.0}, InvalidInput), ({"poses": 0}, InvalidInput), ({"method": "newton"}, InvalidInput),
    ({"params": "legs+legs"}, InvalidInput), ({"repeats": 0}, InvalidInput),
    ({"poses": [[0.5, 0.0, 0.1, 0.0, 0.0, 0.0]]}, UnreachablePose),
])
def test_library_rejects_bad_input(kwargs, error):
    with pytest.raises(error):
        calibrate(**kwargs)


# Command line ---------------------------------------------------------------------
def test_cli_default_reproduces_the_source_procedure(tmp_path, capsys):
    out = tmp_path / "cal"
    assert main(["calibrate", "--out", str(out)]) == 0
    data = json.loads((out / "calibration.json").read_text())
    assert JSON_KEYS <= set(data)
    assert data["method"] == "linear" and data["poses"] == SEED_POSES.tolist()
    assert data["dl_imposed_um"] == [50.0, -20.0, -50.0, 20.0, 10.0, -10.0]
    assert max(data["relative_error_pct"]) <= 0.1 and data["iterations"] == 1 and data["rank"] == 6
    np.testing.assert_allclose(data["dl_estimated_um"], data["dl_imposed_um"], rtol=1e-3)
    table = capsys.readouterr().out
    for word in ("leg", "imposed", "estimated", "error", "rel. error", "l6", "condition number"):
        assert word in table
    assert not [p for p in out.iterdir() if p.name.startswith(".")]


def test_cli_noise_repeats_pose_file_and_plot(tmp_path, capsys):
    pose_file = tmp_path / "poses.json"
    pose_file.write_text(json.dumps(SEED_POSES.tolist()))
    out = tmp_path / "cal"
    assert main(["calibrate", "--method", "gauss-newton", "--pose-file", str(pose_file), "--noise-um", "0.5",
                 "--repeats", "5", "--seed", "2", "--out", str(out), "--plot"]) == 0
    data = json.loads((out / "calibration.json").read_text())
    assert data["noise_um"] == 0.5 and data["repeats"] == 5 and len(data["dl_std_um"]) == 6
    assert all(s > 0 for s in data["covariance_std_um"])
    assert (out / "calibration.png").stat().st_size > 20_000
    assert "MC std" in capsys.readouterr().out


def test_cli_reports_a_rank_deficient_set(tmp_path, capsys):
    out = tmp_path / "cal"
    assert main(["calibrate", "--method", "lm", "--params", "legs+offsets+zeros", "--out", str(out)]) == 0
    data = json.loads((out / "calibration.json").read_text())
    assert data["rank"] == 12 and data["n_parameters"] == 18 and len(data["fixed_parameters"]) == 6
    assert data["relative_error_pct"][12:] == [None] * 6
    assert "a change of c1 acts on the strokes like -1·q0_1" in capsys.readouterr().out


@pytest.mark.parametrize("args, content, message", [
    (["--noise-um", "-1"], None, "noise"),
    (["--poses", "0"], None, "at least 1"),
    (["--poses", "many"], None, "--poses"),
    (["--params", "legs+wheels"], None, "parameter set"),
    (["--pose-file", "{file}"], "0.15,0.10,0.05,-3,2,3\n0.5,0.0,0.1,0,0,0\n", "pose 2 [0.5, 0.0, 0.1, 0.0, 0.0, 0.0]"),
    (["--pose-file", "{file}"], "0.15,0.10,0.05,-3,2\n", "malformed pose file"),
    (["--pose-file", "{file}"], "0.15,0.10,zero,-3,2,3\n", "malformed pose file"),
    (["--pose-file", "{file}"], "", "malformed pose file"),
])
def test_cli_bad_input_is_one_line_and_exit_2(tmp_path, capsys, args, content, message):
    pose_file = tmp_path / "poses.csv"
    if content is not None:
        pose_file.write_text(content)
    out = tmp_path / "cal"
    argv = ["calibrate", *[a.format(file=pose_file) for a in args], "--out", str(out)]
    assert main(argv) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], captured.err
    if "pose 2" in message:
        assert "leg 1" in lines[0]
    assert not out.exists()
