"""Run any-robot fuzz cases in chunks of worker processes: a hang detector, a determinism
repeat in a second process, resumable chunk files, and the summary per failure class.

A worker (``python -m qpik.fuzz.sweep --worker SEED ...``) prints a line when a case
starts and one with its result; the parent kills a worker whose case runs past ``cap``
seconds (that case is a hang) and gives the rest of its chunk to a fresh worker. Each
finished chunk is written whole to ``chunks/`` (when a folder is given), so a stopped
sweep resumes where it was.
"""

from __future__ import annotations

import json
import os
import queue
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter, defaultdict
from contextlib import contextmanager
from pathlib import Path

from ..io import write_json
from .cases import ALL_SOLVERS, CLASSES, DEFECTS, run_case

PROTOCOL = "@@qpik-fuzz "


def worker(seeds: list[int], replays: dict[int, list] | None = None) -> None:
    """Run the seeds, replaying a case's recorded configurations where ``replays`` has them."""
    replays = replays or {}
    with tempfile.TemporaryDirectory(prefix="qpik_fuzz_") as folder:
        for seed in seeds:
            print(PROTOCOL + json.dumps({"start": seed}), flush=True)
            result = run_case(seed, Path(folder), replay=replays.get(seed))
            print(PROTOCOL + json.dumps({"result": _jsonable(result)}), flush=True)


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


class WorkerProcess:
    """A worker subprocess whose protocol lines go to ``lines`` as ``(index, message)``,
    then ``(index, None)`` when its output ends; the reader closes the pipe it reads."""

    def __init__(self, command: list[str], lines: queue.Queue, index: int, **popen):
        self.process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                                        **popen)
        self.reader = threading.Thread(target=self._read, args=(lines, index), daemon=True)
        self.reader.start()

    def _read(self, lines: queue.Queue, index: int) -> None:
        with self.process.stdout:
            for line in self.process.stdout:
                if line.startswith(PROTOCOL):
                    lines.put((index, json.loads(line[len(PROTOCOL):])))
        lines.put((index, None))

    def end(self) -> None:
        """Kill it if it still runs, reap it and wait for its reader (which closes the pipe)."""
        if self.process.poll() is None:
            self.process.kill()  # our own child
        self.process.wait()
        self.reader.join(timeout=10.0)


@contextmanager
def ending_workers_on_exit(workers: dict):
    """Every worker in ``workers`` ended on the way out — normally, on an error, Ctrl-C or
    SIGTERM (turned into SystemExit while this runs in the main thread)."""
    main = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, _exit_on_sigterm) if main else None
    try:
        yield
    finally:
        for w in list(workers.values()):
            w.end()
        if main:
            signal.signal(signal.SIGTERM, previous)


def wait_for_message(workers: dict, cap: float) -> float:
    """Seconds to wait for a message: 0.2, or less when a running case's cap comes first
    (a case is a hang when its cap passes, however soon its result would have come)."""
    now = time.monotonic()
    return max(0.0, min([0.2, *(w.started + cap - now for w in workers.values() if w.current is not None)]))


def _exit_on_sigterm(signum, frame):
    raise SystemExit(128 + signum)


# One BLAS thread per worker: the sweep's parallelism is its workers. With OpenBLAS's
# default (a thread per core) two workers oversubscribe the cores, and the threads that
# spin while they wait for a core count as CPU time: an 85-dof step read 100–170 ms of it
# against 4–7 ms with one thread.
WORKER_ENVIRONMENT = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}


class _Worker(WorkerProcess):
    def __init__(self, seeds: list[int], lines: queue.Queue, index: int, replays: Path | None = None):
        self.seeds, self.done = seeds, set()
        self.current, self.started = None, 0.0
        self.replays = replays
        replay = ["--replay", str(replays)] if replays is not None else []
        super().__init__([sys.executable, "-m", "qpik.fuzz.sweep", *replay, "--worker", *map(str, seeds)], lines,
                         index, env={**os.environ, **WORKER_ENVIRONMENT})

    def rest(self) -> list[int]:
        return [s for s in self.seeds if s not in self.done and s != self.current]


def _lost(seed: int, why: str, detail: dict) -> dict:
    return {"case": seed, "classes": [why], "params": {}, "details": detail}


def run_workers(seeds: list[int], jobs: int, chunk: int, cap: float, progress=None,
                replays: Path | None = None) -> dict[int, dict]:
    """Every seed's result, ``chunk`` seeds per worker, ``jobs`` workers at once
    (``replays``: a JSON file of configurations to replay, by seed)."""
    pending = [seeds[i:i + chunk] for i in range(0, len(seeds), chunk)]
    results: dict[int, dict] = {}
    lines: queue.Queue = queue.Queue()
    workers: dict[int, _Worker] = {}
    count = 0

    def finish(seed: int, result: dict) -> None:
        results[seed] = result
        if progress:
            progress(1)

    with ending_workers_on_exit(workers):
        while pending or workers:
            while pending and len(workers) < jobs:
                workers[count] = _Worker(pending.pop(0), lines, count, replays)
                count += 1
            _handle(lines, workers, pending, finish, cap)
            for index, w in list(workers.items()):
                if w.current is not None and time.monotonic() - w.started > cap:  # the hang detector
                    w.end()
                    finish(w.current, _lost(w.current, "hang", {"cap_s": cap}))
                    w.done.add(w.current)
                    rest, w.current = w.rest(), None
                    if rest:
                        pending.insert(0, rest)
                    del workers[index]
    return results


def _handle(lines: queue.Queue, workers: dict, pending: list, finish, cap: float) -> None:
    """One message from a worker (or none before the next deadline): a case started, a result, its end."""
    try:
        index, message = lines.get(timeout=wait_for_message(workers, cap))
    except queue.Empty:
        return
    w = workers.get(index)
    if w is None:  # a killed worker's last words
        return
    if message is None:  # the worker ended, cleanly or mid-case
        w.end()
        if w.current is not None:
            finish(w.current, _lost(w.current, "untyped", {"error": f"worker died: exit {w.process.returncode}"}))
        if w.rest():
            pending.insert(0, w.rest())
        del workers[index]
    elif "start" in message:
        w.current, w.started = message["start"], time.monotonic()
    else:
        w.done.add(message["result"]["case"])
        w.current = None
        finish(message["result"]["case"], message["result"])


def sweep(seeds: list[int], jobs: int = 1, chunk: int = 50, cap: float = 60.0, folder: Path | None = None,
          repeat_every: int = 20, progress=None) -> dict[int, dict]:
    """Run the seeds (resuming from ``folder``'s chunk files), confirm slow cases once,
    and re-run every ``repeat_every``-th case in another process for determinism."""
    results: dict[int, dict] = {}
    chunks = [seeds[i:i + chunk] for i in range(0, len(seeds), chunk)]
    for part in chunks:
        path = folder / "chunks" / f"{part[0]}-{part[-1]}.json" if folder else None
        if path is not None and path.exists():
            stored = {r["case"]: r for r in json.loads(path.read_text())}
            if set(stored) == set(part):
                results.update(stored)
                if progress:
                    progress(len(part))
                continue
        done = run_workers(part, jobs, max(1, -(-len(part) // jobs)), cap, progress)
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


# Classes that depend on the machine's load at that moment, not on the computation.
TIMING_CLASSES = {"hang", "ok"}


def same_run(first: dict, second: dict) -> bool:
    """Whether a repeat kept the first run's promises: the same classes and, for a case
    that recorded its costs (ProxQP), the same number of steps and each level's cost
    within :data:`PROXQP_COST_TOLERANCE`; for any other, the same q trajectory bit for bit."""
    if set(first["classes"]) - TIMING_CLASSES != set(second["classes"]) - TIMING_CLASSES:
        return False
    if "step_costs" not in first:
        return first.get("q_hash") == second.get("q_hash")
    costs, again = first["step_costs"], second.get("step_costs", [])
    if len(costs) != len(again):
        return False
    gap = max((_cost_gap(float(a), float(b)) for step, other in zip(costs, again) for a, b in zip(step, other)),
              default=0.0)
    first["details"]["proxqp_cost_gap"] = gap
    return gap <= PROXQP_COST_TOLERANCE


def _cost_gap(a: float, b: float) -> float:
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
        label = params.get("controller", "?") + (f"/{solver}" if solver else "") \
            + ("" if params.get("fast_path") is None else f"/fast={params['fast_path']}")
        model = "generated" if params.get("model") == "generated" else "third-party" if params else "?"
        counts["cases"] += 1
        by_controller[label]["cases"] += 1
        by_model[model]["cases"] += 1
        for c in set(result["classes"]):
            counts[c] += 1
            by_controller[label][c] += 1
            by_model[model][c] += 1
            if c in DEFECTS:
                where = details.get("site") or details.get("error", "")[:90] or c
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


def _example(result: dict) -> dict:
    params = result.get("params", {})
    keep = ("model", "controller", "solver", "fast_path", "tasks", "limits", "levels", "invalid", "invalid_value",
            "targets", "start")
    details = result["details"]
    return {"case": result["case"], "classes": result["classes"], "error": details.get("error", "")[:200],
            "repeat": details.get("repeat"), "max_step_cpu_ms": details.get("max_step_cpu_ms"),
            "site": details.get("site"), "params": {k: params[k] for k in keep if k in params},
            "command": f"python benchmarks/fuzz_any_robot.py --case {result['case']}"}


def to_markdown(summary: dict, meta: dict) -> str:
    counts = summary["counts"]
    earlier = f"; {meta['cases_from_chunk_files']} cases read from an earlier run's chunk files" \
        if meta.get("cases_from_chunk_files") else ""
    lines = [f"Any-robot fuzz, seeds {meta['first_seed']}–{meta['first_seed'] + meta['cases'] - 1} "
             f"({meta['cases']} cases, {meta['elapsed_s']:.0f} s with {meta.get('jobs', 1)} workers{earlier}, "
             f"`{meta['command']}`). A case may fall in several classes; defects in bold.", "",
             "| class | cases |", "|---|---:|"]
    for key, label, bad in CLASSES:
        lines.append(f"| {'**' + label + '**' if bad else label} | {counts.get(key, 0)} |")
    shown = ["cases", "ok", "typed", "rejected", *DEFECTS]
    short = {"nondeterministic": "nondet", "stray_warning": "warning", "typed_on_feasible": "typed on feasible",
             "invalid_accepted": "invalid accepted", "hard_missed": "hard missed"}
    for title, table in (("Per controller (and solver, fast path)", summary["by_controller"]),
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


if __name__ == "__main__":
    arguments = sys.argv[1:]
    stored = {}
    if arguments[:1] == ["--replay"]:
        stored = {int(seed): steps for seed, steps in json.loads(Path(arguments[1]).read_text()).items()}
        arguments = arguments[2:]
    if arguments[:1] == ["--worker"]:
        worker([int(s) for s in arguments[1:]], stored)
