"""``import qpik``, QP and SNS steps on the arm and the hexapod, and an infeasibility
decision, in a process where SciPy (and qpsolvers and osqp, which need it) cannot be
imported: the steps are those of the SciPy path (NumPy's linear algebra,
:mod:`qpik.linalg`), and the infeasible step is still refused."""

from __future__ import annotations

import json

import numpy as np
import pytest

from qpik.errors import InfeasibleProblem

WITHOUT_SCIPY = ("scipy", "qpsolvers", "osqp")

# (scenario, controller): the arm with its joint limits binding, SNS at the edge of the
# reach, the hexapod's loop closures (the LU path) and SNS on it.
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
        QPController(robot, [first, second, DampingTask(robot)], dt=0.01, fast_path=False).compute_velocity()
    except InfeasibleProblem as exc:
        return type(exc).__name__
    return "solved"
"""


@pytest.fixture(scope="module")
def without_scipy(run_without_modules):
    code = ROLLOUTS + f"""
import sys, qpik
from qpik import linalg
print(json.dumps({{"backend": linalg.BACKEND, "steps": [rollout(s, k, {STEP_COUNT}) for s, k in {STEPS!r}],
                  "contradictory": contradictory(),
                  "scipy_imported": any(m.split(".")[0] == "scipy" for m in sys.modules)}}))
"""
    done = run_without_modules(code, WITHOUT_SCIPY)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


def test_import_qpik_and_its_steps_need_no_scipy(without_scipy):
    assert without_scipy["backend"] == "numpy"
    assert not without_scipy["scipy_imported"]
    assert without_scipy["contradictory"] == InfeasibleProblem.__name__


def test_the_steps_without_scipy_are_those_with_it(without_scipy):
    """Each step differs by at most 64 eps κ (tests/core/test_linalg.py); the closed loops
    are contracting (gains × dt < 1), so 50 steps do not amplify it: 1e-10 relative
    leaves four orders of magnitude over what is measured (~1e-15)."""
    namespace = {}
    exec(ROLLOUTS, namespace)  # the same rollouts, here on SciPy's LAPACK
    from qpik import linalg

    assert linalg.BACKEND == "scipy"
    for (scenario, kind), theirs in zip(STEPS, without_scipy["steps"]):
        ours = np.array(namespace["rollout"](scenario, kind, STEP_COUNT))
        np.testing.assert_allclose(theirs, ours, rtol=0, atol=1e-10 * (1.0 + np.abs(ours).max()),
                                   err_msg=f"{scenario} {kind}")
