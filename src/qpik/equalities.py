r"""MuJoCo's equality-constraint rows (``connect``, ``weld``, ``joint``, ``tendon``) of one
MjData, alone: what :meth:`qpik.Robot.equality_rows` (and so :class:`qpik.EqualityTask`) reads.

:func:`make_equality_rows` runs ``mj_makeConstraint`` with every other constraint type
disabled, so that ``data.efc_*`` hold the equality rows only, in the order of the
equalities' ids (their layout: :class:`~qpik.tasks.equality.EqualityTask`);
:class:`EqualityRows` reads the rows of chosen equalities into preallocated arrays
(sparse Jacobians expanded with ``mju_sparse2dense``).
"""

from __future__ import annotations

from typing import Sequence

import mujoco
import numpy as np

from .errors import ModelError

# The equality types whose rows qpik takes from MuJoCo, and their row counts.
SUPPORTED = {int(getattr(mujoco.mjtEq, f"mjEQ_{name.upper()}")): (name, rows)
             for name, rows in (("connect", 3), ("weld", 6), ("joint", 1), ("tendon", 1))}
_D = mujoco.mjtDisableBit
# While the rows are made: no contact, limit or friction-loss rows; equalities on.
_DISABLE = int(_D.mjDSBL_CONTACT) | int(_D.mjDSBL_LIMIT) | int(_D.mjDSBL_FRICTIONLOSS)
_ENABLE = int(_D.mjDSBL_CONSTRAINT) | int(_D.mjDSBL_EQUALITY)
_SLEEP = int(mujoco.mjtEnableBit.mjENBL_SLEEP)  # a sleeping tree's equalities would be skipped
_TENDON = int(mujoco.mjtEq.mjEQ_TENDON)


def make_equality_rows(model: mujoco.MjModel, data: mujoco.MjData, tendons: bool, opt=None) -> None:
    """MuJoCo's rows of the active equality constraints, alone, at ``data``'s kinematics.

    Runs ``mj_makeConstraint`` (after ``mj_tendon`` when ``tendons``) with contacts,
    joint limits and friction loss disabled in ``model.opt`` for the call, so that
    ``data.efc_*`` hold the equality rows only (``data.ne`` of them); the model's flags
    are restored after. ``data`` must have had ``mj_kinematics`` and ``mj_comPos``.
    ``opt``: ``model.opt``, when the caller keeps it (MuJoCo's getter makes a new one).
    """
    opt = model.opt if opt is None else opt
    disable, enable = opt.disableflags, opt.enableflags
    opt.disableflags = equality_rows_flags(disable)
    sleep = enable & _SLEEP  # the enable flags touched only when sleep is on (each access is a call)
    if sleep:
        opt.enableflags = enable & ~_SLEEP
    try:
        if tendons:
            mujoco.mj_tendon(model, data)
        mujoco.mj_makeConstraint(model, data)
    finally:
        opt.disableflags = disable
        if sleep:
            opt.enableflags = enable


def equality_rows_flags(disableflags: int) -> int:
    """``disableflags`` with contacts, joint limits and friction loss disabled and the
    equalities enabled: the constraint rows MuJoCo then makes are the equalities' alone."""
    return (disableflags | _DISABLE) & ~_ENABLE


def active_equalities(model: mujoco.MjModel, data: mujoco.MjData) -> list[int]:
    """The ids of the equalities active in ``data`` (``data.eq_active``)."""
    return [i for i in range(model.neq) if data.eq_active[i]]


def needs_tendons(model: mujoco.MjModel, data: mujoco.MjData) -> bool:
    """Whether an active equality is a tendon's: MuJoCo then makes its row from the tendon
    Jacobian of the last ``mj_tendon``, so the tendons are computed before every make
    (whichever equalities a caller reads, the row count must not depend on that)."""
    return any(int(model.eq_type[i]) == _TENDON for i in active_equalities(model, data))


def equality_label(model: mujoco.MjModel, equality: int) -> str:
    """An equality's name for a message (``#id`` for an unnamed one)."""
    return mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_EQUALITY, int(equality)) or f"#{int(equality)}"


def equality_row_ids(model: mujoco.MjModel, data: mujoco.MjData) -> np.ndarray:
    """The equality id of each of MuJoCo's equality rows at ``data``'s kinematics (a copy of
    ``efc_id``; ``data``'s constraint arrays are rewritten). An active equality that acts
    on no dof (a weld of a jointless body to the world) has no row."""
    make_equality_rows(model, data, needs_tendons(model, data))
    return np.array(data.efc_id[: data.ne])


class EqualityRows:
    """The rows of chosen equalities on one MjData, read into preallocated arrays.

    Args:
        model, data: the model and the MjData whose kinematics the rows are made at.
        ids: the equalities, ascending; each active and acting on a dof.

    Raises:
        ModelError: an id that is not ascending, unknown, inactive or without rows.

    Calling it makes MuJoCo's equality rows (:func:`make_equality_rows`) and returns
    ``(residual (1, m), jacobian (1, m, nv))``: its own arrays, overwritten by the next
    call. It raises ModelError when the model's active equalities changed since it was
    built (MuJoCo then makes another number of rows).
    """

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData, ids: Sequence[int]):
        ids = [int(i) for i in ids]
        if not ids or ids != sorted(set(ids)) or ids[0] < 0 or ids[-1] >= model.neq:
            raise ModelError(f"equality rows need ascending ids of the model's {model.neq} equalities, got {ids}")
        self.model, self.data, self.opt = model, data, model.opt  # read once: MuJoCo's getters make new objects
        self.tendons = needs_tendons(model, data)
        efc_id = equality_row_ids(model, data)
        missing = [equality_label(model, i) for i in ids if i not in efc_id]
        if missing:
            raise ModelError(f"equalities {missing} have no rows: inactive (data.eq_active), or acting on no dof")
        self.ne = len(efc_id)
        self.rows = np.flatnonzero(np.isin(efc_id, ids))
        self.sizes = [int(np.count_nonzero(efc_id == i)) for i in ids]
        nv = model.nv
        self.all_rows = len(self.rows) == self.ne
        self.sparse = bool(mujoco.mj_isSparse(model))
        self.residual = np.zeros((1, len(self.rows)))
        self.jacobian = np.zeros((1, len(self.rows), nv))
        # Where a sparse Jacobian is expanded: the output itself when every row is read.
        self._expanded = self.jacobian[0] if self.all_rows else np.zeros((self.ne, nv))
        self._flat = self.jacobian.reshape(-1)
        self._size = self.ne * nv  # efc_J's buffer may be longer than its ne x nv dense rows

    def __call__(self) -> tuple[np.ndarray, np.ndarray]:
        data = self.data
        make_equality_rows(self.model, data, self.tendons, self.opt)
        if data.ne != self.ne or data.nefc != self.ne:
            raise ModelError(f"the model's active equalities changed since their rows were first read ({data.ne} "
                             f"equality rows, {self.ne} expected); build a new task")
        if self.all_rows:
            self.residual[0] = data.efc_pos
        else:
            data.efc_pos.take(self.rows, None, self.residual[0])
        if self.sparse:
            dense = self._expanded
            mujoco.mju_sparse2dense(dense, data.efc_J, data.efc_J_rownnz, data.efc_J_rowadr, data.efc_J_colind)
        elif self.all_rows:
            self._flat[:] = data.efc_J[: self._size]
        else:
            dense = data.efc_J[: self._size].reshape(self.ne, self.model.nv)
        if not self.all_rows:
            dense.take(self.rows, 0, self.jacobian[0])
        return self.residual, self.jacobian
