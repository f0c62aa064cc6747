r"""qpik beside mink on third-party and generated models: the same problem, solver daqp.

Cases (each a qpik problem and its mink mirror, :mod:`benchmarks.peers.mink_mirror`; the untimed
side-by-side rollouts are :mod:`benchmarks.peers.equivalence`):

- ``jaco``: dm_control's Kinova Jaco tracks a 3-D circle with a 6-D pose task, joint
  position and speed limits, 5 s at 2 ms (examples/jaco_circle.py);
- ``humanoid``: the CMU humanoid, feet held by hard pose tasks, CoM lowered, a hand
  reaching, posture, joint limits, 3 s (examples/humanoid_reach.py);
- ``chain7``, ``chain30``, ``chain60``: generated chains of n hinges (MjSpec), a hard
  6-D pose task at the tip along a circle, posture, joint limits, 2 s (examples/pose_circles.py);
- ``chain30-soft``: the same on 30 hinges with the pose task a cost beside the posture's;
- ``pusher``: gymnasium's 7-DoF pusher arm (puck and goal removed), a hard 6-D pose task
  on its fingertip body along a circle, posture, joint limits, 3 s (examples/pose_circles.py);
- ``collision``: the Jaco's hand pulled through a box (examples/collision_avoidance.py)
  by qpik with its collision limit, qpik with the limit's damper off, and mink with its
  ``CollisionAvoidanceLimit`` (same pairs, gain, distances), on the model with MuJoCo's
  native convex collision on (the Jaco's MJCF turns it off; ``collision-mpr`` runs mink
  on the stock flags, where its distances come from libccd's MPR).

Timing (:mod:`timing`): each case runs in a fresh process of its own (as pyperf and asv
run each benchmark: no earlier case's heap or caches weigh on its timing), where every
contestant runs its own fresh copy of the problem; all advance side by side in blocks of
50 steps, the order rotated, ``--repeats`` times. Each
contestant's timed step is exactly what its user writes, nothing else; the reference is
sampled for every step beforehand into plain arrays (the arguments of each moving task's
``set_target``), and each side converts them to its own types inside its step:

- qpik: ``task.set_target(position, rotation, velocity, angular_velocity)`` (or
  ``(position, velocity)``) for each moving task, ``controller.compute_velocity()``,
  ``robot.integrate(qdot, dt)``;
- mink (:class:`benchmarks.peers.mink_mirror.MinkRun`): each moving task's ``set_target`` in mink's types
  (``SE3`` of the pose shifted by the feed-forward over K, precomputed as ``wxyz_xyz``;
  for a position-only task the frame's current pose with the translation replaced; the
  CoM's point), ``mink.solve_ik``, ``configuration.integrate_inplace``. No qpik call.

The tracking, limits and the trajectories' difference come from logged rollouts run
apart (untimed), mink through the exact mirror of the QP (:class:`~benchmarks.peers.mink_mirror.MinkMirror`);
the timed runs' own final configurations are compared too (mink's shifted target is
first-order equal to the mirror's). Reported per case: median and p99 step, the ratio
qpik/mink per repeat (median, range), and whether each of the script's bounds holds
(a missed bound prints FAIL).

    python benchmarks/third_party.py [--repeats 5] [--cases jaco humanoid ...]

writes benchmarks/results/third_party.json and third_party.md.
"""

from __future__ import annotations

import argparse
import multiprocessing
import platform
import sys
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import mujoco
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "examples"))
sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(ROOT))  # the lab's packages: benchmarks.peers, tools

import collision_avoidance  # noqa: E402
import humanoid_reach  # noqa: E402
import jaco_circle  # noqa: E402
from demo_support import Demo  # noqa: E402
from pose_circles import CHAIN_MOTION, PUSHER_MOTION, chain_demo, pusher_demo  # noqa: E402
from timing import Contestant, call_cost_us, interleave  # noqa: E402

from benchmarks.peers.equivalence import (PAIR, SOLVER, equivalence as side_by_side, mink_controller,  # noqa: E402
                                          qpik_controller, without_damper)
from benchmarks.peers.mink_mirror import MinkMirror, MinkRun  # noqa: E402
from qpik.errors import QpikError  # noqa: E402
from qpik.rollout.io import write_json, write_text  # noqa: E402
from tools.results import refresh  # noqa: E402
from tools.tables import ratio_cell  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"


# Cases ------------------------------------------------------------------------------
@dataclass
class Case:
    """A problem, the controllers that run it, and the issue's bounds on what they achieve.

    ``contenders`` maps a label to a function of a fresh demo returning a controller;
    ``build(duration)`` makes a fresh demo (``None``: the case's own length).
    """

    name: str
    title: str
    build: Callable[[float | None], Demo]
    ratio_bound: float | None = None
    contenders: dict[str, Callable[[Demo], object]] = field(default_factory=dict)


def _sized(build, default: float):
    return lambda duration=None: build(default if duration is None else duration)


# The bounds on qpik / mink: the one engine's serial step at most 0.35 of mink's on the
# pusher and 0.45 on the humanoid (its feet held on a floating base that only ε weighs);
# the earlier goals elsewhere.
CASES: dict[str, Case] = {
    "jaco": Case("jaco", "Kinova Jaco (dm_control), 6-D pose circle, joint position + speed limits, 5 s",
                 _sized(jaco_circle.build, jaco_circle.DURATION), 0.25, PAIR),
    "humanoid": Case("humanoid", "CMU humanoid (dm_control), feet hard + CoM + hand + posture + limits, 3 s",
                     _sized(humanoid_reach.build, humanoid_reach.DURATION), 0.45, PAIR),
    **{f"chain{n}": Case(f"chain{n}", f"chain of {n} hinges (MjSpec), hard 6-D pose circle + posture + limits, 2 s",
                         _sized(lambda d, n=n: chain_demo(n, d), CHAIN_MOTION), 0.20, PAIR) for n in (7, 30, 60)},
    "chain30-soft": Case("chain30-soft", "chain of 30 hinges (MjSpec), soft 6-D pose circle + posture + limits, 2 s",
                         _sized(lambda d: chain_demo(30, d, hard=False), CHAIN_MOTION), 0.25, PAIR),
    "pusher": Case("pusher", "7-DoF pusher (gymnasium), hard 6-D pose circle + posture + limits, 3 s",
                   _sized(pusher_demo, PUSHER_MOTION), 0.35, PAIR),
    "collision": Case("collision", "Jaco's hand pulled through a box, minimum distance 2 cm (native convex "
                                   "collision on), 3 s",
                      _sized(lambda d: collision_avoidance.build(d, native_ccd=True), collision_avoidance.DURATION),
                      None, {"qpik": qpik_controller,
                             "qpik (no damper)": lambda demo: qpik_controller(without_damper(demo)),
                             "mink": mink_controller}),
    "collision-mpr": Case("collision-mpr", "the same with the Jaco's stock flags (native convex collision off: "
                                           "mink's mesh distances from libccd's MPR), 3 s",
                          _sized(collision_avoidance.build, collision_avoidance.DURATION), None,
                          {"qpik": qpik_controller, "mink": mink_controller}),
}


# Timed contestants ------------------------------------------------------------------
def recorded_targets(demo: Demo, steps: int) -> list[tuple[object, list[np.ndarray]]]:
    """The reference's targets for every step as plain arrays: per task whose target it
    moves, the columns (steps x ...) of the arguments its ``apply`` gives ``set_target``."""
    calls: dict[int, list] = {id(task): [] for task in demo.tasks}
    for task in demo.tasks:
        original = task.set_target

        def record(*args, _original=original, _calls=calls[id(task)], **keywords):
            if keywords:
                raise TypeError("the reference must give set_target positional arguments")
            _calls.append([np.array(a, dtype=float) for a in args])
            _original(*args)

        task.set_target = record
    try:
        for t in np.arange(steps) * demo.dt:  # the rollout's step times, the same bits
            demo.reference.apply(float(t))
    finally:
        for task in demo.tasks:
            del task.set_target
    return [(task, [np.array(column) for column in zip(*calls[id(task)])]) for task in demo.tasks
            if calls[id(task)]]


class QpikRun:
    """A qpik controller stepped as its user writes it (timing.Run): each moving task's
    ``set_target`` with the step's arrays, ``compute_velocity``, ``robot.integrate``."""

    failures = (QpikError,)

    def __init__(self, demo: Demo, controller, targets: list[tuple[object, list[np.ndarray]]], steps: int):
        self.robot, self.controller, self.dt, self.steps = demo.robot, controller, demo.dt, steps
        self._targets = [tuple((task.set_target, tuple(column[k] for column in columns)) for task, columns in targets)
                         for k in range(steps)]
        self.q = np.full((steps, demo.robot.nq), np.nan)

    def step(self, k: int) -> None:
        for set_target, arguments in self._targets[k]:
            set_target(*arguments)
        self.robot.integrate(self.controller.compute_velocity(), self.dt)

    def after(self, k: int) -> None:
        self.q[k] = self.robot.q


def timed_run(case: Case, label: str):
    """A fresh copy of the case's problem with one contestant, as a timing.Run."""
    demo = case.build(None)
    steps = int(round(demo.duration / demo.dt)) + 1
    if label == "mink":
        mirror = MinkMirror(demo.robot, demo.tasks, demo.limits, demo.dt, solver=SOLVER,
                            regularization=demo.regularization)
        return MinkRun(mirror, recorded_targets(demo, steps), steps)
    controller = case.contenders[label](demo)
    return QpikRun(demo, controller, recorded_targets(demo, steps), steps)


def timed_differences(timing, labels: list[str], logs: dict) -> dict:
    """The last timed runs: each contestant's largest |q| difference to qpik's timed run,
    and to its own logged rollout (q after step k is the log's q at step k + 1)."""
    runs = {label: timing.contestants[label].last_run for label in labels}
    out = {}
    for label, run in runs.items():
        done = int(np.sum(np.isfinite(run.q[:, 0])))
        n = min(done, len(logs[label].q) - 1)
        out[label] = {"vs_logged_q_max": float(np.max(np.abs(run.q[:n] - logs[label].q[1:n + 1]))),
                      "vs_qpik_timed_q_max": float(np.nanmax(np.abs(run.q[:done] - runs[labels[0]].q[:done])))}
    return out


# Measures ---------------------------------------------------------------------------
def kinematics_cost_us(demo: Demo, number: int = 2000) -> float:
    """One ``robot.update_kinematics()`` (in every contender's timed step) in µs."""
    return call_cost_us(demo.robot.update_kinematics, number)


def breakdown(case: Case, at: float = 0.5, number: int = 2000) -> dict:
    """Where qpik's step goes, at the state ``at`` seconds into the run (µs, best of 3 x
    ``number`` calls of each part on that state): the kinematics update, each task's and
    each per-step limit's update, the closed-form attempt, the solver (if this state needs
    it), and the rest of ``compute_velocity`` (assembly, checks) as the difference."""
    demo = case.build(None)
    controller, robot = demo.controller(SOLVER), demo.robot
    run = demo.reference.start(robot, np.arange(round(at / demo.dt) + 1) * demo.dt)
    for k in range(len(run.times) - 1):
        run.apply(k)
        robot.integrate(controller.compute_velocity(), demo.dt)
    run.apply(len(run.times) - 1)
    robot.update_kinematics()

    def cost(call) -> float:
        return call_cost_us(call, number)

    calls = controller.solver_calls
    controller.compute_velocity()
    needs_solver = controller.solver_calls > calls
    parts = {"kinematics update": cost(robot.update_kinematics)}
    for i, task in enumerate(demo.tasks):
        parts[f"task {i}: {type(task).__name__}"] = cost(task.update)
    problem = controller.problem
    changing = [limit for limit in problem.limits if not limit.constant]
    for limit, (apply, arguments) in zip(changing, problem._writes):
        parts[type(limit).__name__] = cost(lambda apply=apply, arguments=arguments: apply(*arguments))
    parts["closed form (bounds held)"] = cost(lambda: controller.held.solve(controller.cost, problem.box,
                                                                              *problem.inequalities))
    if needs_solver:
        parts["solver (daqp)"] = cost(lambda: controller._solve_world(0))
    total = cost(lambda: (robot.update_kinematics(), controller.compute_velocity()))
    parts["rest of compute_velocity"] = total - sum(parts.values())
    return {"at_s": at, "needs_solver": needs_solver, "total_us": total, "parts_us": parts}


def checks(case: Case, result: dict) -> list[dict]:
    """The issue's must-show bounds for this case: value, bound, holds."""
    runs, diff = result["runs"], result["differences"]
    rows = []

    def check(what: str, value, bound: float, holds: bool | None = None):
        rows.append({"check": what, "value": value, "bound": bound,
                     "holds": bool(value is not None and value <= bound) if holds is None else holds})

    if case.name == "jaco":
        check("qpik max position error [m]", runs["qpik"]["max_error"], 1e-5)
        check("qpik max orientation error [rad]", runs["qpik"]["orientation_error_max"], 1e-4)
        check("qpik joint range violation [rad]", runs["qpik"]["range_violation"], 0.0)
        check("qpik joint speed violation [rad/s]", runs["qpik"]["speed_violation"], 0.0)
        check("max |q_qpik(t) − q_mink(t)| [rad]", diff["mink"]["q_max_difference"], 1e-6)
    if case.name == "humanoid":
        check("|q_final qpik − mink| [rad, m]", diff["mink"]["q_final_difference"], 1e-4)
        check("qpik feet drift [m]", runs["qpik"]["feet_drift_max"], 1e-6)
        check("qpik feet rotation [rad]", runs["qpik"]["feet_turn_max"], 1e-6)
    if case.name == "collision":
        check("qpik: d_min − closest distance [m]",
              collision_avoidance.MINIMUM_DISTANCE - runs["qpik"]["distance_min"], 1e-6)
        check("qpik (no damper): d_min − closest distance [m]",
              collision_avoidance.MINIMUM_DISTANCE - runs["qpik (no damper)"]["distance_min"], 1e-6)
    if "timing" in result:  # a timed run that stops early times only the steps before (both contenders')
        stopped = [row["label"] for row in result["timing"]["rows"] if row["failure"]]
        check("timed runs stopped before the end", len(stopped), 0)
        if case.ratio_bound is not None:
            check("step median qpik / mink (median over repeats)", result["timing"]["ratio"]["median"],
                  case.ratio_bound)
    return rows


# Running ----------------------------------------------------------------------------
def equivalence(case: Case, duration: float | None = None) -> dict:
    """Each contender once (no timing): the logs, metrics and trajectory differences."""
    return side_by_side(case.build, case.contenders, duration)


def measure(case: Case, repeats: int) -> dict:
    """Interleaved timing of the contestants (each step what its user writes), and their
    logged rollouts (untimed) compared."""
    labels = list(case.contenders)
    contestants = [Contestant(label, lambda label=label: timed_run(case, label)) for label in labels]
    timing = interleave(contestants, repeats=repeats)
    logged = equivalence(case)
    logs = logged["logs"]
    result = {"name": case.name, "title": case.title, "ratio_bound": case.ratio_bound,
              "runs": logged["runs"], "differences": logged["differences"],
              "timed_differences": timed_differences(timing, labels, logs),
              "kinematics_update_us": kinematics_cost_us(case.build(None)),
              "timing": {"rows": timing.rows(), "repeats": repeats, "block": timing.block}}
    if "mink" in labels:
        result["timing"]["ratio"] = timing.ratio(labels[0], "mink")
        result["timing"]["ratios"] = {label: timing.ratio(label, "mink") for label in labels if label != "mink"}
    if any("distance_min" in run for run in result["runs"].values()):
        result["minimum_distance"] = collision_avoidance.MINIMUM_DISTANCE
    result["checks"] = checks(case, result)
    result["breakdown"] = breakdown(case)
    return result


def measure_alone(name: str, repeats: int) -> dict:
    """:func:`measure` of case ``name`` in a fresh process (spawned: nothing of this one's)."""
    with ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn")) as pool:
        return pool.submit(_measure_named, name, repeats).result()


def _measure_named(name: str, repeats: int) -> dict:
    return measure(CASES[name], repeats)


def _value(value, digits: int = 2) -> str:
    if value is None:
        return "-"
    return "0" if value == 0 else f"{value:.{digits}e}"


def to_markdown(results: list[dict], meta: dict) -> str:
    lines = ["# qpik beside mink on third-party and generated models", "",
             f"Solver {SOLVER}. Timed step, each as its user writes it: qpik `set_target` of each moving task "
             "(from the reference's precomputed arrays), `compute_velocity`, `robot.integrate`; mink `set_target` "
             "of each moving task in its own types (SE3 from precomputed wxyz_xyz), `solve_ik`, "
             f"`configuration.integrate_inplace`. Contestants interleaved in blocks of {meta['block']} steps, "
             f"{meta['repeats']} repeats; ratio = median step of qpik / of mink per repeat: median (range). "
             "Δq = max over the run of |q_qpik(t) − q_mink(t)| in the logged rollouts (mink through the exact "
             "mirror of the QP); timed Δq = the same between the timed runs (mink's feed-forward-shifted "
             f"target is first-order equal). Python {meta['python']}, {meta['machine']}.", "",
             "| case | qpik median [µs] | mink median [µs] | qpik / mink | bound | max Δq | final Δq | timed Δq | "
             "qpik max error [m] | kinematics update [µs] |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in results:
        rows = {row["label"]: row for row in r["timing"]["rows"]}
        first = next(iter(rows))
        diff = r["differences"].get("mink", {})
        bound = "-" if r["ratio_bound"] is None else f"≤ {r['ratio_bound']:.2f}"
        if r["ratio_bound"] is not None and r["timing"]["ratio"]["median"] > r["ratio_bound"]:
            bound += " **missed**"
        timed = r["timed_differences"]["mink"]["vs_qpik_timed_q_max"]
        lines.append(f"| {r['name']} | {rows[first]['median_us']:.1f} | {rows['mink']['median_us']:.1f} | "
                     f"{ratio_cell(r['timing']['ratio'])} | {bound} | {_value(diff.get('q_max_difference'))} | "
                     f"{_value(diff.get('q_final_difference'))} | {_value(timed)} | "
                     f"{_value(r['runs'][first]['max_error'])} | "
                     f"{r['kinematics_update_us']:.1f} |")
    for r in results:
        lines += ["", f"## {r['name']}: {r['title']}", "",
                  "| contender | median [µs] | p99 [µs] | max error [m] | range viol. [rad] | speed viol. [rad/s] | "
                  "closest to a range end [rad] |", "|---|---:|---:|---:|---:|---:|---:|"]
        for row in r["timing"]["rows"]:
            run = r["runs"][row["label"]]
            lines.append(f"| {row['label']} | {row['median_us']:.1f} | {row['p99_us']:.1f} | "
                         f"{_value(run['max_error'])} | {_value(run['range_violation'])} | "
                         f"{_value(run['speed_violation'])} | {run['range_margin_min']:.3f} |")
        extras = sorted({k for run in r["runs"].values() for k in run if k.endswith(("_max", "_min", "_final"))
                         and not k.startswith("range")})
        if extras:
            lines += ["", "| contender | " + " | ".join(extras) + " |", "|---|" + "---:|" * len(extras)]
            for label, run in r["runs"].items():
                lines.append(f"| {label} | " + " | ".join(_value(run.get(k), 4) for k in extras) + " |")
        if "distance_min" in next(iter(r["runs"].values())):
            lines += ["", "| contender | first within d_min at [s] | approach speed then [m/s] | "
                          "d_min − closest [m] |", "|---|---:|---:|---:|"]
            for label, run in r["runs"].items():
                below = collision_avoidance.MINIMUM_DISTANCE - run["distance_min"]
                at = "-" if run["crossed_at_s"] is None else f"{run['crossed_at_s']:.3f}"
                speed = "-" if run["approach_speed_at_crossing"] is None else f"{run['approach_speed_at_crossing']:.3f}"
                lines.append(f"| {label} | {at} | {speed} | {below:.2e} |")
        if r["checks"]:
            lines += ["", "| must show | value | bound | holds |", "|---|---:|---:|:---:|"]
            for c in r["checks"]:
                lines.append(f"| {c['check']} | {_value(c['value'], 3)} | {c['bound']:g} | "
                             f"{'yes' if c['holds'] else '**no**'} |")
        split = r["breakdown"]
        lines += ["", f"Where qpik's step goes ({split['at_s']:g} s into the run, "
                      f"{'the solver needed' if split['needs_solver'] else 'no limit binding: closed form'}; "
                      f"each part timed alone on that state, total {split['total_us']:.1f} µs):", "",
                  "| part | µs |", "|---|---:|"]
        lines += [f"| {part} | {value:.1f} |" for part, value in split["parts_us"].items()]
        ratios = r["timing"].get("ratios", {})
        if ratios:
            lines += ["", "Ratios to mink per repeat: " + "; ".join(
                f"{label}: " + ", ".join(f"{v:.3f}" for v in ratio["per_repeat"]) for label, ratio in ratios.items())]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--cases", nargs="*", default=list(CASES), choices=list(CASES), metavar="CASE",
                        help=f"cases to run (default all): {', '.join(CASES)}")
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    meta = {"python": sys.version.split()[0], "machine": platform.machine(), "processor": platform.processor(),
            "repeats": args.repeats, "block": 50, "solver": SOLVER, "mujoco": mujoco.__version__}
    results = []
    for name in args.cases:
        print(f"{name} ...", file=sys.stderr, flush=True)
        results.append(measure_alone(name, args.repeats))
        for check in results[-1]["checks"]:
            if not check["holds"]:
                print(f"FAIL {name}: {check['check']} = {check['value']} (bound {check['bound']:g})", file=sys.stderr)
    markdown = to_markdown(results, meta)
    print(markdown)
    write_json(args.out / "third_party.json", {"meta": meta, "cases": results})
    write_text(args.out / "third_party.md", markdown)
    return refresh(args.out)


if __name__ == "__main__":
    sys.exit(main())
