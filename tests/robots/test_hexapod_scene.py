"""The generated hexapod MJCF: agreement with the geometry, closed loops, physics sanity."""

from __future__ import annotations

import re

import mujoco
import numpy as np
import pytest

from qpik.errors import ModelError
from qpik.robots.hexapod.kinematics import Hexapod, rotation_from_rpy
from qpik.robots.hexapod.scene import SCENE_PATH, close_loops, hexapod_mjcf, platform_pose

_NUMBER = re.compile(r"-?\d+\.?\d*(?:e[-+]?\d+)?")


@pytest.fixture(scope="module")
def hexapod() -> Hexapod:
    return Hexapod()


@pytest.fixture(scope="module")
def model() -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_path(str(SCENE_PATH))


def _id(model, kind, name: str) -> int:
    idx = mujoco.mj_name2id(model, kind, name)
    assert idx >= 0, f"missing {name}"
    return idx


def loop_residuals(model, data) -> np.ndarray:
    """World distance between the two sites of every connect (after kinematics)."""
    return np.array([
        np.linalg.norm(data.site_xpos[model.eq_obj1id[e]] - data.site_xpos[model.eq_obj2id[e]])
        for e in range(model.neq)
    ])


def test_committed_scene_is_the_generated_one():
    committed, generated = SCENE_PATH.read_text(), hexapod_mjcf()
    # Same text apart from the last ulp of computed numbers (libm may differ by machine).
    assert _NUMBER.sub("#", committed) == _NUMBER.sub("#", generated), "run `python -m qpik.robots.hexapod.scene`"
    a = np.array(_NUMBER.findall(committed), dtype=float)
    b = np.array(_NUMBER.findall(generated), dtype=float)
    # Each number is a few libm calls (sin, cos of the legs' angles) on O(0.1) values,
    # written with 17 digits: machines differ in the last ulp (1e-16), no BLAS involved.
    assert np.allclose(a, b, rtol=1e-14, atol=1e-15)


def test_model_names_ranges_and_order(model):
    assert (model.nq, model.nv, model.nu, model.neq) == (25, 24, 12, 6)  # position + velocity servo per slider
    names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j) for j in range(model.njnt)]
    legs = [[f"slider{i}", f"u{i}_a", f"u{i}_b"] for i in range(1, 7)]
    assert names == sum(legs, []) + ["platform"]
    for i in range(1, 7):
        slider = _id(model, mujoco.mjtObj.mjOBJ_JOINT, f"slider{i}")
        assert model.jnt_type[slider] == mujoco.mjtJoint.mjJNT_SLIDE
        assert model.jnt_range[slider].tolist() == [0.0, 0.35]  # metres
        for hinge in (f"u{i}_a", f"u{i}_b"):
            j = _id(model, mujoco.mjtObj.mjOBJ_JOINT, hinge)
            assert model.jnt_limited[j] and np.allclose(model.jnt_range[j], [-np.pi / 2, np.pi / 2])  # radians
        act = _id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, f"act{i}")
        assert model.actuator_trnid[act, 0] == slider
        assert model.actuator_ctrlrange[act].tolist() == [0.0, 0.35]
        rate = _id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, f"vel{i}")
        assert model.actuator_trnid[rate, 0] == slider
        numeric = _id(model, mujoco.mjtObj.mjOBJ_NUMERIC, f"qpik_velocity_limit_slider{i}")
        assert model.numeric_size[numeric] == 1 and model.numeric_data[model.numeric_adr[numeric]] == 0.5
        eq = _id(model, mujoco.mjtObj.mjOBJ_EQUALITY, f"loop{i}")
        assert model.eq_type[eq] == mujoco.mjtEq.mjEQ_CONNECT and model.eq_objtype[eq] == mujoco.mjtObj.mjOBJ_SITE
        assert model.eq_obj1id[eq] == _id(model, mujoco.mjtObj.mjOBJ_SITE, f"leg{i}_tip")
        assert model.eq_obj2id[eq] == _id(model, mujoco.mjtObj.mjOBJ_SITE, f"platform_point{i}")
    assert np.all(model.geom_contype == 0) and np.all(model.geom_conaffinity == 0)
    assert model.opt.timestep == 0.002 and model.opt.integrator == mujoco.mjtIntegrator.mjINT_IMPLICITFAST


def test_model_geometry_equals_the_hexapod_geometry(model, hexapod):
    g = hexapod.geometry
    for i in range(6):
        body = _id(model, mujoco.mjtObj.mjOBJ_BODY, f"slider{i + 1}")
        joint = _id(model, mujoco.mjtObj.mjOBJ_JOINT, f"slider{i + 1}")
        tip = _id(model, mujoco.mjtObj.mjOBJ_SITE, f"leg{i + 1}_tip")
        point = _id(model, mujoco.mjtObj.mjOBJ_SITE, f"platform_point{i + 1}")
        assert np.allclose(model.body_pos[body], g.slider_origins[i], atol=1e-12, rtol=0)
        assert np.allclose(model.jnt_axis[joint], g.slider_axes[i], atol=1e-12, rtol=0)
        assert abs(np.linalg.norm(model.site_pos[tip]) - g.leg_lengths[i]) <= 1e-12
        assert np.allclose(model.site_pos[point], g.platform_points[i], atol=1e-12, rtol=0)
    platform = _id(model, mujoco.mjtObj.mjOBJ_BODY, "platform")
    assert np.all(model.site_bodyid[[model.eq_obj2id[e] for e in range(6)]] == platform)


def test_home_keyframe_closes_every_loop(model, hexapod):
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, _id(model, mujoco.mjtObj.mjOBJ_KEY, "home"))
    mujoco.mj_forward(model, data)
    equality_rows = data.efc_type == mujoco.mjtConstraint.mjCNSTR_EQUALITY
    assert equality_rows.sum() == 18
    assert np.max(np.abs(data.efc_pos[equality_rows])) <= 1e-9
    assert np.max(loop_residuals(model, data)) <= 1e-9
    center = _id(model, mujoco.mjtObj.mjOBJ_SITE, "platform_center")
    assert np.allclose(data.site_xpos[center], hexapod.geometry.home_position, atol=1e-12)
    assert np.allclose(data.qpos[[0, 3, 6, 9, 12, 15]], hexapod.home_strokes, atol=1e-15)
    assert np.allclose(data.ctrl[0::2], hexapod.home_strokes, atol=1e-15)  # act<i>, then vel<i> = 0
    assert np.all(data.ctrl[1::2] == 0.0)


def test_close_loops_at_random_reachable_poses(model, hexapod):
    data = mujoco.MjData(model)
    center = _id(model, mujoco.mjtObj.mjOBJ_SITE, "platform_center")
    rng = np.random.default_rng(7)
    for _ in range(20):
        position = hexapod.geometry.home_position + rng.uniform(-0.03, 0.03, 3)
        R = rotation_from_rpy(rng.uniform(-5, 5, 3))
        q = hexapod.inverse_kinematics_matrix(position, R)
        p_fk, R_fk = close_loops(model, data, q, hexapod=hexapod)
        assert np.max(loop_residuals(model, data)) <= 1e-9
        assert np.allclose(data.site_xpos[center], p_fk, atol=1e-12)
        assert np.allclose(data.site_xmat[center].reshape(3, 3), R_fk, atol=1e-12)
        assert np.allclose(p_fk, position, atol=1e-8)
        p_read, R_read = platform_pose(model, data)
        assert np.allclose(p_read, p_fk, atol=1e-15) and np.allclose(R_read, R_fk, atol=1e-12)
        hinges = np.abs(np.delete(data.qpos[:18], np.s_[::3]))
        assert np.all(hinges < np.pi / 2)


def test_close_loops_on_seed_pose_4_from_a_nearby_initial_pose(model, hexapod):
    data = mujoco.MjData(model)
    position, R = np.array([0.13, -0.06, -0.02]), rotation_from_rpy([5.0, -4.0, -1.0])
    q = hexapod.inverse_kinematics_matrix(position, R)
    p, _ = close_loops(model, data, q, hexapod=hexapod, initial=(position + 0.001, R))
    assert np.allclose(p, position, atol=1e-8) and np.max(loop_residuals(model, data)) <= 1e-9


def test_close_loops_rejects_another_model(hexapod):
    other = mujoco.MjModel.from_xml_string(
        "<mujoco><worldbody><body><joint type='slide'/><geom size='0.1'/></body></worldbody></mujoco>")
    with pytest.raises(ModelError):
        close_loops(other, mujoco.MjData(other), hexapod.home_strokes, hexapod=hexapod)


def test_platform_holds_under_gravity_at_home(model, hexapod):
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, _id(model, mujoco.mjtObj.mjOBJ_KEY, "home"))
    for _ in range(500):  # 1 s
        mujoco.mj_step(model, data)
    position, R = platform_pose(model, data)
    assert np.all(np.isfinite(data.qpos))
    assert np.linalg.norm(position - hexapod.geometry.home_position) < 1e-3
    assert np.max(loop_residuals(model, data)) < 1e-4
