"""The CPU back-end (``mujoco.batch`` and NumPy) against MuJoCo's own serial routines,
world by world: frame poses, Jacobians, centres of mass and their Jacobians, the
integration q ⊕ q̇Δt, the equality-constraint rows, and MuJoCo's timer callback left as
it was."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from qpik import batch
from qpik.batch.backends.cpu import CpuBackend
from qpik.robot import scene_path

# Every quantity below is a product of a few O(1) numbers (models of ~1 m, unit
# rotations): the back-end and MuJoCo round differently in the last bits only.
ROUNDING = 1e-12


def _model(name: str, model_path) -> mujoco.MjModel:
    if name == "pusher":
        from qpik.models import pusher_arm

        return pusher_arm()
    return mujoco.MjModel.from_xml_path(str(scene_path(name)) if name in ("arm", "hexapod") else str(model_path(name)))


def _states(model: mujoco.MjModel, n: int, seed: int, spread: float) -> np.ndarray:
    """n configurations q0 ⊕ a random velocity (quaternions stay unit)."""
    rng = np.random.default_rng(seed)
    states = np.tile(model.qpos0, (n, 1))
    for q in states:
        mujoco.mj_integratePos(model, q, rng.normal(size=model.nv), spread)
    return states


@pytest.mark.parametrize("name", ["arm", "hexapod", "humanoid"])
def test_kinematics_and_integration_equal_mujoco_in_every_world(name, model_path):
    model = _model(name, model_path)
    n = 4
    backend = CpuBackend(model, n, nthread=2)
    states = _states(model, n, seed=5, spread=0.3)
    backend.qpos[:] = states
    backend.forward()
    data = mujoco.MjData(model)
    for body in range(1, model.nbody):
        position, rotation = backend.frame_pose("body", body)
        jacp, jacr = backend.jacobian(body, position)
        com_jacobian = backend.subtree_com_jacobian(body) if model.body_subtreemass[body] > 0 else None
        for i in range(n):
            data.qpos[:] = states[i]
            mujoco.mj_kinematics(model, data)
            mujoco.mj_comPos(model, data)
            p, r = np.zeros((3, model.nv)), np.zeros((3, model.nv))
            mujoco.mj_jacBody(model, data, p, r, body)
            np.testing.assert_allclose(jacp[i], p, rtol=0, atol=ROUNDING)
            np.testing.assert_allclose(jacr[i], r, rtol=0, atol=ROUNDING)
            np.testing.assert_allclose(position[i], data.xpos[body], rtol=0, atol=ROUNDING)
            np.testing.assert_allclose(rotation[i].ravel(), data.xmat[body], rtol=0, atol=ROUNDING)
            np.testing.assert_allclose(backend.subtree_com(body)[i], data.subtree_com[body], rtol=0, atol=ROUNDING)
            if com_jacobian is not None:
                mujoco.mj_jacSubtreeCom(model, data, p, body)
                np.testing.assert_allclose(com_jacobian[i], p, rtol=0, atol=ROUNDING)
    velocity = np.random.default_rng(6).normal(size=(n, model.nv))
    expected = states.copy()
    for i in range(n):
        mujoco.mj_integratePos(model, expected[i], velocity[i], 0.01)
    backend.integrate(velocity, 0.01)
    np.testing.assert_allclose(backend.qpos, expected, rtol=0, atol=ROUNDING)
    # a subset of the worlds moves, the others stay
    backend.integrate(velocity[[1, 3]], 0.01, ids=np.array([1, 3]))
    for i in (1, 3):
        mujoco.mj_integratePos(model, expected[i], velocity[i], 0.01)
    np.testing.assert_allclose(backend.qpos, expected, rtol=0, atol=ROUNDING)


@pytest.mark.parametrize("name", ["arm", "hexapod", "pusher", "humanoid"])
def test_pared_kinematic_model_changes_no_value_a_task_reads(name, model_path):
    """The back-end's kinematic copy (no contacts, no constraints, no geoms listed on its
    bodies) gives every pose, cdof and centre of mass of MuJoCo on the full model, and
    geom frames as mj_kinematics writes them."""
    model = _model(name, model_path)
    n = 5
    backend = CpuBackend(model, n, nthread=1)
    states = _states(model, n, seed=8, spread=0.5)
    backend.qpos[:] = states
    frames = {(kind, i): backend.frame_pose(kind, i) for kind, count in
              (("site", model.nsite), ("body", model.nbody), ("geom", model.ngeom)) for i in range(count)}
    backend.forward()
    fields = {"site": ("site_xpos", "site_xmat"), "body": ("xpos", "xmat"), "geom": ("geom_xpos", "geom_xmat")}
    data = mujoco.MjData(model)
    for i in range(n):
        data.qpos[:] = states[i]
        mujoco.mj_fwdPosition(model, data)  # the full model's position stage: geoms, contacts, all
        for (kind, k), (position, rotation) in frames.items():
            # MuJoCo's own outputs bit for bit; a geom's pose, formed here from its
            # body's, to 1e-15 (MuJoCo's compiled products may round the last bit otherwise)
            atol = 1e-15 if kind == "geom" else 0.0
            np.testing.assert_allclose(position[i], getattr(data, fields[kind][0])[k], rtol=0, atol=atol,
                                       err_msg=f"{kind} {k}")
            np.testing.assert_allclose(rotation[i].ravel(), getattr(data, fields[kind][1])[k], rtol=0, atol=atol,
                                       err_msg=f"{kind} {k}")
        np.testing.assert_array_equal(backend._cdof[i], data.cdof)
        np.testing.assert_array_equal(backend._subtree_com[i], data.subtree_com)


COUPLED = """
<mujoco>
  <compiler angle="radian"/>
  <worldbody>
    <body name="a">
      <joint name="j1" axis="0 0 1" range="-2 2"/>
      <geom type="capsule" size="0.05" fromto="0 0 0 1 0 0"/>
      <body name="b" pos="1 0 0">
        <joint name="j2" axis="0 1 0" range="-2 2"/>
        <geom type="capsule" size="0.05" fromto="0 0 0 1 0 0"/>
      </body>
    </body>
    <body name="c" pos="0 1 0">
      <joint name="j3" axis="1 0 0" range="-2 2"/>
      <geom type="capsule" size="0.05" fromto="0 0 0 0 0 1"/>
      <body name="d" pos="0 0 1">
        <joint name="j4" type="slide" axis="0 0 1" range="-1 1"/>
        <geom type="box" size="0.05 0.05 0.05"/>
      </body>
    </body>
  </worldbody>
  <equality>
    <joint joint1="j3" joint2="j1" polycoef="0.1 0.5 0.2 -0.3 0.05"/>
    <connect body1="b" body2="d" anchor="0.5 0 0"/>
    <joint joint1="j4" polycoef="0.2 0 0 0 0"/>
  </equality>
</mujoco>
"""


def _mujoco_equality_rows(model: mujoco.MjModel, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """MuJoCo's own equality rows (efc_pos, efc_J) at q, in its row order."""
    data = mujoco.MjData(model)
    data.qpos[:] = q
    mujoco.mj_fwdPosition(model, data)
    rows = data.efc_type == int(mujoco.mjtConstraint.mjCNSTR_EQUALITY)
    jacobian = data.efc_J.reshape(data.nefc, model.nv) if not mujoco.mj_isSparse(model) else None
    if jacobian is None:
        jacobian = np.zeros((data.nefc, model.nv))
        mujoco.mju_sparse2dense(jacobian, data.efc_J, data.efc_J_rownnz, data.efc_J_rowadr, data.efc_J_colind)
    return data.efc_pos[rows], jacobian[rows]


@pytest.mark.parametrize("scene", ["coupled", "hexapod"])
def test_equality_rows_equal_mujocos_make_constraint(scene):
    """Joint couplings (with and without a second joint), body-anchored connects (the
    coupled model) and site-anchored connects (the hexapod's loop closures)."""
    model = (mujoco.MjModel.from_xml_string(COUPLED) if scene == "coupled"
             else mujoco.MjModel.from_xml_path(str(scene_path("hexapod"))))
    n = 5
    backend = CpuBackend(model, n, nthread=1)
    states = _states(model, n, seed=11, spread=0.4)  # loops opened: residuals of cm
    backend.qpos[:] = states
    backend.forward()
    residual, jacobian = backend.equality_rows(np.arange(model.neq))
    assert np.abs(residual).max() > 1e-3  # the rows measure open loops, not zeros
    for i in range(n):
        expected_residual, expected_jacobian = _mujoco_equality_rows(model, states[i])
        np.testing.assert_allclose(residual[i], expected_residual, rtol=0, atol=ROUNDING)
        np.testing.assert_allclose(jacobian[i], expected_jacobian, rtol=0, atol=ROUNDING)


def test_a_weld_equality_is_not_batched_and_says_what_runs_it():
    spec = mujoco.MjSpec()
    body = spec.worldbody.add_body(name="b", pos=[0, 0, 1])
    body.add_joint(name="j", type=mujoco.mjtJoint.mjJNT_HINGE, axis=[0, 1, 0])
    body.add_geom(size=[0.1, 0, 0], mass=1.0)
    spec.add_equality(type=mujoco.mjtEq.mjEQ_WELD, name1="b", objtype=mujoco.mjtObj.mjOBJ_BODY)
    robots = batch.Robot(spec.compile(), 2)
    with pytest.raises(batch.NotBatched, match="weld"):
        robots.backend.equality_rows(np.array([0]))


def test_forward_leaves_mujocos_timer_callback_as_it_was():
    """The back-end runs MuJoCo's stages with the profiling timer callback replaced by a
    constant; the caller's callback is back after each call and times MuJoCo again."""
    model = mujoco.MjModel.from_xml_path(str(scene_path("arm")))
    backend = CpuBackend(model, 8, nthread=1)
    ticks = []

    def timer():
        ticks.append(None)
        return float(len(ticks))

    mujoco.set_mjcb_time(timer)
    try:
        backend.forward()
        assert mujoco.get_mjcb_time() is timer and not ticks  # restored; not called by the batch
        data = mujoco.MjData(model)
        mujoco.mj_forward(model, data)
        assert ticks  # the caller's timer times MuJoCo again
    finally:
        mujoco.set_mjcb_time(None)
    backend.forward()
    assert mujoco.get_mjcb_time() is None  # the bindings' own default, as before
