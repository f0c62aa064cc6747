"""Collision avoidance: a hand pulled into a box stops at the minimum distance."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from qpik import CollisionAvoidanceLimit, DampingTask, InvalidInput, PositionTask, QPController, Robot, UnknownName


SCENE = """
<mujoco model="reach-into-box">
  <compiler angle="radian"/>
  <option timestep="0.002"/>
  <worldbody>
    <geom name="box" type="box" pos="0.9 0.5 0" size="0.1 0.1 0.1"/>
    <body name="link1">
      <joint name="j1" type="hinge" axis="0 0 1" range="-3 3"/>
      <geom type="capsule" fromto="0 0 0 0.5 0 0" size="0.02" contype="0" conaffinity="0"/>
      <body name="link2" pos="0.5 0 0">
        <joint name="j2" type="hinge" axis="0 0 1" range="-3 3"/>
        <geom type="capsule" fromto="0 0 0 0.4 0 0" size="0.02" contype="0" conaffinity="0"/>
        <body name="link3" pos="0.4 0 0">
          <joint name="j3" type="hinge" axis="0 0 1" range="-3 3"/>
          <geom type="capsule" fromto="0 0 0 0.2 0 0" size="0.02" contype="0" conaffinity="0"/>
          <body name="hand" pos="0.2 0 0">
            <geom name="hand" type="sphere" size="0.03"/>
            <site name="hand_site"/>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
</mujoco>
"""

D_MIN = 0.01
DT = 0.002


@pytest.fixture
def robot():
    robot = Robot(mujoco.MjModel.from_xml_string(SCENE), keyframe=None)
    robot.set_q([1.4, -0.6, -0.3])  # the hand 0.35 m from the box
    robot.update_kinematics()
    return robot


def rollout(robot, limit, steps=1500):
    """Pull the hand toward the box's centre; the distance after every step, and the largest
    excess of the QP's own rows G q̇ − h over the run."""
    task = PositionTask(robot, "hand_site", axes="xyz", gain=20.0)
    task.set_target([0.9, 0.5, 0.0])
    qp = QPController(robot, [task, DampingTask(robot, 1e-3)], [limit], dt=DT)
    distances, excess = [], 0.0
    for _ in range(steps):
        qdot = qp.compute_velocity()
        excess = max(excess, float(np.max(qp.G @ qdot - qp.h)))
        robot.integrate(qdot, DT)
        robot.update_kinematics()
        distances.append(mujoco.mj_geomDistance(robot.model, robot.data, *limit.pairs[0], 1.0, None))
    return np.array(distances), excess


def test_hand_stops_at_the_minimum_distance(robot):
    limit = CollisionAvoidanceLimit(robot, [(["hand"], ["box"])], minimum_distance=D_MIN, detection_distance=0.2)
    distances, excess = rollout(robot, limit)
    assert excess <= 1e-9
    assert distances.min() >= D_MIN - 1e-6
    assert distances[-1] == pytest.approx(D_MIN, abs=1e-4)  # it does get there: the task pulls it in


def test_per_step_bound_alone_overshoots_at_speed(robot):
    """Without the damper (mink's form) the first-order row lets a fast hand overshoot d_s:
    why the damper is the default."""
    limit = CollisionAvoidanceLimit(robot, [(["hand"], ["box"])], minimum_distance=D_MIN, detection_distance=0.2,
                                    damper_rate=None)
    distances, excess = rollout(robot, limit)
    assert excess <= 1e-9  # the QP keeps its rows...
    assert D_MIN - 1e-2 < distances.min() < D_MIN - 1e-5  # ...but the linearisation misses by a fraction of a mm


def test_row_is_the_distance_rate(robot):
    """G q̇ = −ḋ: checked against the finite difference of mj_geomDistance."""
    robot.set_q([0.9, 0.5, 0.2])
    robot.update_kinematics()
    limit = CollisionAvoidanceLimit(robot, [(["hand"], ["box"])], minimum_distance=D_MIN, detection_distance=1.0)
    G, h = np.zeros((1, robot.nv)), np.zeros(1)
    limit.apply(DT, None, None, G[None], h[None])  # one world's rows
    damper_bound = h[0]
    limit.damper_rate = None
    limit.apply(DT, None, None, G[None], h[None])
    qdot = np.array([0.3, -0.7, 0.4])
    eps = 1e-7
    q0 = robot.q.copy()
    d0 = limit.distances[0]
    robot.integrate(qdot, eps)
    robot.update_kinematics()
    d1 = mujoco.mj_geomDistance(robot.model, robot.data, *limit.pairs[0], 1.0, None)
    robot.set_q(q0)
    assert G[0] @ qdot == pytest.approx(-(d1 - d0) / eps, rel=1e-5)
    assert h[0] == pytest.approx(0.85 * (d0 - D_MIN) / DT)
    assert damper_bound == pytest.approx(0.5 * (d0 - D_MIN) / (1.0 - D_MIN))


def test_far_pairs_add_no_constraint(robot):
    """A pair farther than d_i plus its reach (how far one step in the speed box can bring
    it) gets no row (0 ≤ +inf). At 1 rad/s the hand's reach over a step is at most
    Δt Σ_k L_k ≈ 0.002 (1.13 + 0.63 + 0.23) ≈ 4 mm, and it is 0.35 m from the box. Without
    a speed bound every pair is within reach and keeps its row (the module's rule: no pair
    is crossed in one step from beyond d_i)."""
    limit = CollisionAvoidanceLimit(robot, [(["hand"], ["box"])], detection_distance=0.05)
    lower, upper = np.full((1, robot.nv), -1.0), np.full((1, robot.nv), 1.0)  # one world's box
    G, h = np.ones((1, 1, robot.nv)), np.zeros((1, 1))
    limit.apply(DT, lower, upper, G, h)
    assert mujoco.mj_geomDistance(robot.model, robot.data, *limit.pairs[0], 1.0, None) > 0.3
    assert h[0, 0] == np.inf and not G.any()
    limit.apply(DT, None, None, G, h)
    assert np.isfinite(h[0, 0]) and G.any()


def test_bad_input(robot):
    with pytest.raises(UnknownName, match="close matches: .*hand"):
        CollisionAvoidanceLimit(robot, [(["hnd"], ["box"])])
    with pytest.raises(InvalidInput, match="detection distance"):
        CollisionAvoidanceLimit(robot, [(["hand"], ["box"])], minimum_distance=0.1, detection_distance=0.05)
    with pytest.raises(InvalidInput, match="no geom pair"):
        CollisionAvoidanceLimit(robot, [(["hand"], ["hand"])])


def test_mesh_distances_are_exact_where_the_model_turns_native_collision_off(jaco_path):
    """dm_control's Jaco disables MuJoCo's native convex collision; its fallback (libccd
    MPR) is centimetres off near contact (here a wrist cylinder 3.0 cm from the box reads
    1.2 cm, a wrist mesh 1.1 cm inside it reads 4.8 cm inside). The limit's distances are
    the native (GJK/EPA) ones whatever the flag, and the flag is left as it was."""
    spec = mujoco.MjSpec.from_file(str(jaco_path))
    spec.worldbody.add_geom(name="box", type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.12, 0.12, 0.02],
                            pos=[-0.49, 0.07, 0.38])
    robot = Robot(spec.compile(), keyframe=None)
    native_off = int(mujoco.mjtDisableBit.mjDSBL_NATIVECCD)
    assert robot.model.opt.disableflags & native_off
    robot.set_q([0.0, 3.9, 2.0, -1.0, -1.5, 1.0])
    robot.update_kinematics()
    limit = CollisionAvoidanceLimit(robot, [(["b_5"], ["box"])], minimum_distance=0.0, detection_distance=0.1)
    rows = len(limit.pairs)
    limit.apply(DT, None, None, np.zeros((1, rows, robot.nv)), np.zeros((1, rows)))  # one world's rows
    assert robot.model.opt.disableflags & native_off  # restored
    fallback = [mujoco.mj_geomDistance(robot.model, robot.data, *pair, 0.1, None) for pair in limit.pairs]
    robot.model.opt.disableflags &= ~native_off
    native = [mujoco.mj_geomDistance(robot.model, robot.data, *pair, 0.1, None) for pair in limit.pairs]
    assert rows == 2 and min(abs(np.subtract(fallback, native))) > 0.01  # why the limit switches
    assert min(native) < 0.0 < max(native)
    np.testing.assert_array_equal(limit.distances, native)
