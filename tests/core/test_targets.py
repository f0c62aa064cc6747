"""Targets the way mink users write them, and the dead-beat default gain."""

from __future__ import annotations

import warnings

import mujoco
import numpy as np
import pytest

from qpik import (
    FrameTask,
    InvalidInput,
    OrientationTask,
    PositionTask,
    PseudoinverseController,
    QPController,
    RelativeFrameTask,
    Robot,
)
from qpik.errors import GainWarning

# A 3-link spatial chain (6 hinges) with a mocap body: small, every pose reachable nearby.
CHAIN = """
<mujoco>
  <compiler angle="radian"/>
  <worldbody>
    <body name="target" mocap="true" pos="0.3 0.1 0.5" quat="0.9238795 0 0.3826834 0"/>
    <body name="l1">
      <joint name="a" axis="0 0 1" range="-3 3"/><joint name="b" axis="0 1 0" range="-3 3"/>
      <geom type="capsule" fromto="0 0 0 0 0 0.3" size="0.03"/>
      <body name="l2" pos="0 0 0.3">
        <joint name="c" axis="0 1 0" range="-3 3"/><joint name="d" axis="1 0 0" range="-3 3"/>
        <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.03"/>
        <body name="l3" pos="0.3 0 0">
          <joint name="e" axis="0 1 0" range="-3 3"/><joint name="f" axis="1 0 0" range="-3 3"/>
          <geom type="capsule" fromto="0 0 0 0.1 0 0" size="0.02"/>
          <site name="tip" pos="0.1 0 0"/>
        </body>
      </body>
    </body>
  </worldbody>
</mujoco>
"""
START = np.array([0.3, 0.4, -0.6, 0.2, 0.5, -0.3])


@pytest.fixture
def chain():
    robot = Robot(mujoco.MjModel.from_xml_string(CHAIN))
    robot.set_q(START)
    robot.update_kinematics()
    return robot


def quaternion_to_matrix(w, x, y, z):
    """The textbook formula for a unit quaternion, written out (independent of MuJoCo)."""
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def test_a_quaternion_target_is_the_matrix_target(chain):
    quat = np.array([0.7, 0.1, -0.5, 0.3])
    quat /= np.linalg.norm(quat)
    matrix = quaternion_to_matrix(*quat)
    by_quat, by_matrix = FrameTask(chain, "tip"), FrameTask(chain, "tip")
    by_quat.set_target([0.2, 0.1, 0.4], quat)
    by_matrix.set_target([0.2, 0.1, 0.4], matrix)
    np.testing.assert_allclose(by_quat.target_rotation, by_matrix.target_rotation, atol=1e-14)  # O(1) terms, a few roundings
    orientation = OrientationTask(chain, "tip")
    orientation.set_target(quat)
    np.testing.assert_allclose(orientation.target_rotation, matrix, atol=1e-14)
    with pytest.raises(InvalidInput, match="unit quaternion"):
        by_quat.set_target([0, 0, 0], [1.0, 0.1, 0, 0])
    with pytest.raises(InvalidInput, match="3x3 matrix or a \\(4,\\) w-x-y-z quaternion"):
        by_quat.set_target([0, 0, 0], np.eye(2))


def test_a_homogeneous_transform_target(chain):
    quat = np.array([0.5, 0.5, 0.5, 0.5])
    transform = np.eye(4)
    transform[:3, :3] = quaternion_to_matrix(*quat)
    transform[:3, 3] = [0.1, -0.2, 0.3]
    task = FrameTask(chain, "tip")
    task.set_target_transform(transform)
    np.testing.assert_allclose(task.target_position, [0.1, -0.2, 0.3], atol=0)
    np.testing.assert_allclose(task.target_rotation, transform[:3, :3], atol=0)
    relative = RelativeFrameTask(chain, "tip", "l1", "site", "body")
    relative.set_target_transform(transform)
    np.testing.assert_allclose(relative.target_rotation, transform[:3, :3], atol=0)
    bad = transform.copy()
    bad[3, 0] = 1.0
    with pytest.raises(InvalidInput, match="last row"):
        task.set_target_transform(bad)


def test_a_mocap_body_target(chain):
    task, position = FrameTask(chain, "tip"), PositionTask(chain, "tip", axes="xz")
    task.set_target_from_mocap("target")
    position.set_target_from_mocap("target")
    np.testing.assert_allclose(task.target_position, [0.3, 0.1, 0.5], atol=1e-15)
    # MuJoCo normalises the written quaternion (cos 22.5°, 0, sin 22.5°, 0): 45° about y.
    c, s = np.cos(np.pi / 4), np.sin(np.pi / 4)
    np.testing.assert_allclose(task.target_rotation, [[c, 0, s], [0, 1, 0], [-s, 0, c]], atol=1e-7)
    np.testing.assert_allclose(position.target, [0.3, 0.5], atol=1e-15)
    with pytest.raises(InvalidInput, match="not a mocap body"):
        task.set_target_from_mocap("l2")


def test_target_from_the_current_configuration(chain):
    task, orientation = FrameTask(chain, "tip", position_gain=5.0), OrientationTask(chain, "tip", gain=5.0)
    chain.set_q(START + 0.2)
    task.set_target_from_configuration()
    orientation.set_target_from_configuration()
    task.update()
    orientation.update()
    np.testing.assert_allclose(task.error, 0.0, atol=1e-12)
    np.testing.assert_allclose(orientation.error, 0.0, atol=1e-12)
    site = chain.model.site("tip").id
    np.testing.assert_allclose(task.target_position, chain.data.site_xpos[site], atol=0)


@pytest.mark.parametrize("dt", [0.1, 0.01, 0.003])
def test_the_default_gain_is_dead_beat(chain, dt):
    """Defaults: K = 1/Δt, so one QP step removes a 5 mm error up to the linearisation
    (second order: |e|² / link length ≈ 1e-4 m at most here). With the old K = 1/s the
    step moved KΔt of it. No GainWarning at K·Δt = 1."""
    task = FrameTask(chain, "tip")
    goal = task.target_position + [0.003, -0.004, 0.0]
    task.set_target(goal, task.target_rotation)
    with warnings.catch_warnings():
        warnings.simplefilter("error", GainWarning)
        controller = QPController(chain, [task], dt=dt)
    np.testing.assert_allclose(task.position_gain, 1.0 / dt)
    chain.integrate(controller.compute_velocity(), dt)
    chain.update_kinematics()
    assert np.linalg.norm(goal - task.frame.position) < 1e-4


def test_the_default_gain_is_dead_beat_in_every_world():
    """N = 4 worlds: the controller's period sets K = 1/Δt in every world's gains, and the
    gains a user reads ((N, 3) views of them, as every batched array) show it."""
    from qpik import batch

    robots = batch.Robot.load(mujoco.MjModel.from_xml_string(CHAIN), n=4)
    task = FrameTask(robots, "tip")
    assert task.needs_period and np.isnan(task.position_gain).all()
    QPController(robots, [task], dt=0.01)
    np.testing.assert_array_equal(task.gains, np.full((4, 6), 100.0))
    np.testing.assert_array_equal(task.position_gain, np.full((4, 3), 100.0))
    np.testing.assert_array_equal(task.orientation_gain, np.full((4, 3), 100.0))


def test_the_default_gain_matches_minks_default(chain):
    """The same step as mink's FrameTask with its defaults (gain 1, costs 1): one target
    5 mm away with the rotation unchanged, a square full-rank Jacobian, so both solve
    J q̇ = e/Δt exactly (to the solvers' tolerance, 1e-8 relative)."""
    mink = pytest.importorskip("mink")
    dt = 0.01
    task = FrameTask(chain, "tip")
    goal = task.target_position + [0.003, -0.004, 0.0]
    task.set_target(goal, task.target_rotation)
    ours = QPController(chain, [task], dt=dt).compute_velocity()
    configuration = mink.Configuration(chain.model, chain.q.copy())
    theirs_task = mink.FrameTask("tip", "site", position_cost=1.0, orientation_cost=1.0)
    theirs_task.set_target(mink.SE3.from_rotation_and_translation(mink.SO3.from_matrix(task.target_rotation), goal))
    theirs = mink.solve_ik(configuration, [theirs_task], dt, "daqp", limits=[])
    np.testing.assert_allclose(ours, theirs, rtol=1e-6, atol=1e-8 * np.max(np.abs(theirs)))


def test_a_law_without_a_period_needs_a_gain(chain):
    with pytest.raises(InvalidInput, match="give the task a gain"):
        PseudoinverseController(chain, [PositionTask(chain, "tip")])
    PseudoinverseController(chain, [PositionTask(chain, "tip", gain=10.0)])


@pytest.mark.parametrize("kind", ["position", "com"])
def test_a_point_target_and_its_rate_are_written_together_or_not_at_all(chain, kind):
    """set_target writes x_d and ẋ_d together (no ẋ_d: zero); a refused call leaves both as
    they were, whichever argument is bad."""
    from qpik import ComTask

    task = PositionTask(chain, "tip") if kind == "position" else ComTask(chain)
    task.set_target([0.1, 0.2, 0.3], [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(task.target, [0.1, 0.2, 0.3])
    np.testing.assert_array_equal(task.target_rate, [1.0, 2.0, 3.0])
    for position, velocity in (([0.4, 0.5, np.nan], None), ([0.4, 0.5, 0.6], [0.0, 1e200, 0.0]),
                               ([0.4, 0.5], None), ([0.4, 0.5, 0.6], [1.0])):
        with pytest.raises(InvalidInput):
            task.set_target(position, velocity)
        np.testing.assert_array_equal(task.target, [0.1, 0.2, 0.3])
        np.testing.assert_array_equal(task.target_rate, [1.0, 2.0, 3.0])
    task.set_target([0.4, 0.5, 0.6])
    np.testing.assert_array_equal(task.target, [0.4, 0.5, 0.6])
    np.testing.assert_array_equal(task.target_rate, [0.0, 0.0, 0.0])
