"""The physics plant: a second MjData on the controller's model whose joint servos track
the commanded configuration and velocity through ``mj_step``.

MuJoCo does not raise when a simulation blows up: ``mj_step`` checks the state, and on a
NaN or huge position, velocity or acceleration it *resets the data* to the model's
reference configuration, counts a warning (``data.warning``) and carries on ("unstable,
reset"). A rollout would go on from the reset state as if nothing happened. The plant
reads those counters after every control step and reports the first increase, naming the
warning, so the rollout stops with a :class:`~qpik.errors.DivergenceError`.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from ..errors import InvalidInput, ModelError
from ..robot import Robot

# MuJoCo's warnings that mean the simulated state is no longer trustworthy.
# Each with what MuJoCo's ``lastinfo`` then indexes.
_INSTABILITY_WARNINGS = {
    int(mujoco.mjtWarning.mjWARN_BADQPOS): ("NaN or huge position", "qpos index"),
    int(mujoco.mjtWarning.mjWARN_BADQVEL): ("NaN or huge velocity", "dof"),
    int(mujoco.mjtWarning.mjWARN_BADQACC): ("NaN or huge acceleration", "dof"),
    int(mujoco.mjtWarning.mjWARN_BADCTRL): ("NaN or huge control", "actuator"),
}


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
        data.ctrl[self.pos_act] = q_cmd[self.pos_q]
        if len(self.vel_act):
            data.ctrl[self.vel_act] = qdot_cmd[self.vel_dof]


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


class PhysicsPlant:
    """The simulated robot a physics rollout measures.

    Args:
        robot: the controller's robot; the plant copies its model and configuration.
        dt: the control period (a multiple of the model's timestep).

    Raises:
        ModelError: no position actuators, or a timestep that is not positive and finite.
        InvalidInput: ``dt`` is not a multiple of the timestep.
    """

    def __init__(self, robot: Robot, dt: float):
        self.substeps = substeps_per_control_step(robot.model, dt)
        self.actuation = Actuation(robot.model)
        self.robot = Robot(robot.model, name=robot.name, keyframe=None)
        model, data = self.robot.model, self.robot.data
        data.qpos[:] = robot.q
        self.actuation.write(data, robot.q, np.zeros(robot.nv))
        mujoco.mj_forward(model, data)
        self._counts = data.warning.number  # a live view of MuJoCo's warning counters
        self._seen = self._counts.copy()
        self._seen_bytes = self._counts.tobytes()  # compared per step: ~0.2 µs

    def step(self, q_cmd: np.ndarray, qdot_cmd: np.ndarray) -> str:
        """Track the command for one control period; ``""``, or what went wrong."""
        model, data = self.robot.model, self.robot.data
        self.actuation.write(data, q_cmd, qdot_cmd)
        for _ in range(self.substeps):
            mujoco.mj_step(model, data)
        if self._counts.tobytes() != self._seen_bytes:
            return self._instability()
        if not math.isfinite(mujoco.mju_sum(data.qpos)):
            return "physics simulation diverged (non-finite state)"
        return ""

    def _instability(self) -> str:
        new = np.flatnonzero(self._counts != self._seen)
        self._seen[:] = self._counts
        self._seen_bytes = self._counts.tobytes()
        unstable = [i for i in new if i in _INSTABILITY_WARNINGS]
        if not unstable:  # e.g. a full contact buffer: MuJoCo's warning only, the state is fine
            return ""
        data = self.robot.data
        what = "; ".join(f"{_INSTABILITY_WARNINGS[i][0]} at {_INSTABILITY_WARNINGS[i][1]} {data.warning[i].lastinfo}"
                         for i in unstable)
        return f"physics simulation unstable, MuJoCo reset its state: {what}"
