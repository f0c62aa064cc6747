"""Load-robust step timing: several controllers advanced side by side in blocks of steps.

Whole rollouts timed one after the other let a burst of load (another job, a frequency
change) land on one controller and not the next: on a busy 2-core machine the ratio
qp/pinv ranged 1.13–1.64 across runs that way. Here every controller (a *contender*)
runs on its own fresh copy of the scenario, and all of them advance in turns of
``block`` steps (~50, a few milliseconds), the order rotated by one every block, so each
block replays the same steps of the scenario for every contender within milliseconds of
each other. The garbage collector is off while they run. This is repeated ``repeats``
times (≥ 3) with fresh setups; the per-step times are those the rollout measures
(kinematics update + ``compute_velocity``), the first step of each rollout left out (it
sets up the solvers).

Reported per contender: median and 99th percentile of the step over all repeats (the
p99 leaves out the first step of each block: it runs after the other contenders' blocks
with cold caches, one step in 50, so alone it would make the 99th percentile; its median
and the p99 of every step are reported beside), the p99/median ratio (the issue's
"p99 ≤ 3× median" row), and per repeat the median; the
ratio of two contenders' medians is given per repeat, so its spread across repeats shows
how much the machine's load moved it.

    from timing import Contender, interleave
    result = interleave([Contender("qp (daqp)", lambda: start_run(...)[1]), ...], repeats=5)
    result.ratio("qp (daqp)", "pinv")  # {"median": ..., "min": ..., "max": ...}
"""

from __future__ import annotations

import gc
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from qpik.rollout import Rollout, RolloutLog

BLOCK = 50
P99_BOUND = 3.0  # p99 of the step at most this many medians


@dataclass(frozen=True)
class Contender:
    """A label and a factory of fresh rollouts (each on its own copy of the scenario)."""

    label: str
    make: Callable[[], Rollout]


@dataclass
class ContenderTiming:
    label: str
    step_times: list[np.ndarray] = field(default_factory=list)  # seconds, one array per repeat
    last_log: RolloutLog | None = None

    @property
    def all_steps_us(self) -> np.ndarray:
        return np.concatenate(self.step_times) * 1e6 if self.step_times else np.empty(0)

    @property
    def repeat_medians_us(self) -> np.ndarray:
        return np.array([np.median(t) * 1e6 for t in self.step_times])

    def row(self, block: int = BLOCK) -> dict:
        steps = self.all_steps_us
        median, p99 = float(np.median(steps)), float(np.percentile(steps, 99))  # p99 of every step
        # The first step of each block follows the other contenders' blocks, whose data
        # evicted this one's from the caches: 1 step in 50, so it alone would fill the top
        # 1 %. The tail bound is judged on the other steps; the first steps are reported.
        first = np.concatenate([np.arange(len(t)) % block == block - 1 for t in self.step_times]) \
            if self.step_times else np.zeros(0, dtype=bool)  # step_times start at step 1
        warm = steps[~first]
        p99_warm = float(np.percentile(warm, 99)) if warm.size else p99
        return {"label": self.label, "steps": int(steps.size), "median_us": median, "p99_us": p99_warm,
                "p99_all_steps_us": p99,
                "block_first_step_median_us": float(np.median(steps[first])) if first.any() else median,
                "mean_us": float(np.mean(steps)), "p99_over_median": p99_warm / median,
                "p99_within_3_medians": bool(p99_warm <= P99_BOUND * median),
                "repeat_medians_us": [float(m) for m in self.repeat_medians_us]}


@dataclass
class Timing:
    """The result of :func:`interleave`: one :class:`ContenderTiming` per label."""

    contenders: dict[str, ContenderTiming]
    repeats: int
    block: int

    def rows(self) -> list[dict]:
        return [c.row(self.block) for c in self.contenders.values()]

    def ratio(self, numerator: str, denominator: str) -> dict:
        """Median step of ``numerator`` / of ``denominator``: per repeat, their median,
        min and max (the spread the load left), and over all steps pooled."""
        num, den = self.contenders[numerator], self.contenders[denominator]
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


def interleave(contenders: Sequence[Contender], repeats: int = 3, block: int = BLOCK,
               progress: Callable[[int, int], None] | None = None) -> Timing:
    """Advance every contender's rollout in turns of ``block`` steps, rotating the order
    each block, ``repeats`` times with fresh rollouts; the collector off meanwhile.

    A contender whose rollout ends early (a failure with ``on_failure="stop"``, or a
    shorter scenario) drops out of the turns; the others go on.
    """
    labels = [c.label for c in contenders]
    if len(set(labels)) != len(labels):
        raise ValueError(f"contender labels must be unique: {labels}")
    if repeats < 1 or block < 1:
        raise ValueError("repeats and block must be at least 1")
    timings = {c.label: ContenderTiming(c.label) for c in contenders}
    for repeat in range(repeats):
        rollouts = {c.label: c.make() for c in contenders}
        gc.collect()
        gc.disable()
        try:
            turn = 0
            while True:
                active = [label for label in rotated(labels, turn) if not rollouts[label].finished]
                if not active:
                    break
                for label in active:
                    rollouts[label].advance(block)
                turn += 1
        finally:
            gc.enable()
        for label, rollout in rollouts.items():
            log = rollout.log()
            timings[label].step_times.append(log.step_time[1:].copy())
            timings[label].last_log = log
        if progress is not None:
            progress(repeat + 1, repeats)
    return Timing(timings, repeats, block)


def ratio_cell(ratio: dict) -> str:
    """``0.42 (0.40–0.45)``: the median over repeats and its range."""
    return f"{ratio['median']:.2f} ({ratio['min']:.2f}–{ratio['max']:.2f})"
