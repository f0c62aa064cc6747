"""One chunk: a batched controller rolled out over its worlds, and what each world did.

Every world runs ``steps`` control steps of ``DT`` (by default ``STEPS``: the reference
moves ``MOVE`` s, then holds ``HOLD`` s). A world whose step has no answer (an
infeasible QP, a singular pseudoinverse) stops there, as ``qpik run`` stops a run: its
configuration is frozen (its target held there, its velocity zero). What is measured, per
world, over the steps it ran:

- ``max_error``: the largest tracking error |x_ref(t) − x| (m, the position rows);
- ``final_error``: |x_target − x| at the end (m); ``final_orientation_error`` (rad) on
  the hexapod;
- ``converge_time``: the first time from which |x_target − x| ≤ ``REACH_TOLERANCE`` for
  good (s; NaN when the world ends farther);
- ``range_violation``: the largest excess of a joint beyond its range (rad or m, 0 inside);
- ``speed_violation``: the largest excess of a commanded joint speed over its limit;
- ``peak_speed``: each dof's largest commanded |q̇| (nv,);
- ``loop_residual``: the largest loop-closure gap (m, the hexapod; 0 on the arm);
- ``stopped_at``: the step where the world stopped (−1: it ran to the end), and
  ``stop_reason`` (:data:`STOP_REASONS`).
"""

from __future__ import annotations

import numpy as np

from .studies import DT, HOLD, MOVE, steps_of

REACH_TOLERANCE = 1e-3  # m: benchmarks/monte_carlo.py's success error
STOP_REASONS = ("none", "infeasible", "singular", "other")


def stop_code(reason: str) -> int:
    if "infeasible" in reason:
        return 1
    if "singular" in reason or "diverged" in reason:
        return 2
    return 3


class Recorder:
    """Running per-world maxima over the steps, vectorised."""

    def __init__(self, study, built, samples, steps: int):
        robots = built.robots
        n = robots.n
        self.study, self.built, self.samples = study, built, samples
        self.target = samples["target"][:, :study.position_dims]
        self.steps = steps
        self.limits = robots.joint_limits
        self.vmax = robots.velocity_limits
        self.max_error = np.zeros(n)
        self.range_violation = np.zeros(n)
        self.speed_violation = np.zeros(n)
        self.peak_speed = np.zeros((n, robots.nv))
        self.loop_residual = np.zeros(n)
        self.last_far = np.full(n, -1)
        self.stopped_at = np.full(n, -1, dtype=np.int32)
        self.stop_reason = np.zeros(n, dtype=np.int8)
        self.running = np.ones(n, dtype=bool)

    def before_step(self, k: int, reference: np.ndarray) -> None:
        """The state at step k (kinematics current): tracking error, distance to the target."""
        x = self.study.position(self.built)
        error = np.linalg.norm(reference - x, axis=1)
        self.max_error = np.where(self.running, np.maximum(self.max_error, error), self.max_error)
        self._far(k, x)
        loops = self.built.loops
        if loops is not None:
            gap = np.linalg.norm(loops.error.reshape(len(x), -1, 3), axis=2).max(axis=1)
            self.loop_residual = np.where(self.running, np.maximum(self.loop_residual, gap), self.loop_residual)

    def _far(self, k: int, x: np.ndarray) -> None:
        far = self.running & (np.linalg.norm(self.target - x, axis=1) > REACH_TOLERANCE)
        self.last_far[far] = k

    def stop(self, k: int, reasons: dict[int, str]) -> None:
        for world, reason in reasons.items():
            if self.running[world]:
                self.running[world] = False
                self.stopped_at[world] = k
                self.stop_reason[world] = stop_code(reason)

    def after_step(self, qdot: np.ndarray) -> None:
        speed = np.abs(qdot)
        np.maximum(self.peak_speed, speed, out=self.peak_speed)
        self.speed_violation = np.maximum(self.speed_violation, (speed - self.vmax).max(axis=1))
        q = self.built.robots.q[:, self.limits.qpos_index]
        excess = np.maximum(self.limits.lower - q, q - self.limits.upper).max(axis=1, initial=0.0)
        self.range_violation = np.maximum(self.range_violation, excess)

    def result(self) -> dict[str, np.ndarray]:
        built = self.built
        built.robots.update_kinematics()
        x = self.study.position(built)
        self._far(self.steps, x)
        final_error = np.linalg.norm(self.target - x, axis=1)
        converged = self.running & (final_error <= REACH_TOLERANCE)
        out = {
            "max_error": self.max_error, "final_error": final_error,
            "converge_time": np.where(converged, (self.last_far + 1) * DT, np.nan),
            "range_violation": self.range_violation, "speed_violation": np.maximum(self.speed_violation, 0.0),
            "peak_speed": self.peak_speed, "loop_residual": self.loop_residual,
            "stopped_at": self.stopped_at, "stop_reason": self.stop_reason,
        }
        if self.study.name == "hexapod":
            from ...numerics import rotation_error
            from ...trajectories import rpy_rotations_and_rates

            rpy = self.samples["target"][:, 3:]
            target = rpy_rotations_and_rates(rpy, np.zeros_like(rpy))[0]
            out["final_orientation_error"] = np.linalg.norm(rotation_error(target, built.task.frame.rotation), axis=1)
        return out


def run_chunk(study, kind: str, samples: dict[str, np.ndarray], nthread: int | None = None, move: float = MOVE,
              hold: float = HOLD) -> dict[str, np.ndarray]:
    """Roll controller ``kind`` out over the worlds of ``samples``; every world's metrics."""
    from ...batch import WorldsFailed

    steps = steps_of(move, hold)
    built = study.build(kind, samples, nthread)
    reference = study.reference(built, samples, move)
    recorder = Recorder(study, built, samples, steps)
    for k in range(steps):
        t = k * DT
        study.set_reference(built, reference, t, ~recorder.running)
        try:
            qdot = built.controller.compute_velocity().copy()
        except WorldsFailed as failed:
            qdot = failed.qdot.copy()
            recorder.stop(k, failed.reasons)
        qdot[~recorder.running] = 0.0  # a stopped world stays where it stopped
        recorder.before_step(k, reference.at(t)[0])
        built.robots.integrate(qdot, DT)
        recorder.after_step(qdot)
    return recorder.result()
