"""The engine's joint-space tasks (PostureTask, on a free-joint model too; DampingTask;
DofFreezingTask) and the KineticEnergyRegularizationTask: on one robot equal to their rows
written out (the dof selection from the model's joints, the posture's difference by
``mj_differentiatePos``, the inertia's factor against MuJoCo's ``mj_fullM``); a user's
own joint-space task; on 4 worlds with their own states and targets, each world equal to its own
one-world run; the kinetic energy against MuJoCo's own (``mj_energyVel``), a semidefinite
inertia included; bad input is a typed error naming the worlds."""

from __future__ import annotations

import copy
import importlib.util
from pathlib import Path

import mujoco
import numpy as np
import pytest

from qpik import InvalidInput, UnknownName
from qpik import tasks as engine
from qpik.errors import InvalidWorlds

def _load(name: str):
    spec = importlib.util.spec_from_file_location(name, Path(__file__).with_name(f"{name}.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


support, references = _load("tasks_support"), _load("references")

# Two slides along x, then a hinge: with the first body made massless after compiling,
# M is singular (the two slides move the same mass), so its Cholesky factor fails.
SLIDES = """<mujoco><worldbody><body name="a"><joint name="s1" type="slide" axis="1 0 0"/><geom size=".1" mass="1"/>
<body name="b"><joint name="s2" type="slide" axis="1 0 0"/><joint name="h" axis="0 0 1"/>
<geom size=".1" pos=".2 0 0" mass="1"/></body></body></worldbody></mujoco>"""


def semidefinite_model() -> mujoco.MjModel:
    model = mujoco.MjModel.from_xml_string(SLIDES)
    model.body_mass[1], model.body_inertia[1] = 0.0, 0.0
    return model


def postures(robot, rng, n: int) -> np.ndarray:
    """(n, nq) reference configurations near the robot's start (quaternions kept unit)."""
    return np.array([support.displaced(robot.model, robot.qpos[0], int(rng.integers(1000)), 0.2) for _ in range(n)])


def posture_all_joints(robot, target):
    return engine.PostureTask(robot, target=target, gain=2.0, weight=0.5, joints=robot.joint_names)


def posture_default(robot, target):
    return engine.PostureTask(robot, target=target, gain=3.0)


def damping(robot, target):
    return engine.DampingTask(robot, weight=1e-2)


def freezing(robot, target):
    return engine.DofFreezingTask(robot, [robot.joint_names[-1], robot.joint_names[0]], priority=1)


def kinetic_energy(robot, target):
    return engine.KineticEnergyRegularizationTask(robot, weight=0.5)


class Stiffness(engine.JointSpaceTask):
    """A user's joint-space task: v = −k q on its dofs (a spring toward q = 0; scalar
    joints), written over the world axis with ``measure_rows`` as the built-in ones are."""

    name = "stiffness task"

    def __init__(self, robot, joints=None, stiffness: float = 4.0, weight=1.0):
        super().__init__(robot, joints, weight)
        self.stiffness = stiffness
        self._qpos = robot.model.jnt_qposadr[[robot.model.dof_jntid[d] for d in self.dofs]]

    def measure_rows(self) -> None:
        np.negative(self.robot.qpos[:, self._qpos], self.errors)

    def track(self) -> None:
        np.multiply(self.errors, self.stiffness, self.target_velocities)


def stiffness(robot, target):
    return Stiffness(robot, stiffness=4.0, weight=2.0)


CASES = [posture_all_joints, posture_default, damping, freezing, kinetic_energy, stiffness]

_WIDTH = {int(mujoco.mjtJoint.mjJNT_FREE): 6, int(mujoco.mjtJoint.mjJNT_BALL): 3}
_SCALAR = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))


def dofs_of(model, joints=None) -> np.ndarray:
    """The dofs of the named joints (every hinge and slide joint's when None), ascending."""
    ids = [j for j in range(model.njnt) if int(model.jnt_type[j]) in _SCALAR] if joints is None else \
        [model.joint(name).id for name in joints]
    return np.array(sorted(model.jnt_dofadr[j] + k for j in ids for k in range(_WIDTH.get(int(model.jnt_type[j]), 1))))


def expected_rows(case, model, q, target):
    """(e, J, v) of a joint-space case written out: J the identity's rows of its dofs, e
    the posture's q_ref ⊖ q (``mj_differentiatePos``) or −q (the stiffness) or zero."""
    names = [model.joint(j).name for j in range(model.njnt)]
    dofs = {posture_all_joints: dofs_of(model, names), freezing: dofs_of(model, [names[-1], names[0]])}.get(
        case, dofs_of(model))
    difference = np.zeros(model.nv)
    mujoco.mj_differentiatePos(model, difference, 1.0, q, target)
    e = {posture_all_joints: difference[dofs], posture_default: difference[dofs],
         stiffness: -q[model.jnt_qposadr[model.dof_jntid[dofs]]]}.get(case, np.zeros(len(dofs)))
    gain = {posture_all_joints: 2.0, posture_default: 3.0, stiffness: 4.0}.get(case, 0.0)
    return e, np.eye(model.nv)[dofs], gain * e


def assert_inertia_factor(task, model, q) -> None:
    """J is M's Cholesky factor U (upper triangular, a positive diagonal, UᵀU = M: the one
    such matrix), M MuJoCo's own (``mj_crb``, ``mj_fullM``) on a fresh MjData; e = v = 0."""
    error, jacobian, velocity = support.measured(task)
    data = references.mujoco_data(model, q)
    mujoco.mj_crb(model, data)
    inertia = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, data, inertia)
    np.testing.assert_array_equal(np.tril(jacobian, -1), 0.0)
    assert np.all(np.diag(jacobian) > 0.0)
    # UᵀU against M: one factorisation of O(1) entries (62 dofs at most), 1e-12 relative.
    assert support.relative(jacobian.T @ jacobian, inertia) <= support.REFERENCE
    np.testing.assert_array_equal(error, 0.0)
    np.testing.assert_array_equal(velocity, 0.0)


@pytest.mark.parametrize("name", ["arm", "jaco", "humanoid"])
def test_one_robot_equals_the_rows_written_out(model_path, name):
    path = model_path(name)
    start = support.one_robot(path)
    q = support.displaced(start.model, start.q, seed=1)
    target = postures(start, np.random.default_rng(2), 1)[0]
    for case in CASES:
        task = case(support.one_robot(path, q), target)
        if case is kinetic_energy:
            assert_inertia_factor(task, start.model, q)
        else:
            support.assert_rows(task, expected_rows(case, start.model, q, target))


@pytest.mark.parametrize("name", ["arm", "humanoid"])
def test_each_of_four_worlds_is_its_own_one_world_run(model_path, name):
    robots = support.worlds(model_path(name), n=4, seed=3)
    targets = postures(robots, np.random.default_rng(4), robots.n)
    for case in CASES:
        support.assert_each_world(robots, lambda robot, w, case=case: case(robot,
                                                                            targets if w is None else targets[w]))


def test_a_free_joint_posture_takes_the_quaternion_difference(humanoid_path):
    """The root's rotation error is MuJoCo's own (``mj_differentiatePos``) in every world."""
    robots = support.worlds(humanoid_path, n=4, seed=5)
    targets = postures(robots, np.random.default_rng(6), robots.n)
    task = engine.PostureTask(robots, target=targets, joints=robots.joint_names)
    support.measured(task)
    for w in range(robots.n):
        difference = np.zeros(robots.nv)
        mujoco.mj_differentiatePos(robots.model, difference, 1.0, robots.q[w], targets[w])
        assert support.relative(task.error[w], difference) <= support.WORLDS
    assert np.abs(task.error[:, 3:6]).max() > 1e-2  # the root turned


def test_joint_space_tasks_are_the_dof_selection():
    robots = support.worlds("arm", n=4)
    freeze = engine.DofFreezingTask(robots, ["theta3", "theta1"])
    assert freeze.hard and freeze.joint_space and freeze.priority == 0
    np.testing.assert_array_equal(freeze.dofs, [0, 2])
    support.measured(freeze)
    np.testing.assert_array_equal(freeze.jacobian, np.broadcast_to(np.eye(4)[[0, 2]], (4, 2, 4)))
    np.testing.assert_array_equal(freeze.target_velocity, 0.0)
    np.testing.assert_array_equal(freeze.error, 0.0)


def test_kinetic_energy_rows_give_mujocos_kinetic_energy(humanoid_path):
    robots = support.worlds(humanoid_path, n=4, seed=7)
    task = engine.KineticEnergyRegularizationTask(robots, weight=1.0)
    _, jacobian, velocity = support.measured(task)
    rng = np.random.default_rng(8)
    model = copy.deepcopy(robots.model)  # the batch's own model left as it is
    model.opt.enableflags |= mujoco.mjtEnableBit.mjENBL_ENERGY
    for w in range(robots.n):
        qdot = rng.normal(size=robots.nv)
        data = mujoco.MjData(model)
        data.qpos[:], data.qvel[:] = robots.q[w], qdot
        mujoco.mj_forward(model, data)
        # ½‖Jq̇‖² against MuJoCo's ½q̇ᵀMq̇: the same M (62 dofs), its factor and the sums
        # rounded in other orders: 1e-10 relative is a wide margin.
        assert 0.5 * np.sum((jacobian[w] @ qdot) ** 2) == pytest.approx(data.energy[1], rel=1e-10)
    np.testing.assert_array_equal(velocity, 0.0)


def test_a_semidefinite_inertia_takes_the_eigendecomposition():
    model = semidefinite_model()
    robot = support.one_robot(model, [0.1, 0.2, 0.3])
    task = engine.KineticEnergyRegularizationTask(robot, weight=1.0)
    _, _, velocity = support.measured(task)
    data = references.mujoco_data(model, robot.q)
    mujoco.mj_crb(model, data)
    inertia = np.zeros((3, 3))
    mujoco.mj_fullM(model, data, inertia)  # MuJoCo's own M, singular here
    assert np.linalg.eigvalsh(inertia)[0] <= 1e-12 * np.abs(inertia).max()
    # JᵀJ = VΛVᵀ = M: one eigendecomposition of O(1) entries, rounding ~1e-16.
    np.testing.assert_allclose(task.jacobian.T @ task.jacobian, inertia, rtol=0, atol=1e-14)
    np.testing.assert_array_equal(task.error, 0.0)
    np.testing.assert_array_equal(velocity, 0.0)
    robots = support.worlds(model, n=4, seed=9)
    support.assert_each_world(robots, lambda robot, w: engine.KineticEnergyRegularizationTask(robot, weight=1.0))


def test_bad_input_is_a_typed_error():
    robots = support.worlds("arm", n=4)
    posture = engine.PostureTask(robots)
    targets = np.array(robots.q)
    targets[[1, 3], 2] = [np.nan, np.inf]
    with pytest.raises(InvalidWorlds, match="worlds 1, 3") as caught:
        posture.set_target(targets)
    np.testing.assert_array_equal(caught.value.worlds, [1, 3])
    with pytest.raises(InvalidInput, match="shape"):
        posture.set_target(np.zeros(robots.nq + 1))
    with pytest.raises(InvalidInput, match="name the joints"):
        engine.DofFreezingTask(robots, [])
    with pytest.raises(UnknownName, match="theta3"):
        engine.DofFreezingTask(robots, ["theta33"])
    with pytest.raises(InvalidInput, match="hard"):
        engine.KineticEnergyRegularizationTask(robots, hard=True)
    with pytest.raises(InvalidInput, match="one number"):
        engine.KineticEnergyRegularizationTask(robots, weight=[1.0, 2.0])
    with pytest.raises(InvalidInput, match="weight"):
        engine.DampingTask(robots, weight=1e308)
    with pytest.raises(InvalidInput, match="NaN"):
        engine.PostureTask(support.one_robot("arm")).set_target([0.0, np.nan, 0.0, 0.0])
