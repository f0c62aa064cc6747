r"""MuJoCo's equality constraints (closed chains, welds, coupled joints and tendons) as task rows."""

from __future__ import annotations

from typing import Sequence

import mujoco
import numpy as np

from ..equalities import SUPPORTED, make_equality_rows
from ..errors import InvalidInput, ModelError
from ..robot import Robot
from .task import Task, positive_scalar

class EqualityTask(Task):
    r"""The model's equality constraints (``connect``, ``weld``, ``joint``, ``tendon``) as rows

    .. math::
        J_e\,\dot q = -K\,e_e,

    hard (the default: closed kinematic chains stay closed) or soft. :math:`e_e` and
    :math:`J_e` are MuJoCo's own constraint residual and Jacobian (``efc_pos``,
    ``efc_J``), made by ``mj_makeConstraint`` from the step's kinematics update with
    every other constraint type disabled for the call: a ``connect`` gives the 3 rows
    :math:`p_1 - p_2`, a ``weld`` 6 (position, then orientation scaled by its
    ``torquescale``), a ``joint`` or ``tendon`` coupling 1 (its polynomial residual).
    Sparse Jacobians (large models) are expanded with ``mju_sparse2dense``. Rows follow
    the equalities' ids.

    ``error`` holds the residual :math:`e_e` (zero when the constraints hold).

    Args:
        robot: the robot.
        equalities: names of the equalities to enforce (default: every equality active
            when the task is built, ``data.eq_active``, that acts on a dof: MuJoCo makes
            no row for one that does not, such as a weld of a jointless body to the world).
        gain: K (1/s); by default 1/Δt of the controller the task is given to
            (dead-beat): the rows J_e q̇ = −e_e/Δt remove the whole residual in one step, so
            the commanded configuration meets the constraints up to the step's second-order
            (linearisation) error. A smaller K leaves a fraction (1 − KΔt) of each step's
            residual behind, and those second-order errors accumulate.
        hard: enforce the rows as equalities in the QP (else weighed in the cost).
        weight: cost weight of a soft task, a scalar or one per row.

    Raises:
        UnknownName: an unknown equality name (the closest are listed).
        ModelError: no active equality, an inactive one or one that acts on no dof
            named, or a type other than connect, weld, joint and tendon (flex equalities
            are not supported).
        InvalidInput: a gain that is not a finite number >= 0.

    The set of active equalities is read when the task is built; switching one on or off
    later (``data.eq_active``) makes :meth:`update` raise ModelError.
    """

    name = "equality task"

    def __init__(self, robot: Robot, equalities: Sequence[str] | None = None, gain: float | None = None,
                 hard: bool = True, weight=1.0):
        model, data = robot.model, robot.data
        active = [i for i in range(model.neq) if data.eq_active[i]]
        if equalities is None:
            ids = active
        else:
            if isinstance(equalities, str):
                raise InvalidInput(f"equalities must be a list of names, got the string {equalities!r}")
            ids = [robot.equality_id(name) for name in equalities]
            if len(set(ids)) != len(ids):
                raise InvalidInput(f"an equality is named twice in {list(equalities)}")
            inactive = [name for name, i in zip(equalities, ids) if i not in active]
            if inactive:
                raise ModelError(f"{self.name}: equalities {inactive} are inactive (data.eq_active)")
            ids = sorted(ids)
        if not ids:
            raise ModelError(f"{self.name}: model {robot.name!r} has no active equality constraint")
        for i in ids:
            if int(model.eq_type[i]) not in SUPPORTED:
                label = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_EQUALITY, i) or f"#{i}"
                kind = mujoco.mjtEq(int(model.eq_type[i])).name
                raise ModelError(f"{self.name}: equality {label!r} is a {kind}; supported: "
                                 f"{[name for name, _ in SUPPORTED.values()]}")
        if gain is not None:
            gain = positive_scalar(gain, f"{self.name} gain", allow_zero=True)
        # MuJoCo makes an active tendon equality's row from the tendon Jacobian of the last
        # mj_tendon, whether or not the task holds it: the row count must not depend on that.
        self._tendons = any(int(model.eq_type[i]) == int(mujoco.mjtEq.mjEQ_TENDON) for i in active)
        self._sparse = bool(mujoco.mj_isSparse(model))
        # Where each equality's rows lie among MuJoCo's equality rows (read once).
        robot.update_kinematics()
        make_equality_rows(model, data, self._tendons)
        self._ne = int(data.ne)
        efc_id = np.array(data.efc_id[: self._ne])
        ids = self._acting(robot, ids, efc_id, named=equalities is not None)
        self.equalities = tuple(ids)  # model equality ids, in row order
        rows = np.flatnonzero(np.isin(efc_id, ids))
        super().__init__(robot, len(rows), weight, hard)
        self.dead_beat = gain is None
        self.gain = np.nan if gain is None else gain  # set by attach() when dead-beat
        self._rows = rows
        self._all_rows = len(rows) == self._ne
        self._dense = None if self._all_rows and self._sparse else np.zeros((self._ne, robot.nv))
        self._slices = []  # per equality: its slice of the task's rows
        for i in ids:
            where = np.flatnonzero(efc_id[rows] == i)
            self._slices.append(slice(int(where[0]), int(where[-1]) + 1))
        self._scratch = None
        self._opt, self._data = model.opt, data  # read once: MuJoCo's getters make new objects
        self._rows_size = self._ne * robot.nv  # efc_J's buffer may be longer than its ne x nv dense rows
        self._flat_jacobian = self.jacobian.reshape(-1)

    def _acting(self, robot: Robot, ids: list[int], efc_id: np.ndarray, named: bool) -> list[int]:
        """The equalities MuJoCo makes rows for: one that acts on no dof (a weld of a
        jointless body to the world) has none, and no velocity can change its residual;
        left out of the default set, refused when named."""
        idle = [i for i in ids if i not in efc_id]
        if idle and named:
            labels = [mujoco.mj_id2name(robot.model, mujoco.mjtObj.mjOBJ_EQUALITY, i) or f"#{i}" for i in idle]
            raise ModelError(f"{self.name}: equalities {labels} act on no dof (their bodies, joints or "
                             "tendons move with no joint): MuJoCo makes no row for them")
        acting = [i for i in ids if i not in idle]
        if not acting:
            raise ModelError(f"{self.name}: model {robot.name!r} has no active equality constraint that acts "
                             "on a dof")
        return acting

    @property
    def gain(self) -> float:
        """K (1/s); NaN until a controller gives its period when dead-beat."""
        return self._gain

    @gain.setter
    def gain(self, value: float) -> None:
        self._gain = value
        self._neg_k = np.array(-value)  # a 0-d array: NumPy multiplies by it faster than by a float

    def feedback_gains(self) -> np.ndarray:
        return np.full(self.dim, self.gain)

    def attach(self, dt: float | None) -> None:
        if self.dead_beat and dt is not None:
            self.gain = 1.0 / dt
        super().attach(dt)

    @property
    def needs_period(self) -> bool:
        """Whether the gain is still to come from a controller's period (see ``gain``)."""
        return self.gain != self.gain  # NaN

    def update(self) -> None:
        data = self._data
        make_equality_rows(self.robot.model, data, self._tendons, self._opt)
        self._read_rows(data)
        np.multiply(self._neg_k, self.error, self.target_velocity)

    def _read_rows(self, data: mujoco.MjData) -> None:
        ne = self._ne
        if data.ne != ne or data.nefc != ne:
            raise ModelError(f"{self.name}: the model's active equalities changed since the task was built "
                             f"({data.ne} equality rows, {ne} expected); build a new task")
        if self._all_rows:
            self.error[:] = data.efc_pos
        else:
            data.efc_pos.take(self._rows, None, self.error)
        if self._sparse:
            dense = self.jacobian if self._all_rows else self._dense
            mujoco.mju_sparse2dense(dense, data.efc_J, data.efc_J_rownnz, data.efc_J_rowadr, data.efc_J_colind)
        elif self._all_rows:
            self._flat_jacobian[:] = data.efc_J[: self._rows_size]
        else:
            dense = data.efc_J[: self._rows_size].reshape(ne, self.robot.nv)
        if not self._all_rows:
            dense.take(self._rows, 0, self.jacobian)

    def residuals(self, robot: Robot | None = None) -> np.ndarray:
        """The norm of each equality's residual (its units: m, rad, ...), in row order, at
        the configuration of the bound robot or of another robot of the same model.

        Computed on a scratch MjData (the robot's own data and constraint rows untouched).
        """
        robot = robot or self.robot
        if self._scratch is None:
            self._scratch = mujoco.MjData(self.robot.model)
        model, scratch = self.robot.model, self._scratch
        source = robot.data
        scratch.qpos[:] = source.qpos
        scratch.mocap_pos[:] = source.mocap_pos
        scratch.mocap_quat[:] = source.mocap_quat
        scratch.eq_active[:] = source.eq_active
        mujoco.mj_kinematics(model, scratch)
        mujoco.mj_comPos(model, scratch)
        make_equality_rows(model, scratch, self._tendons)
        if scratch.ne != self._ne:
            raise ModelError(f"{self.name}: the robot's active equalities differ from the task's")
        residual = np.asarray(scratch.efc_pos)[self._rows]
        return np.array([np.linalg.norm(residual[rows]) for rows in self._slices])

    def max_residual(self, robot: Robot | None = None) -> float:
        """The largest residual norm of :meth:`residuals` (e.g. a loop-closure gap in m)."""
        return float(np.max(self.residuals(robot)))
