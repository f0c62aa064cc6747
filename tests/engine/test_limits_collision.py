"""The engine's CollisionAvoidanceLimit: its rows at N = 1 against the rule written out
pair by pair on MuJoCo's own distances and point Jacobians, each of N worlds its own, the
pairs within one step's reach of the detection distance (no pair crossed in one step),
typed errors, and QP rollouts through the controller (the closed form checks the rows;
worlds whose rows bind go to the solver), each step the minimiser of its QP solved
independently."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import mujoco
import numpy as np
import pytest

import qpik
from qpik import batch
from qpik.controllers import QPController
from qpik.errors import InvalidInput, UnknownName
from qpik.limits import CollisionAvoidanceLimit, JointPositionLimit, JointVelocityLimit
from qpik.limits.geom_pairs import geom_pairs
from qpik.limits.reach import PairReach
from qpik.tasks import DampingTask, FrameTask, PositionTask

_spec = importlib.util.spec_from_file_location("references", Path(__file__).with_name("references.py"))
references = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(references)

DT = 0.002
D_MIN = 0.01

# A planar three-link arm whose hand (a sphere) reaches toward a box.
REACH = """
<mujoco model="reach-into-box">
  <compiler angle="radian"/>
  <worldbody>
    <geom name="box" type="box" pos="0.9 0.5 0" size="0.1 0.1 0.1"/>
    <body name="link1">
      <joint name="j1" type="hinge" axis="0 0 1" range="-3 3"/>
      <geom type="capsule" fromto="0 0 0 0.5 0 0" size="0.02" contype="0" conaffinity="0"/>
      <body name="link2" pos="0.5 0 0">
        <joint name="j2" type="hinge" axis="0 0 1" range="-3 3"/>
        <geom name="forearm" type="capsule" fromto="0 0 0 0.4 0 0" size="0.02"/>
        <body name="link3" pos="0.4 0 0">
          <joint name="j3" type="hinge" axis="0 0 1" range="-3 3"/>
          <geom name="wrist" type="capsule" fromto="0 0 0 0.2 0 0" size="0.02"/>
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
REACH_STATES = np.array([[1.4, -0.6, -0.3], [0.9, 0.5, 0.2], [0.75, 0.35, 0.9], [1.1, -0.2, 0.1]])
REACH_PAIRS = [(["hand", "wrist", "forearm"], ["box"])]

# A rod lifted by a slide above a floor (a plane), and a swinging bar: the fuzz's plane–capsule
# pairs. Each moving body sits below a first joint, so that MuJoCo's filter keeps the pair.
CROSSING = """
<mujoco>
  <worldbody>
    <geom name="floor" type="plane" size="2 2 0.1"/>
    <body name="turn" pos="0 0 0.5">
      <joint name="yaw" axis="0 0 1" range="-3 3"/>
      <geom size="0.01" contype="0" conaffinity="0"/>
      <body name="lift">
        <joint name="z" type="slide" axis="0 0 1" range="-3 3"/>
        <geom name="rod" type="capsule" fromto="-0.2 0 0 0.2 0 0" size="0.02"/>
        <site name="rod_site"/>
      </body>
    </body>
    <body name="upper" pos="1 0 0.6">
      <joint name="shoulder" axis="0 1 0" range="-3 3"/>
      <geom size="0.01" contype="0" conaffinity="0"/>
      <body name="lower" pos="0.1 0 0">
        <joint name="elbow" axis="0 1 0" range="-3 3"/>
        <geom name="bar" type="capsule" fromto="0 0 0 0.5 0 0" size="0.02"/>
        <site name="bar_site" pos="0.5 0 0"/>
      </body>
    </body>
  </worldbody>
</mujoco>
"""

JACO_START = np.array([0.0, 3.6, 2.0, -1.0, -1.5, 1.0])
JACO_HAND = ["b_4", "b_5", "b_6"]
JACO_SPEEDS = {"joint_1": 1.0, "joint_2": 1.0, "joint_3": 1.0, "joint_4": 1.5, "joint_5": 1.5, "joint_6": 1.5}


def reach_robot(q=REACH_STATES[0]) -> qpik.Robot:
    robot = qpik.Robot(mujoco.MjModel.from_xml_string(REACH))
    robot.set_q(q)
    robot.update_kinematics()
    return robot


def speed_box(n: int, nv: int, speed: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    return np.full((n, nv), -speed), np.full((n, nv), speed)


def engine_rows(limit, robot, dt: float = DT, speed: float = 2.0):
    robot.ensure_kinematics()
    rows = limit.inequality_rows
    G, h = np.zeros((robot.n, rows, robot.nv)), np.zeros((robot.n, rows))
    limit.apply(dt, *speed_box(robot.n, robot.nv, speed), G, h)
    return G, h


@pytest.fixture(scope="module")
def jaco_model(jaco_path) -> mujoco.MjModel:
    """dm_control's Jaco and a box under its hand, 5 cm below it at ``JACO_START``."""

    def compiled(height: float) -> mujoco.MjModel:
        spec = mujoco.MjSpec.from_file(str(jaco_path))
        spec.worldbody.add_geom(name="box", type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.12, 0.12, 0.02],
                                pos=[wrist[0], wrist[1], height])
        return spec.compile()

    bare = qpik.Robot(mujoco.MjModel.from_xml_path(str(jaco_path)))
    bare.set_q(JACO_START)
    bare.update_kinematics()
    wrist = bare.data.site_xpos[bare.site_id("wristsite")].copy()
    probe = qpik.Robot(compiled(wrist[2] - 0.4))
    probe.set_q(JACO_START)
    limit = CollisionAvoidanceLimit(probe, [(JACO_HAND, ["box"])], detection_distance=1.0)
    engine_rows(limit, probe)
    return compiled(wrist[2] - 0.4 + limit.distances.min() - 0.05)


# -- the rows ---------------------------------------------------------------------------
# The rows against references.collision_rows: the same MuJoCo calls (mj_geomDistance,
# mj_jac) on the same geom poses, the normal and the products formed in another order:
# 1e-12 of a row's norm; the bounds are products of those distances, 1e-13.
ROW_TOLERANCE, BOUND_TOLERANCE = 1e-12, 1e-13


def assert_rows_follow_the_rule(G, h, expected_G, expected_h, pairs) -> None:
    for p in pairs:
        np.testing.assert_allclose(G[p], expected_G[p], rtol=0, atol=ROW_TOLERANCE * np.linalg.norm(expected_G[p]))
        assert h[p] == pytest.approx(expected_h[p], rel=BOUND_TOLERANCE, abs=1e-300)


@pytest.mark.parametrize("options", [{}, {"damper_rate": None}, {"bound_relaxation": 0.01, "gain": 0.5}])
def test_rows_follow_the_rule_pair_by_pair(options):
    """Within the detection distance every pair's row is the rule's; a pair beyond d_i has
    the same row (its bound the step's alone) when one step in the speed box could bring
    it within d_i, and none (0 ≤ +inf) otherwise."""
    robot = reach_robot()
    kwargs = dict(minimum_distance=D_MIN, detection_distance=0.3, **options)
    limit = CollisionAvoidanceLimit(robot, REACH_PAIRS, **kwargs)
    geoms = [mujoco.mj_name2id(robot.model, mujoco.mjtObj.mjOBJ_GEOM, name) for name in ("hand", "wrist", "forearm")]
    box = mujoco.mj_name2id(robot.model, mujoco.mjtObj.mjOBJ_GEOM, "box")
    assert sorted(tuple(sorted(pair)) for pair in limit.pairs) == sorted(tuple(sorted((g, box))) for g in geoms)
    rule = dict(minimum_distance=D_MIN, detection_distance=0.3, gain=options.get("gain", 0.85),
                damper_rate=options.get("damper_rate", 0.5), bound_relaxation=options.get("bound_relaxation", 0.0))
    kinds = set()
    for q in REACH_STATES:
        robot.set_q(q)
        robot.update_kinematics()
        G, h = engine_rows(limit, robot, speed=30.0)
        distances, expected_G, expected_h = references.collision_rows(robot.model, q, limit.pairs, DT, **rule)
        near = distances < 0.3
        np.testing.assert_allclose(limit.distances[near], distances[near], rtol=1e-15, atol=0)
        assert_rows_follow_the_rule(G[0], h[0], expected_G, expected_h, np.flatnonzero(near))
        for p in np.flatnonzero(~near):
            if limit.distances[p] < limit.cutoffs[0, p]:  # within one step's reach of d_i
                step_bound = rule["gain"] * (distances[p] - D_MIN) / DT + rule["bound_relaxation"]
                assert h[0, p] == pytest.approx(step_bound, rel=BOUND_TOLERANCE)
                assert_rows_follow_the_rule(G[0], h[0], expected_G, expected_h, [p])
                kinds.add("reachable")
            else:
                assert h[0, p] == np.inf and not G[0, p].any()
                assert distances[p] >= limit.cutoffs[0, p]  # truly beyond its reach
                kinds.add("far")
        kinds.update({"near"} if near.any() else set())
    assert kinds == {"near", "reachable", "far"}


def test_mesh_rows_follow_the_rule_with_native_collision(jaco_model):
    """The Jaco disables MuJoCo's native convex collision; the limit measures with it (the
    fallback's mesh distances are centimetres off), as the written-out rule does on a copy
    of the model, and leaves the flag as it was."""
    native_off = int(mujoco.mjtDisableBit.mjDSBL_NATIVECCD)
    assert jaco_model.opt.disableflags & native_off
    robot = qpik.Robot(jaco_model)
    q = JACO_START + [0.0, 0.1, 0.05, 0.0, 0.0, 0.0]
    robot.set_q(q)
    robot.update_kinematics()
    limit = CollisionAvoidanceLimit(robot, [(JACO_HAND, ["box"])], minimum_distance=0.02)
    G, h = engine_rows(limit, robot, speed=0.5)
    assert robot.model.opt.disableflags & native_off
    distances, expected_G, expected_h = references.collision_rows(jaco_model, q, limit.pairs, DT, 0.02, 0.1)
    near = distances < 0.1
    assert near.sum() >= 3
    np.testing.assert_allclose(limit.distances[near], distances[near], rtol=1e-15, atol=0)
    assert_rows_follow_the_rule(G[0], h[0], expected_G, expected_h, np.flatnonzero(near))
    data = references.mujoco_data(jaco_model, q)
    fallback = [mujoco.mj_geomDistance(jaco_model, data, *pair, 1.0, None) for pair in np.array(limit.pairs)[near]]
    assert np.abs(np.array(fallback) - distances[near]).max() > 1e-3  # the flag matters here


def test_each_world_is_its_own_run(jaco_model, assert_same):
    """Four worlds of the Jaco at different configurations: each world's distances are
    its one-world run's (the same geom poses, MuJoCo's C), its rows too to 1e-10 of their
    norm (the batch forms the Jacobians in NumPy, mj_jac's to rounding)."""
    states = JACO_START + np.random.default_rng(3).normal(0.0, 0.08, (4, 6))
    robots = batch.Robot(jaco_model, 4)
    robots.set_q(states)
    limit = CollisionAvoidanceLimit(robots, [(JACO_HAND, ["box"])], minimum_distance=0.02)
    G, h = engine_rows(limit, robots, speed=1.5)
    active = 0
    for w, q in enumerate(states):
        robot = qpik.Robot(jaco_model)
        robot.set_q(q)
        one = CollisionAvoidanceLimit(robot, [(JACO_HAND, ["box"])], minimum_distance=0.02)
        expected_G, expected_h = engine_rows(one, robot, speed=1.5)
        np.testing.assert_array_equal(limit.pair_distances[w], one.pair_distances[0])
        assert_same(G[w], expected_G[0])
        assert_same(h[w], expected_h[0])
        active += int(np.isfinite(expected_h).sum())
    assert 0 < active < 4 * limit.inequality_rows  # some pairs with rows, some without


def test_row_is_the_distance_rate():
    r"""G q̇ = −ḋ against the finite difference of mj_geomDistance (relative 1e-5: the
    difference's truncation at ε = 1e-7)."""
    robot = reach_robot(REACH_STATES[1])
    limit = CollisionAvoidanceLimit(robot, [(["hand"], ["box"])], minimum_distance=D_MIN, detection_distance=1.0)
    G, h = engine_rows(limit, robot)
    qdot, eps = np.array([0.3, -0.7, 0.4]), 1e-7
    d0 = limit.distances[0]
    robot.integrate(qdot, eps)
    robot.update_kinematics()
    d1 = mujoco.mj_geomDistance(robot.model, robot.data, *limit.pairs[0], 1.0, None)
    assert G[0, 0] @ qdot == pytest.approx(-(d1 - d0) / eps, rel=1e-5)
    assert h[0, 0] == pytest.approx(0.5 * (d0 - D_MIN) / (1.0 - D_MIN))  # the damper's bound (below the step's)


# -- one step's reach ---------------------------------------------------------------------
BALL_FREE_SLIDE = """
<mujoco><worldbody>
  <body name="base" pos="0.1 0.2 0.3"><freejoint/><geom type="box" size="0.1 0.05 0.02"/>
    <body pos="0.3 0 0"><joint type="ball" pos="0.05 0 0"/><geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.03"/>
      <body pos="0.3 0 0.1"><joint type="slide" axis="1 0 0"/><joint axis="0 1 0" pos="0 0.1 0"/>
        <geom type="sphere" size="0.05" pos="0.2 0 0"/>
        <body pos="0.2 0.1 0"><joint axis="0 0 1"/><joint type="slide" axis="0 1 0" pos="0.1 0 0"/>
          <joint axis="1 0 0" pos="0 0 0.2"/><geom type="ellipsoid" size="0.1 0.05 0.02" pos="0.1 0.2 0.3"/>
        </body>
      </body>
    </body>
  </body>
</worldbody></mujoco>
"""


@pytest.mark.parametrize("scene", ["ball_free_slide", "arm", "hexapod", "jaco"])
def test_reach_bounds_the_true_motion_of_every_geom(scene, jaco_path):
    """Random configurations and steps q̇ in random boxes: no geom's bounding sphere moves
    farther over the step (q ⊕ q̇Δt, MuJoCo's kinematics) than its reach. A pair (g, g)
    reaches twice the geom's reach."""
    model = {"ball_free_slide": lambda: mujoco.MjModel.from_xml_string(BALL_FREE_SLIDE),
             "arm": lambda: qpik.Robot.load("arm").model, "hexapod": lambda: qpik.Robot.load("hexapod").model,
             "jaco": lambda: mujoco.MjModel.from_xml_path(str(jaco_path))}[scene]()
    geoms = [g for g in range(model.ngeom) if model.geom_type[g] != mujoco.mjtGeom.mjGEOM_PLANE]
    reach, data, rng = PairReach(model, [(g, g) for g in geoms], 1), mujoco.MjData(model), np.random.default_rng(5)
    worst, bounds = 0.0, np.empty((1, len(geoms)))
    for _ in range(60):
        q = model.qpos0.copy()
        mujoco.mj_integratePos(model, q, rng.normal(0.0, 1.5, model.nv), 1.0)
        box, dt = rng.uniform(0.1, 5.0, model.nv), float(rng.choice([0.002, 0.02, 0.2]))
        reach.reach(dt, -box[None], box[None], q[None], bounds)
        poses = []
        for configuration in (q, q.copy()):
            if poses:
                mujoco.mj_integratePos(model, configuration, rng.uniform(-1.0, 1.0, model.nv) * box, dt)
            data.qpos[:] = configuration
            mujoco.mj_kinematics(model, data)
            poses.append((data.geom_xpos[geoms].copy(), data.geom_xmat[geoms].reshape(-1, 3, 3).copy()))
        (c0, R0), (c1, R1) = poses
        moved = np.linalg.norm(c1 - c0, axis=1) + np.linalg.norm(R1 - R0, ord=2, axis=(1, 2)) * model.geom_rbound[geoms]
        still = bounds[0] == 0.0  # geoms on the world
        assert not moved[still].any()
        worst = max(worst, float(np.max(moved[~still] / (0.5 * bounds[0, ~still]))))
    assert 0.5 < worst <= 1.0 + 1e-12  # a bound, and not a loose one


def test_a_far_pair_is_not_crossed_in_one_step():
    """The fuzz's failure: a rod 0.48 m above a floor, pulled 1.5 m down in one step
    (dead-beat gain, speeds up to 200 m/s). A limit with no row for a pair beyond its
    detection distance let the rod through the floor; this limit keeps the pair's row (its
    reach, 2 m, brings it within d_i), the rod stops short of d_s in the first step, then
    the damper brings it down gently."""
    model = mujoco.MjModel.from_xml_string(CROSSING)
    dt, d_s, d_i = 0.01, 0.005, 0.1
    robot = qpik.Robot(model)
    task = PositionTask(robot, "rod_site")
    task.set_target([0.0, 0.0, -1.0])
    collision = CollisionAvoidanceLimit(robot, [(["floor"], ["rod"])], minimum_distance=d_s, detection_distance=d_i)
    controller = QPController(robot, [task, DampingTask(robot, 1e-6)],
                              [JointVelocityLimit(robot, {"z": 200.0, "yaw": 1.0, "shoulder": 1.0, "elbow": 1.0}),
                               collision], dt=dt)
    assert mujoco.mj_geomDistance(model, robot.data, *collision.pairs[0], 10.0, None) > 0.4
    distances = []
    for _ in range(20):
        robot.integrate(np.array(controller.compute_velocity()), dt)
        robot.update_kinematics()
        distances.append(mujoco.mj_geomDistance(model, robot.data, *collision.pairs[0], 10.0, None))
    assert min(distances) >= d_s - 1e-12  # a slide: the row's linearisation is exact
    assert distances[0] < d_i  # the first step did cover γ of the margin, into the damper's zone


def test_a_far_swinging_bar_keeps_its_distance():
    """A bar on a two-hinge arm swung at the floor at up to 100 rad/s (dead-beat gain):
    pairs beyond d_i get their row from the hinges' reach, and the bar never comes
    nearer than d_s (to the linearisation's second order)."""
    model = mujoco.MjModel.from_xml_string(CROSSING)
    robot = qpik.Robot(model)
    task = PositionTask(robot, "bar_site")
    task.set_target([1.0, 0.0, -0.5])
    collision = CollisionAvoidanceLimit(robot, [(["floor"], ["bar"])], minimum_distance=0.005)
    speeds = {"z": 1.0, "yaw": 1.0, "shoulder": 100.0, "elbow": 100.0}
    controller = QPController(robot, [task, DampingTask(robot, 1e-6)], [JointVelocityLimit(robot, speeds), collision],
                              dt=0.01)
    seen = []
    for _ in range(30):
        robot.integrate(np.array(controller.compute_velocity()), 0.01)
        robot.update_kinematics()
        seen.append(mujoco.mj_geomDistance(model, robot.data, *collision.pairs[0], 10.0, None))
    assert collision.cutoffs[0, 0] > 1.0 and min(seen) >= 0.005 - 1e-4


def test_without_speed_limits_every_pair_has_a_row():
    robot = reach_robot()
    limit = CollisionAvoidanceLimit(robot, REACH_PAIRS, minimum_distance=D_MIN, detection_distance=0.02)
    G, h = np.zeros((1, 3, 3)), np.zeros((1, 3))
    limit.apply(DT, np.full((1, 3), -np.inf), np.full((1, 3), np.inf), G, h)
    assert np.all(np.isfinite(h)) and np.all(limit.distances > 0.02)
    np.testing.assert_array_equal(h[0], 0.85 * (limit.distances - D_MIN) / DT)


# -- pairs and parameters ---------------------------------------------------------------------
def test_pairs_are_those_mujoco_tests():
    """MuJoCo's own filter: the same weld and parent–child welds are left out, except with
    the world (a floor and a first link do collide), or where the model disables the
    parent filter; contype/conaffinity."""
    xml = """<mujoco><worldbody><geom name="ground" size="1" pos="0 0 -1"/>
      <body name="a"><joint axis="1 0 0"/><geom name="ga" size="0.1"/>
        <body name="b"><joint axis="1 0 0"/><geom name="gb" size="0.1"/><geom name="gb2" size="0.1"/>
          <body name="c"><joint axis="1 0 0"/><geom name="gc" size="0.1" contype="2" conaffinity="2"/></body>
        </body></body></worldbody></mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    everything = [(["ground", "a", "b", "c"], ["ground", "a", "b", "c"])]
    names = {mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, n): n for n in ("ground", "ga", "gb", "gb2", "gc")}
    kept = {(names[g1], names[g2]) for g1, g2 in geom_pairs(model, everything)}
    assert kept == {("ground", "ga"), ("ground", "gb"), ("ground", "gb2")}
    model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_FILTERPARENT)
    kept = {(names[g1], names[g2]) for g1, g2 in geom_pairs(model, everything)}
    assert kept == {("ground", "ga"), ("ground", "gb"), ("ground", "gb2"), ("ga", "gb"), ("ga", "gb2")}


@pytest.mark.parametrize("options, match", [
    ({"minimum_distance": 1e308}, "minimum distance"), ({"minimum_distance": np.nan}, "minimum distance"),
    ({"detection_distance": np.inf}, "detection distance"), ({"detection_distance": 1e13}, "detection distance"),
    ({"detection_distance": 0.005}, "must exceed"), ({"gain": 0.0}, "gain"), ({"gain": 1.5}, "gain"),
    ({"damper_rate": 1e308}, "damper rate"), ({"damper_rate": 0.0}, "damper rate"),
    ({"damper_rate": -1.0}, "damper rate"), ({"bound_relaxation": 1e13}, "bound relaxation"),
    ({"minimum_distance": "near"}, "minimum distance"), ({"gain": [0.5]}, "gain")])
def test_refuses_bad_parameters(options, match):
    with pytest.raises(InvalidInput, match=match):
        CollisionAvoidanceLimit(reach_robot(), REACH_PAIRS, **options)


def test_refuses_bad_pairs():
    robot = reach_robot()
    with pytest.raises(UnknownName, match="close matches: .*hand"):
        CollisionAvoidanceLimit(robot, [(["hnd"], ["box"])])
    with pytest.raises(InvalidInput, match="no geom pair"):
        CollisionAvoidanceLimit(robot, [(["hand"], ["hand"])])
    with pytest.raises(InvalidInput, match="list of geom"):
        CollisionAvoidanceLimit(robot, [("hand", ["box"])])


def test_refuses_a_configuration_that_is_not_finite():
    """MuJoCo finds no contact between NaN poses (the pair would silently lose its row)."""
    robot = reach_robot()
    limit = CollisionAvoidanceLimit(robot, [(["hand"], ["box"])])
    robot.q[0] = np.nan
    with pytest.raises(InvalidInput, match="configuration is not finite"):
        engine_rows(limit, robot)


# -- the QP --------------------------------------------------------------------------------------
def test_hand_stops_at_the_minimum_distance_and_leaves_it_through_the_closed_form():
    """The hand pulled into the box: the engine's QP keeps its rows (G q̇ ≤ h) and the hand
    stops at d_s. The closed form holds bounds, not rows: while the hand rests against
    the box the steps go straight to the solver (rows_held); once the target leaves,
    the row lets go and the closed form answers again."""
    robot = reach_robot()
    task = PositionTask(robot, "hand_site", gain=20.0)
    task.set_target([0.9, 0.5, 0.0])
    limit = CollisionAvoidanceLimit(robot, [(["hand"], ["box"])], minimum_distance=D_MIN, detection_distance=0.2)
    controller = QPController(robot, [task, DampingTask(robot, 1e-3)], [limit], dt=DT)
    distances, excess = [], 0.0
    for _ in range(1500):
        qdot = controller.compute_velocity()
        excess = max(excess, float(np.max(controller.G @ qdot - controller.h)))
        robot.integrate(qdot, DT)
        robot.update_kinematics()
        distances.append(mujoco.mj_geomDistance(robot.model, robot.data, *limit.pairs[0], 1.0, None))
    assert excess <= 1e-9
    assert min(distances) >= D_MIN - 1e-6 and distances[-1] == pytest.approx(D_MIN, abs=1e-4)
    assert 0 < controller.solver_calls < 1500 and controller.rows_held[0]
    task.set_target(task.target + [-0.3, 0.0, 0.0])
    calls = []
    for _ in range(300):
        robot.integrate(controller.compute_velocity(), DT)
        calls.append(controller.solver_calls)
    assert not controller.rows_held[0] and calls[-1] == calls[-50]  # the last steps: closed forms


def jaco_controller(model, n: int):
    """The Jaco's wrist pose task, its joint limits and the hand–box collision limit."""
    robot = batch.Robot(model, n) if n > 1 else qpik.Robot(model)
    robot.set_q(JACO_START)
    robot.update_kinematics()
    pose = FrameTask(robot, "wristsite", "site", position_gain=50.0, orientation_gain=50.0)
    collision = CollisionAvoidanceLimit(robot, [(JACO_HAND, ["box"])], minimum_distance=0.02, detection_distance=0.1)
    controller = QPController(robot, [pose], [JointPositionLimit(robot), JointVelocityLimit(robot, JACO_SPEEDS),
                                              collision], dt=DT)
    return robot, controller, pose


def descend(pose, start: np.ndarray, rotation: np.ndarray, drops: np.ndarray):
    """``before(k)``: the wrist's target ``drops`` (m, per world) down over 150 steps."""
    def before(k: int) -> None:
        pose.set_target(start - min(1.0, k / 150) * drops[..., None] * np.array([0.0, 0.0, 1.0]), rotation)
    return before


def test_qp_on_the_jaco_keeps_the_hand_off_the_box_and_each_step_is_its_qps_minimiser(jaco_model, lockstep):
    """The wrist's target goes 25 cm down through the box: the rows bind from the first
    steps. Every answer (one robot) is the minimiser of its QP solved independently, the
    box and rows the limits' own; the hand stays at least d_s from the box."""
    robot, controller, pose = jaco_controller(jaco_model, 1)
    start, rotation = np.array(pose.target_position), np.array(pose.target_rotation)
    collision = controller.limits[-1]

    native = references.native_collision(jaco_model)  # the distances the limit keeps apart

    def after(k, qdot):
        data = references.mujoco_data(native, robot.q)
        nearest = min(mujoco.mj_geomDistance(native, data, *pair, 1.0, None) for pair in collision.pairs)
        assert nearest >= 0.02 - 1e-4  # (the rows' linearisation: second order in the step)
        seen.append(nearest)

    seen = []
    lockstep(robot, controller, 200, DT, descend(pose, start, rotation, np.array(0.25)), after)
    assert controller.solver_calls > 100
    assert min(seen) < 0.025  # it did come down near d_s


def test_qp_worlds_on_the_jaco_each_answer_as_their_own_run(jaco_model):
    """Four worlds with targets 0 to 25 cm down (world 0 never reaches the box, the
    others bind their rows at different steps): at every step each world's answer equals
    its one-world controller's on the same configuration (1e-10 of its norm, or of
    1 mrad/s for an answer at rest: world 0's first steps)."""
    drops = np.array([0.0, 0.1, 0.2, 0.25])
    robots, controller, pose = jaco_controller(jaco_model, 4)
    start, rotation = np.array(pose.target_position), np.array(pose.target_rotation)
    follow = descend(pose, start, rotation, drops)
    alone = [jaco_controller(jaco_model, 1) for _ in drops]
    followers = [descend(one_pose, start[w], rotation[w], drops[w]) for w, (_, _, one_pose) in enumerate(alone)]
    held = np.zeros(4, dtype=bool)
    for k in range(100):
        follow(k)
        answers = np.array(controller.compute_velocity())
        held |= controller.rows_held
        for w, ((robot, one, _), one_follow) in enumerate(zip(alone, followers)):
            one_follow(k)
            robot.q[:] = robots.q[w]
            expected = np.array(one.compute_velocity())
            assert np.linalg.norm(answers[w] - expected) <= 1e-10 * max(np.linalg.norm(expected), 1e-3), (k, w)
        robots.integrate(answers, DT)
    np.testing.assert_array_equal(held, [False, True, True, True])

