"""A sweep's results: each controller's aggregates (``summary.json``), one table, the maps.

Everything here is computed from the chunk files alone, world by world in world order,
so the same sweep gives the same ``summary.json`` however and wherever its chunks ran
(timings live in ``timing.json`` beside it).

A world *reaches* when its controller ran to the end with the end effector (platform)
within ``REACH_TOLERANCE`` of the target; it *keeps the limits* when no joint went
beyond its range and no commanded speed beyond its limit (both to ``VIOLATION_TOLERANCE``);
it *succeeds* when both hold.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .chunks import Chunk, read_chunk, study_key
from .rollout import REACH_TOLERANCE, STOP_REASONS

VIOLATION_TOLERANCE = 1e-6  # joint units and joint units/s: benchmarks/monte_carlo.py's


def gather(folder: Path, chunks: list[Chunk], controllers: list[str]) -> tuple[np.ndarray, dict[str, dict]]:
    """Every world's targets and, per controller, its metrics in world order."""
    parts: dict[str, list[dict]] = {c: [] for c in controllers}
    for chunk in sorted(chunks, key=lambda c: c.start):
        data = read_chunk(folder, chunk)
        if data is None:
            raise FileNotFoundError(f"chunk {chunk.path(folder)} is missing")
        parts[chunk.controller].append(data)
    metrics = {c: {key: np.concatenate([p[key] for p in parts[c]]) for key in parts[c][0]} for c in controllers}
    targets = metrics[controllers[0]]["target"]
    return targets, metrics


def outcomes(m: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Per world: reached, kept the limits, succeeded (bool arrays)."""
    reached = (m["stopped_at"] < 0) & (m["final_error"] <= REACH_TOLERANCE)
    within = (m["range_violation"] <= VIOLATION_TOLERANCE) & (m["speed_violation"] <= VIOLATION_TOLERANCE)
    return {"reached": reached, "within_limits": within, "succeeded": reached & within}


def _stats(values: np.ndarray, percentiles=(50, 95, 99)) -> dict | None:
    values = values[np.isfinite(values)]
    if not len(values):
        return None
    out = {f"p{p}": float(v) for p, v in zip(percentiles, np.percentile(values, percentiles))}
    out["max"] = float(values.max())
    return out


def _violation(values: np.ndarray) -> dict:
    return {"worlds": int((values > VIOLATION_TOLERANCE).sum()), "max": float(values.max())}


def aggregate(m: dict[str, np.ndarray], joint_names: list[str], joint_dofs: np.ndarray,
              vmax: np.ndarray, hexapod: bool) -> dict:
    """One controller's aggregates over its worlds."""
    o = outcomes(m)
    n = len(m["final_error"])
    stopped = m["stopped_at"] >= 0
    ratio = (m["peak_speed"] / vmax).max(axis=1)
    out = {
        "worlds": n,
        "reach_rate": float(o["reached"].mean()), "within_limits_rate": float(o["within_limits"].mean()),
        "success_rate": float(o["succeeded"].mean()),
        "stopped": int(stopped.sum()),
        "stop_reasons": {r: int((m["stop_reason"] == i).sum()) for i, r in enumerate(STOP_REASONS) if i},
        "tracking_error_m": _stats(m["max_error"]),
        "final_error_m": _stats(m["final_error"][~stopped]),
        "range_violation": _violation(m["range_violation"]),
        "speed_violation": _violation(m["speed_violation"]),
        "peak_speed_over_limit": _stats(ratio),
        "peak_joint_speed": {name: _stats(m["peak_speed"][:, dof], (50, 99)) for name, dof in zip(joint_names, joint_dofs)},
        "converge_time_s": _stats(m["converge_time"], (50, 95)),
    }
    if hexapod:
        out["loop_residual_m"] = _stats(m["loop_residual"])
        out["final_orientation_error_rad"] = _stats(m["final_orientation_error"][~stopped], (50, 99))
    return out


def comparison(metrics: dict[str, dict], first: str, second: str) -> dict:
    """Where ``first`` and ``second`` succeed or fail on the same worlds."""
    a, b = outcomes(metrics[first]), outcomes(metrics[second])
    return {
        "both_succeed": int((a["succeeded"] & b["succeeded"]).sum()),
        f"only_{first}_succeeds": int((a["succeeded"] & ~b["succeeded"]).sum()),
        f"only_{second}_succeeds": int((~a["succeeded"] & b["succeeded"]).sum()),
        "both_fail": int((~a["succeeded"] & ~b["succeeded"]).sum()),
        f"{first}_keeps_limits_{second}_breaks": int((a["within_limits"] & ~b["within_limits"]).sum()),
        f"{first}_reaches_within_limits_{second}_breaks": int((a["succeeded"] & ~b["within_limits"]).sum()),
    }


def pairs(controllers: list[str]) -> list[tuple[str, str]]:
    """Each QP controller against each classical law."""
    qps = [c for c in controllers if c.startswith("qp")]
    laws = [c for c in controllers if not c.startswith("qp")]
    return [(q, law) for q in qps for law in laws]


def summarize(robot: str, seed: int, controllers: list[str], metrics: dict[str, dict], template, move: float,
              hold: float) -> dict:
    limits = template.joint_limits
    hexapod = robot == "hexapod"
    vmax = template.velocity_limits
    summary = {"robot": robot, "targets": len(next(iter(metrics.values()))["final_error"]), "seed": seed,
               "study": study_key(move, hold), "violation_tolerance": VIOLATION_TOLERANCE,
               "controllers": {c: aggregate(metrics[c], list(limits.names), limits.dof_index, vmax, hexapod)
                               for c in controllers}}
    summary["comparisons"] = {f"{a} vs {b}": comparison(metrics, a, b) for a, b in pairs(controllers)}
    return summary


def _pct(x: float) -> str:
    return f"{100 * x:.1f} %"


def _span(stats: dict | None, keys=("p50", "p99", "max"), fmt="{:.1e}") -> str:
    return "-" if stats is None else " / ".join(fmt.format(stats[k]) for k in keys)


def table(summary: dict) -> str:
    """The per-controller table (markdown)."""
    hexapod = summary["robot"] == "hexapod"
    lines = ["| controller | reached | limits kept | succeeded (both) | stopped | tracking error p50 / p99 / max [m] | "
             "range viol. worlds / max | speed viol. worlds / max | peak speed / limit p50 / p99 / max | "
             "converge time p50 / p95 [s] |" + (" loop residual p50 / p99 / max [m] |" if hexapod else ""),
             "|---|---:|---:|---:|---:|---|---|---|---|---|" + ("---|" if hexapod else "")]
    for name, a in summary["controllers"].items():
        row = (f"| {name} | {_pct(a['reach_rate'])} | {_pct(a['within_limits_rate'])} | {_pct(a['success_rate'])} | "
               f"{a['stopped']} | {_span(a['tracking_error_m'])} | "
               f"{a['range_violation']['worlds']} / {a['range_violation']['max']:.1e} | "
               f"{a['speed_violation']['worlds']} / {a['speed_violation']['max']:.1e} | "
               f"{_span(a['peak_speed_over_limit'], fmt='{:.2f}')} | "
               f"{_span(a['converge_time_s'], ('p50', 'p95'), '{:.3f}')} |")
        if hexapod:
            row += f" {_span(a['loop_residual_m'])} |"
        lines.append(row)
    return "\n".join(lines) + "\n"


def to_markdown(summary: dict) -> str:
    """What the sweep was, its table, and each QP–law comparison world by world."""
    study = summary["study"]
    lines = [f"qpik sweep {summary['robot']}: {summary['targets']} targets (seed {summary['seed']}), "
             f"quintic segment {study['move_s']:g} s + hold {study['hold_s']:g} s at {study['dt'] * 1e3:g} ms, "
             f"K log-uniform in [{study['gain_range'][0]:g}, {study['gain_range'][1]:g}] 1/s. Reached: final error "
             f"≤ {study['reach_tolerance_m']:g} m; limits kept: no range or speed excess over "
             f"{summary['violation_tolerance']:g}.", "", table(summary).rstrip("\n")]
    for pair, counts in summary["comparisons"].items():
        lines += ["", f"{pair}, world by world: " + ", ".join(f"{k.replace('_', ' ')} {v}" for k, v in counts.items())]
    return "\n".join(lines) + "\n"
