r"""The GPU back-end: MuJoCo Warp for the worlds' kinematics, Jacobians and constraint rows
on a Warp device (``"cuda:0"``, or ``"cpu"``: the same kernels on the CPU, slowly, which
is how the test suite checks this back-end).

What runs where:

- the N configurations live on the host in float64 (``qpos``, as the interface asks)
  and are copied to the device before each :meth:`WarpBackend.forward`;
- MuJoCo Warp computes the kinematics (``kinematics``, ``com_pos``), the Jacobians
  (``jac``) and the equality-constraint rows (``make_constraint``, its own rows: loop
  closures are never rebuilt on the host) on the device, in float32, MuJoCo Warp's only
  precision; the host reads them as float64;
- the engine's step (the tasks' rows, the limits, the QP) runs on the host, as on the
  CPU back-end: a controller built on these worlds says so once
  (:class:`~qpik.errors.HostStepWarning`). The engine's numerical primitives have device
  mirrors (:mod:`qpik.batch.backends.warp_mirror`), its tasks, limits, cost assembly and
  held-bounds iteration do not, so no part of the step moves to the device;
- the physics rollouts step MuJoCo Warp's ``step`` on the device.

Install with the ``gpu`` extra: ``pip install -e ".[gpu]"``.
"""

from __future__ import annotations

import copy

import mujoco
import numpy as np

from ...equalities import equality_label, equality_row_ids, equality_rows_flags
from ...errors import InvalidInput, ModelError
from ...extras import require
from ...robot import FRAMES
from ..errors import NotBatched
from .base import KinematicsBackend
from .cpu import _Integration

wp = require("warp", "the warp batch back-end", extra="gpu")
mjw = require("mujoco_warp", "the warp batch back-end", extra="gpu")

_EQUALITY_ROW = int(mujoco.mjtConstraint.mjCNSTR_EQUALITY)


def equality_row_index(kind: np.ndarray, ids: np.ndarray, equalities: np.ndarray, model: mujoco.MjModel) -> np.ndarray:
    """(N, m): in each world, the columns of the constraint rows of ``equalities``, in
    their order. MuJoCo Warp numbers rows with atomic counters, so on a GPU the
    equalities' blocks come in a different order in each world (each block's own rows
    stay together, in order).

    Raises:
        ModelError: an equality without rows in some world, or with a different number
            of rows in different worlds.
    """
    blocks = []
    for eq in equalities:
        mask = (kind == _EQUALITY_ROW) & (ids == eq)
        counts = mask.sum(axis=1)
        if counts.min() == 0 or counts.max() != counts.min():
            raise ModelError(f"MuJoCo Warp made {sorted(set(counts.tolist()))} constraint rows for equality "
                             f"{equality_label(model, eq)!r} across the worlds (inactive, or acting on no dof, "
                             "somewhere)")
        blocks.append(np.nonzero(mask)[1].reshape(len(kind), int(counts[0])))  # row-major: each world's in order
    return np.concatenate(blocks, axis=1)


def warp_device(device: str | None):
    """The Warp device called ``device`` (default: Warp's preferred one, a GPU when there
    is one), or InvalidInput naming the devices this machine has."""
    names = [str(d) for d in wp.get_devices()]
    if device is None:
        return wp.get_preferred_device()
    if str(device) not in names:
        raise InvalidInput(f"unknown Warp device {device!r}; this machine has {names}")
    return wp.get_device(str(device))


class WarpBackend(KinematicsBackend):
    """N worlds on a Warp device through MuJoCo Warp.

    Args:
        model: the model (copied: the back-end never writes it).
        nworld: N.
        device: a Warp device name, ``"cuda:0"`` or ``"cpu"`` (default: Warp's preferred
            device).

    Raises:
        MissingExtra: warp or mujoco_warp is not installed (the ``gpu`` extra).
        InvalidInput: an unknown device.
        NotBatched: a model MuJoCo Warp cannot load (its message is kept).
    """

    name = "warp"

    def __init__(self, model: mujoco.MjModel, nworld: int, device: str | None = None):
        # Warp logs a line per loaded module (and its banner) at its default level.
        wp.config.quiet, wp.config.log_level = True, max(wp.config.log_level, wp.LOG_WARNING)
        self.model = model
        self.nworld = int(nworld)
        self.device = warp_device(device)
        kinematic = copy.deepcopy(model)  # it makes equality rows only: no contact, joint-limit or friction rows
        kinematic.opt.disableflags = equality_rows_flags(int(kinematic.opt.disableflags))
        data = mujoco.MjData(kinematic)
        mujoco.mj_kinematics(kinematic, data)
        mujoco.mj_comPos(kinematic, data)
        self._nefc = len(equality_row_ids(kinematic, data))  # MuJoCo's own count of the copy's rows
        with wp.ScopedDevice(self.device):
            try:
                self._m = mjw.put_model(kinematic)
                self._d = mjw.put_data(kinematic, mujoco.MjData(kinematic), nworld=self.nworld, nconmax=0,
                                       njmax=max(1, self._nefc))
            except (NotImplementedError, ValueError) as exc:
                raise NotBatched(f"MuJoCo Warp cannot load this model: {exc}") from None
            self._body_ids = wp.zeros(self.nworld, dtype=int)
            self._points = wp.zeros(self.nworld, dtype=wp.vec3)
            self._jacp = wp.zeros((self.nworld, 3, model.nv), dtype=float)
            self._jacr = wp.zeros((self.nworld, 3, model.nv), dtype=float)
        self.qpos = np.zeros((self.nworld, model.nq))
        self.qpos[:] = model.qpos0
        self._host: dict[str, np.ndarray] = {}  # device field -> float64 host mirror
        self._rows_current = False
        self._integration = _Integration(model)
        self._subtrees: dict[int, list[int]] = {}
        self._physics = None

    # -- kinematics ------------------------------------------------------------------
    def forward(self) -> None:
        with wp.ScopedDevice(self.device):
            self._d.qpos.assign(self.qpos.astype(np.float32))
            mjw.kinematics(self._m, self._d)
            mjw.com_pos(self._m, self._d)
        for name, host in self._host.items():
            host.reshape(self.nworld, -1)[:] = getattr(self._d, name).numpy().reshape(self.nworld, -1)
        self._rows_current = False

    def _field(self, name: str) -> np.ndarray:
        """The float64 host copy of a device field, refreshed by every :meth:`forward` (and
        filled at once by one, as the CPU back-end's fields: current at ``qpos`` when a
        task reads its start from it)."""
        if name not in self._host:
            field = getattr(self._d, name)
            self._host[name] = np.empty(field.shape + _inner(field))
            self.forward()
        return self._host[name]

    def frame_pose(self, frame_type: str, frame_id: int,
                   rotation: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        positions, rotations = FRAMES[frame_type][1:3]
        return self._field(positions)[:, frame_id], self._field(rotations)[:, frame_id] if rotation else None

    def jacobian(self, body: int, points: np.ndarray, out_p: np.ndarray | None = None,
                 out_r: np.ndarray | None = None, rotational: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        with wp.ScopedDevice(self.device):
            self._body_ids.fill_(int(body))
            self._points.assign(np.ascontiguousarray(points, dtype=np.float32))
            mjw.jac(self._m, self._d, self._jacp, self._jacr, self._points, self._body_ids)
        jacp = np.empty((self.nworld, 3, self.model.nv)) if out_p is None else out_p
        jacp[:] = self._jacp.numpy()
        if not rotational:
            return jacp, None
        jacr = np.empty((self.nworld, 3, self.model.nv)) if out_r is None else out_r
        jacr[:] = self._jacr.numpy()
        return jacp, jacr

    def subtree_com(self, body: int) -> np.ndarray:
        return self._field("subtree_com")[:, body]

    def equality_rows(self, equalities: np.ndarray, out=None) -> tuple[np.ndarray, np.ndarray]:
        equalities = np.asarray(equalities, dtype=np.int64)
        self._make_rows()
        index = equality_row_index(self._efc_type[:, : self._nefc], self._efc_id[:, : self._nefc], equalities,
                                   self.model)
        residual = np.take_along_axis(self._d.efc.pos.numpy()[:, : self._nefc], index, axis=1)
        jacobian = np.take_along_axis(self._d.efc.J.numpy()[:, : self._nefc, : self.model.nv], index[:, :, None],
                                      axis=1)
        if out is None:
            return residual.astype(np.float64), jacobian.astype(np.float64)
        out[0][...], out[1][...] = residual, jacobian
        return out

    def _make_rows(self) -> None:
        """MuJoCo Warp's constraint rows at the current kinematics (once per forward)."""
        if self._rows_current:
            return
        with wp.ScopedDevice(self.device):
            if self.model.ntendon:
                mjw.tendon(self._m, self._d)
            mjw.make_constraint(self._m, self._d)
        nefc = self._d.nefc.numpy()
        if np.any(nefc != self._nefc):
            raise ModelError(f"MuJoCo Warp made {sorted(set(nefc.tolist()))} constraint rows where MuJoCo makes "
                             f"{self._nefc}: the worlds' active equalities differ")
        self._efc_type = self._d.efc.type.numpy()
        self._efc_id = self._d.efc.id.numpy()
        self._rows_current = True

    # -- physics -----------------------------------------------------------------------
    def physics_reset(self, qpos: np.ndarray, ctrl: np.ndarray) -> None:
        with wp.ScopedDevice(self.device):
            if self._physics is None:
                self._physics = (mjw.put_model(self.model),
                                 mjw.put_data(self.model, mujoco.MjData(self.model), nworld=self.nworld))
            m, d = self._physics
            mjw.reset_data(m, d)
            d.qpos.assign(np.asarray(qpos, dtype=np.float32))
            d.ctrl.assign(np.asarray(ctrl, dtype=np.float32))
            mjw.forward(m, d)

    def physics_step(self, ctrl: np.ndarray, nstep: int) -> tuple[np.ndarray, np.ndarray]:
        m, d = self._physics
        with wp.ScopedDevice(self.device):
            d.ctrl.assign(np.asarray(ctrl, dtype=np.float32))
            for _ in range(int(nstep)):
                mjw.step(m, d)
        qpos = d.qpos.numpy().astype(np.float64)
        unstable = ~(np.isfinite(qpos).all(axis=1) & np.isfinite(d.qvel.numpy()).all(axis=1))
        return qpos, unstable


def _inner(field) -> tuple:
    """The shape of one element of a Warp array (vec3 -> (3,), mat33 -> (3, 3))."""
    return tuple(getattr(field.dtype, "_shape_", ()))

