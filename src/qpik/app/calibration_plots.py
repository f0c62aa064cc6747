r"""The calibration figure: imposed vs estimated errors, and error vs number of poses.

Right panel: for N in SWEEP_POSE_COUNTS random poses (nested: one seeded stream), the
RMS over the identified parameters of (estimate − imposed), mean ± std over the run's
``repeats`` noise draws (SWEEP_REPEATS when the run has one), against the covariance prediction
:math:`\sqrt{\mathrm{mean}\,\mathrm{diag}\,σ^2 (J^\top J)^{-1}}` and a σ/√N trend
(each pose adds six independent strokes, so :math:`J^\top J` grows like N).
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from ..extras import require

require("matplotlib", "the calibration plots")
from matplotlib.figure import Figure  # noqa: E402

from ..robots.hexapod.calibration import Calibration, calibrate

SWEEP_POSE_COUNTS = (6, 12, 25, 50, 100)
SWEEP_REPEATS = 10
SWEEP_DEFAULT_NOISE_UM = 1.0  # when the run itself is noise-free


def error_vs_pose_count(result: Calibration, noise_um: float, repeats: int = SWEEP_REPEATS,
                        progress: Callable[[int, int], None] | None = None) -> dict[str, np.ndarray]:
    """Mean and std (over ``repeats`` noise draws) of the RMS parameter error (µm) and its
    prediction, per N; ``progress(i, len(SWEEP_POSE_COUNTS))`` after each N."""
    mean, std, predicted = [], [], []
    for i, n in enumerate(SWEEP_POSE_COUNTS, 1):
        run = calibrate(result.method, n, params=result.params, noise_um=noise_um, seed=result.seed,
                        repeats=repeats)
        free = run.ident.free
        rms = np.sqrt(np.mean((run.monte_carlo[:, free] - run.reference[free]) ** 2, axis=1)) * 1e6
        mean.append(rms.mean())
        std.append(rms.std(ddof=1))
        predicted.append(np.sqrt(np.mean(run.covariance_std[free] ** 2)) * 1e6)
        if progress is not None:
            progress(i, len(SWEEP_POSE_COUNTS))
    return {"n": np.array(SWEEP_POSE_COUNTS, dtype=float), "mean": np.array(mean),
            "std": np.array(std), "predicted": np.array(predicted)}


def plot_calibration(result: Calibration, progress: Callable[[int, int], None] | None = None) -> Figure:
    """Left: imposed (in the gauge) and estimated value of every identified parameter, with
    ±σ covariance bars under noise. Right: :func:`error_vs_pose_count`, log-log, over as
    many noise draws as the run had (``repeats``; SWEEP_REPEATS if it had one)."""
    fig = Figure(figsize=(13, 4.8))
    left, right = fig.subplots(1, 2, gridspec_kw={"width_ratios": [1.6, 1]})
    free = result.ident.free
    names = [n for n, f in zip(result.params.names, free) if f]
    x = np.arange(len(names))
    err = result.covariance_std[free] * 1e6 if result.noise_um > 0 else None
    left.bar(x - 0.2, result.reference[free] * 1e6, 0.4, label="imposed", color="0.6")
    left.bar(x + 0.2, result.fit.theta[free] * 1e6, 0.4, yerr=err, capsize=2, label="estimated",
             color="tab:blue")
    left.set_xticks(x, names, rotation=90 if len(names) > 12 else 0, fontsize=8)
    left.axhline(0.0, color="k", linewidth=0.6)
    left.set_ylabel("parameter error (µm)")
    # The bars coincide to the eye; the estimation error needs its own (log) axis.
    gap = left.twinx()
    gaps = np.maximum(np.abs(result.error[free]) * 1e6, 1e-12)  # an exact 0 drawn at 1e-18 m
    gap.semilogy(x, gaps, "x", color="tab:red", label="|estimated − imposed|")
    gap.set_ylabel("|estimated − imposed| (µm)", color="tab:red")
    # Head room on both axes for the legend strip at the top.
    gap.set_ylim(gaps.min() / 3, gaps.max() * 30)
    bottom, top = left.get_ylim()
    left.set_ylim(bottom, top + 0.3 * (top - bottom))
    worst = np.nanmax(result.relative_error_pct)
    left.set_title(f"{result.method}, {result.params.label}, {len(result.poses)} poses, "
                   f"σ = {result.noise_um:g} µm: max relative error {worst:.2g} %", fontsize=10)
    handles = [h for ax in (left, gap) for h in ax.get_legend_handles_labels()[0]]
    left.legend(handles=handles, fontsize=8, loc="upper center", ncol=3)

    noise = result.noise_um if result.noise_um > 0 else SWEEP_DEFAULT_NOISE_UM
    repeats = SWEEP_REPEATS if result.monte_carlo is None else len(result.monte_carlo)
    sweep = error_vs_pose_count(result, noise, repeats, progress)
    n = sweep["n"]
    right.errorbar(n, sweep["mean"], yerr=sweep["std"], fmt="o-", capsize=3,
                   label=f"RMS error, mean ± std of {repeats} noise draws")
    right.plot(n, sweep["predicted"], "s--", color="tab:orange", label="covariance prediction")
    # Anchored at the largest N: with few poses per parameter the error falls faster.
    right.plot(n, sweep["predicted"][-1] * np.sqrt(n[-1] / n), ":", color="k", label="∝ σ/√N")
    right.set_xscale("log")
    right.set_yscale("log")
    right.set_xlabel("number of poses N")
    right.set_ylabel("RMS parameter error (µm)")
    right.set_title(f"{result.method}, random poses, noise σ = {noise:g} µm", fontsize=10)
    right.grid(True, which="both", alpha=0.3)
    right.legend(fontsize=8, loc="lower left")  # the curves fall from upper left to lower right
    fig.tight_layout()
    return fig
