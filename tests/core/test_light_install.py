"""``import qpik``, QP and SNS steps on the arm and the hexapod, and an infeasibility
decision, in a process where nothing but qpik's dependencies (mujoco, numpy, daqp, SciPy)
can be imported of what pyproject.toml names: every optional extra's module
(:data:`qpik.extras.EXTRAS`: matplotlib, the qpsolvers back-ends, the peers, Warp, Ray, ...)
and the test extra's are hidden. The steps are those of a full install, and the infeasible
step is still refused. (SciPy is a dependency: before, this ran with SciPy hidden too, on
NumPy's LAPACK; an install without SciPy is now a broken one, as one without numpy.)"""

from __future__ import annotations

import json

import numpy as np
import pytest

from qpik.errors import InfeasibleProblem
from qpik.extras import EXTRAS

# Every module of pyproject.toml's optional dependencies: the extras' and the test extra's.
WITHOUT_EXTRAS = tuple(sorted(set(EXTRAS) | {"pytest", "_pytest", "xdist", "hypothesis"}))

# (scenario, controller): the arm with its joint limits binding, SNS at the edge of the
# reach, the hexapod's loop closures (equality rows) and SNS on it.
STEPS = [("joint-limits", "qp"), ("unreachable", "qp"), ("unreachable", "sns"), ("hexapod-circle", "qp"),
         ("hexapod-circle", "sns")]
STEP_COUNT = 50

ROLLOUTS = """
import json
import numpy as np
from qpik.scenario import build_scenario

def rollout(scenario, kind, steps):
    setup = build_scenario(scenario)
    controller = setup.controller(kind)
    for k in range(steps):
        setup.reference.apply(k * setup.dt)
        qdot = controller.compute_velocity()
        setup.robot.integrate(qdot, setup.dt)
    return qdot.tolist()

def contradictory():
    from qpik import DampingTask, PositionTask, QPController, Robot
    from qpik.errors import InfeasibleProblem
    robot = Robot.load("arm")
    first, second = (PositionTask(robot, "end_effector", gain=10.0, hard=True) for _ in range(2))
    first.set_target(first.target + [0.1, 0.0, 0.0])
    second.set_target(second.target - [0.1, 0.0, 0.0])
    try:
        QPController(robot, [first, second, DampingTask(robot)], dt=0.01).compute_velocity()
    except InfeasibleProblem as exc:
        return type(exc).__name__
    return "solved"
"""


@pytest.fixture(scope="module")
def without_extras(run_without_modules):
    code = ROLLOUTS + f"""
import sys, qpik
steps = [rollout(s, k, {STEP_COUNT}) for s, k in {STEPS!r}]
extras = sorted({{m.split(".")[0] for m in sys.modules}} & set({WITHOUT_EXTRAS!r}))
print(json.dumps({{"steps": steps, "contradictory": contradictory(), "extras": extras}}))
"""
    done = run_without_modules(code, WITHOUT_EXTRAS)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


def test_import_qpik_and_its_steps_need_only_its_dependencies(without_extras):
    assert without_extras["extras"] == []
    assert without_extras["contradictory"] == InfeasibleProblem.__name__


def test_the_steps_without_the_extras_are_those_with_them(without_extras):
    """The same engine on the same libraries (the extras are never on a step's path): 1e-10
    relative is the bound the light install was held to when it ran NumPy's LAPACK instead
    of SciPy's (64 eps κ per step, contracting closed loops); here ~0 is measured."""
    namespace = {}
    exec(ROLLOUTS, namespace)  # the same rollouts, here with every extra importable
    for (scenario, kind), theirs in zip(STEPS, without_extras["steps"]):
        ours = np.array(namespace["rollout"](scenario, kind, STEP_COUNT))
        np.testing.assert_allclose(theirs, ours, rtol=0, atol=1e-10 * (1.0 + np.abs(ours).max()),
                                   err_msg=f"{scenario} {kind}")
