r"""The CPU back-end: MuJoCo's own thread pool (``mujoco.batch.Batch``) and NumPy.

Kinematics: one ``Batch.forward(stage=mjSTAGE_POS)`` per control step computes every
world's kinematics on MuJoCo's threads; the poses, ``cdof`` and the centres of mass are
bound (copied out by the batch after each call). The kinematic copy of the model is
pared down to what a control step reads: contacts and constraints are disabled (a
control step needs neither, and collision detection would dominate the call), and its
bodies list no geoms, so that ``mj_kinematics`` skips the geoms' poses (a tenth of its
work on a robot with a few meshes per link). A task on a geom frame gets that geom's
pose from its body's, as ``mj_local2Global`` computes it, after each forward.

Jacobians are then formed across worlds from ``cdof``, as ``mj_jac`` forms them: for a
point p on body b and each dof j on b's chain,

.. math::
    J_r[:, j] = \mathrm{cdof}_j^{\omega},\qquad
    J_p[:, j] = \mathrm{cdof}_j^{v} + \mathrm{cdof}_j^{\omega} \times (p - c_{root(b)}),

with :math:`c_{root}` the subtree centre of mass of b's root body (``subtree_com``).
``Batch.jac`` would run the kinematics again per call; this costs one NumPy pass and
equals ``mj_jac`` to rounding (tests/batch/test_backend_cpu.py).

Physics: a second batch on the unmodified model, stepped with ``Batch.step``.

MuJoCo's profiling timers: MuJoCo's Python bindings install a timer callback
(``mjcb_time``, a ``clock_gettime`` per call) that every stage of ``mj_fwdPosition``
calls twice, to fill ``MjData.timer``; on the planar arm that was about a third of the
position stage's cost per world. The batch's own ``MjData`` are never shown to anyone,
so during the back-end's batch calls the callback is a C function that returns a
constant (CPython's ``PyFloat_GetMax``): the timers add zero, nothing else changes,
and the caller's callback (``mujoco.get_mjcb_time()``) is put back after each call.
"""

from __future__ import annotations

import contextlib
import copy
import ctypes
import os

import mujoco
import mujoco.batch
import numpy as np

from ...equalities import equality_label
from ...numerics import mul, quat2mat, quat_integrate
from ...robot import FRAMES, as_index
from ..errors import NotBatched
from .base import KinematicsBackend

_D = mujoco.mjtDisableBit
# The kinematic copy computes no contact and no constraint: a forward to the position
# stage then skips collision detection and constraint assembly.
_KINEMATIC_DISABLE = int(_D.mjDSBL_CONSTRAINT) | int(_D.mjDSBL_CONTACT)
_SAME = mujoco.mjtSameFrame
ALL = slice(None)  # a chain on every dof
_J = mujoco.mjtJoint
_EQ = mujoco.mjtEq


# Worlds per MuJoCo thread by default: below about this many small worlds, waking a
# second thread and waiting for it costs more than it saves (on a quiet machine; on a
# busy one the crossover moves up: measurements in docs/batch.md, Throughput).
WORLDS_PER_THREAD = 512


def _constant_timer():
    """A C function taking nothing and returning a double that never changes: as MuJoCo's
    timer callback it makes every profiling interval zero, at the cost of a call. None
    where CPython's C API is not reachable through ctypes."""
    try:
        return ctypes.cast(ctypes.pythonapi.PyFloat_GetMax, ctypes.CFUNCTYPE(ctypes.c_double))
    except (AttributeError, OSError, ValueError):
        return None


_NO_TIMER = _constant_timer()


@contextlib.contextmanager
def profiling_timers_off():
    """MuJoCo's timer callback replaced by a constant for the duration (see the module's
    description), the previous one restored after, even on an error."""
    if _NO_TIMER is None:
        yield
        return
    previous = mujoco.get_mjcb_time()
    mujoco.set_mjcb_time(_NO_TIMER)
    try:
        yield
    finally:
        mujoco.set_mjcb_time(previous)


def default_threads(nworld: int) -> int:
    """One MuJoCo thread per ``WORLDS_PER_THREAD`` worlds, at most the CPUs this process
    may run on."""
    try:
        cpus = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        cpus = os.cpu_count() or 1
    return max(1, min(cpus, nworld // WORLDS_PER_THREAD))


class CpuBackend(KinematicsBackend):
    """N worlds on ``mujoco.batch.Batch``.

    Args:
        model: the model (copied: the back-end never writes it).
        nworld: N.
        nthread: MuJoCo threads (default: :func:`default_threads`).
    """

    name = "cpu"

    def __init__(self, model: mujoco.MjModel, nworld: int, nthread: int | None = None):
        self.model = model
        self.nworld = int(nworld)
        self.nthread = default_threads(self.nworld) if nthread is None else int(nthread)
        kinematic = copy.deepcopy(model)
        kinematic.opt.disableflags = int(kinematic.opt.disableflags) | _KINEMATIC_DISABLE
        kinematic.body_geomnum[:] = 0  # no geom poses: see _geom_pose
        self._batch = mujoco.batch.Batch(kinematic, self.nworld, self.nthread, persistent=False)
        self.qpos = self._batch.bind("qpos")
        self._cdof = self._batch.bind("cdof").reshape(self.nworld, model.nv, 6)
        self._subtree_com = self._batch.bind("subtree_com").reshape(self.nworld, model.nbody, 3)
        self._fields: dict[str, np.ndarray] = {}
        self._geoms: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self._cdof_components = np.empty((8, model.nv, self.nworld))  # see _cdof_by_component
        self._cdof_current = False
        # _chain_jacobian's scratch, made once (a fresh large array each step costs page faults)
        self._chain_scratch = np.empty((5, self.nworld)), np.empty((2, 3, model.nv, self.nworld))
        self._difference = np.zeros((3, model.nv, self.nworld))  # a connect's rows, worlds last
        self._chains: dict[int, np.ndarray] = {}
        self._subtrees: dict[int, list[int]] = {}
        self._physics = None
        self._integration = _Integration(model)

    # -- kinematics ------------------------------------------------------------------
    def forward(self) -> None:
        with profiling_timers_off():
            self._batch.forward(stage=int(mujoco.mjtStage.mjSTAGE_POS))
        self._cdof_current = False
        for geom, pose in self._geoms.items():
            self._geom_pose(geom, *pose)

    def _field(self, name: str) -> np.ndarray:
        """A bound output field, registered on first use (and then filled at once: the
        batch copies a field out only after a call made once it was bound)."""
        if name not in self._fields:
            self._fields[name] = self._batch.bind(name)
            self.forward()
        return self._fields[name]

    def frame_pose(self, frame_type: str, frame_id: int,
                   rotation: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        if frame_type == "geom":
            if frame_id not in self._geoms:
                for name in ("xpos", "xmat", "xquat", "xipos", "ximat"):
                    self._field(name)
                pose = (np.empty((self.nworld, 3)), np.empty((self.nworld, 3, 3)))
                self._geom_pose(frame_id, *pose)
                self._geoms[frame_id] = pose
            return self._geoms[frame_id]
        positions, rotations = FRAMES[frame_type][1:3]
        xpos = self._field(positions).reshape(self.nworld, -1, 3)[:, frame_id]
        return xpos, self._field(rotations).reshape(self.nworld, -1, 3, 3)[:, frame_id] if rotation else None

    def _geom_pose(self, geom: int, position: np.ndarray, rotation: np.ndarray) -> None:
        """``mj_local2Global`` of a geom across worlds, into ``position``, ``rotation``."""
        m, n = self.model, self.nworld
        body, same = int(m.geom_bodyid[geom]), int(m.geom_sameframe[geom])
        xpos = self._fields["xpos"].reshape(n, -1, 3)[:, body]
        xmat = self._fields["xmat"].reshape(n, -1, 3, 3)[:, body]
        if same in (int(_SAME.mjSAMEFRAME_BODY), int(_SAME.mjSAMEFRAME_INERTIA)):
            frame = "xpos" if same == int(_SAME.mjSAMEFRAME_BODY) else "xipos"
            position[:] = self._fields[frame].reshape(n, -1, 3)[:, body]
        else:
            local = m.geom_pos[geom]
            for i in range(3):  # mju_mulMatVec3, then mju_addTo3
                position[:, i] = xmat[:, i, 0] * local[0] + xmat[:, i, 1] * local[1] + xmat[:, i, 2] * local[2]
            position += xpos
        if same == int(_SAME.mjSAMEFRAME_NONE):
            quat = mul(self._fields["xquat"].reshape(n, -1, 4)[:, body], m.geom_quat[geom][None])
            rotation[:] = quat2mat(quat)
        elif same in (int(_SAME.mjSAMEFRAME_BODY), int(_SAME.mjSAMEFRAME_BODYROT)):
            rotation[:] = xmat
        else:
            rotation[:] = self._fields["ximat"].reshape(n, -1, 3, 3)[:, body]

    def chain(self, body: int) -> slice | np.ndarray:
        """The columns of the dofs on ``body``'s chain to the world (``mj_jac``'s loop), as
        :func:`as_index` gives them (``ALL`` for every dof)."""
        if body not in self._chains:
            m, link, dofs = self.model, body, []
            while link and not m.body_dofnum[link]:
                link = int(m.body_parentid[link])
            if link:
                dof = int(m.body_dofadr[link] + m.body_dofnum[link] - 1)
                while dof >= 0:
                    dofs.append(dof)
                    dof = int(m.dof_parentid[dof])
            self._chains[body] = ALL if len(dofs) == m.nv else as_index(sorted(dofs))
        return self._chains[body]

    def _cdof_by_component(self) -> np.ndarray:
        """``cdof`` as (8, nv, N), worlds last: v, ω, then ω₀ and ω₁ again (ω turned by one or
        two components is a slice; each operation below is one pass over contiguous
        memory): made once per forward and shared by every Jacobian of the step."""
        components = self._cdof_components
        if not self._cdof_current:
            cdof = self._cdof.transpose(2, 1, 0)  # (6, nv, N): ω, v
            components[:3], components[3:6] = cdof[3:], cdof[:3]
            components[6:] = components[3:5]
            self._cdof_current = True
        return components

    def jacobian(self, body: int, points: np.ndarray, out_p: np.ndarray | None = None,
                 out_r: np.ndarray | None = None, rotational: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        n, nv = self.nworld, self.model.nv
        jacp = np.empty((n, 3, nv)) if out_p is None else out_p
        jacr = None if not rotational else np.empty((n, 3, nv)) if out_r is None else out_r
        columns, chain_p, chain_r = self._chain_jacobian(body, points, rotational)
        for jac, chain in [(jacp, chain_p)] + ([(jacr, chain_r)] if rotational else []):
            if columns is not ALL:  # zeros off the chain
                jac.fill(0.0)
            jac[:, :, columns] = chain
        return jacp, jacr

    def _chain_jacobian(self, body: int, points: np.ndarray, rotational: bool = True):
        """(columns, jacp (N, 3, k), jacr (N, 3, k)): ``mj_jac``'s columns of the k dofs
        on ``body``'s chain (``columns`` as :meth:`chain` gives them; jacr None unless
        ``rotational``); jacp is scratch, valid until the next call."""
        columns = self.chain(body)
        offset, products = self._chain_scratch  # o = points − com, then o₀ and o₁ again
        np.subtract(points.T, self._subtree_com[:, int(self.model.body_rootid[body])].T, offset[:3])
        offset[3:] = offset[:2]
        cdof = self._cdof_by_component()[:, columns]
        jacp, cross = products[:, :, :cdof.shape[1]]
        o = offset[:, None, :]
        # v + mju_cross(ω, o), every component at once: ω_a o_b − ω_b o_a, (a, b) = (i + 1, i + 2) mod 3
        np.multiply(cdof[4:7], o[2:5], jacp)
        np.multiply(cdof[5:8], o[1:4], cross)
        np.subtract(jacp, cross, jacp)
        np.add(cdof[:3], jacp, jacp)
        jacr = cdof[3:6].transpose(2, 0, 1) if rotational else None
        return columns, jacp.transpose(2, 0, 1), jacr  # (N, 3, k) views

    def subtree_com(self, body: int) -> np.ndarray:
        return self._subtree_com[:, body]

    def equality_rows(self, equalities: np.ndarray, out=None) -> tuple[np.ndarray, np.ndarray]:
        equalities = [int(eq) for eq in np.asarray(equalities, dtype=np.int64)]
        sizes = [self._equality_size(eq) for eq in equalities]
        n, nv = self.nworld, self.model.nv
        residual, jacobian = (np.empty((n, sum(sizes))), np.zeros((n, sum(sizes), nv))) if out is None else out
        row = 0
        for eq, size in zip(equalities, sizes):
            rows = slice(row, row + size)
            (self._connect_rows if size == 3 else self._joint_rows)(eq, residual[:, rows], jacobian[:, rows])
            row += size
        return residual, jacobian

    def _equality_size(self, eq: int) -> int:
        """Rows of an equality (3 for a connect, 1 for a joint coupling); NotBatched for
        the other types."""
        kind = int(self.model.eq_type[eq])
        if kind == int(_EQ.mjEQ_CONNECT):
            return 3
        if kind == int(_EQ.mjEQ_JOINT):
            return 1
        raise NotBatched(f"equality {equality_label(self.model, eq)!r} is a {_EQ(kind).name}: the batched engine "
                         "writes rows for connect and joint equalities only (weld and tendon equalities run in the "
                         "serial qpik.EqualityTask)")

    def _anchor(self, eq: int, side: int) -> tuple[int, np.ndarray]:
        """(body, world point) of one side of a connect equality (as mj_makeConstraint)."""
        m = self.model
        obj = int(m.eq_obj1id[eq] if side == 0 else m.eq_obj2id[eq])
        if int(m.eq_objtype[eq]) == int(mujoco.mjtObj.mjOBJ_SITE):
            return int(m.site_bodyid[obj]), self._field("site_xpos").reshape(self.nworld, -1, 3)[:, obj]
        xpos = self._field("xpos").reshape(self.nworld, -1, 3)[:, obj]
        xmat = self._field("xmat").reshape(self.nworld, -1, 3, 3)[:, obj]
        local = m.eq_data[eq, 3 * side:3 * side + 3]
        return obj, np.einsum("nij,j->ni", xmat, local) + xpos

    def _connect_rows(self, eq: int, residual: np.ndarray, jacobian: np.ndarray) -> None:
        """The anchors' difference and the difference of their Jacobians, written into
        ``residual`` (N, 3) and ``jacobian`` (N, 3, nv), which holds zeros off the anchors'
        chains. The difference is formed worlds last, then copied onto each chain's columns
        (a copy across layouts costs less than arithmetic across them)."""
        body0, point0 = self._anchor(eq, 0)
        body1, point1 = self._anchor(eq, 1)
        np.subtract(point0, point1, out=residual)
        difference, columns1 = self._difference, self.chain(body1)  # J0 − J1 (3, nv, N) on the chains' columns
        difference[:, columns1] = 0.0
        columns0, jacp0, _ = self._chain_jacobian(body0, point0, False)
        difference[:, columns0] = jacp0.transpose(1, 2, 0) + 0.0  # 0 + J0, as the rows' own zeros gave
        difference[:, columns1] -= self._chain_jacobian(body1, point1, False)[1].transpose(1, 2, 0)
        for columns in (columns0, columns1):
            jacobian[:, :, columns] = difference[:, columns].transpose(2, 0, 1)

    def _joint_rows(self, eq: int, residual: np.ndarray, jacobian: np.ndarray) -> None:
        m = self.model
        data = m.eq_data[eq]
        joint0, joint1 = int(m.eq_obj1id[eq]), int(m.eq_obj2id[eq])
        q0 = self.qpos[:, m.jnt_qposadr[joint0]] - m.qpos0[m.jnt_qposadr[joint0]]
        jacobian[:, 0, m.jnt_dofadr[joint0]] = 1.0
        if joint1 < 0:
            residual[:, 0] = q0 - data[0]
            return
        q1 = self.qpos[:, m.jnt_qposadr[joint1]] - m.qpos0[m.jnt_qposadr[joint1]]
        residual[:, 0] = q0 - data[0] - (data[1] * q1 + data[2] * q1 * q1 + data[3] * q1 * q1 * q1
                                         + data[4] * q1 * q1 * q1 * q1)
        jacobian[:, 0, m.jnt_dofadr[joint1]] = -(data[1] + 2 * data[2] * q1 + 3 * data[3] * q1 * q1
                                                 + 4 * data[4] * q1 * q1 * q1)

    # -- physics -----------------------------------------------------------------------
    def physics_reset(self, qpos: np.ndarray, ctrl: np.ndarray) -> None:
        if self._physics is None:
            self._physics = mujoco.batch.Batch(self.model, self.nworld, self.nthread, persistent=True)
            self._physics_qpos = self._physics.bind("qpos")
            self._physics_ctrl = self._physics.bind("ctrl")
        batch = self._physics
        batch.reset(stage=int(mujoco.mjtStage.mjSTAGE_NONE))
        self._physics_qpos[:] = qpos
        self._physics_ctrl[:] = ctrl
        batch.forward()
        self._warnings = batch.warning[:, :, 0].copy()

    def physics_step(self, ctrl: np.ndarray, nstep: int) -> tuple[np.ndarray, np.ndarray]:
        batch = self._physics
        self._physics_ctrl[:] = ctrl
        with profiling_timers_off():
            batch.step(nstep=int(nstep))
        counts = batch.warning[:, :, 0]
        unstable = (counts != self._warnings).any(axis=1)
        self._warnings = counts.copy()
        return self._physics_qpos, unstable


class _Integration:
    """``mj_integratePos`` across worlds: scalar joints add q̇Δt, ball and free joints
    integrate their quaternion (``mju_quatIntegrate``) in NumPy."""

    def __init__(self, model: mujoco.MjModel):
        scalar_q, scalar_v, linear_q, linear_v, quat_q, quat_v = [], [], [], [], [], []
        for j in range(model.njnt):
            kind, qadr, vadr = int(model.jnt_type[j]), int(model.jnt_qposadr[j]), int(model.jnt_dofadr[j])
            if kind in (int(_J.mjJNT_HINGE), int(_J.mjJNT_SLIDE)):
                scalar_q.append(qadr)
                scalar_v.append(vadr)
            elif kind == int(_J.mjJNT_FREE):
                linear_q += [qadr, qadr + 1, qadr + 2]
                linear_v += [vadr, vadr + 1, vadr + 2]
                quat_q.append(qadr + 3)
                quat_v.append(vadr + 3)
            else:  # ball
                quat_q.append(qadr)
                quat_v.append(vadr)
        self.scalar_q = np.array(scalar_q + linear_q, dtype=np.int64)
        self.scalar_v = np.array(scalar_v + linear_v, dtype=np.int64)
        self.quat_q = np.array(quat_q, dtype=np.int64)
        self.quat_v = np.array(quat_v, dtype=np.int64)
        self._contiguous = len(self.quat_q) == 0 and np.array_equal(self.scalar_q, np.arange(model.nq)) \
            and np.array_equal(self.scalar_v, np.arange(model.nv))

    def apply(self, qpos: np.ndarray, qvel: np.ndarray, dt: float) -> None:
        if self._contiguous:
            qpos += qvel * dt
            return
        qpos[:, self.scalar_q] += qvel[:, self.scalar_v] * dt
        for qadr, vadr in zip(self.quat_q, self.quat_v):
            quat = qpos[:, qadr:qadr + 4]
            qpos[:, qadr:qadr + 4] = quat_integrate(quat, qvel[:, vadr:vadr + 3], dt)

