"""Workspace maps: per hexagonal bin of target positions, the fraction of worlds with an outcome.

One figure per pair (a QP controller, a classical law): where each succeeds (reaches
within the limits), where the QP reaches within the limits that the law breaks, and
where both fail. A sweep with one controller gets its success map alone.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ...rollout.io import save_figure
from .report import outcomes, pairs

GRID = 40  # hexagons across the x range


def _panel(fig, ax, xy: np.ndarray, values: np.ndarray, title: str, cmap: str) -> None:
    art = ax.hexbin(xy[:, 0], xy[:, 1], C=values.astype(float), reduce_C_function=np.mean, gridsize=GRID,
                    cmap=cmap, vmin=0.0, vmax=1.0, mincnt=1, linewidths=0.0)
    ax.set(title=f"{title}\n{int(values.sum())} of {len(values)} targets", aspect="equal")
    ax.set_facecolor("0.88")  # grey: no target in the bin
    ax.set_xlabel("target x [m]")
    ax.set_ylabel("target y [m]")
    fig.colorbar(art, ax=ax, shrink=0.85, label="fraction of the bin's targets")


def draw_pair(xy: np.ndarray, metrics: dict, first: str, second: str, robot: str, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    a, b = outcomes(metrics[first]), outcomes(metrics[second])
    fig, axes = plt.subplots(2, 2, figsize=(12, 10.5))
    _panel(fig, axes[0, 0], xy, a["succeeded"], f"{first}: reaches, limits kept", "viridis")
    _panel(fig, axes[0, 1], xy, b["succeeded"], f"{second}: reaches, limits kept", "viridis")
    _panel(fig, axes[1, 0], xy, a["succeeded"] & ~b["within_limits"],
           f"{first} reaches within the limits that {second} breaks", "viridis")
    _panel(fig, axes[1, 1], xy, ~a["succeeded"] & ~b["succeeded"], "both fail (neither reaches within the limits)",
           "viridis")
    fig.suptitle(f"{robot}: {len(xy)} targets, random start states and gains; each hexagon: the fraction of its "
                 "targets", fontsize=11)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


def draw_single(xy: np.ndarray, metrics: dict, name: str, robot: str, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 5.5))
    _panel(fig, ax, xy, outcomes(metrics[name])["succeeded"], f"{robot}, {name}: reaches, limits kept", "viridis")
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


def draw(folder: Path, robot: str, targets: np.ndarray, metrics: dict, controllers: list[str]) -> list[Path]:
    """Write the maps into ``folder``; returns their paths."""
    xy = targets[:, :2]
    written = []
    for first, second in pairs(controllers):
        path = Path(folder) / f"workspace-{first}-vs-{second}.png"
        draw_pair(xy, metrics, first, second, robot, path)
        written.append(path)
    if not written:
        for name in controllers:
            path = Path(folder) / f"workspace-{name}.png"
            draw_single(xy, metrics, name, robot, path)
            written.append(path)
    return written
