"""How a physics copy of a model is driven: its joint servos fed the commanded
configuration and velocity, and the number of ``mj_step`` in one control period.

Shared by the serial physics plant (:mod:`qpik.rollout.plant`) and the batched rollouts
(:mod:`qpik.batch.rollout`); it lives here, below both, so that the batched engine
imports nothing from the rollouts above it.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from .errors import InvalidInput, ModelError


class Actuation:
    """Maps a commanded configuration and velocity onto the plant's joint actuators."""

    def __init__(self, model: mujoco.MjModel):
        pos_act, pos_q, vel_act, vel_dof = [], [], [], []
        for a in range(model.nu):
            if model.actuator_trntype[a] != mujoco.mjtTrn.mjTRN_JOINT:
                continue
            joint = model.actuator_trnid[a, 0]
            bias = model.actuator_biasprm[a]
            if bias[1] < 0:  # position servo: force = kp (ctrl - q) - kv q̇
                pos_act.append(a)
                pos_q.append(model.jnt_qposadr[joint])
            elif bias[1] == 0 and bias[2] < 0:  # velocity servo: kv (ctrl - q̇)
                vel_act.append(a)
                vel_dof.append(model.jnt_dofadr[joint])
        if not pos_act:
            raise ModelError("physics mode needs position actuators on the joints; the model has none")
        self.pos_act, self.pos_q = np.array(pos_act), np.array(pos_q)
        self.vel_act, self.vel_dof = np.array(vel_act, dtype=int), np.array(vel_dof, dtype=int)

    def write(self, data: mujoco.MjData, q_cmd: np.ndarray, qdot_cmd: np.ndarray) -> None:
        self.fill(data.ctrl, q_cmd, qdot_cmd)

    def fill(self, ctrl: np.ndarray, q_cmd: np.ndarray, qdot_cmd: np.ndarray) -> None:
        """The servos' controls ``ctrl`` (..., nu) from commands (..., nq) and (..., nv): one
        world's or N worlds' (the leading axes)."""
        ctrl[..., self.pos_act] = q_cmd[..., self.pos_q]
        if len(self.vel_act):
            ctrl[..., self.vel_act] = qdot_cmd[..., self.vel_dof]


def substeps_per_control_step(model: mujoco.MjModel, dt: float) -> int:
    """How many ``mj_step`` make one control period ``dt``.

    Raises:
        ModelError: the model's timestep is not positive and finite.
        InvalidInput: ``dt`` is not a multiple of the timestep.
    """
    timestep = float(model.opt.timestep)
    if not (math.isfinite(timestep) and timestep > 0.0):
        raise ModelError(f"physics mode needs a positive, finite model timestep, got {timestep}")
    substeps = max(1, int(round(dt / timestep)))
    if abs(substeps * timestep - dt) > 1e-12:
        raise InvalidInput(f"dt={dt} is not a multiple of the model timestep {timestep}")
    return substeps
