"""Hexapod geometry, IK branch selection, FK (Newton + continuation) and Jacobians."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from qpik.errors import ConvergenceError, InvalidInput, UnreachablePose
from qpik.robots.hexapod.kinematics import Hexapod, HexapodGeometry, rotation_from_rpy, rpy_from_rotation

# The source's four calibration poses (docs/calibration.md): position (m), [θx, θy, θz] (deg).
SEED_POSES = [
    ((0.15, 0.10, 0.05), (-3.0, 2.0, 3.0)),
    ((0.07, 0.08, 0.04), (4.0, -3.0, -2.0)),
    ((-0.01, 0.02, 0.07), (-2.0, 5.0, 8.0)),
    ((0.13, -0.06, -0.02), (5.0, -4.0, -1.0)),
]
MIRROR = np.diag([1.0, 1.0, -1.0])


@pytest.fixture(scope="module")
def hexapod() -> Hexapod:
    return Hexapod()


def pose_error(p, R, p_ref, R_ref) -> float:
    """max(position error (m), rotation angle error (rad))."""
    angle = Rotation.from_matrix(R @ np.asarray(R_ref).T).magnitude()
    return max(float(np.max(np.abs(np.asarray(p) - p_ref))), float(angle))


near_home = st.tuples(
    st.lists(st.floats(-0.03, 0.03), min_size=3, max_size=3),
    st.lists(st.floats(-5.0, 5.0), min_size=3, max_size=3),
)


# Geometry -------------------------------------------------------------------------
def test_default_geometry_has_six_distinct_points_on_the_circle():
    g = HexapodGeometry.default()
    assert np.allclose(np.linalg.norm(g.platform_points, axis=1), 0.1)
    gaps = np.linalg.norm(g.platform_points[:, None] - g.platform_points[None], axis=2)
    assert np.min(gaps + np.eye(6)) > 0.03
    assert g.leg_side.tolist() == [1, -1, 1, 1, -1, -1]
    assert (g.stroke_min, g.stroke_max) == (0.0, 0.35)
    with pytest.raises(ValueError):
        g.leg_lengths[0] = 1.0  # arrays are read-only: the geometry is one source of truth


def test_geometry_validation_and_perturbations(hexapod):
    g = hexapod.geometry
    with pytest.raises(InvalidInput):
        g.replace(slider_axes=2 * g.slider_axes)
    with pytest.raises(InvalidInput):
        g.with_leg_length_errors(np.zeros(5))
    with pytest.raises(InvalidInput):
        g.replace(home_position=[0.0, np.nan, 0.1])
    pose = SEED_POSES[1]
    q = hexapod.inverse_kinematics(*pose)
    dq0 = np.linspace(-1e-3, 1e-3, 6)
    # A slider whose zero sits dq0 further along its axis needs dq0 less stroke.
    shifted = Hexapod(g.with_slider_home_offsets(dq0)).inverse_kinematics(*pose)
    assert np.allclose(shifted, q - dq0, atol=1e-15)
    moved = Hexapod(g.with_platform_point_errors(np.full((6, 3), 1e-4))).inverse_kinematics(*pose)
    assert 0 < np.max(np.abs(moved - q)) < 1e-3
    assert np.allclose(g.with_leg_length_errors(np.ones(6) * 1e-5).leg_lengths, 0.2 + 1e-5)


def test_rotation_convention_is_rz_ry_rx_in_degrees():
    ax, ay, az = np.radians([10.0, -20.0, 30.0])
    c, s = np.cos, np.sin
    Rx = np.array([[1, 0, 0], [0, c(ax), -s(ax)], [0, s(ax), c(ax)]])
    Ry = np.array([[c(ay), 0, s(ay)], [0, 1, 0], [-s(ay), 0, c(ay)]])
    Rz = np.array([[c(az), -s(az), 0], [s(az), c(az), 0], [0, 0, 1]])
    assert np.allclose(rotation_from_rpy([10, -20, 30]), Rz @ Ry @ Rx, atol=1e-15)
    assert np.allclose(rpy_from_rotation(Rz @ Ry @ Rx), [10, -20, 30])


# Inverse kinematics ----------------------------------------------------------------
@pytest.mark.parametrize("k", range(4))
def test_seed_poses_are_reachable(hexapod, k):
    position, rpy = SEED_POSES[k]
    q = hexapod.inverse_kinematics(position, rpy)
    assert np.all((q >= 0) & (q <= 0.35)), f"pose {k + 1} strokes {q}"
    residual = hexapod.leg_residuals(q, position, rotation_from_rpy(rpy))
    assert np.max(np.abs(residual)) < 1e-15, f"pose {k + 1} strokes {q}, residuals {residual}"


def test_home_strokes_are_mid_range(hexapod):
    assert np.all((hexapod.home_strokes > 0.14) & (hexapod.home_strokes < 0.22)), hexapod.home_strokes


@settings(max_examples=60, deadline=None)
@given(near_home)
def test_ik_respects_the_branch_rules(pose):
    hexapod = Hexapod()
    dp, rpy = pose
    position = hexapod.geometry.home_position + dp
    R = rotation_from_rpy(rpy)
    try:
        q = hexapod.inverse_kinematics_matrix(position, R)
    except UnreachablePose:  # a corner of the box (y −3 cm, z +3 cm, tilted) is out of reach
        assume(False)
    L, S, P = hexapod.legs(q, position, R)
    g = hexapod.geometry
    assert np.all((q >= g.stroke_min) & (q <= g.stroke_max)), q
    assert np.all(g.leg_side * (S[:, 0] - P[:, 0]) > 0), "leg-side rule"
    assert np.allclose(np.linalg.norm(L, axis=1), g.leg_lengths, atol=1e-15)
    # The other root of every leg is the mirror of the slider point about P's x: wrong side.
    other = 2 * np.einsum("ij,ij->i", g.slider_axes, P - g.slider_origins) - q
    S_other = hexapod.legs(other, position, R)[1]
    assert np.all(g.leg_side * (S_other[:, 0] - P[:, 0]) < 0)


def test_mirror_pose_through_the_slider_plane_has_the_same_strokes(hexapod):
    position, rpy = SEED_POSES[0]
    R = rotation_from_rpy(rpy)
    q = hexapod.inverse_kinematics_matrix(position, R)
    assert np.allclose(hexapod.inverse_kinematics_matrix(MIRROR @ position, MIRROR @ R @ MIRROR), q, atol=1e-15)


def test_too_far_pose_raises_naming_the_leg(hexapod):
    with pytest.raises(UnreachablePose, match=r"leg [1-6] is too short to reach"):
        hexapod.inverse_kinematics([0.08, 0.02, 0.5], [0, 0, 0])


def test_stroke_out_of_range_raises_with_the_numbers(hexapod):
    with pytest.raises(UnreachablePose, match=r"leg 1 stroke 1\.1\d* m .* outside \[0, 0\.35\]"):
        hexapod.inverse_kinematics([1.0, 0.0, 0.1], [0, 0, 0])


def test_wrong_side_raises():
    # Leg 1 slides along y from x = 0.15: its slider point can never pass P1's x.
    g = HexapodGeometry.default()
    axes = g.slider_axes.copy()
    axes[0] = [0.0, 1.0, 0.0]
    hexapod = Hexapod(g.replace(slider_axes=axes, home_position=[0.03, 0.02, 0.11]))
    with pytest.raises(UnreachablePose, match="leg 1 would stand on the wrong side"):
        hexapod.inverse_kinematics([0.08, 0.02, 0.11], [0, 0, 0])


@pytest.mark.parametrize(
    "call",
    [
        lambda h: h.inverse_kinematics([0.1, 0.0], [0, 0, 0]),
        lambda h: h.inverse_kinematics([0.1, np.nan, 0.1], [0, 0, 0]),
        lambda h: h.inverse_kinematics([0.1, 0.0, 0.1], [0, np.inf, 0]),
        lambda h: h.inverse_kinematics_matrix([0.1, 0.0, 0.1], 2 * np.eye(3)),
        lambda h: h.inverse_kinematics_matrix([0.1, 0.0, 0.1], np.eye(2)),
        lambda h: h.forward_kinematics(np.full(5, 0.1)),
        lambda h: h.forward_kinematics([0.1, 0.1, np.nan, 0.1, 0.1, 0.1]),
        lambda h: h.forward_kinematics(h.home_strokes, steps=0),
    ],
)
def test_bad_input_raises_invalid_input(hexapod, call):
    with pytest.raises(InvalidInput):
        call(hexapod)


# Forward kinematics ----------------------------------------------------------------
@pytest.mark.parametrize("k", range(3))
def test_fk_recovers_seed_poses_from_home(hexapod, k):
    position, rpy = SEED_POSES[k]
    q = hexapod.inverse_kinematics(position, rpy)
    p, R = hexapod.forward_kinematics(q)
    err = pose_error(p, R, position, rotation_from_rpy(rpy))
    assert err <= 1e-8, f"pose {k + 1}: strokes {q} -> {p}, {rpy_from_rotation(R)} (error {err:.2e})"


def test_fk_of_seed_pose_4_depends_on_the_assembly_branch(hexapod):
    """Pose 4 (z = −0.02 m) is below the slider plane, near a singularity (manipulability
    0.006): continuation from home reaches another assembly with the same strokes, above
    the plane; asking for the assembly nearest to a pose close to pose 4 gives pose 4."""
    position, rpy = SEED_POSES[3]
    R4 = rotation_from_rpy(rpy)
    q = hexapod.inverse_kinematics_matrix(position, R4)
    from_home = hexapod.forward_kinematics(q)
    p_home, R_home = from_home
    assert from_home.side == "above" and p_home[2] > 0 and pose_error(p_home, R_home, position, R4) > 1e-2
    assert np.allclose(hexapod.inverse_kinematics_matrix(p_home, R_home), q, atol=1e-12)
    near = hexapod.forward_kinematics(q, near=(np.add(position, 0.002), rotation_from_rpy(np.add(rpy, 0.5))))
    assert near.side == "below" and pose_error(*near, position, R4) <= 1e-8


# Every corner of a 5 mm box about pose 4 (8.7 mm away), each angle 0.5° off. From these,
# plain Newton reaches another assembly (3 mm, 3° away) from the 4 corners with z + 5 mm
# and tilt (0.5, 0.5, 0.5)°, and continuation from the guess fails for 7 of the 16.
CORNERS = [(np.array(sx), np.array(sa)) for sx in np.array(np.meshgrid(*[[-1, 1]] * 3)).reshape(3, -1).T
           for sa in ([0.5, 0.5, 0.5], [-0.5, 0.5, -0.5])]


@pytest.mark.parametrize("signs,tilt", CORNERS)
def test_fk_near_finds_seed_pose_4_from_5_mm_away(hexapod, signs, tilt):
    position, rpy = SEED_POSES[3]
    R4 = rotation_from_rpy(rpy)
    q = hexapod.inverse_kinematics_matrix(position, R4)
    guess = (np.add(position, 0.005 * signs), rotation_from_rpy(np.add(rpy, tilt)))
    found = hexapod.forward_kinematics(q, near=guess)
    assert pose_error(*found, position, R4) <= 1e-8, found
    assert found.side == "below" and "nearest" in found.method


def test_fk_side_chooses_the_mirror_assembly(hexapod):
    """Sliders and platform points are coplanar, so every pose has a mirror twin through the
    slider plane with the same strokes; ``side`` picks it."""
    position, rpy = SEED_POSES[0]
    R1 = rotation_from_rpy(rpy)
    q = hexapod.inverse_kinematics_matrix(position, R1)
    above = hexapod.forward_kinematics(q, side="above")
    assert above.side == "above" and pose_error(*above, position, R1) <= 1e-8 and above.method == "continuation from home"
    below = hexapod.forward_kinematics(q, side="below")
    mirror_p, mirror_R = hexapod.mirror_pose(position, R1)
    assert below.side == "below" and mirror_p[2] < 0 and pose_error(*below, mirror_p, mirror_R) <= 1e-8
    assert "mirror" in below.method
    assert np.max(np.abs(hexapod.leg_residuals(q, *below))) <= 1e-12
    with pytest.raises(InvalidInput):
        hexapod.forward_kinematics(q, side="left")
    with pytest.raises(InvalidInput):
        hexapod.forward_kinematics(q, initial=above, near=above)


@settings(max_examples=40, deadline=None)
@given(near_home)
def test_fk_inverts_ik_near_home(pose):
    hexapod = Hexapod()
    dp, rpy = pose
    position = hexapod.geometry.home_position + dp
    R = rotation_from_rpy(rpy)
    # Corners of the box (y and z both near +3 cm) are unreachable or near a singularity,
    # where two assemblies meet and the one from home is not the pose asked for (the
    # inverse Jacobian's condition number 2e3-4e3 there, 140 at the median): not "near home".
    try:
        assume(np.linalg.cond(hexapod.inverse_jacobian(position, R)) < 1e3)
    except UnreachablePose:
        assume(False)
    p, R_fk = hexapod.forward_kinematics(hexapod.inverse_kinematics_matrix(position, R))
    assert pose_error(p, R_fk, position, R) <= 1e-8


def test_fk_of_strokes_without_assembly_raises(hexapod):
    # Sliders 1 and 2 end up 0.77 m apart, more than two legs and the platform can span.
    with pytest.raises(ConvergenceError):
        hexapod.forward_kinematics([0.35, 0.0, 0.0, 0.0, 0.0, 0.0])


# Differential kinematics -----------------------------------------------------------
@pytest.mark.parametrize("pose", [(np.array([0.08, 0.02, 0.11]), (0.0, 0.0, 0.0)), *SEED_POSES[:3]])
def test_inverse_jacobian_matches_finite_differences(hexapod, pose):
    position, R = np.asarray(pose[0], dtype=float), rotation_from_rpy(pose[1])
    Jinv = hexapod.inverse_jacobian(position, R)
    h = 1e-6
    fd = np.empty((6, 6))
    for k in range(3):
        e = np.eye(3)[k] * h
        fd[:, k] = (hexapod.inverse_kinematics_matrix(position + e, R)
                    - hexapod.inverse_kinematics_matrix(position - e, R)) / (2 * h)
        turn = Rotation.from_rotvec(e).as_matrix()  # world-frame rotation: ω = e/h
        fd[:, 3 + k] = (hexapod.inverse_kinematics_matrix(position, turn @ R)
                        - hexapod.inverse_kinematics_matrix(position, turn.T @ R)) / (2 * h)
    assert np.max(np.abs(fd - Jinv)) <= 1e-6 * np.max(np.abs(Jinv))


@pytest.mark.parametrize("k", range(4))
def test_stroke_sensitivity_matches_finite_differences(hexapod, k):
    position, rpy = SEED_POSES[k]
    R = rotation_from_rpy(rpy)
    h = 1e-7
    plus = Hexapod(hexapod.geometry.with_leg_length_errors(np.full(6, h))).inverse_kinematics_matrix(position, R)
    minus = Hexapod(hexapod.geometry.with_leg_length_errors(np.full(6, -h))).inverse_kinematics_matrix(position, R)
    analytic = hexapod.stroke_sensitivity_to_leg_length(position, R)
    assert np.allclose((plus - minus) / (2 * h), analytic, rtol=1e-6, atol=0), analytic


def test_manipulability_is_highest_near_home_and_vanishes_on_the_slider_plane(hexapod):
    home = hexapod.manipulability(hexapod.geometry.home_position, np.eye(3))
    assert 0.05 < home < 0.07
    for position, rpy in SEED_POSES:
        assert 0 < hexapod.manipulability(position, rotation_from_rpy(rpy)) < home
    assert hexapod.manipulability([0.08, 0.02, 1e-7], np.eye(3)) < 1e-5
