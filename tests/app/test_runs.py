"""qpik.app.runs: the custom-run path (a Setup of one's own) and fresh setups per run."""

import numpy as np
import pytest

from qpik import Circle, InvalidInput
from qpik.app.runs import compare, run
from qpik.robots.arm.model import end_effector_position
from qpik.robots.arm.scenarios import ARM_START, arm_setup


def _circle_setup():
    # Starts where the arm's end effector is at q0 = [π/2, 0, 0, 0.5]: (0.5, 2.0) m.
    return arm_setup("my-circle", Circle((0.8, 2.0), 0.3, 4.0, u=(1.0, 0.0), w=(0.0, 1.0), start_angle=np.pi),
                     redundant=True)


def test_a_custom_setup_runs_and_tracks_its_path():
    setup, log = run(setup=_circle_setup(), controller="qp")
    assert log.info.scenario == "my-circle" and log.info.robot == "arm" and log.completed
    assert log.summary().max_error < 2e-5
    # Measured on the logged q by the DH model (independent of MuJoCo): the circle's end point.
    np.testing.assert_allclose(end_effector_position(log.q[-1]), [0.5, 2.0], atol=1e-6)


def test_a_used_setup_is_refused_not_silently_continued():
    setup = _circle_setup()
    run(setup=setup, controller="qp")
    final = setup.robot.q.copy()
    assert not np.allclose(final, ARM_START)  # the robot moved: a second run would start here
    with pytest.raises(InvalidInput, match="already run"):
        run(setup=setup, controller="pinv")
    np.testing.assert_array_equal(setup.robot.q, final)  # refused before touching anything
    # A fresh setup of the same definition starts from q0 again and tracks the same circle.
    _, pinv_log = run(setup=_circle_setup(), controller="pinv")
    np.testing.assert_array_equal(pinv_log.q[0], ARM_START)
    assert pinv_log.summary().max_error < 2e-5
    np.testing.assert_allclose(end_effector_position(pinv_log.q[-1]), [0.5, 2.0], atol=1e-6)


def test_compare_runs_every_controller_from_the_same_start():
    _, logs, _ = compare("arm", "seed-primary", ["daqp"], peers=())
    assert [log.info.controller for log in logs] == ["qp", "hqp", "sns", "pinv", "jt"]
    for log in logs:
        np.testing.assert_array_equal(log.q[0], ARM_START)


def test_the_kinds_registry_names_every_controller_a_scenario_builds():
    """Every controller a bundled scenario builds is in qpik.app.kinds under the name its
    summary gives it, and takes a QP solver exactly when the registry says so."""
    from qpik.app.kinds import KINDS, OFFERED_KINDS, PEER_KINDS, SOLVER_KINDS
    from qpik.scenario import build_scenario, scenarios

    built = set()
    for name in scenarios():
        setup = build_scenario(name)
        for kind in setup.controller_kinds():
            controller = setup.controller(kind, "osqp") if kind in SOLVER_KINDS else setup.controller(kind)
            assert controller.kind == kind, (name, kind)
            assert (controller.solver == "osqp") == (kind in SOLVER_KINDS), (name, kind, controller.solver)
            built.add(kind)
    assert built == {"qp", *OFFERED_KINDS} and set(KINDS) == built | set(PEER_KINDS)
