r"""qpik beside mink on third-party and generated models: the same problem, solver daqp.

Cases (each a qpik problem and its mink mirror, :mod:`mink_mirror`):

- ``jaco``: dm_control's Kinova Jaco tracks a 3-D circle with a 6-D pose task, joint
  position and speed limits, 5 s at 2 ms (examples/jaco_circle.py);
- ``humanoid``: the CMU humanoid, feet held by hard pose tasks, CoM lowered, a hand
  reaching, posture, joint limits, 3 s (examples/humanoid_reach.py);
- ``chain7``, ``chain30``, ``chain60``: generated chains of n hinges (MjSpec), a hard
  6-D pose task at the tip along a circle, posture, joint limits, 2 s;
- ``pusher``: gymnasium's 7-DoF pusher arm (puck and goal removed), a hard 6-D pose task
  on its fingertip body along a circle, posture, joint limits, 3 s;
- ``collision``: the Jaco's hand pulled through a box (examples/collision_avoidance.py)
  by qpik with its collision limit, qpik with the limit's damper off, and mink with its
  ``CollisionAvoidanceLimit`` (same pairs, gain, distances), on the model with MuJoCo's
  native convex collision on (the Jaco's MJCF turns it off; ``collision-mpr`` runs mink
  on the stock flags, where its distances come from libccd's MPR).

Timing (:mod:`timing`): every contestant runs its own fresh copy of the problem; all
advance side by side in blocks of 50 steps, the order rotated, ``--repeats`` times. Each
contestant's timed step is exactly what its user writes, nothing else; the reference is
sampled for every step beforehand into plain arrays (the arguments of each moving task's
``set_target``), and each side converts them to its own types inside its step:

- qpik: ``task.set_target(position, rotation, velocity, angular_velocity)`` (or
  ``(position, velocity)``) for each moving task, ``controller.compute_velocity()``,
  ``robot.integrate(qdot, dt)``;
- mink (:class:`mink_mirror.MinkRun`): each moving task's ``set_target`` in mink's types
  (``SE3`` of the pose shifted by the feed-forward over K, precomputed as ``wxyz_xyz``;
  for a position-only task the frame's current pose with the translation replaced; the
  CoM's point), ``mink.solve_ik``, ``configuration.integrate_inplace``. No qpik call.

The tracking, limits and the trajectories' difference come from logged rollouts run
apart (untimed), mink through the exact mirror of the QP (:class:`mink_mirror.MinkMirror`);
the timed runs' own final configurations are compared too (mink's shifted target is
first-order equal to the mirror's). Reported per case: median and p99 step, the ratio
qpik/mink per repeat (median, range), and whether each of the script's bounds holds
(a missed bound prints FAIL).

    python benchmarks/third_party.py [--repeats 5] [--cases jaco humanoid ...]

writes benchmarks/results/third_party.json and third_party.md.
"""

from __future__ import annotations

import argparse
import platform
import sys
import timeit
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import mujoco
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "examples"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import collision_avoidance  # noqa: E402
import humanoid_reach  # noqa: E402
import jaco_circle  # noqa: E402
from demo_support import Demo, speed_violation  # noqa: E402
from mink_mirror import MinkMirror, MinkRun  # noqa: E402
from timing import Contestant, interleave, ratio_cell  # noqa: E402

from qpik.errors import QpikError  # noqa: E402
from qpik import FrameTask, JointPositionLimit, JointVelocityLimit, PostureTask, Robot  # noqa: E402
from qpik.io import write_json, write_text  # noqa: E402
from qpik.models import third_party as third_party_model  # noqa: E402
from qpik.rollout import Rollout  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
SOLVER = "daqp"
DT = 0.002

# Generated chains and the pusher: a hard pose task along a circle, a posture, limits.
CHAIN_LENGTH = 1.0  # m
CHAIN_AXES = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))  # joint i turns about axis i mod 3
CHAIN_BEND = (1.5, 0.8, 0.4)  # rad shared by the joints of each axis at the start (curled, far from singular)
CHAIN_RANGE = 2.0  # rad, each hinge
POSE_GAIN = 100.0  # 1/s
POSTURE = dict(gain=10.0, weight=1e-3)
SPEED = 3.0  # rad/s, each hinge
CIRCLE = dict(radius=0.05, plane=((1.0, 0.0, 0.0), (0.0, 0.6, 0.8)), tilt_deg=10.0)
PUSHER_START = np.array([0.2, 0.3, 0.0, -1.2, 0.0, -0.6, 0.0])


def chain_model(n: int) -> mujoco.MjModel:
    """A chain of n hinges (axes x, y, z in turn), 1 m long, a site ``tip`` at its end."""
    spec = mujoco.MjSpec()
    spec.modelname = f"chain{n}"
    spec.compiler.degree = False
    link = CHAIN_LENGTH / n
    body = spec.worldbody
    for i in range(n):
        body = body.add_body(name=f"link{i}", pos=[0.0, 0.0, link if i else 0.0])
        body.add_joint(name=f"joint{i}", type=mujoco.mjtJoint.mjJNT_HINGE, axis=list(CHAIN_AXES[i % 3]),
                       range=[-CHAIN_RANGE, CHAIN_RANGE], limited=mujoco.mjtLimited.mjLIMITED_TRUE)
        body.add_geom(type=mujoco.mjtGeom.mjGEOM_CAPSULE, fromto=[0.0, 0.0, 0.0, 0.0, 0.0, link], size=[0.01, 0, 0],
                      mass=0.1)
    body.add_site(name="tip", pos=[0.0, 0.0, link])
    return spec.compile()


def pose_demo(name: str, robot: Robot, frame: str, frame_type: str, motion: float, duration: float) -> Demo:
    """A hard 6-D pose task on ``frame`` along the circle (``motion`` seconds), posture, position
    and speed limits, run for ``duration`` seconds."""
    robot.update_kinematics()
    pose = FrameTask(robot, frame, frame_type, position_gain=POSE_GAIN, orientation_gain=POSE_GAIN, hard=True)
    posture = PostureTask(robot, **POSTURE)
    limits = [JointPositionLimit(robot), JointVelocityLimit(robot, np.full(robot.nv, SPEED))]
    reference = jaco_circle.PoseCircle(pose, motion, **CIRCLE)
    return Demo(name, robot, [pose, posture], limits, reference, DT, duration, follow=pose, moving=(pose,))


CHAIN_MOTION, PUSHER_MOTION = 2.0, 3.0  # s


def chain_demo(n: int, duration: float = CHAIN_MOTION) -> Demo:
    robot = Robot(chain_model(n), name=f"chain{n}")
    bend = np.array(CHAIN_BEND) * 3.0 / n
    robot.set_q(np.array([bend[i % 3] for i in range(n)]))
    return pose_demo(f"chain{n}", robot, "tip", "site", CHAIN_MOTION, duration)


def pusher_demo(duration: float = PUSHER_MOTION) -> Demo:
    """gymnasium's pusher without its puck and goal (4 slide joints that no task moves)."""
    spec = mujoco.MjSpec.from_file(str(third_party_model("pusher")))
    for body in ("object", "goal"):
        spec.delete(spec.body(body))
    robot = Robot(spec.compile(), name="pusher")
    robot.set_q(PUSHER_START)
    return pose_demo("pusher", robot, "tips_arm", "body", PUSHER_MOTION, duration)


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


def qpik_controller(demo: Demo):
    return demo.controller(SOLVER)


def mink_controller(demo: Demo):
    return MinkMirror(demo.robot, demo.tasks, demo.limits, demo.dt, solver=SOLVER,
                      regularization=demo.regularization, moving=demo.moving)


PAIR = {"qpik": qpik_controller, "mink": mink_controller}


def _sized(build, default: float):
    return lambda duration=None: build(default if duration is None else duration)


CASES: dict[str, Case] = {
    "jaco": Case("jaco", "Kinova Jaco (dm_control), 6-D pose circle, joint position + speed limits, 5 s",
                 _sized(jaco_circle.build, jaco_circle.DURATION), 0.25, PAIR),
    "humanoid": Case("humanoid", "CMU humanoid (dm_control), feet hard + CoM + hand + posture + limits, 3 s",
                     _sized(humanoid_reach.build, humanoid_reach.DURATION), 0.35, PAIR),
    **{f"chain{n}": Case(f"chain{n}", f"chain of {n} hinges (MjSpec), hard 6-D pose circle + posture + limits, 2 s",
                         _sized(lambda d, n=n: chain_demo(n, d), CHAIN_MOTION), 0.20, PAIR) for n in (7, 30, 60)},
    "pusher": Case("pusher", "7-DoF pusher (gymnasium), hard 6-D pose circle + posture + limits, 3 s",
                   _sized(pusher_demo, PUSHER_MOTION), 0.20, PAIR),
    "collision": Case("collision", "Jaco's hand pulled through a box, minimum distance 2 cm (native convex "
                                   "collision on), 3 s",
                      _sized(lambda d: collision_avoidance.build(d, native_ccd=True), collision_avoidance.DURATION),
                      None, {"qpik": qpik_controller,
                             "qpik (no damper)": lambda demo: _without_damper(demo).controller(SOLVER),
                             "mink": mink_controller}),
    "collision-mpr": Case("collision-mpr", "the same with the Jaco's stock flags (native convex collision off: "
                                           "mink's mesh distances from libccd's MPR), 3 s",
                          _sized(collision_avoidance.build, collision_avoidance.DURATION), None,
                          {"qpik": qpik_controller, "mink": mink_controller}),
}


def _without_damper(demo: Demo) -> Demo:
    """The demo with its collision limit's velocity damper off (mink's bound, in q̇ units)."""
    for limit in demo.limits:
        if hasattr(limit, "damper_rate"):
            limit.damper_rate = None
    return demo


def rollout(demo: Demo, controller) -> Rollout:
    return Rollout(controller, demo.reference, demo.duration, dt=demo.dt, robot_name=demo.robot.name,
                   scenario=demo.name, on_failure="stop")


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
def log_metrics(case: Case, demo: Demo, log) -> dict:
    """What one run achieved (plain floats), from its log."""
    out = {"steps": int(len(log.t)), "completed": bool(log.completed), "failure": log.failure,
           "max_error": float(np.max(log.error)), "final_error": float(log.error[-1]),
           "range_violation": float(np.max(log.limit_violation)),
           "speed_violation": speed_violation(log, _speed_bounds(demo)),
           "range_margin_min": _range_margin(demo.robot, log.q)}
    for name, series in log.extras.items():
        out[f"{name}_max"] = float(np.max(series))
        out[f"{name}_min"] = float(np.min(series))
        out[f"{name}_final"] = float(series[-1])
    if "distance" in log.extras:
        out.update(_crossing(log, collision_avoidance.MINIMUM_DISTANCE))
    return out


def _speed_bounds(demo: Demo) -> np.ndarray:
    bounds = np.full(demo.robot.nv, np.inf)
    for limit in demo.limits:
        if isinstance(limit, JointVelocityLimit):
            bounds = np.minimum(bounds, limit.max_velocity)
    return bounds


def _range_margin(robot: Robot, q: np.ndarray) -> float:
    """The smallest distance of a limited joint to its range's ends over the run (rad)."""
    limits = robot.joint_limits
    values = q[:, limits.qpos_index]
    return float(np.min(np.minimum(values - limits.lower, limits.upper - values)))


def _crossing(log, minimum: float) -> dict:
    """When the hand first came within the minimum distance, and how fast it was approaching."""
    distance = log.extras["distance"]
    inside = np.flatnonzero(distance < minimum)
    if not len(inside):
        return {"crossed_at_s": None, "approach_speed_at_crossing": None}
    k = int(inside[0])
    speed = float((distance[k - 1] - distance[k]) / log.dt) if k else float("nan")
    return {"crossed_at_s": float(log.t[k]), "approach_speed_at_crossing": speed}


def kinematics_cost_us(demo: Demo, number: int = 2000) -> float:
    """One ``robot.update_kinematics()`` (in every contender's timed step) in µs."""
    update = demo.robot.update_kinematics
    update()
    return min(timeit.repeat(update, number=number, repeat=3)) / number * 1e6


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
        call()
        return min(timeit.repeat(call, number=number, repeat=3)) / number * 1e6

    calls = controller.solver_calls
    controller.compute_velocity()
    needs_solver = controller.solver_calls > calls
    parts = {"kinematics update": cost(robot.update_kinematics)}
    for i, task in enumerate(demo.tasks):
        parts[f"task {i}: {type(task).__name__}"] = cost(task.update)
    for limit in controller.limits:
        if not limit.constant:
            rows = slice(0, limit.inequality_rows)
            parts[type(limit).__name__] = cost(lambda: limit.apply(demo.dt, controller.lb, controller.ub,
                                                                   controller.G[rows], controller.h[rows]))
    step = controller._step
    if controller._closed_form is not None:
        parts["closed-form attempt"] = cost(lambda: step.solve(controller.H, controller._Ac, controller.b))
    if needs_solver:
        backend = controller._backend
        backend.A[:], backend.b[:] = controller.A, controller.b
        parts["solver (daqp)"] = cost(lambda: backend.solve(controller.H, controller.c, hessian_changed=True))
    total = cost(lambda: (robot.update_kinematics(), controller.compute_velocity()))
    parts["rest of compute_velocity"] = total - sum(parts.values())
    return {"at_s": at, "needs_solver": needs_solver, "total_us": total, "parts_us": parts}


def compare(case: Case, logs: dict, demos: dict) -> dict:
    """The contenders' runs side by side: trajectory differences to the first (qpik)."""
    labels = list(logs)
    reference = logs[labels[0]]
    out = {}
    for label in labels[1:]:
        log = logs[label]
        n = min(len(log.q), len(reference.q))
        difference = np.abs(log.q[:n] - reference.q[:n])
        out[label] = {"q_max_difference": float(np.max(difference)),
                      "q_final_difference": float(np.max(difference[-1]))}
    return out


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
    if case.ratio_bound is not None and "timing" in result:
        ratio = result["timing"]["ratio"]
        check("step median qpik / mink (median over repeats)", ratio["median"], case.ratio_bound)
    return rows


# Running ----------------------------------------------------------------------------
def equivalence(case: Case, duration: float | None = None) -> dict:
    """Each contender once (no timing): the logs, metrics and trajectory differences."""
    demos, logs = {}, {}
    for label, make in case.contenders.items():
        demo = case.build(duration)
        run = rollout(demo, make(demo))
        run.advance()
        demos[label], logs[label] = demo, run.log()
    return {"logs": logs, "runs": {label: log_metrics(case, demos[label], log) for label, log in logs.items()},
            "differences": compare(case, logs, demos)}


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
        results.append(measure(CASES[name], args.repeats))
        for check in results[-1]["checks"]:
            if not check["holds"]:
                print(f"FAIL {name}: {check['check']} = {check['value']} (bound {check['bound']:g})", file=sys.stderr)
    markdown = to_markdown(results, meta)
    print(markdown)
    write_json(args.out / "third_party.json", {"meta": meta, "cases": results})
    write_text(args.out / "third_party.md", markdown)
    return 0


if __name__ == "__main__":
    sys.exit(main())
