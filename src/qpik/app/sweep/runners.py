"""Where a sweep's chunks run: in this process (the default) or as Ray tasks.

Both runners hand each finished chunk to ``done(chunk, result, seconds)`` as soon as it
arrives (the caller writes it whole and moves the progress bar), so a sweep stopped at
any moment keeps every chunk finished so far. A chunk's result is the same wherever it
ran: the same samples (drawn from the seed and the world ids), the same batched
arithmetic (MuJoCo's batch is bit-identical at any thread count).

Ray (the ``ray`` extra): ``address="auto"`` starts a local cluster for the sweep and stops
it after; any other address joins a running cluster (``ray start --head`` on one
machine, ``ray start --address=...`` on the others). Each chunk is one task of one CPU,
retried by Ray if its worker or node dies; at most ``workers`` run at once (default: the
cluster's CPUs). The driver receives each chunk's arrays through Ray's object store and
writes the files, so the nodes need no shared folder.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from functools import cache

import numpy as np

from ...errors import InvalidInput
from .chunks import NUMERICAL_PACKAGES, Chunk
from .rollout import run_chunk
from .studies import study

Done = Callable[[Chunk, dict, float], None]
TASK_RETRIES = 3


@cache
def _study(robot: str):
    return study(robot)


def compute(chunk: Chunk, nthread: int | None = None) -> tuple[dict[str, np.ndarray], float]:
    """One chunk's result (every world's metrics, and its targets) and its compute time (s)."""
    begin = time.perf_counter()
    robot_study = _study(chunk.robot)
    samples = robot_study.samples(chunk.seed, chunk.start, chunk.stop)
    result = run_chunk(robot_study, chunk.controller, samples, nthread, chunk.move, chunk.hold)
    result["target"] = samples["target"]
    return result, time.perf_counter() - begin


def run_in_process(chunks: list[Chunk], done: Done) -> None:
    for chunk in chunks:
        result, seconds = compute(chunk)
        done(chunk, result, seconds)


def _ray_task(chunk: Chunk) -> tuple[dict[str, np.ndarray], float, str]:
    from .chunks import code_fingerprint

    result, seconds = compute(chunk, nthread=1)  # one CPU per task: Ray runs one task per CPU
    return result, seconds, code_fingerprint()


class RayRunner:
    """Chunks as Ray tasks (see the module's description)."""

    def __init__(self, address: str, workers: int | None = None):
        from ...extras import require

        self.ray = require("ray", "--ray", extra="ray")
        self.address, self.workers = address, workers
        self.started = False

    def __enter__(self) -> RayRunner:
        ray = self.ray
        options = dict(include_dashboard=False, log_to_driver=False, logging_level="ERROR", configure_logging=True)
        if self.address == "auto":
            ray.init(num_cpus=self.workers, **options)
        else:
            ray.init(address=self.address, **options)
        self.started = True
        cpus = int(ray.cluster_resources().get("CPU", 1))
        self.slots = max(1, min(self.workers or cpus, cpus))
        return self

    def __exit__(self, *exc) -> None:
        if self.started:
            self.ray.shutdown()

    def run(self, chunks: list[Chunk], done: Done) -> dict:
        """Run ``chunks``; returns the driver-side latency of each (submit to result, s)."""
        from .chunks import code_fingerprint

        ray = self.ray
        task = ray.remote(num_cpus=1, max_retries=TASK_RETRIES)(_ray_task)
        ours = code_fingerprint()
        queue, pending, submitted, latency = list(chunks), {}, {}, {}
        try:
            while queue or pending:
                while queue and len(pending) < self.slots:
                    chunk = queue.pop(0)
                    submitted[chunk] = time.perf_counter()  # before the call: the task may start within it
                    pending[task.remote(chunk)] = chunk
                refs = list(pending)
                ray.wait(refs, num_returns=1)  # one ready, then every other already ready too
                ready, _ = ray.wait(refs, num_returns=len(refs), timeout=0)
                for ref in ready:
                    chunk = pending.pop(ref)
                    result, seconds, theirs = ray.get(ref)
                    if theirs != ours:
                        raise InvalidInput(f"a Ray worker runs other code than this driver (qpik's sources or "
                                           f"{', '.join(NUMERICAL_PACKAGES)} differ): install the same on every node")
                    latency[chunk] = time.perf_counter() - submitted[chunk]
                    done(chunk, result, seconds)
        finally:
            for ref in pending:
                ray.cancel(ref, force=True)
        return latency
