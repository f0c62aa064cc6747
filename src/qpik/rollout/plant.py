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

from ..actuation import Actuation, substeps_per_control_step
from ..robot import Robot

# MuJoCo's warnings that mean the simulated state is no longer trustworthy.
# Each with what MuJoCo's ``lastinfo`` then indexes.
_INSTABILITY_WARNINGS = {
    int(mujoco.mjtWarning.mjWARN_BADQPOS): ("NaN or huge position", "qpos index"),
    int(mujoco.mjtWarning.mjWARN_BADQVEL): ("NaN or huge velocity", "dof"),
    int(mujoco.mjtWarning.mjWARN_BADQACC): ("NaN or huge acceleration", "dof"),
    int(mujoco.mjtWarning.mjWARN_BADCTRL): ("NaN or huge control", "actuator"),
}


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
