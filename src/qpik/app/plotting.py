"""The source's figures, for one run or overlaid for a comparison.

path.png (tracked point vs desired, x-y plane), joints.png (joint positions with the
limits given to the controllers), velocities.png (joint velocities), error.png
(error norm, log scale), manipulability.png; plus extras.png for extra series
(orientation error, loop-closure residual) when the logs have them.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ..io import save_figure  # noqa: E402
from ..rollout import RolloutLog  # noqa: E402
from ..scenario import JointPlotSpec  # noqa: E402


def _label(log: RolloutLog) -> str:
    return log.controller if log.solver in ("none", "") else f"{log.controller} ({log.solver})"


def _style(i: int) -> dict:
    return {"linestyle": ["-", "--", "-.", ":"][i % 4], "linewidth": 1.6 if i == 0 else 1.2}


def _grid(n: int):
    cols = 2 if n > 1 else 1
    rows = (n + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(5.2 * cols, 2.6 * rows), squeeze=False, sharex=True)
    for ax in axes.ravel()[n:]:
        ax.set_visible(False)
    return fig, axes.ravel()


def plot_logs(logs: Sequence[RolloutLog], joints: JointPlotSpec, out_dir: str | Path, title: str) -> list[Path]:
    """Write the figures for one or several (overlaid) runs; returns the files."""
    out_dir = Path(out_dir)
    written = []

    def finish(fig, name: str) -> None:
        fig.suptitle(title, fontsize=10)
        fig.tight_layout()
        path = out_dir / name
        save_figure(fig, path)
        plt.close(fig)
        written.append(path)

    # End-effector / platform path in the x-y plane.
    fig, ax = plt.subplots(figsize=(5.5, 5))
    ref = logs[0]
    ax.plot(ref.x_des[:, 0], ref.x_des[:, 1], color="k", linewidth=3, alpha=0.25, label="desired")
    for i, log in enumerate(logs):
        ax.plot(log.x[:, 0], log.x[:, 1], label=_label(log), **_style(i))
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    finish(fig, "path.png")

    for name, kind in (("joints.png", "q"), ("velocities.png", "qdot")):
        fig, axes = _grid(len(joints.names))
        for j, ax in enumerate(axes[: len(joints.names)]):
            for i, log in enumerate(logs):
                series = log.q[:, joints.qpos_index[j]] if kind == "q" else log.qdot[:, joints.dof_index[j]]
                ax.plot(log.t, series, label=_label(log), **_style(i))
            if kind == "q":
                finite = [b for b in (joints.lower[j], joints.upper[j]) if np.isfinite(b)]
                for k, bound in enumerate(finite):
                    # grey, not a controller colour: the controllers' cycle includes red dotted
                    ax.axhline(bound, color="0.4", linewidth=1.0, linestyle=(0, (1, 1)),
                               label="limit" if k == 0 else None)
            unit = joints.units[j] + ("/s" if kind == "qdot" else "")
            ax.set_ylabel(f"{joints.names[j]} [{unit}]")
            ax.grid(alpha=0.3)
        axes[0].legend(fontsize=7)
        for ax in axes[max(0, len(joints.names) - 2): len(joints.names)]:
            ax.set_xlabel("t [s]")
        finish(fig, name)

    fig, ax = plt.subplots(figsize=(6.5, 3.2))
    for i, log in enumerate(logs):
        ax.semilogy(log.t, np.maximum(log.error, 1e-16), label=_label(log), **_style(i))
    ax.set_xlabel("t [s]")
    ax.set_ylabel("position error norm [m]")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    finish(fig, "error.png")

    fig, ax = plt.subplots(figsize=(6.5, 3.2))
    for i, log in enumerate(logs):
        ax.plot(log.t, log.manipulability, label=_label(log), **_style(i))
    ax.set_xlabel("t [s]")
    ax.set_ylabel(f"manipulability ({ref.manipulability_measure})")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    finish(fig, "manipulability.png")

    extra_names = sorted({name for log in logs for name in log.extras})
    if extra_names:
        fig, axes = _grid(len(extra_names))
        for ax, name in zip(axes, extra_names):
            for i, log in enumerate(logs):
                if name in log.extras:
                    ax.semilogy(log.t, np.maximum(log.extras[name], 1e-16), label=_label(log), **_style(i))
            ax.set_ylabel(name.replace("_", " "))
            ax.set_xlabel("t [s]")
            ax.grid(alpha=0.3, which="both")
        axes[0].legend(fontsize=7)
        finish(fig, "extras.png")
    return written


def plot_level_errors(logs: Sequence[RolloutLog], out_dir: str | Path, title: str) -> list[Path]:
    """levels.png: each level's error over time (one panel per level, log scale, the
    controllers overlaid), and SNS's task scale per level when a run reports it.
    Writes nothing when no log has per-level errors."""
    levelled = [log for log in logs if log.level_error is not None]
    if not levelled:
        return []
    names, units = levelled[0].level_names, levelled[0].level_units
    scaled = [log for log in logs if "task_scale" in log.report]
    fig, axes = _grid(len(names) + (1 if scaled else 0))
    for k, (ax, name, unit) in enumerate(zip(axes, names, units)):
        for i, log in enumerate(levelled):
            ax.semilogy(log.t, np.maximum(log.level_error[:, k], 1e-16), label=_label(log), **_style(i))
        ax.set_ylabel(f"L{k} {name} [{unit}]")
        ax.grid(alpha=0.3, which="both")
    if scaled:
        ax = axes[len(names)]
        for log in scaled:
            scale = log.report["task_scale"]
            for k in range(scale.shape[1]):
                ax.plot(log.t, scale[:, k], label=f"{_label(log)} L{k}", **_style(k))
        ax.set_ylabel("task scale s")
        ax.set_ylim(-0.05, 1.05)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    axes[0].legend(fontsize=7)
    for ax in axes[max(0, len(axes) - 2):]:
        ax.set_xlabel("t [s]")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    path = Path(out_dir) / "levels.png"
    save_figure(fig, path)
    plt.close(fig)
    return [path]
