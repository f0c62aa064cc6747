"""The bundled robots' fuzz run many cases at once (:mod:`qpik.fuzz.bundled`): chunks of
cases in worker processes, a hang detector, and the summary per outcome class.

A worker (``python -m qpik.fuzz.bundled_sweep --worker KIND:SEED ...``) prints a line
when a case starts and one with its result; the parent times every case and kills a
worker whose case runs past ``cap`` seconds: that case is a *hang*, the rest of the
chunk goes to a fresh worker.
"""

from __future__ import annotations

import json
import queue
import sys
import tempfile
import time
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np

from .bundled import CLASSES, DEFECTS, KINDS, run_case
from .sweep import PROTOCOL, WorkerProcess, ending_workers_on_exit, wait_for_message

# Worker and parent --------------------------------------------------------------------

def worker(case_ids: list[str]) -> None:
    """Run cases one after the other, printing a start line and a result line for each."""
    with tempfile.TemporaryDirectory(prefix="qpik_fuzz_") as folder:
        for case_id in case_ids:
            kind, seed = case_id.split(":")
            print(PROTOCOL + json.dumps({"start": case_id}), flush=True)
            result = run_case(kind, int(seed), Path(folder))
            print(PROTOCOL + json.dumps({"result": result}, default=float), flush=True)


class _Worker(WorkerProcess):
    def __init__(self, cases: list[str], lines: queue.Queue, index: int):
        self.cases, self.current, self.started, self.done = cases, None, 0.0, set()
        super().__init__([sys.executable, "-m", "qpik.fuzz.bundled_sweep", "--worker", *cases], lines, index)


def sweep(case_ids: list[str], jobs: int, chunk: int, cap: float, progress=None) -> dict[str, dict]:
    """Every case's result, in chunks over ``jobs`` worker processes, hangs detected."""
    pending = [case_ids[i:i + chunk] for i in range(0, len(case_ids), chunk)]
    results: dict[str, dict] = {}
    lines: queue.Queue = queue.Queue()
    workers: dict[int, _Worker] = {}
    next_index = 0
    with ending_workers_on_exit(workers):
        while pending or workers:
            while pending and len(workers) < jobs:
                workers[next_index] = _Worker(pending.pop(0), lines, next_index)
                next_index += 1
            _handle(lines, workers, pending, results, progress, cap)
            now = time.monotonic()
            for index, w in list(workers.items()):
                if w.current is not None and now - w.started > cap:
                    w.end()  # the hang detector
                    results[w.current] = {"case": w.current, "classes": ["hang"], "params": {},
                                          "details": {"cap_s": cap}}
                    w.done.add(w.current)
                    if progress:
                        progress(1)
                    rest = [c for c in w.cases if c not in w.done]
                    if rest:
                        pending.insert(0, rest)
                    del workers[index]  # its reader thread sees EOF and its message is ignored
    return results


def _handle(lines: queue.Queue, workers: dict, pending: list, results: dict, progress, cap: float) -> None:
    """One message from a worker (or none before the next deadline): a case started, a result, its end."""
    try:
        index, message = lines.get(timeout=wait_for_message(workers, cap))
    except queue.Empty:
        return
    w = workers.get(index)
    if w is None:
        return
    if message is None:  # the worker ended: cleanly, or it crashed mid-case
        w.end()
        if w.current is not None and w.current not in w.done:
            results[w.current] = {"case": w.current, "classes": ["crash"], "params": {},
                                  "details": {"exit_code": w.process.returncode}}
            w.done.add(w.current)
            if progress:
                progress(1)
        rest = [c for c in w.cases if c not in w.done and c != w.current]
        if rest:
            pending.insert(0, rest)
        del workers[index]
    elif "start" in message:
        w.current, w.started = message["start"], time.monotonic()
    else:
        result = message["result"]
        results[result["case"]] = result
        w.done.add(result["case"])
        w.current = None
        if progress:
            progress(1)


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
            "details": details, "command": f"python benchmarks/fuzz.py --case {result['case']}"}


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
                  "`python benchmarks/fuzz.py --case KIND:SEED`:", ""]
        for f in summary["failing"][:40]:
            lines.append(f"- `{f['case']}`: {', '.join(f['classes'])}"
                         + (f" — {f['details'].get('error', '')[:100]}" if f["details"].get("error") else ""))
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    if sys.argv[1:2] == ["--worker"]:
        worker(sys.argv[2:])
