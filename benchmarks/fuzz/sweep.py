"""Run any-robot fuzz cases in the fuzzes' worker pool (:mod:`.pool`: chunks, the hang
detector), with a determinism repeat in a second process, resumable chunk files, and
the summary per failure class.

Each finished chunk is written whole to ``chunks/`` (when a folder is given), so a
stopped sweep resumes where it was.
"""

from __future__ import annotations

import functools
import json
import tempfile
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np

from qpik.rollout.io import write_json

from .cases import ALL_SOLVERS, CLASSES, DEFECTS, run_case
from .pool import run_cases

# One BLAS thread per worker: the sweep's parallelism is its workers. With OpenBLAS's
# default (a thread per core) two workers oversubscribe the cores, and the threads that
# spin while they wait for a core count as CPU time: an 85-dof step read 100–170 ms of it
# against 4–7 ms with one thread.
WORKER_ENVIRONMENT = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}


def run_seed(seed: int, folder: Path, replays: str | None = None, batched_every: int = 0) -> dict:
    """A worker's case (:mod:`.pool`): case ``seed``, replaying the configurations
    recorded for it in the JSON file ``replays`` where it has them; on N worlds too
    (:mod:`.batched`) where :func:`batched` says."""
    replay = _replays(replays).get(seed) if replays else None
    return _jsonable(run_case(seed, folder, replay=replay, batched=batched(seed, batched_every)))


def batched(seed: int, every: int) -> bool:
    """Whether case ``seed`` is also run on N worlds: every ``every``-th seed (0: none)."""
    return every > 0 and seed % every == 0


@functools.lru_cache(maxsize=1)
def _replays(path: str) -> dict[int, list]:
    return {int(seed): steps for seed, steps in json.loads(Path(path).read_text()).items()}


def _jsonable(value):
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, float) and value != value or value in (float("inf"), float("-inf")):
        return str(value)
    if hasattr(value, "item"):  # NumPy scalars
        return _jsonable(value.item())
    return value


def _died(seed: int, exit_code: int) -> dict:
    return {"case": seed, "classes": ["untyped"], "params": {}, "details": {"error": f"worker died: exit {exit_code}"}}


def run_workers(seeds: list[int], jobs: int, chunk: int, cap: float, progress=None,
                replays: Path | None = None, batched_every: int = 0) -> dict[int, dict]:
    """Every seed's result, ``chunk`` seeds per worker, ``jobs`` workers at once
    (``replays``: a JSON file of configurations to replay, by seed; ``batched_every``:
    see :func:`batched`)."""
    options = {"replays": str(replays)} if replays is not None else {}
    if batched_every:
        options["batched_every"] = batched_every
    return run_cases(seeds, "benchmarks.fuzz.sweep:run_seed", jobs=jobs, chunk=chunk, cap=cap, options=options,
                     environment=WORKER_ENVIRONMENT, on_death=_died, progress=progress)


def sweep(seeds: list[int], jobs: int = 1, chunk: int = 50, cap: float = 60.0, folder: Path | None = None,
          repeat_every: int = 20, progress=None, batched_every: int = 0) -> dict[int, dict]:
    """Run the seeds (resuming from ``folder``'s chunk files; every ``batched_every``-th
    on N worlds too: :func:`batched`), confirm slow cases once, and re-run every
    ``repeat_every``-th case in another process for determinism (without the N worlds)."""
    results: dict[int, dict] = {}
    chunks = [seeds[i:i + chunk] for i in range(0, len(seeds), chunk)]
    for part in chunks:
        name = f"{part[0]}-{part[-1]}" + (f"-batched{batched_every}" if batched_every else "")
        path = folder / "chunks" / f"{name}.json" if folder else None
        if path is not None and path.exists():
            stored = {r["case"]: r for r in json.loads(path.read_text())}
            if set(stored) == set(part):
                results.update(stored)
                if progress:
                    progress(len(part))
                continue
        done = run_workers(part, jobs, max(1, -(-len(part) // jobs)), cap, progress, batched_every=batched_every)
        if path is not None:
            write_json(path, [done[s] for s in part])
        results.update(done)
    _confirm_slow(results, cap)
    _repeat(results, seeds[::repeat_every], cap)
    return results


def _confirm_slow(results: dict[int, dict], cap: float) -> None:
    """CPU time still grows on a loaded machine (shared caches and cores): a slow step
    counts only if slow again."""
    slow = [s for s, r in results.items() if "hang" in r["classes"] and "max_step_cpu_ms" in r["details"]]
    again = run_workers(slow, 1, len(slow) or 1, cap) if slow else {}
    for seed in slow:
        if "hang" not in again[seed]["classes"]:
            classes = results[seed]["classes"]
            classes.remove("hang")
            results[seed]["details"]["slow_once_cpu_ms"] = results[seed]["details"]["max_step_cpu_ms"]
            if not any(c in DEFECTS or c in ("typed", "rejected") for c in classes):
                classes.append("ok")


# ProxQP's answers differ across processes in their last digits (docs/controllers.md,
# "Repeatability"), and a cost whose smallest curvature is 1e-12 carries such a digit to
# 1e-3 in q over 25 steps: its argmin is not unique to its tolerance, so a trajectory is
# no measure of it. Its repeat answers the first run's configurations again and must
# keep the same promises: the same classes (hard rows and limits are checked on every
# step of both runs) and each level's cost at each answer equal to this, relative to
# 1 + the cost (ProxQP's documented tolerance, as for its hard rows).
PROXQP_COST_TOLERANCE = 1e-6


def _repeat(results: dict[int, dict], sample: list[int], cap: float) -> None:
    """The sample run again in a fresh process: the same classes and a bitwise-equal q
    trajectory, or for ProxQP the same promises on the same configurations
    (:func:`same_run`)."""
    sample = [s for s in sample if "hang" not in results[s]["classes"]]
    replays = {s: results[s]["q_steps"] for s in sample if results[s].get("q_steps")}
    with tempfile.TemporaryDirectory(prefix="qpik_fuzz_replay_") as folder:
        path = Path(folder) / "replays.json"
        write_json(path, {str(seed): steps for seed, steps in replays.items()})
        again = run_workers(sample, 1, len(sample) or 1, cap, replays=path) if sample else {}
    for seed in sample:
        first, second = results[seed], again[seed]
        first["details"]["repeated"] = True
        if not same_run(first, second):
            first["classes"] = [c for c in first["classes"] if c != "ok"] + ["nondeterministic"]
            first["details"]["repeat"] = {"classes": second["classes"], "q_hash": second.get("q_hash")}


# Classes that depend on the machine's load at that moment, not on the computation; and
# those of the N-world run, which a repeat does not do again.
TIMING_CLASSES = {"hang", "ok"}
BATCH_CLASSES = {"batch_same", "batch_same_minimum", "batch_differs"}


def same_run(first: dict, second: dict) -> bool:
    """Whether a repeat kept the first run's promises: the same classes and, for a case
    that recorded its costs (ProxQP), the same number of steps and each level's cost
    within :data:`PROXQP_COST_TOLERANCE`; for any other, the same q trajectory bit for bit."""
    ignored = TIMING_CLASSES | BATCH_CLASSES
    if set(first["classes"]) - ignored != set(second["classes"]) - ignored:
        return False
    if "step_costs" not in first:
        return first.get("q_hash") == second.get("q_hash")
    costs, again = first["step_costs"], second.get("step_costs", [])
    if len(costs) != len(again):
        return False
    gap = max((cost_gap(float(a), float(b)) for step, other in zip(costs, again) for a, b in zip(step, other)),
              default=0.0)
    first["details"]["proxqp_cost_gap"] = gap
    return gap <= PROXQP_COST_TOLERANCE


def cost_gap(a: float, b: float) -> float:
    """|a − b| / (1 + |a|); 0 for equal values (an infinite cost repeated included)."""
    return 0.0 if a == b else abs(a - b) / (1.0 + abs(a))


# Summary ------------------------------------------------------------------------------

def summarise(results: dict[int, dict]) -> dict:
    counts, by_controller, by_model = Counter(), defaultdict(Counter), defaultdict(Counter)
    sites, examples = defaultdict(Counter), defaultdict(list)
    for seed in sorted(results):
        result = results[seed]
        params, details = result.get("params", {}), result["details"]
        solver = params.get("solver")
        solver = solver if isinstance(solver, str) and solver in ALL_SOLVERS else "invalid" if "solver" in params else None
        label = params.get("controller", "?") + (f"/{solver}" if solver else "")
        model = "generated" if params.get("model") == "generated" else "third-party" if params else "?"
        counts["cases"] += 1
        by_controller[label]["cases"] += 1
        by_model[model]["cases"] += 1
        for c in set(result["classes"]):
            counts[c] += 1
            by_controller[label][c] += 1
            by_model[model][c] += 1
            if c in DEFECTS:
                where = _batch_site(result) if c == "batch_differs" else \
                    details.get("site") or details.get("error", "")[:90] or c
                if c == "stray_warning":
                    for w in details.get("warnings", []):
                        sites[c][w.split(":")[0] + ":" + w.split(":")[1].split()[0]] += 1
                else:
                    sites[c][where] += 1
                if len(examples[c]) < 8:
                    examples[c].append(_example(result))
    return {"counts": dict(counts), "by_controller": {k: dict(v) for k, v in sorted(by_controller.items())},
            "by_model": {k: dict(v) for k, v in by_model.items()},
            "sites": {k: dict(v.most_common(12)) for k, v in sites.items()}, "examples": dict(examples)}


def _batch_site(result: dict) -> str:
    """Where a world of N differed: the controller (and solver), at build or on a step, in
    q̇ (by how much, in decades) or in its error."""
    params = result.get("params", {})
    difference = result["details"].get("batched", {}).get("difference", {})
    label = params.get("controller", "?") + (f"/{params['solver']}" if isinstance(params.get("solver"), str) else "")
    where = "build" if difference.get("at") == "build" else "step"
    what = difference.get("what", "?")
    size = float(difference.get("gap") or 0.0)  # (inf and nan stored as strings: see _jsonable)
    return f"{label} {where} {what}" + (f" ~1e{int(np.floor(np.log10(size)))}" if np.isfinite(size) and size > 0
                                        else f" {size}" if size else "")


def _difference(difference: dict | None) -> str:
    """A world of N's difference in words (its q̇ lists left out)."""
    if not difference:
        return ""
    shown = {k: (f"{v:.2e}" if isinstance(v, float) else v) for k, v in difference.items() if k not in ("batch", "alone")}
    return "N worlds: " + ", ".join(f"{k} {v}" for k, v in shown.items())


def _example(result: dict) -> dict:
    params = result.get("params", {})
    keep = ("model", "controller", "solver", "tasks", "limits", "levels", "invalid", "invalid_value",
            "targets", "start")
    details = result["details"]
    error = details.get("error", "") or _difference(details.get("batched", {}).get("difference"))
    return {"case": result["case"], "classes": result["classes"], "error": error[:200],
            "repeat": details.get("repeat"), "max_step_cpu_ms": details.get("max_step_cpu_ms"),
            "site": details.get("site"), "params": {k: params[k] for k in keep if k in params},
            "batched": {k: v for k, v in details["batched"].items() if k != "difference"} | {
                "difference": {k: v for k, v in details["batched"].get("difference", {}).items()
                               if k not in ("batch", "alone")}} if "batched" in details else None,
            "command": f"python benchmarks/fuzz_any_robot.py --case {result['case']}"
                       + (" --batched 1" if "batched" in details else "")}


def _batched_note(meta: dict) -> str:
    every = meta.get("batched_every", 0)
    if not every:
        return ""
    which = "Every case" if every == 1 else f"Every {every}th case (seed divisible by {every})"
    return (f" {which} also ran on N = 4 worlds of other states and targets, each world against its own "
            "one-world run (benchmarks/fuzz/batched.py).")


def to_markdown(summary: dict, meta: dict) -> str:
    counts = summary["counts"]
    earlier = f"; {meta['cases_from_chunk_files']} cases read from an earlier run's chunk files" \
        if meta.get("cases_from_chunk_files") else ""
    lines = [f"Any-robot fuzz, seeds {meta['first_seed']}–{meta['first_seed'] + meta['cases'] - 1} "
             f"({meta['cases']} cases, {meta['elapsed_s']:.0f} s with {meta.get('jobs', 1)} workers{earlier}, "
             f"`{meta['command']}`). A case may fall in several classes; defects in bold." + _batched_note(meta), "",
             "| class | cases |", "|---|---:|"]
    for key, label, bad in CLASSES:
        lines.append(f"| {'**' + label + '**' if bad else label} | {counts.get(key, 0)} |")
    shown = ["cases", "ok", "typed", "rejected", "batch_same", "batch_same_minimum", *DEFECTS]
    short = {"nondeterministic": "nondet", "stray_warning": "warning", "typed_on_feasible": "typed on feasible",
             "invalid_accepted": "invalid accepted", "hard_missed": "hard missed", "batch_same": "N worlds same",
             "batch_same_minimum": "N worlds same minimum", "batch_differs": "N worlds differ"}
    for title, table in (("Per controller (and solver)", summary["by_controller"]),
                         ("Per model source", summary["by_model"])):
        lines += ["", title + ":", "", "| | " + " | ".join(short.get(k, k) for k in shown) + " |",
                  "|---|" + "---:|" * len(shown)]
        for name, row in table.items():
            lines.append(f"| {name} | " + " | ".join(str(row.get(k, 0)) for k in shown) + " |")
    for key in DEFECTS:
        if summary["sites"].get(key):
            lines += ["", f"Where ({key}): " + "; ".join(f"{n} × `{s}`" for s, n in summary["sites"][key].items())]
            for example in summary["examples"][key][:3]:
                lines.append(f"- case {example['case']}: {json.dumps(example['params'])[:300]} — "
                             f"{example['error'][:150]} (`{example['command']}`)")
    return "\n".join(lines) + "\n"
