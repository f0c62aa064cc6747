"""The source's figures, for one run or overlaid for a comparison.

- ``path.png``: the tracked point against the desired path in the x-y plane, with start
  and end marked;
- ``joints.png``: the *commanded* joint positions q ⊕ q̇Δt (what each controller asks
  for, which the end stops may cut: where they did, the reached position is drawn thin),
  with the limits the controllers were given;
- ``velocities.png``: the commanded joint velocities; a run whose peak would flatten
  every other curve is clipped at the axis, its peak written on the plot;
- ``error.png``: the tracking error norm, log scale, starting at the smallest error
  reached after t = 0 (the error is 0 by construction at t = 0);
- ``manipulability.png``; ``extras.png`` for the extra series (orientation error, loop
  residual) when the logs have them.

Every axis has its unit; the legend sits under the plots, inside the figure (as many
columns as fit its width). Each controller has one colour in every figure and video, its
QP solver the line style (:mod:`qpik.app.palette`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

from ..extras import require

matplotlib = require("matplotlib", "plotting (--plot)")
matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ..rollout.io import save_figure  # noqa: E402
from ..rollout import RolloutLog  # noqa: E402
from ..scenario import JointPlotSpec  # noqa: E402
from .palette import LIMIT_GREY, controller_colour, solver_linestyle  # noqa: E402
from .runs import run_label  # noqa: E402

# Extra series: label and unit.
EXTRA_LABELS = {
    "orientation_error": ("orientation error", "rad"),
    "constraint_violation": ("loop-closure residual", "m"),
    "path_deviation": ("distance off the path", "m"),
}
# A run whose peak exceeds the others' by this factor gets the axis clipped.
OFF_SCALE_FACTOR = 4.0


def _label(log: RolloutLog) -> str:
    return run_label(log.info.controller, log.info.solver)


def _style(log: RolloutLog) -> dict:
    """The controller's colour, the solver's line style; qp thick, so that where the runs
    drawn after it coincide its colour still shows along their edges."""
    return {"color": controller_colour(log.info.controller), "linestyle": solver_linestyle(log.info.solver),
            "linewidth": 2.8 if log.info.controller == "qp" else 1.3}


def _legend(fig, logs: Sequence[RolloutLog], extra: Sequence[tuple[dict, str]] = (), ncol: int | None = None) -> None:
    """One legend for the whole figure, below the axes (never over the data), in as many
    columns as fit the figure's width (at most ``ncol``)."""
    handles = [plt.Line2D([], [], **_style(log)) for log in logs]
    labels = [_label(log) + ("" if log.completed else f" (stopped at t = {log.t[-1]:.2f} s)") for log in logs]
    for style, text in extra:
        handles.append(plt.Line2D([], [], **style))
        labels.append(text)
    columns = min(ncol or len(labels), len(labels))
    renderer = fig.canvas.get_renderer()
    while True:
        legend = fig.legend(handles, labels, loc="outside lower center", ncol=columns, fontsize=8, frameon=False)
        if columns == 1 or legend.get_window_extent(renderer).width <= 0.98 * fig.bbox.width:
            return
        legend.remove()
        columns -= 1


def _grid(n: int, height: float = 2.4):
    cols = 2 if n > 1 else 1
    rows = (n + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(5.4 * cols, height * rows + 1.0), squeeze=False, sharex=True,
                             layout="constrained")
    for ax in axes.ravel()[n:]:
        ax.set_visible(False)
    for ax in axes.ravel()[max(0, n - cols):n]:
        ax.set_xlabel("t [s]")
        ax.xaxis.set_tick_params(labelbottom=True)
    return fig, axes.ravel()


def _clip_outliers(ax, series: Sequence[tuple[np.ndarray, np.ndarray, str, int]], unit: str) -> None:
    """If one run's peak |value| dwarfs the others', clip the y axis to the others' range and
    write the clipped run's peak (value and time) on the plot."""
    peaks = np.array([np.nanmax(np.abs(y)) if len(y) else 0.0 for _, y, _, _ in series])
    if len(peaks) < 2:
        return
    order = np.argsort(peaks)
    typical = peaks[order[-2]] if len(peaks) > 1 else peaks[order[-1]]
    outliers = [i for i in range(len(peaks)) if peaks[i] > OFF_SCALE_FACTOR * max(typical, 1e-12)]
    kept = [p for i, p in enumerate(peaks) if i not in outliers]
    if not outliers or not kept or max(kept) == 0:
        return
    bound = 1.25 * max(kept)
    ax.set_ylim(-bound, bound)
    notes = []
    for i in outliers:
        t, y, label, _ = series[i]
        k = int(np.nanargmax(np.abs(y)))
        notes.append(f"{label}: peak {y[k]:.3g} {unit} at t = {t[k]:.2f} s (off scale)")
    ax.text(0.99, 0.97, "\n".join(notes), transform=ax.transAxes, ha="right", va="top", fontsize=7,
            bbox={"boxstyle": "round", "facecolor": "white", "edgecolor": "0.7", "alpha": 0.9})


def _log_limits(ax, values: Sequence[np.ndarray]) -> None:
    """Log axis from a third of the smallest positive value after the first step to three
    times the largest (exact zeros, e.g. the error at t = 0, are not drawn: they would pull
    the axis down to the clamp, 1e-16, wasting decades)."""
    positive = np.concatenate([v[1:][v[1:] > 0] for v in values if len(v) > 1] or [np.array([1.0])])
    if positive.size:
        ax.set_ylim(float(np.min(positive)) / 3, float(np.max(positive)) * 3)


def _positive(values: np.ndarray) -> np.ndarray:
    return np.where(values > 0, values, np.nan)


def plot_logs(logs: Sequence[RolloutLog], joints: JointPlotSpec, out_dir: str | Path, title: str) -> list[Path]:
    """Write the figures for one or several (overlaid) runs into ``out_dir``; returns the files."""
    out_dir = Path(out_dir)
    written = []
    for name, fig in make_figures(logs, joints, title).items():
        save_figure(fig, out_dir / name)
        plt.close(fig)
        written.append(out_dir / name)
    return written


def make_figures(logs: Sequence[RolloutLog], joints: JointPlotSpec, title: str) -> dict[str, plt.Figure]:
    """The figures of one or several (overlaid) runs, by file name (open: close them)."""
    drawn = {"path.png": _path_figure(logs), "joints.png": _joints_figure(logs, joints),
             "velocities.png": _velocities_figure(logs, joints), "error.png": _error_figure(logs),
             "manipulability.png": _manipulability_figure(logs), "extras.png": _extras_figure(logs),
             "levels.png": _level_figure(logs)}
    figures = {}
    for name, figure in drawn.items():
        if figure is None:  # nothing to draw (no extra series, no levels)
            continue
        fig, legend_extra, ncol = figure if isinstance(figure, tuple) else (figure, (), None)
        _legend(fig, logs, legend_extra, ncol)
        fig.suptitle(title, fontsize=10)
        figures[name] = fig
    return figures


def _path_figure(logs: Sequence[RolloutLog]):
    """path.png: the tracked point against the desired path, with its legend's extras."""
    ref = logs[0]
    planar = ref.x.shape[1] == 2
    fig, ax = plt.subplots(figsize=(5.6, 5.8), layout="constrained")
    ax.plot(ref.x_des[:, 0], ref.x_des[:, 1], color="k", linewidth=4, alpha=0.2)
    ax.plot(*ref.x_des[0, :2], "o", color="k", markersize=12, markerfacecolor="none")  # around a closed path's end
    ax.plot(*ref.x_des[-1, :2], "s", color="k", markersize=7, markerfacecolor="none")
    for log in logs:
        style = _style(log)
        ax.plot(log.x[:, 0], log.x[:, 1], **style)
        ax.plot(*log.x[-1, :2], "x", color=style["color"], markersize=8, markeredgewidth=1.8)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title("end effector" if planar else "platform centre, projected on the x-y plane", fontsize=9)
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(alpha=0.3)
    grey = {"color": "k", "linewidth": 4, "alpha": 0.2}
    return fig, [(grey, "desired"),
                 ({"color": "k", "marker": "o", "linestyle": "none", "markerfacecolor": "none"}, "start"),
                 ({"color": "k", "marker": "s", "linestyle": "none", "markerfacecolor": "none"}, "end (desired)"),
                 ({"color": "0.3", "marker": "x", "linestyle": "none"}, "end (reached)")], 3


def _joint_positions(ax, logs: Sequence[RolloutLog], qi: int) -> bool:
    """One joint's commanded positions (what each controller asks for), with the reached
    ones drawn thin where the end stops cut the command; whether any was cut."""
    cut_any = False
    for log in logs:
        style = _style(log)
        reached = log.q[:, qi]
        if log.q_commanded is None:
            ax.plot(log.t, reached, **style)
            continue
        commanded = log.q_commanded[:-1, qi]  # reached, or not, at the next step
        ax.plot(np.concatenate([log.t[:1], log.t[1:]]), np.concatenate([reached[:1], commanded]), **style)
        if np.max(np.abs(commanded - reached[1:]), initial=0.0) > 1e-6:
            cut_any = True
            ax.plot(log.t, reached, color=style["color"], linewidth=0.8, alpha=0.8)
    return cut_any


def _joints_figure(logs: Sequence[RolloutLog], joints: JointPlotSpec):
    """joints.png: commanded positions, thin where the stops cut them, with the limits."""
    fig, axes = _grid(len(joints.names))
    cut_any = False
    for j, ax in enumerate(axes[: len(joints.names)]):
        cut_any |= _joint_positions(ax, logs, joints.qpos_index[j])
        for bound in (b for b in (joints.lower[j], joints.upper[j]) if np.isfinite(b)):
            # grey: no controller is grey (qpik.app.palette)
            ax.axhline(bound, color=LIMIT_GREY, linewidth=1.0, linestyle=(0, (1, 1)))
        ax.set_ylabel(f"{joints.names[j]} [{joints.units[j]}]")
        ax.grid(alpha=0.3)
    extra = [({"color": LIMIT_GREY, "linewidth": 1.0, "linestyle": (0, (1, 1))}, "limit")]
    if cut_any:
        extra.append(({"color": "0.3", "linewidth": 0.8}, "thin: reached (the end stop cut the command)"))
    axes[0].set_title("commanded position q ⊕ q̇Δt", fontsize=9, loc="left")
    return fig, extra, None


def _velocities_figure(logs: Sequence[RolloutLog], joints: JointPlotSpec):
    fig, axes = _grid(len(joints.names))
    for j, ax in enumerate(axes[: len(joints.names)]):
        unit = joints.units[j] + "/s"
        series = []
        for i, log in enumerate(logs):
            y = log.qdot[:, joints.dof_index[j]]
            ax.plot(log.t, y, **_style(log))
            series.append((log.t, y, _label(log), i))
        _clip_outliers(ax, series, unit)
        ax.set_ylabel(f"{joints.names[j]} [{unit}]")
        ax.grid(alpha=0.3)
    axes[0].set_title("commanded velocity q̇", fontsize=9, loc="left")
    return fig


def _error_figure(logs: Sequence[RolloutLog]):
    fig, ax = plt.subplots(figsize=(6.8, 3.8), layout="constrained")
    for log in logs:
        ax.semilogy(log.t, _positive(log.error), **_style(log))
    _log_limits(ax, [log.error for log in logs])
    ax.set_xlabel("t [s]")
    ax.set_ylabel("position error ‖x_d − x‖ [m]")
    ax.grid(alpha=0.3, which="both")
    return fig


def _manipulability_figure(logs: Sequence[RolloutLog]):
    fig, ax = plt.subplots(figsize=(6.8, 3.8), layout="constrained")
    for log in logs:
        ax.plot(log.t, log.manipulability, **_style(log))
    ax.set_xlabel("t [s]")
    ax.set_ylabel("manipulability [-]")
    ax.set_title(logs[0].info.manipulability_measure, fontsize=9, loc="left")
    ax.grid(alpha=0.3)
    return fig


def _extras_figure(logs: Sequence[RolloutLog]):
    """extras.png: the extra series (orientation error, loop residual, ...), or None."""
    extra_names = sorted({name for log in logs for name in log.extras})
    if not extra_names:
        return None
    fig, axes = _grid(len(extra_names), height=3.0)
    for ax, name in zip(axes, extra_names):
        label, unit = EXTRA_LABELS.get(name, (name.replace("_", " "), None))
        values = []
        for log in logs:
            if name in log.extras:
                ax.semilogy(log.t, _positive(log.extras[name]), **_style(log))
                values.append(log.extras[name])
        _log_limits(ax, values)
        ax.set_ylabel(label if unit is None else f"{label} [{unit}]")  # no unit claimed for an unknown series
        ax.grid(alpha=0.3, which="both")
    return fig


def _level_figure(logs: Sequence[RolloutLog]):
    """levels.png: each level's error over time (one panel per level, log scale, the
    controllers overlaid), and the task scale per level of the runs that report one
    (SNS); None when no log has per-level errors."""
    levelled = [log for log in logs if log.levels is not None]
    if not levelled:
        return None
    names, units = levelled[0].levels.names, levelled[0].levels.units
    scaled = [log for log in logs if "task_scale" in log.report]
    fig, axes = _grid(len(names) + (1 if scaled else 0))
    for k, (ax, name, unit) in enumerate(zip(axes, names, units)):
        series = [log.levels.error[:, k] for log in levelled]
        for log, values in zip(levelled, series):
            ax.semilogy(log.t, _positive(values), **_style(log))
        _log_limits(ax, series)
        ax.set_ylabel(f"level {k}: {name} [{unit}]")
        ax.grid(alpha=0.3, which="both")
    if scaled:
        ax = axes[len(names)]
        for log in scaled:
            scale = np.atleast_2d(log.report["task_scale"].T).T
            for k in range(min(scale.shape[1], len(names))):  # the levels drawn above (not a last damping level)
                style = dict(_style(log), linestyle=["-", "--", "-.", ":"][k % 4])
                ax.plot(log.t, scale[:, k], **style)
        ax.set_ylabel("task scale s [-] (level 0 solid)")
        ax.set_ylim(-0.05, 1.05)
        ax.grid(alpha=0.3)
    return fig
