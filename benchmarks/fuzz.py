"""Fuzz qpik's promises as an outside tester would: random rollouts and mutated models.

qpik promises, in QP mode: (a) no joint position or velocity limit crossed on the
commanded configuration (by more than 1e-9); (b) never NaN or inf; (c) every failure a
typed qpik error (a :class:`qpik.QpikError`), never another exception or a hang; (d) a
soft task with an unreachable target degrades (the run ends, bounded) instead of
raising; on the hexapod, loops kept closed on the commanded configuration (1e-4 m).

Case kinds, each case reproducible from its seed (``kind:seed``):

- ``arm``: the planar arm through the public API: random start on, near or inside the
  (randomly tightened, down to 1e-6 of their width) joint ranges; a segment to a target
  in the workspace, just outside or far outside it (up to 1 km); random gains (K up to
  3000 1/s), null-space gain, damper, hard or soft task (with or without
  Levenberg–Marquardt damping), one of the four solvers.
- ``hexapod``: the 6-PUS hexapod: random reachable start pose, stroke ranges tightened
  about the start (on, near, far from or, in one case in ten, just past the start), pose
  or position task, hard or soft, random loop and task gains, optional manipulability
  task, targets in and far outside the workspace (up to 100 m, 60°).
- ``physics``: either robot as above in physics mode, servos sometimes made up to 10⁴
  times stiffer (MuJoCo's explicit step may then blow up: a typed DivergenceError is the
  promise, not a silently reset state).
- ``model``: the bundled MJCF files mutated (NaN or reversed ranges, zero, negative,
  NaN, inf or mismatched timestep, keyframes outside the ranges or NaN, missing joints
  or sites, malformed XML, a random number replaced by NaN/inf/0/-1/1e300, actuators or
  velocity limits removed), then a scenario built on them and rolled out: a typed error
  at load or a clean run are the promise.

The sweep runs in chunks of cases in worker subprocesses; the parent times every case
and kills a worker whose case runs past ``--cap`` seconds: that case is a *hang* (its
seed recorded), the rest of the chunk goes to a fresh worker. A step over 50 ms is a
*slow step*; slow cases are re-run once at the end (a busy machine can stall one step)
and reported as confirmed only if slow again.

    nice -n 10 python benchmarks/fuzz.py --arm 1000 --hexapod 200 --physics 50 --model 50 --seed 0
    python benchmarks/fuzz.py --case arm:17        # one case, in this process, with details

writes benchmarks/results/fuzz.json (every failing case with its command) and fuzz.md
(the counts of every outcome class, per kind and per solver).
"""

from __future__ import annotations

import argparse
import json
import queue
import re
import sys
import tempfile
import time
import traceback
import warnings
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from qpik.fuzz.sweep import PROTOCOL, WorkerProcess, ending_workers_on_exit, wait_for_message

RESULTS = Path(__file__).resolve().parent / "results"
KINDS = ("arm", "hexapod", "physics", "model")
KIND_CODE = {kind: i + 1 for i, kind in enumerate(KINDS)}
ALL_SOLVERS = ("daqp", "osqp", "proxqp", "quadprog")
DT = 0.002
CROSSING_TOL = 1e-9
SLOW_STEP_S = 0.050
LOOP_TOL = 1e-4

# Outcome classes: (key, label, a defect?)
CLASSES = (
    ("ok", "completed, every promise kept", False),
    ("rejected", "typed error at load or set-up (models)", False),
    ("typed", "stopped with a typed qpik error", False),
    ("untyped", "untyped exception (not a QpikError)", True),
    ("hang", "hang (killed past the cap)", True),
    ("crash", "worker died (segfault, abort)", True),
    ("nan", "NaN or inf in the log", True),
    ("crossing", "position limit crossed > 1e-9 (commanded q)", True),
    ("speed", "velocity limit crossed > 1e-9", True),
    ("slow", "a step over 50 ms (confirmed on a re-run)", True),
    ("loop", "hexapod loop residual > 1e-4 m (commanded q)", True),
    ("soft_raised", "soft task, unreachable target: raised instead of degrading", True),
    ("soft_bounded", "soft task, unreachable target: ended bounded", False),
    ("gain_unflagged", "a gain with K·dt > 1 accepted without a warning or error", True),
)
DEFECTS = {key for key, _, bad in CLASSES if bad}


def _solvers() -> list[str]:
    from qpik.solvers import available_solvers

    return [s for s in ALL_SOLVERS if s in available_solvers()]


def _log_uniform(rng: np.random.Generator, low_exp: float, high_exp: float) -> float:
    return float(10.0 ** rng.uniform(low_exp, high_exp))


@dataclass
class Case:
    """A built case: its rollout plus what the checks need; ``params`` describes it."""

    kind: str
    seed: int
    params: dict = field(default_factory=dict)
    rollout: object = None
    soft_unreachable: bool = False
    loops: object = None  # the hexapod's loop closures (EqualityTask)
    start_inside: bool = True


# Generators ---------------------------------------------------------------------------

def _arm(rng: np.random.Generator, mode: str, params: dict) -> Case:
    from qpik import (DampingTask, JointPositionLimit, JointVelocityLimit, ManipulabilityTask, PositionReference,
                      PositionTask, QPController, Robot, Segment, SigmaProxy)
    from qpik.rollout import Rollout

    robot = Robot.load("arm")
    limits = robot.joint_limits
    ranges = {}
    if rng.random() < 0.5:
        for i, name in enumerate(limits.names):
            if rng.random() < 0.5:
                full = limits.upper[i] - limits.lower[i]
                width = full * _log_uniform(rng, -12, 0)  # down to below twice the limits' margin
                low = limits.lower[i] + rng.uniform(0.0, full - width)
                ranges[name] = (float(low), float(min(low + width, limits.upper[i])))
    tight = limits.tightened(ranges)
    start = np.empty(robot.nq)
    placements = []
    for i in range(robot.nq):
        low, high = tight.lower[i], tight.upper[i]
        where = str(rng.choice(["inside", "lower", "upper", "near lower", "near upper"],
                               p=[0.4, 0.15, 0.15, 0.15, 0.15]))
        gap = (high - low) * _log_uniform(rng, -12, -1)
        start[i] = {"inside": rng.uniform(low, high), "lower": low, "upper": high,
                    "near lower": low + gap, "near upper": high - gap}[where]
        placements.append(where)
    robot.set_q(start)
    robot.update_kinematics()
    site = robot.site_id("end_effector")
    p0 = robot.site_position(site)[:2].copy()
    target_kind = str(rng.choice(["reachable", "outside", "far"], p=[0.5, 0.3, 0.2]))
    if target_kind == "reachable":
        probe = Robot(robot.model, keyframe=None)
        probe.set_q(rng.uniform(tight.lower, tight.upper))
        probe.update_kinematics()
        target = probe.site_position(site)[:2].copy()
    else:
        angle = rng.uniform(0, 2 * np.pi)
        radius = rng.uniform(3.05, 4.0) if target_kind == "outside" else _log_uniform(rng, 1, 30)
        target = radius * np.array([np.cos(angle), np.sin(angle)])
    duration, hold = float(rng.uniform(0.1, 1.0)), float(rng.uniform(0.05, 0.5))
    law = str(rng.choice(["cubic", "quintic"]))
    hard = bool(rng.random() < 0.5)
    gain = _log_uniform(rng, -1, 4)
    lm = 0.0 if hard or rng.random() < 0.3 else _log_uniform(rng, -2, 2)
    k0 = 0.0 if rng.random() < 0.4 else _log_uniform(rng, -1, 2)
    influence = 0.0 if rng.random() < 0.5 else float(rng.uniform(0.01, 1.0))
    damper = _log_uniform(rng, -1, 2)
    solver = str(rng.choice(_solvers()))
    damping = _log_uniform(rng, -8, -1)
    params.update(robot="arm", mode=mode, gain_dt_max=gain * DT, ranges=ranges, start=start.tolist(),
                  start_placement=placements,
                  target=target.tolist(), target_kind=target_kind, duration=duration, hold=hold, law=law, hard=hard,
                  gain=gain, lm_damping=lm, k0=k0, influence=influence, damper_rate=damper, solver=solver,
                  damping=damping)
    task = PositionTask(robot, "end_effector", axes="xy", gain=gain, hard=hard, lm_damping=lm)
    measure = SigmaProxy(robot, ("theta2", "theta3"))
    second = ManipulabilityTask(robot, measure, gain=k0) if k0 else DampingTask(robot, weight=damping)
    limit_list = [JointPositionLimit(robot, tight, influence=influence, damper_rate=damper), JointVelocityLimit(robot)]
    controller = QPController(robot, [task, second], limit_list, solver=solver, dt=DT)
    reference = PositionReference(task, Segment(p0, target, duration, law))
    if mode == "physics":
        _stiffen(robot, rng, params)
    rollout = Rollout(controller, reference, duration + hold, dt=DT, mode=mode, joint_limits=tight,
                      manipulability=measure.value, on_failure="stop")
    return Case("arm", 0, params, rollout,
                soft_unreachable=mode == "kinematic" and not hard and target_kind != "reachable")


def _stiffen(robot, rng: np.random.Generator, params: dict) -> None:
    """Physics cases: servos sometimes up to 10⁴ times stiffer (MuJoCo may blow up)."""
    factor = 1.0 if rng.random() < 0.6 else _log_uniform(rng, 0, 4)
    params["servo_stiffness_factor"] = factor
    model = robot.model
    servos = model.actuator_biasprm[:, 1] < 0
    model.actuator_gainprm[servos, 0] *= factor
    model.actuator_biasprm[servos, 1] *= factor


def _random_pose(rng: np.random.Generator, hexapod, home, spread: float = 1.0):
    """A reachable pose about home (uniform in ±(8, 6, 4) cm · spread, ±10° · spread)."""
    from qpik.errors import UnreachablePose
    from qpik.robots.hexapod.kinematics import rotation_from_rpy

    for _ in range(200):
        p = home + rng.uniform(-1, 1, 3) * np.array([0.08, 0.06, 0.04]) * spread
        rpy = rng.uniform(-10, 10, 3) * spread
        try:
            strokes = hexapod.inverse_kinematics_matrix(p, rotation_from_rpy(rpy))
        except UnreachablePose:
            continue
        return p, rpy, strokes
    return home.copy(), np.zeros(3), hexapod.home_strokes.copy()


def _hexapod(rng: np.random.Generator, mode: str, params: dict) -> Case:
    from qpik import (DampingTask, FrameTask, JointPositionLimit, JointVelocityLimit, EqualityTask, PositionTask,
                      QPController, Robot, Segment)
    from qpik.robots.hexapod.control import (HexapodModel, PlatformManipulability, PlatformManipulabilityTask,
                                             PlatformReference)
    from qpik.robots.hexapod.kinematics import rotation_from_rpy
    from qpik.robots.hexapod.scene import assembly_qpos
    from qpik.rollout import Rollout
    from qpik.trajectories import PoseTrajectory

    robot = Robot.load("hexapod")
    model = HexapodModel(robot)
    hexapod = model.hexapod
    home = np.array(hexapod.geometry.home_position)
    if rng.random() < 0.3:
        p0, rpy0, strokes = home.copy(), np.zeros(3), hexapod.home_strokes.copy()
    else:
        p0, rpy0, strokes = _random_pose(rng, hexapod, home)
    robot.q[model.assembly_index] = assembly_qpos(hexapod, strokes, p0, rotation_from_rpy(rpy0))
    robot.update_kinematics()
    limits = robot.joint_limits
    ranges, start_inside = {}, True
    for i, stroke in enumerate(strokes):
        if rng.random() >= 0.4:
            continue
        name = f"slider{i + 1}"
        j = limits.names.index(name)

        def offset():
            kind = rng.choice(["on", "near", "far", "past"], p=[0.2, 0.3, 0.4, 0.1])
            return {"on": 0.0, "near": _log_uniform(rng, -12, -3), "far": rng.uniform(0.01, 0.15),
                    "past": -_log_uniform(rng, -6, -2)}[kind]

        low = max(limits.lower[j], stroke - offset())
        high = min(limits.upper[j], stroke + offset())
        if low < high:
            ranges[name] = (float(low), float(high))
            start_inside &= bool(low <= stroke <= high)
    tight = limits.tightened(ranges)
    frame = bool(rng.random() < 0.7)
    hard = bool(rng.random() < 0.5)
    gains = {"position": _log_uniform(rng, -1, 4), "orientation": _log_uniform(rng, -1, 4),
             # The loops are the mechanism's own constraints: closed dead-beat (K·dt = 1) or near
             # it; a slower gain lets every step's linearisation error accumulate, by design.
             "loops": float(rng.uniform(0.5, 1.0)) / DT}
    lm = 0.0 if hard or rng.random() < 0.3 else _log_uniform(rng, -2, 2)
    k0 = 0.0 if rng.random() < 0.8 else _log_uniform(rng, -1, 1)
    damping = _log_uniform(rng, -8, -2)
    target_kind = str(rng.choice(["reachable", "outside", "far"], p=[0.5, 0.3, 0.2]))
    if target_kind == "reachable":
        p1, rpy1, _ = _random_pose(rng, hexapod, home)
    else:
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        distance = rng.uniform(0.15, 0.5) if target_kind == "outside" else _log_uniform(rng, 0, 30)
        p1 = p0 + distance * direction
        rpy1 = rng.uniform(-60, 60, 3)
    duration, hold = float(rng.uniform(0.2, 1.0)), float(rng.uniform(0.05, 0.4))
    law = str(rng.choice(["cubic", "quintic"]))
    solver = str(rng.choice(_solvers()))
    used = [g for name, g in gains.items() if frame or name != "orientation"]  # a position task has no orientation gain
    params.update(robot="hexapod", mode=mode, gain_dt_max=max(used) * DT,
                  start_pose=p0.tolist() + rpy0.tolist(), ranges=ranges,
                  start_inside=start_inside, frame_task=frame, hard=hard, gains=gains, lm_damping=lm, k0=k0,
                  damping=damping, target_pose=p1.tolist() + np.asarray(rpy1).tolist(), target_kind=target_kind,
                  duration=duration, hold=hold, law=law, solver=solver)
    if frame:
        task = FrameTask(robot, "platform_center", position_gain=gains["position"],
                         orientation_gain=gains["orientation"], hard=hard, lm_damping=lm)
    else:
        task = PositionTask(robot, "platform_center", axes="xyz", gain=gains["position"], hard=hard, lm_damping=lm)
    loops = EqualityTask(robot, model.loop_names, gain=gains["loops"])
    tasks = [task, loops]
    if k0:
        tasks.append(PlatformManipulabilityTask(model, gain=k0))
    tasks.append(DampingTask(robot, weight=damping, joints=robot.joint_names))
    controller = QPController(robot, tasks, [JointPositionLimit(robot, tight), JointVelocityLimit(robot)],
                              solver=solver, dt=DT)
    trajectory = PoseTrajectory(Segment(p0, p1, duration, law), Segment(rpy0, rpy1, duration, law))
    reference = PlatformReference(model, task, trajectory, loops)
    if mode == "physics":
        _stiffen(robot, rng, params)
    rollout = Rollout(controller, reference, duration + hold, dt=DT, mode=mode, joint_limits=tight,
                      manipulability=PlatformManipulability(model), on_failure="stop")
    return Case("hexapod", 0, params, rollout,
                soft_unreachable=mode == "kinematic" and not hard and target_kind != "reachable",
                loops=loops, start_inside=start_inside)


# Model mutations ----------------------------------------------------------------------

_NUMBER = re.compile(r'(?<=["\s])-?\d+(?:\.\d+)?(?:e-?\d+)?(?=["\s])')
MUTATIONS = ("nan_range", "reversed_range", "timestep", "keyframe_outside", "keyframe_nan", "missing_joint",
             "missing_site", "malformed_xml", "number", "no_actuators", "no_velocity_limits")


def mutate(text: str, mutation: str, rng: np.random.Generator) -> tuple[str, str]:
    """The MJCF ``text`` with one mutation; returns it and a description."""
    def attribute_values(name):
        return [m for m in re.finditer(rf'{name}="([^"]*)"', text)]

    def replace(match, value, group=1):
        return text[: match.start(group)] + value + text[match.end(group):]

    if mutation in ("nan_range", "reversed_range"):
        m = attribute_values(r"(?<!ctrl)range")[int(rng.integers(len(attribute_values(r"(?<!ctrl)range"))))]
        low, high = m.group(1).split()
        value = {"nan_range": rng.choice([f"nan {high}", f"{low} nan", "nan nan"]),
                 "reversed_range": f"{high} {low}"}[mutation]
        return replace(m, str(value)), f"range {m.group(1)!r} -> {value!r}"
    if mutation == "timestep":
        value = str(rng.choice(["0", "-0.002", "nan", "inf", "0.003", "0.0005"]))
        return replace(attribute_values("timestep")[0], value), f"timestep -> {value}"
    if mutation in ("keyframe_outside", "keyframe_nan"):
        m = attribute_values("qpos")[0]
        values = m.group(1).split()
        i = int(rng.integers(len(values)))
        shift = float(rng.choice([-5.0, 5.0, 1.0]))
        values[i] = "nan" if mutation == "keyframe_nan" else repr(float(values[i]) + shift)
        return replace(m, " ".join(values)), f"keyframe qpos[{i}] -> {values[i]}"
    if mutation in ("missing_joint", "missing_site"):
        kind = "joint" if mutation == "missing_joint" else "site"
        names = re.findall(rf'<{kind}[^>]*name="([^"]+)"', text)
        if not names:
            return text, f"no named {kind}"
        name = str(rng.choice(names))
        return re.sub(rf'(<{kind}[^>]*name="){re.escape(name)}"', rf'\g<1>{name}_renamed"', text, count=1), \
            f"{kind} {name!r} renamed"
    if mutation == "malformed_xml":
        how = str(rng.choice(["truncate", "drop >", "garbage", "unclosed"]))
        at = int(rng.integers(len(text) // 4, len(text)))
        if how == "truncate":
            return text[:at], f"truncated at {at}"
        if how == "drop >":
            at = text.index(">", at) if ">" in text[at:] else text.rindex(">")
            return text[:at] + text[at + 1:], f"'>' at {at} dropped"
        if how == "garbage":
            return text[:at] + "<<&\x01" + text[at:], f"garbage at {at}"
        return text.replace("</worldbody>", "", 1), "</worldbody> removed"
    if mutation == "number":
        matches = list(_NUMBER.finditer(text))
        m = matches[int(rng.integers(len(matches)))]
        value = str(rng.choice(["nan", "inf", "-inf", "0", "-1", "1e300", "1e-300"]))
        return text[: m.start()] + value + text[m.end():], f"number {m.group(0)} at {m.start()} -> {value}"
    if mutation == "no_actuators":
        return re.sub(r"<actuator>.*?</actuator>", "", text, flags=re.S), "actuators removed"
    if mutation == "no_velocity_limits":
        return re.sub(r'<numeric name="qpik_velocity_limit_[^"]*"[^>]*/>', "", text), "velocity limits removed"
    raise ValueError(mutation)


def _model(rng: np.random.Generator, params: dict, folder: Path) -> Case:
    from qpik.robots import BUNDLED
    from qpik.rollout import Rollout
    from qpik.scenario import build_scenario

    robot = str(rng.choice(["arm", "hexapod"]))
    mutation = str(rng.choice(MUTATIONS))
    text, description = mutate(BUNDLED[robot][0].read_text(), mutation, rng)
    path = folder / f"mutated_{robot}.xml"
    path.write_text(text)
    scenario = "seed-redundant" if robot == "arm" else "hexapod-circle"
    mode = "physics" if rng.random() < 0.3 else "kinematic"
    solver = str(rng.choice(_solvers()))
    params.update(robot=robot, mutation=mutation, description=description, scenario=scenario, mode=mode,
                  solver=solver)
    setup = build_scenario(scenario, str(path))
    rollout = Rollout(setup.controller("qp", solver), setup.reference, 0.2, dt=setup.dt, mode=mode,
                      joint_limits=setup.joint_limits, manipulability=setup.manipulability, closure=setup.closure,
                      on_failure="stop")
    return Case("model", 0, params, rollout)


def build_case(kind: str, seed: int, folder: Path, params: dict | None = None) -> Case:
    """The case ``kind:seed`` (its description goes into ``params`` as it is drawn)."""
    rng = np.random.default_rng([KIND_CODE[kind], seed])
    params = {} if params is None else params
    try:
        if kind == "arm":
            case = _arm(rng, "kinematic", params)
        elif kind == "hexapod":
            case = _hexapod(rng, "kinematic", params)
        elif kind == "physics":
            case = (_arm if rng.random() < 0.5 else _hexapod)(rng, "physics", params)
        elif kind == "model":
            case = _model(rng, params, folder)
        else:
            raise ValueError(f"unknown case kind {kind!r}")
    finally:
        params.setdefault("kind", kind)
    case.kind, case.seed, case.params = kind, seed, params
    return case


# Running and classifying one case -----------------------------------------------------

def _loop_residual(case: Case) -> float:
    """Largest loop gap over the commanded configurations (replayed on a scratch robot)."""
    from qpik.robot import Robot

    commanded = case.rollout.q_commanded
    rows = commanded[np.all(np.isfinite(commanded), axis=1)]
    if not len(rows):
        return 0.0
    scratch = Robot(case.loops.robot.model, keyframe=None)
    worst = 0.0
    for q in rows:
        scratch.data.qpos[:] = q
        scratch.update_kinematics()
        worst = max(worst, case.loops.max_residual(scratch))
    return worst


def run_case(kind: str, seed: int, folder: Path) -> dict:
    """Build, run and classify one case: ``{"case", "classes", "details", "params"}``."""
    from qpik.errors import GainWarning

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = _run_case(kind, seed, folder)
    qpik_warnings = [str(w.message) for w in caught
                     if issubclass(w.category, GainWarning) or "qpik" in str(w.filename)]
    if qpik_warnings:
        result["details"]["warnings"] = sorted(set(qpik_warnings))[:5]
    if result["params"].get("gain_dt_max", 0.0) > 1.0 and not qpik_warnings and "rejected" not in result["classes"] \
            and not result["details"].get("set_up_error"):
        result["classes"].append("gain_unflagged")
        if "ok" in result["classes"]:
            result["classes"].remove("ok")
    return result


def _run_case(kind: str, seed: int, folder: Path) -> dict:
    from qpik.errors import QpikError

    result = {"case": f"{kind}:{seed}", "classes": [], "details": {}, "params": {}}
    classes, details = result["classes"], result["details"]
    try:
        case = build_case(kind, seed, folder, result["params"])
    except QpikError as exc:
        classes.append("rejected" if kind == "model" else "typed")
        details["error"] = f"{type(exc).__name__}: {exc}"
        details["set_up_error"] = True
        return result
    except Exception as exc:  # noqa: BLE001 - what the fuzz looks for
        classes.append("untyped")
        details["error"] = f"{type(exc).__name__}: {exc}"
        details["traceback"] = traceback.format_exc(limit=-6)
        return result
    result["params"] = case.params
    rollout = case.rollout
    try:
        rollout.advance()
        log = rollout.log()
    except QpikError as exc:
        classes.append("typed")
        details["error"] = f"{type(exc).__name__}: {exc}"
        if case.soft_unreachable:
            classes.append("soft_raised")
        return result
    except Exception as exc:  # noqa: BLE001
        classes.append("untyped")
        details["error"] = f"{type(exc).__name__}: {exc}"
        details["traceback"] = traceback.format_exc(limit=-6)
        return result
    details["steps"] = int(len(log.t))
    details["max_step_ms"] = float(np.max(log.step_time) * 1e3)
    if not log.completed:
        classes.append("typed")
        details["error"] = log.failure
    arrays = [log.q, log.qdot, log.x, log.x_des, log.error] + list(log.extras.values())
    if not all(np.all(np.isfinite(a)) for a in arrays):
        classes.append("nan")
    robot = rollout.robot
    if case.start_inside:
        crossing = float(np.max(log.commanded_violation))
        details["crossing"] = crossing
        if crossing > CROSSING_TOL:
            classes.append("crossing")
    vmax = robot.velocity_limits
    speed = float(np.max(np.abs(log.qdot) - vmax)) if np.all(np.isfinite(log.qdot)) else np.inf
    details["speed_excess"] = speed
    if speed > CROSSING_TOL:
        classes.append("speed")
    if details["max_step_ms"] > SLOW_STEP_S * 1e3:
        classes.append("slow")
    if case.loops is not None:
        residual = _loop_residual(case)
        details["loop_residual_commanded"] = residual
        if residual > LOOP_TOL:
            classes.append("loop")
    if case.soft_unreachable:  # (its speeds are checked above, as every run's)
        classes.append("soft_bounded" if log.completed and np.all(np.isfinite(log.qdot)) else "soft_raised")
    if not any(c in DEFECTS or c == "typed" for c in classes):
        classes.append("ok")
    return result


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
        super().__init__([sys.executable, __file__, "--worker", *cases], lines, index, cwd=Path(__file__).parent)


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

def _jsonable(value):
    """Nested data with every non-finite float written as a string ("inf", "nan")."""
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
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


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--arm", type=int, default=1000)
    parser.add_argument("--hexapod", type=int, default=200)
    parser.add_argument("--physics", type=int, default=50)
    parser.add_argument("--model", type=int, default=50)
    parser.add_argument("--seed", type=int, default=0, help="first seed of every kind")
    parser.add_argument("--jobs", type=int, default=1, help="worker processes at once")
    parser.add_argument("--chunk", type=int, default=25, help="cases per worker process")
    parser.add_argument("--cap", type=float, default=20.0, help="seconds a case may run before it is a hang")
    parser.add_argument("--case", help="run one case KIND:SEED here and print it")
    parser.add_argument("--all-results", action="store_true",
                        help="every case's result in fuzz.json, not only the failures")
    parser.add_argument("--worker", nargs="*", help=argparse.SUPPRESS)
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    if args.worker is not None:
        worker(args.worker)
        return 0
    if args.case:
        kind, seed = args.case.split(":")
        with tempfile.TemporaryDirectory(prefix="qpik_fuzz_") as folder:
            result = run_case(kind, int(seed), Path(folder))
        print(json.dumps(result, indent=1, default=float))
        return 1 if DEFECTS & set(result["classes"]) else 0
    from tqdm import tqdm

    case_ids = [f"{kind}:{args.seed + i}" for kind in KINDS for i in range(getattr(args, kind))]
    started = time.monotonic()
    with tqdm(total=len(case_ids), desc="fuzz", unit="case", file=sys.stderr) as bar:
        results = sweep(case_ids, args.jobs, args.chunk, args.cap, progress=bar.update)
        slow = [cid for cid, r in results.items() if "slow" in r["classes"]][:40]
        if slow:  # a busy machine can stall one step: confirm on a re-run
            bar.set_description("re-running slow cases")
            again = sweep(slow, 1, len(slow), args.cap)
            for cid in slow:
                if "slow" not in again.get(cid, {}).get("classes", []):
                    results[cid]["classes"].remove("slow")
                    results[cid]["details"]["slow_once"] = True
                    if not DEFECTS & set(results[cid]["classes"]) and "typed" not in results[cid]["classes"]:
                        results[cid]["classes"].append("ok")
    with tempfile.TemporaryDirectory(prefix="qpik_fuzz_") as folder:
        for result in results.values():  # a killed case's description: built again here, not run
            if not result["params"]:
                kind, seed = result["case"].split(":")
                try:
                    build_case(kind, int(seed), Path(folder), result["params"])
                except Exception:  # noqa: BLE001 - its description is all we want
                    pass
    summary = summarise(results)
    meta = {"seed": args.seed, "cap_s": args.cap, "jobs": args.jobs, "chunk": args.chunk,
            "elapsed_s": time.monotonic() - started, "solvers": _solvers(), "python": sys.version.split()[0],
            "command": "python benchmarks/fuzz.py " + " ".join(f"--{k} {getattr(args, k)}" for k in KINDS)
                       + f" --seed {args.seed}"}
    md = to_markdown(summary, meta)
    print(md)
    from qpik.io import write_json, write_text

    everything = {"results": sorted(results.values(), key=lambda r: r["case"])} if args.all_results else {}
    write_json(args.out / "fuzz.json", _jsonable({"meta": meta, **summary, **everything}))
    write_text(args.out / "fuzz.md", md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
