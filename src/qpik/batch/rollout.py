"""Batched rollouts: N worlds stepped together, kinematically or with physics.

- ``kinematic``: q ← q ⊕ q̇Δt in every world (:meth:`Robot.integrate`).
- ``physics``: as the serial rollouts, the controller integrates its own commanded
  configuration and a physics copy of the worlds tracks it — position servos get q, the
  velocity servos q̇ — through ``mujoco.batch.Batch.step``; the measured configurations
  are returned. A world MuJoCo finds unstable ("unstable, reset") is reported.

A long run shows a tqdm bar on stderr (the ``cli`` extra) when stderr is a terminal.
"""

from __future__ import annotations

import sys
from typing import Callable

import numpy as np

from ..actuation import Actuation, substeps_per_control_step
from ..errors import InvalidInput, WorldsFailed

MODES = ("kinematic", "physics")
# A bar is drawn for runs of at least this many robot-steps.
PROGRESS_ROBOT_STEPS = 200_000


def progress_bar(total: int, enabled: bool | None, label: str):
    """A tqdm bar on stderr, or None (disabled, not a terminal, or tqdm not installed)."""
    from ..extras import installed

    if enabled is False or not installed("tqdm"):
        return None
    if enabled is None and not sys.stderr.isatty():
        return None
    from tqdm import tqdm

    return tqdm(total=total, desc=label, unit="step", file=sys.stderr, leave=False)


def rollout(controller, steps: int, *, mode: str = "kinematic", on_step: Callable[[int], None] | None = None,
            progress: bool | None = None) -> np.ndarray:
    """Run ``steps`` control steps of every world; returns the final configurations (N, nq)
    (the physics worlds' in physics mode).

    Args:
        controller: an engine controller on a :class:`~qpik.batch.Robot` (its worlds move).
        steps: the number of control periods.
        mode: ``"kinematic"`` or ``"physics"``.
        on_step: called with k before each step (move the targets there).
        progress: True draws a bar, False none, None a bar on a terminal for long runs.

    Raises:
        WorldsFailed: a world had no answer at some step (the step's answers are on the
            exception), or a physics world went unstable.
    """
    if mode not in MODES:
        raise InvalidInput(f"mode must be one of {MODES}, got {mode!r}")
    robots = controller.robot
    if not robots.batched:
        raise InvalidInput("batch.rollout steps the worlds of a batch.Robot; roll one robot out with qpik.simulate")
    dt = getattr(controller, "dt", None)
    if dt is None:
        raise InvalidInput("a rollout needs a controller with a period dt (the QP controller)")
    plant = _Plant(robots, dt) if mode == "physics" else None
    wanted = progress if progress is not None else (None if steps * robots.n >= PROGRESS_ROBOT_STEPS else False)
    bar = progress_bar(steps, wanted, f"{robots.name} x{robots.n}")
    try:
        for k in range(steps):
            if on_step is not None:
                on_step(k)
            qdot = controller.compute_velocity()
            robots.integrate(qdot, dt)
            if plant is not None:
                plant.step(qdot)
            if bar is not None:
                bar.update(1)
    finally:
        if bar is not None:
            bar.close()
    return robots.q.copy() if plant is None else plant.qpos.copy()


class _Plant:
    """The physics copy of the worlds, its servos tracking the commanded q and q̇."""

    def __init__(self, robots, dt: float):
        self.robots = robots
        self.substeps = substeps_per_control_step(robots.model, dt)
        self.actuation = Actuation(robots.model)
        self.ctrl = np.zeros((robots.n, robots.model.nu))
        self.actuation.fill(self.ctrl, robots.q, np.zeros((robots.n, robots.nv)))
        robots.backend.physics_reset(robots.q, self.ctrl)
        self.qpos = robots.q.copy()

    def step(self, qdot: np.ndarray) -> None:
        self.actuation.fill(self.ctrl, self.robots.q, qdot)
        self.qpos, unstable = self.robots.backend.physics_step(self.ctrl, self.substeps)
        if unstable.any():
            reasons = {int(w): "physics simulation unstable (MuJoCo reset the world)" for w in np.flatnonzero(unstable)}
            raise WorldsFailed(reasons, qdot, "batch rollout (physics)")
