"""The fuzzes' one pool of worker processes: cases in chunks, a hang detector, progress,
and no worker left behind.

:func:`run_cases` gives each chunk of cases to a worker subprocess, ``jobs`` at once. A
worker (``python -m benchmarks.fuzz.pool RUNNER OPTIONS CASES``) imports the runner, a
``module:function`` that runs one case (``function(case, folder, **options)`` returns
its result, a dict with the case under ``"case"``), and prints a line when a case starts
and one with its result. The parent kills a worker whose case runs past ``cap`` seconds
(that case is a *hang*) and gives the rest of its chunk to a fresh worker; a worker that
dies mid-case is reported by the caller's ``on_death``. On the way out (normally, on an
error, Ctrl-C or SIGTERM) every worker is killed and reaped.

Workers start the same from a benchmark script, from pytest or from any folder: the
repository's root is put on their ``PYTHONPATH``, so ``benchmarks.fuzz`` imports there.
"""

from __future__ import annotations

import importlib
import json
import os
import queue
import signal
import subprocess
import sys
import tempfile
import threading
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Callable

PROTOCOL = "@@qpik-fuzz "
ROOT = Path(__file__).resolve().parents[2]  # the repository: benchmarks/ is a package in it


def worker(runner: str, options: dict, cases: list) -> None:
    """Run the cases one after the other, printing a start line and a result line for each."""
    module, _, name = runner.partition(":")
    run = getattr(importlib.import_module(module), name)
    with tempfile.TemporaryDirectory(prefix="qpik_fuzz_") as folder:
        for case in cases:
            print(PROTOCOL + json.dumps({"start": case}), flush=True)
            result = run(case, Path(folder), **options)
            print(PROTOCOL + json.dumps({"result": result}, default=float), flush=True)


def _import_path() -> str:
    """The repository's root first on the workers' import path, then the parent's own."""
    return os.pathsep.join(p for p in (str(ROOT), os.environ.get("PYTHONPATH")) if p)


class WorkerProcess:
    """A worker subprocess on a chunk of cases; its protocol lines go to ``lines`` as
    ``(index, message)``, then ``(index, None)`` when its output ends."""

    def __init__(self, runner: str, options: dict, cases: list, lines: queue.Queue, index: int,
                 environment: dict[str, str] | None = None):
        self.cases, self.done = cases, set()
        self.current, self.started = None, 0.0
        command = [sys.executable, "-m", "benchmarks.fuzz.pool", runner, json.dumps(options), json.dumps(cases)]
        env = {**os.environ, **(environment or {}), "PYTHONPATH": _import_path()}
        self.process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                                        env=env)
        self.reader = threading.Thread(target=self._read, args=(lines, index), daemon=True)
        self.reader.start()

    def _read(self, lines: queue.Queue, index: int) -> None:
        with self.process.stdout:
            for line in self.process.stdout:
                if line.startswith(PROTOCOL):
                    lines.put((index, json.loads(line[len(PROTOCOL):])))
        lines.put((index, None))

    def rest(self) -> list:
        """The cases of its chunk not finished and not running."""
        return [c for c in self.cases if c not in self.done and c != self.current]

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


def _exit_on_sigterm(signum, frame):
    raise SystemExit(128 + signum)


def hang(case, cap: float) -> dict:
    """The result of a case killed past its cap."""
    return {"case": case, "classes": ["hang"], "params": {}, "details": {"cap_s": cap}}


class _Pool:
    """The parent's bookkeeping: chunks waiting, workers running, results."""

    def __init__(self, runner: str, options: dict, chunks: list[list], jobs: int, cap: float,
                 environment: dict | None, on_death: Callable[[object, int], dict], progress):
        self.runner, self.options, self.environment = runner, options, environment
        self.pending, self.jobs, self.cap = chunks, jobs, cap
        self.on_death, self.progress = on_death, progress
        self.lines: queue.Queue = queue.Queue()
        self.workers: dict[int, WorkerProcess] = {}
        self.results: dict = {}
        self.started = 0

    def finish(self, case, result: dict) -> None:
        self.results[case] = result
        if self.progress:
            self.progress(1)

    def start_workers(self) -> None:
        while self.pending and len(self.workers) < self.jobs:
            self.workers[self.started] = WorkerProcess(self.runner, self.options, self.pending.pop(0), self.lines,
                                                       self.started, self.environment)
            self.started += 1

    def retire(self, index: int) -> None:
        """End worker ``index`` and give what is left of its chunk to a fresh worker."""
        w = self.workers.pop(index)
        w.end()
        if w.rest():
            self.pending.insert(0, w.rest())

    def kill_hangs(self) -> None:
        """The hang detector: a case past its cap is a hang, however soon its result would come."""
        for index, w in list(self.workers.items()):
            if w.current is not None and time.monotonic() - w.started > self.cap:
                self.finish(w.current, hang(w.current, self.cap))
                w.done.add(w.current)
                w.current = None
                self.retire(index)

    def wait_for_message(self) -> float:
        """Seconds to wait for a message: 0.2, or less when a running case's cap comes first."""
        now = time.monotonic()
        running = [w.started + self.cap - now for w in self.workers.values() if w.current is not None]
        return max(0.0, min([0.2, *running]))

    def handle_message(self) -> None:
        """One message from a worker (or none before the next deadline): a case started, a result, its end."""
        try:
            index, message = self.lines.get(timeout=self.wait_for_message())
        except queue.Empty:
            return
        w = self.workers.get(index)
        if w is None:  # a killed worker's last words
            return
        if message is None:  # the worker ended, cleanly or mid-case
            if w.current is not None:
                w.process.wait()
                self.finish(w.current, self.on_death(w.current, w.process.returncode))
                w.done.add(w.current)
                w.current = None
            self.retire(index)
        elif "start" in message:
            w.current, w.started = message["start"], time.monotonic()
        else:
            case = message["result"]["case"]
            w.done.add(case)
            w.current = None
            self.finish(case, message["result"])


def run_cases(cases: list, runner: str, *, jobs: int = 1, chunk: int = 25, cap: float = 60.0,
              options: dict | None = None, environment: dict[str, str] | None = None,
              on_death: Callable[[object, int], dict], progress: Callable[[int], object] | None = None) -> dict:
    """Every case's result, by case: ``chunk`` cases per worker, ``jobs`` workers at once.

    Args:
        cases: JSON-able case names (seeds, ``"kind:seed"``).
        runner: ``"module:function"``, importable from the repository's root; the worker
            calls ``function(case, folder, **options)`` for each case.
        cap: seconds a case may run before it is a hang.
        options: JSON-able keyword arguments of the runner.
        environment: variables set in the workers' environment.
        on_death: the result of a case whose worker died while running it, from the case
            and the worker's exit code.
        progress: called with 1 as each case finishes.
    """
    chunks = [cases[i:i + chunk] for i in range(0, len(cases), chunk)]
    pool = _Pool(runner, options or {}, chunks, jobs, cap, environment, on_death, progress)
    with ending_workers_on_exit(pool.workers):
        while pool.pending or pool.workers:
            pool.start_workers()
            pool.handle_message()
            pool.kill_hangs()
    return pool.results


if __name__ == "__main__":  # a worker: python -m benchmarks.fuzz.pool RUNNER OPTIONS CASES
    worker(sys.argv[1], json.loads(sys.argv[2]), json.loads(sys.argv[3]))
