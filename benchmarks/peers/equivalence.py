"""One problem rolled out by qpik and by mink's exact mirror of it, side by side.

A *problem* is anything with ``name``, ``robot``, ``tasks``, ``limits``, ``reference``,
``dt``, ``duration``, ``regularization``, ``moving`` and ``controller(solver)`` (the
examples' ``Demo``); a fresh one is built for each contender, whose controller a
*contender* function makes from it. :func:`equivalence` rolls each out (untimed) and
gives their logs, what each achieved (:func:`log_metrics`) and how far their
trajectories differ from the first contender's. benchmarks/third_party.py times the
same problems; the tests check the equivalence on shortened runs.
"""

from __future__ import annotations

from typing import Callable, Mapping

import numpy as np

from qpik.limits import CollisionAvoidanceLimit, JointVelocityLimit
from qpik.robot import Robot
from qpik.rollout import Rollout, RolloutLog

from .mink_mirror import MinkMirror

SOLVER = "daqp"


def qpik_controller(problem):
    """qpik's QPController on the problem."""
    return problem.controller(SOLVER)


def mink_controller(problem):
    """mink on the same QP (:class:`~benchmarks.peers.mink_mirror.MinkMirror`)."""
    return MinkMirror(problem.robot, problem.tasks, problem.limits, problem.dt, solver=SOLVER,
                      regularization=problem.regularization, moving=problem.moving)


def without_damper(problem):
    """The problem with its collision limit's velocity damper off (mink's bound, in q̇ units)."""
    for limit in problem.limits:
        if hasattr(limit, "damper_rate"):
            limit.damper_rate = None
    return problem


# qpik against mink, the pair most problems compare.
PAIR = {"qpik": qpik_controller, "mink": mink_controller}


def rollout(problem, controller) -> Rollout:
    return Rollout(controller, problem.reference, problem.duration, dt=problem.dt, robot_name=problem.robot.name,
                   scenario=problem.name, on_failure="stop")


def equivalence(build: Callable[[float | None], object], contenders: Mapping[str, Callable],
                duration: float | None = None) -> dict:
    """Each contender once on a fresh ``build(duration)`` (no timing): ``{"logs", "runs"
    (each one's :func:`log_metrics`), "differences" (each but the first against the
    first: largest and final |q| difference)}``."""
    problems, logs = {}, {}
    for label, make in contenders.items():
        problem = build(duration)
        run = rollout(problem, make(problem))
        run.advance()
        problems[label], logs[label] = problem, run.log()
    return {"logs": logs, "runs": {label: log_metrics(problems[label], log) for label, log in logs.items()},
            "differences": differences(logs)}


def differences(logs: Mapping[str, RolloutLog]) -> dict:
    """Each run's trajectory against the first's: the largest and the final |q| difference."""
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


def log_metrics(problem, log: RolloutLog) -> dict:
    """What one run achieved (plain floats), from its log: errors, range and speed
    violations, the closest approach to a range end, each extra series' extremes and,
    with a collision limit, when the minimum distance was first crossed."""
    out = {"steps": int(len(log.t)), "completed": bool(log.completed), "failure": log.failure,
           "max_error": float(np.max(log.error)), "final_error": float(log.error[-1]),
           "range_violation": float(np.max(log.limit_violation)),
           "speed_violation": speed_violation(log, speed_bounds(problem.limits, problem.robot.nv)),
           "range_margin_min": _range_margin(problem.robot, log.q)}
    for name, series in log.extras.items():
        out[f"{name}_max"] = float(np.max(series))
        out[f"{name}_min"] = float(np.min(series))
        out[f"{name}_final"] = float(series[-1])
    collision = next((limit for limit in problem.limits if isinstance(limit, CollisionAvoidanceLimit)), None)
    if "distance" in log.extras and collision is not None:
        out.update(_crossing(log, collision.minimum_distance))
    return out


def speed_bounds(limits, nv: int) -> np.ndarray:
    """The tightest speed bound of each dof over the velocity limits (inf: none)."""
    bounds = np.full(nv, np.inf)
    for limit in limits:
        if isinstance(limit, JointVelocityLimit):
            bounds = np.minimum(bounds, limit.max_velocity)
    return bounds


def speed_violation(log: RolloutLog, max_velocity: np.ndarray) -> float:
    """Largest joint speed beyond its bound over the run (0.0 when all are kept)."""
    excess = np.abs(log.qdot) - max_velocity
    return float(max(0.0, np.max(excess[:, np.isfinite(max_velocity)], initial=0.0)))


def _range_margin(robot: Robot, q: np.ndarray) -> float:
    """The smallest distance of a limited joint to its range's ends over the run (rad)."""
    limits = robot.joint_limits
    values = q[:, limits.qpos_index]
    return float(np.min(np.minimum(values - limits.lower, limits.upper - values)))


def _crossing(log: RolloutLog, minimum: float) -> dict:
    """When the hand first came within the minimum distance, and how fast it was approaching."""
    distance = log.extras["distance"]
    inside = np.flatnonzero(distance < minimum)
    if not len(inside):
        return {"crossed_at_s": None, "approach_speed_at_crossing": None}
    k = int(inside[0])
    speed = float((distance[k - 1] - distance[k]) / log.info.dt) if k else float("nan")
    return {"crossed_at_s": float(log.t[k]), "approach_speed_at_crossing": speed}
