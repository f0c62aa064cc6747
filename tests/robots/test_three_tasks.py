"""The arm's three-tasks scenario (path, then φ, then σ) and too-fast's table: the strict
hierarchy keeps the path exact and gets φ as close as the limits allow (checked every step
against independent QPs), the soft QP trades path for φ, SNS and the QPs keep the limits,
the classical law does not."""

import dataclasses

import numpy as np
import pytest
import qpsolvers

from qpik.app.plotting import make_figures
from qpik.app.runs import compare, format_table, run
from qpik.rollout import simulate
from qpik.scenario import build_scenario


@pytest.fixture(scope="module")
def logs():
    return {kind: run("arm", "three-tasks", kind)[1] for kind in ("qp", "qp-hard", "hqp", "sns", "pinv")}


@pytest.fixture(scope="module")
def setup_joints():
    from qpik.scenario import build_scenario

    return build_scenario("three-tasks").plot_joints


@pytest.fixture(scope="module")
def summaries(logs):
    return {kind: log.summary() for kind, log in logs.items()}


def test_hqp_keeps_the_path_exact_and_the_limits(summaries):
    hqp = summaries["hqp"]
    assert hqp.levels.names == ("path", "phi", "sigma") and hqp.levels.units == ("m", "rad", "rad/s, m/s")
    assert hqp.levels.error_max[0] <= 1e-6
    assert hqp.limit_violation_max == 0.0
    assert hqp.levels.error_max[1] > 0.3  # φ is infeasible part of the time ...
    assert hqp.levels.error_final[1] <= 1e-5  # ... and tracked again at the end


def test_soft_qp_trades_the_path_for_phi_and_the_classical_law_breaks_the_limits(summaries):
    soft, hard, hqp = summaries["qp"], summaries["qp-hard"], summaries["hqp"]
    assert soft.levels.error_max[0] >= 1e-2  # centimetres off the path ...
    assert soft.levels.error_max[1] < hqp.levels.error_max[1] - 0.03  # ... for a better φ
    assert hard.levels.error_max[0] <= 1e-6  # the path hard: exact; but φ weighed against σ
    assert hard.levels.error_final[1] > 100 * hqp.levels.error_final[1]  # gives way to it
    for kind in ("qp", "qp-hard", "hqp", "sns"):
        assert summaries[kind].limit_violation_max == 0.0, kind
    assert summaries["pinv"].limit_violation_max > 0.1
    sns = summaries["sns"]
    assert sns.levels.error_max[0] <= 1e-5 and sns.task_scale_min == 1.0
    assert sns.report["level_task_scale_min"][1] < 1.0  # φ scaled (or dropped) where infeasible


class _Checked:
    """The hierarchy, with each step's level 1 checked against an independent solution: the
    best path velocity in the box (quadprog, level 0 alone), then the smallest φ residual
    with that path velocity kept (quadprog again)."""

    def __init__(self, controller, position, phi):
        self.inner, self.position, self.phi = controller, position, phi
        self.kind, self.solver, self.robot = controller.kind, controller.solver, controller.robot
        self.gaps, self.optima = [], []

    def compute_velocity(self):
        qdot = self.inner.compute_velocity()
        J0, v0 = self.position.jacobian, self.position.target_velocity
        J1, v1 = self.phi.jacobian, self.phi.target_velocity
        lb, ub = self.inner.lb, self.inner.ub
        eye = 1e-9 * np.eye(len(qdot))
        best_path = qpsolvers.solve_qp(J0.T @ J0 + eye, -J0.T @ v0, lb=lb, ub=ub, solver="quadprog")
        best = qpsolvers.solve_qp(J1.T @ J1 + eye, -J1.T @ v1, A=J0, b=J0 @ best_path, lb=lb, ub=ub,
                                  solver="quadprog")
        optimum = float(np.linalg.norm(J1 @ best - v1))
        self.optima.append(optimum)
        self.gaps.append(float(np.linalg.norm(J1 @ qdot - v1)) - optimum)
        # level 0 kept its optimum: no larger path residual than the reference's (whose 1e-9
        # regulariser makes it, if anything, the less exact of the two)
        path_gap = np.linalg.norm(J0 @ qdot - v0) - np.linalg.norm(J0 @ best_path - v0)
        assert path_gap <= 1e-9, path_gap
        return qdot


def test_hqp_gets_phi_as_close_as_the_limits_allow_every_step():
    setup = build_scenario("three-tasks")
    position, phi = setup.hierarchy[0], setup.hierarchy[1]
    checked = _Checked(setup.controller("hqp"), position, phi)
    log = simulate(checked, setup.reference, setup.duration, dt=setup.dt, joint_limits=setup.joint_limits,
                   levels=setup.level_errors)
    gaps, optima = np.array(checked.gaps), np.array(checked.optima)
    assert len(gaps) == len(log.t)
    assert np.sum(optima > 1.0) > 500  # φ infeasible (residual over 1 rad/s) for over a second
    assert np.max(np.abs(gaps)) <= 1e-6 * (1.0 + np.max(optima))


@pytest.mark.parametrize("scenario,columns", [
    ("three-tasks", ["L0 path [m]", "L1 phi [rad]", "L2 sigma [rad/s, m/s]", "task scale min"]),
    ("too-fast", ["off path [m]", "done at [s]", "task scale min"]),
])
def test_compare_shows_the_hierarchy_columns(scenario, columns):
    _, logs, _ = compare("arm", scenario, ["daqp"], peers=())
    assert {"qp", "qp-hard", "hqp", "sns", "pinv"} <= {log.info.controller for log in logs}
    table = format_table([log.summary() for log in logs])
    for column in columns:
        assert column in table


def test_level_error_figure(logs, setup_joints):
    import matplotlib.pyplot as plt

    figures = make_figures(list(logs.values()), setup_joints, "arm / three-tasks")
    assert "levels.png" in figures
    levels = figures["levels.png"]
    # One panel per level (log scale, every controller drawn) and one for SNS's task scale.
    panels = [ax for ax in levels.axes if ax.get_visible()]
    assert len(panels) == 4
    assert all(len(ax.lines) == len(logs) for ax in panels[:3])
    assert panels[3].get_ylabel().startswith("task scale")
    without = dataclasses.replace(logs["pinv"], levels=None)
    assert "levels.png" not in make_figures([without], setup_joints, "no levels")
    plt.close("all")
