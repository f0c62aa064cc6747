"""The bundled robots' fuzz: random rollouts and mutated models, each case from its seed.

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

:func:`run_case` builds, runs and classifies one case; :mod:`.bundled_sweep`
runs many in worker processes with a hang detector and summarises them. The benchmark
``benchmarks/fuzz_bundled.py`` is their command line; the test suite runs a few dozen cases.
"""

from __future__ import annotations

import re
import traceback
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from qpik import (DampingTask, EqualityTask, FrameTask, JointPositionLimit, JointVelocityLimit, ManipulabilityTask,
                  PositionReference, PositionTask, QPController, Robot, Segment, SigmaProxy)
from qpik.errors import GainWarning, QpikError, UnreachablePose
from qpik.robots import BUNDLED
from qpik.robots.hexapod.control import (HexapodModel, PlatformManipulability, PlatformManipulabilityTask,
                                      PlatformReference)
from qpik.robots.hexapod.kinematics import rotation_from_rpy
from qpik.robots.hexapod.scene import assembly_qpos
from qpik.rollout import Rollout
from qpik.scenario import build_scenario
from qpik.solvers import available_solvers
from qpik.trajectories import PoseTrajectory

from .checks import box_and_rows, lp_feasible

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


def installed_solvers() -> list[str]:
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
    solver = str(rng.choice(installed_solvers()))
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
    solver = str(rng.choice(installed_solvers()))
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
        return _malformed(text, rng)
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


def _malformed(text: str, rng: np.random.Generator) -> tuple[str, str]:
    """The MJCF ``text`` made invalid XML: truncated, a '>' dropped, garbage, a tag unclosed."""
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


def _model(rng: np.random.Generator, params: dict, folder: Path) -> Case:
    robot = str(rng.choice(["arm", "hexapod"]))
    mutation = str(rng.choice(MUTATIONS))
    text, description = mutate(BUNDLED[robot][0].read_text(), mutation, rng)
    path = folder / f"mutated_{robot}.xml"
    path.write_text(text)
    scenario = "seed-redundant" if robot == "arm" else "hexapod-circle"
    mode = "physics" if rng.random() < 0.3 else "kinematic"
    solver = str(rng.choice(installed_solvers()))
    params.update(robot=robot, mutation=mutation, description=description, scenario=scenario, mode=mode,
                  solver=solver)
    setup = build_scenario(scenario, str(path))
    rollout = setup.rollout(setup.controller("qp", solver), mode=mode, on_failure="stop", duration=0.2)
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
        _untyped(details, classes, exc)
        return result
    result["params"] = case.params
    try:
        case.rollout.advance()
        log = case.rollout.log()
    except QpikError as exc:
        classes.append("typed")
        details["error"] = f"{type(exc).__name__}: {exc}"
        if case.soft_unreachable and not _hard_part_infeasible(case, details):
            classes.append("soft_raised")
        return result
    except Exception as exc:  # noqa: BLE001
        _untyped(details, classes, exc)
        return result
    _classify(case, log, classes, details)
    return result


def _hard_part_infeasible(case: Case, details: dict) -> bool:
    """Whether the step the rollout stopped on has no point that meets its hard rows and
    limits, by an independent LP (:func:`~.checks.lp_feasible`, no margin): a raise there
    is the promise, whatever the soft task asks (a hexapod slider started outside the range
    the case gives it, its loops closed: hexapod:1803 and 1827)."""
    controller = case.rollout.controller
    hard = [task for task in controller.tasks if task.hard]
    A, b, lb, ub, G, h = box_and_rows(controller.robot, hard, controller.limits, controller.dt)
    details["hard_part_infeasible"] = infeasible = not lp_feasible(A, b, lb, ub, G, h, margin=False)
    return infeasible


def _untyped(details: dict, classes: list, exc: Exception) -> None:
    classes.append("untyped")
    details["error"] = f"{type(exc).__name__}: {exc}"
    details["traceback"] = traceback.format_exc(limit=-6)


def _classify(case: Case, log, classes: list, details: dict) -> None:
    """The classes of a rollout that ran: each promise checked on its log."""
    details["steps"] = int(len(log.t))
    details["max_step_ms"] = float(np.max(log.step_time) * 1e3)
    if not log.completed:
        classes.append("typed")
        details["error"] = log.failure
    arrays = [log.q, log.qdot, log.x, log.x_des, log.error] + list(log.extras.values())
    if not all(np.all(np.isfinite(a)) for a in arrays):
        classes.append("nan")
    if case.start_inside:
        crossing = float(np.max(log.commanded_violation))
        details["crossing"] = crossing
        if crossing > CROSSING_TOL:
            classes.append("crossing")
    vmax = case.rollout.robot.velocity_limits
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
        if log.completed and np.all(np.isfinite(log.qdot)):
            classes.append("soft_bounded")
        elif not _hard_part_infeasible(case, details):
            classes.append("soft_raised")
    if not any(c in DEFECTS or c == "typed" for c in classes):
        classes.append("ok")
