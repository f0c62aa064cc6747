"""Figures: what they draw (commanded strokes, clipped outliers, log ranges), on real rollouts."""

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import re  # noqa: E402

from qpik.app.plotting import _clip_outliers, _log_limits, make_figures, plot_logs  # noqa: E402
from qpik.app.runs import run  # noqa: E402


def test_the_log_keeps_the_commanded_configuration_the_stops_cut():
    setup, log = run("hexapod", "hexapod-stroke-limits", "pinv")
    strokes = np.array(setup.plot_joints.qpos_index)
    dofs = np.array(setup.plot_joints.dof_index)
    commanded, reached = log.q_commanded[:-1, strokes], log.q[:, strokes]
    # Scalar joints integrate as q + q̇Δt: the commanded strokes follow from the log's q and q̇.
    np.testing.assert_allclose(commanded, reached[:-1] + log.info.dt * log.qdot[:-1, dofs], atol=1e-15)
    assert np.all(np.isnan(log.q_commanded[-1]))
    # The inverse-Jacobian law asks for strokes past the 0.35 m end of travel; the stops
    # (and the jammed mechanism) keep the reached strokes inside. How far past is chaotic
    # (it jams, and what follows depends on rounding: 0.06-0.15 m across OpenBLAS kernels),
    # so the test asks only that it crosses by more than a centimetre.
    assert commanded.max() > 0.35 + 0.01 and reached.max() <= 0.35 + 1e-12
    assert log.summary().limit_violation_max == np.max(commanded - 0.35)
    # The QP on the same scenario never commands a stroke past the stop (1e-12: rounding
    # of q + q̇Δt at |q| < 1).
    _, qp = run("hexapod", "hexapod-stroke-limits", "qp")
    assert np.max(qp.q_commanded[:-1, strokes]) <= 0.35 + 1e-12 and qp.summary().limit_violation_max <= 1e-12


def test_an_off_scale_run_is_clipped_and_its_peak_written():
    fig, ax = plt.subplots()
    t = np.linspace(0, 1, 101)
    calm = 0.2 * np.sin(2 * np.pi * t)
    wild = calm.copy()
    wild[40] = 30.8
    ax.plot(t, calm)
    ax.plot(t, wild)
    _clip_outliers(ax, [(t, calm, "qp", 0), (t, wild, "pinv", 1)], "m/s")
    low, high = ax.get_ylim()
    assert high < 0.3 and low > -0.3  # the calm run fills the axis
    texts = [text.get_text() for text in ax.texts]
    assert texts == ["pinv: peak 30.8 m/s at t = 0.40 s (off scale)"]
    # Comparable runs: nothing clipped.
    fig, ax = plt.subplots()
    _clip_outliers(ax, [(t, calm, "qp", 0), (t, 1.5 * calm, "pinv", 1)], "m/s")
    assert not ax.texts
    plt.close("all")


def test_error_axis_starts_at_the_smallest_error_after_t0():
    fig, ax = plt.subplots()
    error = np.concatenate([[0.0], np.geomspace(7e-7, 5e-6, 99)])  # exactly 0 at t = 0
    ax.semilogy(error)
    _log_limits(ax, [error])
    low, high = ax.get_ylim()
    assert np.isclose(low, 7e-7 / 3) and np.isclose(high, 5e-6 * 3)
    plt.close("all")


def test_every_axis_has_a_unit_and_the_legend_is_off_the_axes(tmp_path):
    setup, log = run("hexapod", "hexapod-circle", "qp")
    _, pinv = run("hexapod", "hexapod-circle", "pinv")
    figures = make_figures([log, pinv], setup.plot_joints, "hexapod / hexapod-circle")
    assert sorted(figures) == ["error.png", "extras.png", "joints.png", "levels.png", "manipulability.png",
                               "path.png", "velocities.png"]
    for name, fig in figures.items():
        fig.canvas.draw()
        axes = [a for a in fig.axes if a.get_visible()]
        for ax in axes:
            assert re.search(r"\[[^\]]+\]$", ax.get_ylabel()), (name, ax.get_ylabel())
            # x: a unit, or no label where the axes shares t with the labelled row below
            assert re.search(r"\[[^\]]+\]$", ax.get_xlabel()) or ax.get_shared_x_axes().get_siblings(ax)[1:], name
            assert ax.get_legend() is None  # one legend per figure, outside every axes
        assert any(re.search(r"\[[^\]]+\]$", ax.get_xlabel()) for ax in axes), name
        legend_box = fig.legends[0].get_window_extent()
        for ax in fig.axes:
            assert not legend_box.overlaps(ax.get_window_extent()), name
    plt.close("all")
    assert [p.name for p in plot_logs([log], setup.plot_joints, tmp_path, "t")][0] == "path.png"
    assert not plt.get_fignums()  # plot_logs closes what it draws


def test_readme_command_figures_keep_the_legend_inside_and_one_colour_per_controller():
    """The README's first command (`qpik compare arm --scenario seed-redundant --plot`, every
    solver and peer: 13 runs): each legend lies inside the saved canvas (it was cut on both
    sides of error.png and manipulability.png), and each run is drawn in its controller's
    colour, the solver setting the line style."""
    from matplotlib.colors import to_hex

    from qpik.app.palette import CONTROLLER_COLOURS, controller_colour, solver_linestyle
    from qpik.app.runs import compare

    setup, logs, _ = compare("arm", "seed-redundant")
    figures = make_figures(logs, setup.plot_joints, "arm / seed-redundant (kinematic)")
    for name, fig in figures.items():
        fig.canvas.draw()
        legend, canvas = fig.legends[0].get_window_extent(), fig.bbox
        assert canvas.x0 <= legend.x0 and legend.x1 <= canvas.x1 and canvas.y0 <= legend.y0, name
    lines = figures["error.png"].axes[0].get_lines()
    assert [to_hex(line.get_color()) for line in lines] == [controller_colour(log.info.controller) for log in logs]
    # No two runs alike: the same controller with another solver has another line style.
    assert len({(log.info.controller, repr(solver_linestyle(log.info.solver))) for log in logs}) == len(logs)
    assert len(set(CONTROLLER_COLOURS.values())) == len(CONTROLLER_COLOURS)
    plt.close("all")


def test_controller_colours_are_saturated_never_the_limit_grey():
    from matplotlib.colors import rgb_to_hsv, to_rgb

    from qpik.app.palette import CONTROLLER_COLOURS, OTHER_COLOUR

    for colour in (*CONTROLLER_COLOURS.values(), OTHER_COLOUR):
        assert rgb_to_hsv(to_rgb(colour))[1] > 0.4, colour
