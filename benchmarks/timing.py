"""The one timing harness of the benchmarks: contestants stepped side by side in blocks.

A *contestant* is one library (or controller) running its own fresh copy of a problem,
and its timed step is exactly what its user writes in a control loop, nothing else:

1. the target for step k, from the reference in that library's own types (the
   reference is sampled for every step before the first, as plain arrays: no
   trajectory evaluation, logging or conversion between libraries in the step);
2. the solve (qpik's ``compute_velocity``, mink's ``solve_ik``, ...);
3. the integration (qpik's ``robot.integrate``, mink's ``configuration.integrate_inplace``).

A contestant's run has ``steps``, ``step(k)`` (timed) and ``after(k)`` (not timed: the
plant's end stops, copying the state for the metrics); ``failures`` are the exception
types that end its run early (an infeasible hard task) instead of the benchmark; an
optional ``begin_block()`` (not timed) runs before each of its blocks (e.g. selecting
its linear-algebra back-end).

Whole runs timed one after the other let a burst of load (another job, a frequency
change) land on one contestant and not the next: on a busy 2-core machine the ratio
qp/pinv ranged 1.13–1.64 across runs that way. Here all contestants advance in turns of
``block`` steps (~50, a few milliseconds), the order rotated by one every block, so each
block replays the same steps for every contestant within milliseconds of each other.
The garbage collector is off while they run. This is repeated ``repeats`` times (≥ 3)
with fresh runs; the first step of each run is left out (it sets up the solvers).

Every timing benchmark uses this module and nothing else to time: the steps
(:func:`interleave`), a part of a step timed inside it (:class:`MethodTimer`), the cost of
one call on a fixed state (:func:`call_cost_us`), whole rollouts (a contestant whose step
is one rollout), another revision of the package beside this one (:func:`import_revision`).

Reported per contestant: median and 99th percentile of the step over all repeats (the
p99 leaves out the first step of each block: it runs after the other contestants' blocks
with cold caches, one step in 50, so alone it would make the 99th percentile; its median
and the p99 of every step are reported beside), the p99/median ratio, and per repeat the
median; the ratio of two contestants' medians is given per repeat, so its spread across
repeats shows how much the machine's load moved it.

    from timing import Contestant, interleave
    result = interleave([Contestant("qp (daqp)", lambda: ControllerRun(...)), ...], repeats=5)
    result.ratio("qp (daqp)", "pinv")  # {"median": ..., "min": ..., "max": ...}
"""

from __future__ import annotations

import gc
import importlib
import re
import subprocess
import sys
import time
import timeit
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Protocol, Sequence

import numpy as np

from qpik.errors import QpikError
from qpik.rollout.references import start_reference
from qpik.rollout.simulate import single_threaded_blas

BLOCK = 50
P99_BOUND = 3.0  # p99 of the step at most this many medians


class Run(Protocol):
    """One contestant's run: ``step(k)`` is timed, ``after(k)`` is not."""

    steps: int
    failures: tuple[type[BaseException], ...]

    def step(self, k: int) -> None: ...

    def after(self, k: int) -> None: ...


@dataclass(frozen=True)
class Contestant:
    """A label and a factory of fresh runs (each on its own copy of the problem)."""

    label: str
    make: Callable[[], Run]


@dataclass
class ContestantTiming:
    label: str
    step_times: list[np.ndarray] = field(default_factory=list)  # seconds, one array per repeat
    cpu_times: list[np.ndarray] = field(default_factory=list)  # the thread's CPU time, when asked for
    last_run: Run | None = None
    failures: list[str] = field(default_factory=list)  # per repeat, "" when the run completed

    @property
    def all_steps_us(self) -> np.ndarray:
        return np.concatenate(self.step_times) * 1e6 if self.step_times else np.empty(0)

    @property
    def repeat_medians_us(self) -> np.ndarray:
        return np.array([np.median(t) * 1e6 for t in self.step_times])

    def row(self, block: int = BLOCK) -> dict:
        steps = self.all_steps_us
        median, p99 = float(np.median(steps)), float(np.percentile(steps, 99))  # p99 of every step
        # The first step of each block follows the other contestants' blocks, whose data
        # evicted this one's from the caches: 1 step in 50, so it alone would fill the top
        # 1 %. The tail bound is judged on the other steps; the first steps are reported.
        first = np.concatenate([np.arange(len(t)) % block == block - 1 for t in self.step_times])
        warm = steps[~first]
        p99_warm = float(np.percentile(warm, 99)) if warm.size else p99
        return {"label": self.label, "steps": int(steps.size), "median_us": median, "p99_us": p99_warm,
                "p99_all_steps_us": p99,
                "block_first_step_median_us": float(np.median(steps[first])) if first.any() else median,
                "mean_us": float(np.mean(steps)), "p99_over_median": p99_warm / median,
                "p99_within_3_medians": bool(p99_warm <= P99_BOUND * median),
                "repeat_medians_us": [float(m) for m in self.repeat_medians_us],
                "failure": next((f for f in self.failures if f), "")}


@dataclass
class Timing:
    """The result of :func:`interleave`: one :class:`ContestantTiming` per label."""

    contestants: dict[str, ContestantTiming]
    repeats: int
    block: int

    def rows(self) -> list[dict]:
        return [c.row(self.block) for c in self.contestants.values()]

    def ratio(self, numerator: str, denominator: str) -> dict:
        """Median step of ``numerator`` / of ``denominator``: per repeat, their median,
        min and max (the spread the load left), and over all steps pooled."""
        num, den = self.contestants[numerator], self.contestants[denominator]
        pooled = float(np.median(num.all_steps_us) / np.median(den.all_steps_us))
        return {"numerator": numerator, "denominator": denominator, "pooled": pooled,
                **spread(num.repeat_medians_us / den.repeat_medians_us)}


def spread(per_repeat: np.ndarray) -> dict:
    """A ratio measured once per repeat: its median, min, max and the values."""
    return {"median": float(np.median(per_repeat)), "min": float(per_repeat.min()),
            "max": float(per_repeat.max()), "per_repeat": [float(r) for r in per_repeat]}


def rotated(labels: Sequence[str], shift: int) -> list[str]:
    shift %= len(labels)
    return list(labels[shift:]) + list(labels[:shift])


class _Clocked:
    """A run with its per-step times, advanced a block at a time."""

    def __init__(self, run: Run, cpu: bool):
        self.run = run
        self.wall = np.full(run.steps, np.nan)
        self.cpu = np.full(run.steps, np.nan) if cpu else None
        self.done = 0
        self.failure = ""

    @property
    def finished(self) -> bool:
        return bool(self.failure) or self.done >= self.run.steps

    def advance(self, count: int) -> None:
        run, wall, cpu, clock = self.run, self.wall, self.cpu, time.perf_counter
        failures = getattr(run, "failures", (QpikError,))
        begin_block = getattr(run, "begin_block", None)
        if begin_block is not None:
            begin_block()
        for k in range(self.done, min(self.done + count, run.steps)):
            cpu_start = time.thread_time() if cpu is not None else 0.0
            start = clock()
            try:
                run.step(k)
            except failures as exc:
                self.failure = f"{type(exc).__name__} at step {k}: {exc}"
                return
            wall[k] = clock() - start
            if cpu is not None:
                cpu[k] = time.thread_time() - cpu_start
            run.after(k)
            self.done = k + 1


def interleave(contestants: Sequence[Contestant], repeats: int = 3, block: int = BLOCK, cpu: bool = False,
               progress: Callable[[int, int], None] | None = None) -> Timing:
    """Advance every contestant's run in turns of ``block`` steps, rotating the order
    each block, ``repeats`` times with fresh runs; the collector off and the BLAS on
    one thread meanwhile (as in a real-time loop). ``cpu``: also the thread's CPU time
    per step (the scheduler's slices to other processes left out).

    A contestant whose run ends early (a failure, or a shorter run) drops out of the
    turns; the others go on.
    """
    labels = [c.label for c in contestants]
    if len(set(labels)) != len(labels):
        raise ValueError(f"contestant labels must be unique: {labels}")
    if repeats < 1 or block < 1:
        raise ValueError("repeats and block must be at least 1")
    timings = {c.label: ContestantTiming(c.label) for c in contestants}
    for repeat in range(repeats):
        runs = None  # the last repeat's runs freed before the next are built
        for timing in timings.values():
            timing.last_run = None
        gc.collect()
        runs = {c.label: _Clocked(c.make(), cpu) for c in contestants}
        gc.collect()
        gc.disable()
        try:
            with single_threaded_blas():
                turn = 0
                while active := [label for label in rotated(labels, turn) if not runs[label].finished]:
                    for label in active:
                        runs[label].advance(block)
                    turn += 1
        finally:
            gc.enable()
        for label, clocked in runs.items():
            timing = timings[label]
            timing.step_times.append(clocked.wall[1:clocked.done].copy())
            if cpu:
                timing.cpu_times.append(clocked.cpu[1:clocked.done].copy())
            timing.last_run, timing.failures = clocked.run, timing.failures + [clocked.failure]
        if progress is not None:
            progress(repeat + 1, repeats)
    return Timing(timings, repeats, block)


def call_cost_us(call: Callable[[], object], number: int = 2000, repeat: int = 3) -> float:
    """One call's cost in µs: the best of ``repeat`` rounds of ``number`` calls on the same
    state (a part of a step, timed alone after a first call that warms it)."""
    call()
    return min(timeit.repeat(call, number=number, repeat=repeat)) / number * 1e6


class MethodTimer:
    """An object whose method ``method`` is timed into ``times`` (seconds, one entry per
    call) inside a contestant's step; every other attribute passes through."""

    def __init__(self, inner, method: str, times: list[float]):
        self._inner, self._method, self._times = inner, getattr(inner, method), times
        setattr(self, method, self._timed)

    def __getattr__(self, name):
        return getattr(self._inner, name)

    def _timed(self, *args):
        start = time.perf_counter()
        result = self._method(*args)
        self._times.append(time.perf_counter() - start)
        return result


def import_revision(repository: Path, revision: str, folder: Path) -> str:
    """Import the package at git ``revision`` of ``repository`` as ``qpik_<rev>`` (its
    files exported into ``folder``), so that both versions run in this one process;
    returns the module name."""
    name = "qpik_" + re.sub(r"\W", "_", revision)
    # The bundled scenes live in a top-level scenes/ folder (installed as qpik.scenes) since
    # they left src/qpik: a revision that has it gets it back inside the package.
    scenes = subprocess.run(["git", "-C", str(repository), "cat-file", "-e", f"{revision}:scenes"],
                            capture_output=True).returncode == 0
    archive = subprocess.run(["git", "-C", str(repository), "archive", revision, "src/qpik",
                              *(["scenes"] if scenes else [])], check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(folder)], input=archive, check=True)
    package = folder / name
    (folder / "src" / "qpik").rename(package)
    if scenes:
        (folder / "scenes").rename(package / "scenes")
    # Module paths written as strings (the lazy exports, the robot registry) and absolute
    # imports name the package: point them at the copy.
    pattern = re.compile(r"""(["'])qpik\.|\bfrom qpik\b|\bimport qpik\b""")
    for path in package.rglob("*.py"):
        text = path.read_text()
        new = pattern.sub(lambda m: (m.group(1) + name + ".") if m.group(1) else m.group(0).replace("qpik", name),
                          text)
        if new != text:
            path.write_text(new)
    sys.path.insert(0, str(folder))
    importlib.import_module(name + ".app.runs")
    return name


class ControllerRun:
    """A controller on a bundled scenario, stepped as its user's loop does.

    Timed step: the scenario's target for step k (its reference sampled for every step
    beforehand: one ``set_target`` of the task with those arrays), the controller's
    ``compute_velocity`` (qpik's controllers refresh the kinematics themselves when q
    changed), ``robot.integrate``. ``refresh``: the step also updates qpik's kinematics
    first (a peer's mapping reads qpik's robot; qpik's own controllers do not need it).
    Not timed: the end stops (the model's joint ranges, clipped, as the rollouts' plant
    does), the loop closure of a controller that moves only the actuated joints, and the
    copy of q for the comparison with the logged rollout.
    """

    failures = (QpikError,)

    def __init__(self, controller, setup, refresh: bool = False):
        self.controller, self.robot, self.dt = controller, controller.robot, setup.dt
        self.steps = int(round(setup.duration / setup.dt)) + 1
        times = np.arange(self.steps) * setup.dt
        # The reference's own start (also that of another revision's package, which this
        # tree's start_reference would not recognise and would sample step by step).
        start = getattr(setup.reference, "start", None)
        self._targets = start(self.robot, times) if callable(start) else start_reference(setup.reference, self.robot,
                                                                                          times)
        self._refresh = refresh
        self._closure = setup.closure if getattr(controller, "actuated_only", False) else None
        stops = self.robot.joint_limits
        self._stop_index, self._lower, self._upper = stops.qpos_index, stops.lower, stops.upper
        self.q = np.full((self.steps, self.robot.nq), np.nan)

    def step(self, k: int) -> None:
        self._targets.apply(k)
        if self._refresh:
            self.robot.update_kinematics()
        self.robot.integrate(self.controller.compute_velocity(), self.dt)

    def after(self, k: int) -> None:
        q = self.robot.q
        q[self._stop_index] = np.clip(q[self._stop_index], self._lower, self._upper)
        if self._closure is not None:
            self._closure(self.robot)
        self.q[k] = q


def scenario_run(robot: str, scenario: str, controller: str, solver: str) -> ControllerRun:
    """A fresh copy of a bundled scenario with one controller (qpik's, or a peer through
    ``qpik compare``'s mapping), as a :class:`ControllerRun`."""
    from qpik.app.peers import PEERS, peer_controller
    from qpik.scenario import build_scenario

    setup = build_scenario(scenario, robot)
    if controller in PEERS:
        return ControllerRun(peer_controller(controller, setup, solver), setup, refresh=True)
    return ControllerRun(setup.controller(controller, solver), setup)


def timed_run(*args, **kwargs):
    """``qpik.app.runs.run`` with the garbage collector off, so no collector pause lands in
    a step its log times (the Monte Carlo's whole rollouts, whose step times are the
    rollout's own per-step clock)."""
    from qpik.app.runs import run

    gc.collect()
    gc.disable()
    try:
        return run(*args, **kwargs)
    finally:
        gc.enable()


def logged_run(robot: str, scenario: str, controller: str, solver: str):
    """The same controller's logged rollout (``qpik.app.runs.run``), untimed: its tracking,
    limit and loop metrics."""
    from qpik.app.runs import run

    return run(robot, scenario, controller, solver, on_failure="stop")[1]


def timed_vs_logged(run: ControllerRun, log) -> float:
    """Largest |q| difference between a timed run and the logged rollout of the same
    controller (q after step k in the timed run is the log's q at step k + 1): 0 when the
    timed loop is the rollout's."""
    n = min(len(log.q) - 1, int(np.sum(np.isfinite(run.q[:, 0]))))
    return float(np.max(np.abs(run.q[:n] - log.q[1:n + 1]))) if n > 0 else float("nan")
