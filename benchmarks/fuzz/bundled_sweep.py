"""The bundled robots' fuzz run many cases at once (:mod:`.bundled`) in the fuzzes' worker
pool (:mod:`.pool`: chunks, the hang detector), and the summary per outcome class.
"""

from __future__ import annotations

from collections import Counter, defaultdict
from pathlib import Path

import numpy as np

from .bundled import CLASSES, DEFECTS, KINDS, run_case
from .pool import run_cases

# Worker and parent --------------------------------------------------------------------

def run_case_id(case_id: str, folder: Path) -> dict:
    """A worker's case (:mod:`.pool`): ``"kind:seed"``."""
    kind, seed = case_id.split(":")
    return run_case(kind, int(seed), folder)


def _crashed(case_id: str, exit_code: int) -> dict:
    return {"case": case_id, "classes": ["crash"], "params": {}, "details": {"exit_code": exit_code}}


def sweep(case_ids: list[str], jobs: int, chunk: int, cap: float, progress=None) -> dict[str, dict]:
    """Every case's result, in chunks over ``jobs`` worker processes, hangs detected."""
    return run_cases(case_ids, "benchmarks.fuzz.bundled_sweep:run_case_id", jobs=jobs, chunk=chunk, cap=cap,
                     on_death=_crashed, progress=progress)


# Report --------------------------------------------------------------------------------

def jsonable(value):
    """Nested data with every non-finite float written as a string ("inf", "nan")."""
    if isinstance(value, dict):
        return {k: jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if isinstance(value, float) and not np.isfinite(value):
        return str(value)
    return value


def summarise(results: dict[str, dict]) -> dict:
    counts = {kind: Counter() for kind in KINDS}
    per_solver = defaultdict(Counter)
    typed = defaultdict(Counter)
    untyped = Counter()
    worst = defaultdict(float)
    loop_by_gain = defaultdict(Counter)  # hexapod runs by their largest K·dt: loop residual kept or not
    for result in results.values():
        kind = result["case"].split(":")[0]
        counts[kind]["runs"] += 1
        for c in set(result["classes"]):
            counts[kind][c] += 1
        solver = result.get("params", {}).get("solver")
        if solver and "rejected" not in result["classes"]:
            per_solver[solver]["runs"] += 1
            for c in set(result["classes"]):
                per_solver[solver][c] += 1
        error = result["details"].get("error", "")
        # "Name: ...", "Name at t = ...: ..." (a stopped rollout), "at t = ...: ..." (a divergence)
        if not error:
            name = ""
        else:
            name = "DivergenceError" if error.startswith("at t") else error.split(":")[0].split(" at t")[0]
        if "typed" in result["classes"] or "rejected" in result["classes"]:
            typed[kind][name] += 1
        if "untyped" in result["classes"]:
            untyped[error[:120]] += 1
        if "loop_residual_commanded" in result["details"]:
            kdt = result["params"].get("gain_dt_max", 0.0)
            bucket = "K·dt ≤ 1" if kdt <= 1 else "1 < K·dt ≤ 2" if kdt <= 2 else "K·dt > 2"
            loop_by_gain[bucket]["runs"] += 1
            loop_by_gain[bucket]["loop"] += "loop" in result["classes"]
            inside = result["params"]["start_inside"]
            loop_by_gain[bucket]["loop, start inside"] += "loop" in result["classes"] and inside
        for key in ("crossing", "speed_excess", "loop_residual_commanded", "max_step_ms"):
            value = result["details"].get(key)
            if value is not None and np.isfinite(value):
                worst[f"{kind}/{key}"] = max(worst[f"{kind}/{key}"], float(value))
    failing = sorted((r for r in results.values() if DEFECTS & set(r["classes"])),
                     key=lambda r: (r["case"].split(":")[0], int(r["case"].split(":")[1])))
    return {"counts": {k: dict(v) for k, v in counts.items()},
            "per_solver": {k: dict(v) for k, v in per_solver.items()},
            "typed_errors": {k: dict(v) for k, v in typed.items()}, "untyped_errors": dict(untyped.most_common()),
            "worst": dict(worst), "loop_by_gain": {k: dict(v) for k, v in loop_by_gain.items()},
            "failing": [_failure(r) for r in failing]}


def _failure(result: dict) -> dict:
    """A failing case, short: its classes, solver, error and numbers (the rest comes back
    with its command)."""
    details = {k: v for k, v in result["details"].items() if k != "traceback"}
    if "error" in details:
        details["error"] = details["error"][:200]
    return {"case": result["case"], "classes": result["classes"], "solver": result["params"].get("solver"),
            "details": details, "command": f"python benchmarks/fuzz_bundled.py --case {result['case']}"}


def outcome_table(counts: dict) -> list[str]:
    """The outcome classes by case kind (defects in bold): the fuzz's headline table."""
    kinds = [k for k in KINDS if counts[k].get("runs")]
    lines = ["| outcome | " + " | ".join(kinds) + " |", "|---|" + "---:|" * len(kinds)]
    for key, label, bad in CLASSES:
        row = [str(counts[k].get(key, 0)) for k in kinds]
        if bad or any(v != "0" for v in row):
            lines.append(f"| {'**' + label + '**' if bad else label} | " + " | ".join(row) + " |")
    return lines


def to_markdown(summary: dict, meta: dict) -> str:
    kinds = [k for k in KINDS if summary["counts"][k].get("runs")]
    lines = [f"Fuzz of qpik's promises, seed {meta['seed']}: "
             + ", ".join(f"{summary['counts'][k]['runs']} {k}" for k in kinds)
             + f" cases; per-case cap {meta['cap_s']:g} s (`{meta['command']}`). A case may fall in several classes.",
             "", *outcome_table(summary["counts"])]
    solvers = sorted(summary["per_solver"])
    if solvers:
        shown = [key for key, _, bad in CLASSES if bad or key in ("ok", "typed")]
        lines += ["", "Per solver (arm, hexapod and physics cases, and models that got as far as a rollout):", "",
                  "| solver | runs | " + " | ".join(shown) + " |", "|---|---:|" + "---:|" * len(shown)]
        for s in solvers:
            c = summary["per_solver"][s]
            lines.append(f"| {s} | {c.get('runs', 0)} | " + " | ".join(str(c.get(k, 0)) for k in shown) + " |")
    lines += ["", "Typed errors (stops and rejections) by kind: "
              + "; ".join(f"{k}: " + ", ".join(f"{n} {v}" for n, v in sorted(c.items(), key=lambda x: -x[1]))
                          for k, c in summary["typed_errors"].items() if c)]
    if summary["untyped_errors"]:
        lines += ["", "Untyped exceptions:", ""] + [f"- {n} × `{e}`" for e, n in summary["untyped_errors"].items()]
    if summary["loop_by_gain"]:
        lines += ["", "Hexapod runs by their largest gain × Δt (loop residual on the commanded configuration "
                  "> 1e-4 m: all runs / runs that started inside their stroke ranges):", "",
                  "| largest K·dt | runs | loop residual > 1e-4 | of which started inside |", "|---|---:|---:|---:|"]
        for bucket in ("K·dt ≤ 1", "1 < K·dt ≤ 2", "K·dt > 2"):
            c = summary["loop_by_gain"].get(bucket)
            if c:
                lines.append(f"| {bucket} | {c['runs']} | {c['loop']} | {c['loop, start inside']} |")
    lines += ["", "Worst values: " + ", ".join(f"{k} {v:.3g}" for k, v in sorted(summary["worst"].items()))]
    if summary["failing"]:
        lines += ["", f"Failing cases ({len(summary['failing'])}; first 40), each reproduced by "
                  "`python benchmarks/fuzz_bundled.py --case KIND:SEED`:", ""]
        for f in summary["failing"][:40]:
            lines.append(f"- `{f['case']}`: {', '.join(f['classes'])}"
                         + (f" — {f['details'].get('error', '')[:100]}" if f["details"].get("error") else ""))
    return "\n".join(lines) + "\n"
