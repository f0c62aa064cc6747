"""Equality constraints of the model (closed kinematic chains) as task rows."""

from __future__ import annotations

from typing import Sequence

import mujoco
import numpy as np

from ..errors import ModelError, UnknownName
from ..robot import Robot
from .task import Task


class LoopClosureTask(Task):
    """Closed kinematic chains: MuJoCo ``connect`` equalities as hard rows J_c q̇ = −K_c e_c.

    The residual e_c = p1 − p2 (the two anchor points in world) and its Jacobian
    J_c = J(p1) − J(p2) are computed from the kinematics update alone (``mj_jacSite`` /
    ``mj_jac``), without running MuJoCo's constraint pipeline.
    """

    name = "loop closure"

    def __init__(self, robot: Robot, equalities: Sequence[str] | None = None, gain: float = 1.0):
        model = robot.model
        if equalities is None:
            ids = list(range(model.neq))
        else:
            ids = []
            for name in equalities:
                eq = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_EQUALITY, name)
                if eq < 0:
                    raise UnknownName(f"unknown equality constraint {name!r}")
                ids.append(eq)
        if not ids:
            raise ModelError("the model has no equality constraints to close")
        for eq in ids:
            if model.eq_type[eq] != mujoco.mjtEq.mjEQ_CONNECT:
                raise ModelError(f"equality {eq} is not a 'connect' constraint")
        n = len(ids)
        super().__init__(robot, 3 * n, weight=1.0, hard=True)
        self.gain = float(gain)
        self.equalities = tuple(ids)  # model equality ids, in row order
        self._sites = all(model.eq_objtype[eq] == mujoco.mjtObj.mjOBJ_SITE for eq in ids)
        self._obj1 = np.array([model.eq_obj1id[eq] for eq in ids], dtype=int)
        self._obj2 = np.array([model.eq_obj2id[eq] for eq in ids], dtype=int)
        if not self._sites and any(model.eq_objtype[eq] == mujoco.mjtObj.mjOBJ_SITE for eq in ids):
            raise ModelError("mixing site- and body-based connect constraints is not supported")
        # Body-based connects: the anchors in each body's frame (MuJoCo's eq_data layout).
        self._anchor1 = np.array([model.eq_data[eq][0:3] for eq in ids])
        self._anchor2 = np.array([model.eq_data[eq][3:6] for eq in ids])
        self._jac1 = np.zeros((n, 3, robot.nv))
        self._jac2 = np.zeros((n, 3, robot.nv))
        self._jac_rows = self.jacobian.reshape(n, 3, robot.nv)
        self._error_rows = self.error.reshape(n, 3)

    def _points(self, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray]:
        if self._sites:
            return data.site_xpos[self._obj1], data.site_xpos[self._obj2]
        p1 = data.xpos[self._obj1] + np.einsum("kij,kj->ki", data.xmat[self._obj1].reshape(-1, 3, 3), self._anchor1)
        p2 = data.xpos[self._obj2] + np.einsum("kij,kj->ki", data.xmat[self._obj2].reshape(-1, 3, 3), self._anchor2)
        return p1, p2

    def update(self) -> None:
        model, data = self.robot.model, self.robot.data
        p1, p2 = self._points(data)
        np.subtract(p1, p2, out=self._error_rows)
        if self._sites:
            for k in range(len(self._obj1)):
                mujoco.mj_jacSite(model, data, self._jac1[k], None, self._obj1[k])
                mujoco.mj_jacSite(model, data, self._jac2[k], None, self._obj2[k])
        else:
            for k in range(len(self._obj1)):
                mujoco.mj_jac(model, data, self._jac1[k], None, p1[k], self._obj1[k])
                mujoco.mj_jac(model, data, self._jac2[k], None, p2[k], self._obj2[k])
        np.subtract(self._jac1, self._jac2, out=self._jac_rows)
        np.multiply(-self.gain, self.error, out=self.target_velocity)

    def max_residual(self, robot: Robot | None = None) -> float:
        """Largest loop-closure gap (m) on the bound robot, or another of the same model."""
        p1, p2 = self._points((robot or self.robot).data)
        return float(np.max(np.linalg.norm(p1 - p2, axis=1)))
