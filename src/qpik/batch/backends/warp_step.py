r"""The device-resident control step of the warp back-end: one step of a
``batch.QPController`` as a fixed sequence of Warp kernel launches, replayed as one CUDA
graph on a GPU.

One step (:meth:`DeviceStep.run`), every array on the device:

1. the float64 state ``q`` to MuJoCo Warp's float32 ``qpos``; its kinematics and
   centres of mass (``kinematics``, ``com_pos``) and, for an ``EqualityTask``, its
   constraint rows (``make_constraint``);
2. each task's rows (error, Jacobian, target velocity), then H, c, A, b as the
   controller builds them, and the box of the limits
   (:mod:`qpik.batch.backends.warp_kernels`);
3. the dual active set per world (:mod:`qpik.batch.backends.warp_qp`, float64,
   warm-started);
4. each answer checked on the device as the host checks it (hard rows to
   1e-9 (1 + |b|), the box to 1e-9 (1 + |bound|)) and clipped into the box;
5. ``q ← q ⊕ q̇ Δt`` for every world whose answer holds;
6. the count of the other worlds copied to the host.

Only when that count is not zero does anything else cross: those worlds' QPs go to
the host, DAQP solves them (or says why not), their answers come back and they are
integrated. A world with no answer keeps its configuration and is reported by
:class:`~qpik.batch.WorldsFailed` after the others moved.

Targets and parameters are read from the tasks before each step: a target array (N, …)
is copied to the device when it is a new array (``set_target`` makes one) and is then
made read-only, so that writing into it in place raises instead of being missed;
gains, weights and the limits' rates are compared and copied when they changed.

On a CUDA device the first step runs the launches one by one (it compiles and loads
every kernel); the second captures them (``wp.ScopedCapture``) and every step replays
the graph. Warp's CPU device has no graphs: there every step runs the same launches
directly. The capture path has not run on a GPU yet.
"""

from __future__ import annotations

import mujoco
import numpy as np

from ...errors import InvalidInput
from ..errors import NotBatched, WorldsFailed
from ..limits import JointPositionLimit, JointVelocityLimit
from ..tasks import DampingTask, EqualityTask, FrameTask, OrientationTask, PositionTask, PostureTask
from ...extras import require
from . import warp_kernels as K
from . import warp_qp
from .daqp_fallback import TOLERANCE, daqp_solve

wp = require("warp", "the warp batch back-end", extra="gpu")
mjw = require("mujoco_warp", "the warp batch back-end", extra="gpu")

F64 = wp.float64
_FRAME_FIELDS = {"site": ("site_xpos", "site_xmat"), "body": ("xpos", "xmat"), "geom": ("geom_xpos", "geom_xmat")}
_EQUALITY_ROW = int(mujoco.mjtConstraint.mjCNSTR_EQUALITY)
_ROW_TASKS = (FrameTask, PositionTask, OrientationTask, PostureTask, EqualityTask)
_LIMITS = (JointPositionLimit, JointVelocityLimit)


def unsupported(backend, controller) -> str | None:
    """Why ``controller`` cannot run on the device step (None: it can)."""
    for task in controller.tasks:
        if type(task) not in (*_ROW_TASKS, DampingTask):
            return f"{type(task).__name__} has no device kernel"
        if isinstance(task, (FrameTask, PositionTask, OrientationTask)) and _pose_rows(task) is None:
            return f"the {task.name}'s rows are not laid out as the device kernel reads them"
    for limit in controller.limits:
        if type(limit) not in _LIMITS:
            return f"{type(limit).__name__} has no device kernel"
    if any(isinstance(t, EqualityTask) for t in controller.tasks) and backend._m.is_sparse:
        return "MuJoCo Warp keeps this model's constraint Jacobian sparse; the equality kernel reads it dense"
    return None


def _pose_rows(task):
    """(rows in 0..5, local) of a frame task's masked pose rows, or None."""
    pose = getattr(task, "_rows", None) if isinstance(task, FrameTask) else getattr(task, "_pose", None)
    if not all(hasattr(pose, name) for name in ("rows", "local", "has_position")):
        return None
    # The host's rows index [position rows; orientation rows], the position block absent
    # when it has none.
    rows = np.asarray(pose.rows, dtype=np.int32) + (0 if pose.has_position else 3)
    return rows, bool(pose.local)


class _Mirror:
    """A task's per-world target array on the device, copied when the task holds a new
    array; the copied array is made read-only, so that an in-place write raises instead
    of being missed (a view, which cannot be guarded so, is copied every step)."""

    def __init__(self, task, attribute: str, device):
        self.task, self.attribute = task, attribute
        host = np.asarray(getattr(task, attribute))
        self.array = wp.zeros(host.shape, dtype=F64, device=device)
        self._last = None

    def sync(self) -> None:
        host = getattr(self.task, self.attribute)
        if host is self._last:
            return
        if host.shape != tuple(self.array.shape):
            raise InvalidInput(f"{self.task.name}: {self.attribute} has shape {host.shape}, the device step was "
                               f"built for {tuple(self.array.shape)}")
        self.array.assign(np.ascontiguousarray(host, dtype=np.float64))
        if host.flags.owndata:
            host.flags.writeable = False
            self._last = host
        else:
            self._last = None


class _Parameters:
    """Small parameter vectors (gains, weights, rates) on the device, copied when they
    change."""

    def __init__(self, read, device):
        self.read = read
        self._last = np.asarray(read(), dtype=np.float64).copy()
        self.array = wp.array(self._last, dtype=F64, device=device)

    def sync(self) -> None:
        values = np.asarray(self.read(), dtype=np.float64)
        if not np.array_equal(values, self._last):
            self.array.assign(values)
            self._last = values.copy()


class _TaskRows:
    """A task's rows on the device and how they enter the QP."""

    def __init__(self, step: DeviceStep, index: int, task):
        self.step, self.index, self.task = step, index, task
        n, nv, device = step.nworld, step.nv, step.device
        self.error = wp.zeros((n, task.dim), dtype=F64, device=device)
        self.velocity = wp.zeros((n, task.dim), dtype=F64, device=device)
        self.jacobian = wp.zeros((n, task.dim, nv), dtype=F64, device=device) if not task.joint_space else None
        self.gains = _Parameters(lambda: _gains(task), device)
        self.weight = _Parameters(lambda: task.weight, device)
        self.lm_damping = _Parameters(lambda: [task.lm_damping], device)
        self.mirrors: list[_Mirror] = []
        self.offset = 0  # first row in A, for a hard task

    def sync(self) -> None:
        for item in (self.gains, self.weight, self.lm_damping, *self.mirrors):
            item.sync()

    def launch_rows(self) -> None:
        raise NotImplementedError

    def launch_assembly(self) -> None:
        s = self.step
        if self.task.hard:
            wp.launch(K.add_hard, dim=s.nworld, inputs=[self.jacobian, self.velocity, self.offset, s.A, s.b])
        elif self.task.joint_space:
            wp.launch(K.add_joint_space, dim=s.nworld, inputs=[self.dofs, self.weight.array, self.velocity, s.c])
        else:
            wp.launch(K.add_soft, dim=s.nworld, inputs=[self.jacobian, self.velocity, self.error, self.weight.array,
                                                        self.lm_damping.array, s.H, s.c, s.lm_total])

    def host_copies(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(error, Jacobian, target velocity) of every world, host copies."""
        jacobian = self.task.jacobian if self.jacobian is None else self.jacobian.numpy()
        return self.error.numpy(), jacobian, self.velocity.numpy()


def _gains(task) -> np.ndarray:
    gains = task.feedback_gains()
    return np.zeros(task.dim) if gains is None else gains


class _FrameRows(_TaskRows):
    """FrameTask, PositionTask, OrientationTask."""

    def __init__(self, step: DeviceStep, index: int, task):
        super().__init__(step, index, task)
        device, d, m = step.device, step.data, step.model
        rows, self.local = _pose_rows(task)
        self.rows = wp.array(rows, dtype=int, device=device)
        frame = task.frame
        position, rotation = _FRAME_FIELDS[frame.type]
        self.xpos, self.xmat = getattr(d, position), getattr(d, rotation)
        self.frame_id, self.root = frame.id, int(m.body_rootid[frame.body])
        self.chain = wp.array(_chain(m, frame.body), dtype=int, device=device)
        targets = {FrameTask: ("target_position", "target_linear_velocity", "target_rotation",
                               "target_angular_velocity"),
                   PositionTask: ("target", "target_rate", None, None),
                   OrientationTask: (None, None, "target_rotation", "target_angular_velocity")}[type(task)]
        # The column of the position target that each world axis reads (-1: none): a
        # PositionTask in world axes keeps its masked axes only.
        columns = np.arange(3, dtype=np.int32)
        if isinstance(task, OrientationTask):
            columns[:] = -1
        elif isinstance(task, PositionTask) and not self.local:
            columns[:] = -1
            columns[rows] = np.arange(len(rows))
        self.columns = wp.array(columns, dtype=int, device=device)
        self.has_rotation = int(targets[2] is not None)
        self.arrays = []
        for k, attribute in enumerate(targets):
            if attribute is None:  # never read by the kernel
                self.arrays.append(wp.zeros((1, 1, 1) if k == 2 else (1, 1), dtype=F64, device=device))
            else:
                mirror = _Mirror(task, attribute, device)
                self.mirrors.append(mirror)
                self.arrays.append(mirror.array)

    def launch_rows(self) -> None:
        s = self.step
        target_position, linear, target_rotation, angular = self.arrays
        wp.launch(K.frame_rows, dim=s.nworld,
                  inputs=[self.xpos, self.xmat, self.frame_id, self.root, self.chain, s.data.subtree_com, s.data.cdof,
                          self.rows, int(self.local), self.has_rotation, self.gains.array, target_position,
                          self.columns, linear, target_rotation, angular, self.index, self.error, self.jacobian,
                          self.velocity, s.fault])


class _PostureRows(_TaskRows):
    def __init__(self, step: DeviceStep, index: int, task):
        super().__init__(step, index, task)
        self.dofs = wp.array(np.asarray(task.dofs, dtype=np.int32), dtype=int, device=step.device)
        self.mirrors.append(_Mirror(task, "target", step.device))
        self.scratch = wp.zeros((step.nworld, step.nv), dtype=F64, device=step.device)

    def launch_rows(self) -> None:
        s = self.step
        wp.launch(K.posture_rows, dim=s.nworld,
                  inputs=[s.q, self.mirrors[0].array, *s.joints, self.dofs, self.gains.array, self.index, self.scratch,
                          self.error, self.velocity, s.fault])


class _DampingRows(_TaskRows):
    """No rows to build: its weights are on H0's diagonal, its target velocity zero."""

    def launch_rows(self) -> None:
        pass

    def launch_assembly(self) -> None:
        pass


class _EqualityRows(_TaskRows):
    def __init__(self, step: DeviceStep, index: int, task):
        super().__init__(step, index, task)
        backend = step.backend
        backend._make_rows()  # MuJoCo Warp's row layout of world 0 gives each equality's row count
        kind, ids = backend._efc_type[0, : backend._nefc], backend._efc_id[0, : backend._nefc]
        counts = np.array([np.count_nonzero((kind == _EQUALITY_ROW) & (ids == eq)) for eq in task.equalities])
        if counts.sum() != task.dim:
            raise NotBatched(f"the {task.name}: MuJoCo Warp makes {counts.sum()} rows for its equalities, the task "
                             f"has {task.dim}")
        device = step.device
        self.expected = int(backend._nefc)
        self.equalities = wp.array(np.asarray(task.equalities, dtype=np.int32), dtype=int, device=device)
        self.offsets = wp.array(np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int32), dtype=int,
                                device=device)
        self.counts = wp.array(counts.astype(np.int32), dtype=int, device=device)

    def launch_rows(self) -> None:
        s, efc = self.step, self.step.data.efc
        wp.launch(K.equality_rows, dim=s.nworld,
                  inputs=[s.data.nefc, efc.type, efc.id, efc.pos, efc.J, _EQUALITY_ROW, self.equalities, self.offsets,
                          self.counts, self.expected, self.gains.array, self.index, self.error, self.jacobian,
                          self.velocity, s.fault])


_KINDS = {FrameTask: _FrameRows, PositionTask: _FrameRows, OrientationTask: _FrameRows, PostureTask: _PostureRows,
          DampingTask: _DampingRows, EqualityTask: _EqualityRows}


class _PositionLimitBox:
    """JointPositionLimit on the device (the velocity box, constant, is copied in first)."""

    def __init__(self, step: DeviceStep, limit: JointPositionLimit):
        self.step, self.limit = step, limit
        lim, device = limit.limits, step.device
        self.qpos_index = wp.array(np.asarray(lim.qpos_index, dtype=np.int32), dtype=int, device=device)
        self.dof_index = wp.array(np.asarray(lim.dof_index, dtype=np.int32), dtype=int, device=device)
        self.lower = wp.array(lim.lower + limit.margin, dtype=F64, device=device)
        self.upper = wp.array(lim.upper - limit.margin, dtype=F64, device=device)
        self.rates = _Parameters(self._rates, device)

    def _rates(self) -> list[float]:
        limit = self.limit
        step_rate = limit.gain / self.step.dt
        return [step_rate, limit.influence, min(limit._rate, step_rate)]

    def launch(self) -> None:
        s = self.step
        wp.launch(K.position_limit, dim=s.nworld, inputs=[s.q, self.qpos_index, self.dof_index, self.lower, self.upper,
                                                           self.rates.array, s.lb, s.ub])


def _chain(model: mujoco.MjModel, body: int) -> np.ndarray:
    """(nv,) int32: 1 for the dofs on ``body``'s chain to the world (those that move it)."""
    ancestors = set()
    b = int(body)
    while b > 0:
        ancestors.add(b)
        b = int(model.body_parentid[b])
    return np.array([int(model.dof_bodyid[j]) in ancestors for j in range(model.nv)], dtype=np.int32)


class DeviceStep:
    """A ``batch.QPController``'s control step, resident on the warp back-end's device.

    Built by ``QPController.step`` on the warp back-end (``DeviceStep(backend,
    controller)``); the task set is fixed at construction.

    Attributes:
        captured: the step replays a CUDA graph (False on Warp's CPU device, and
            before the second step).
        host_worlds: the worlds the last step handed to the host (ascending).

    Raises:
        NotBatched: a task or limit without a device kernel (the reason says which).
    """

    def __init__(self, backend, controller):
        reason = unsupported(backend, controller)
        if reason:
            raise NotBatched(reason)
        self.backend, self.controller = backend, controller
        robots = controller.robots
        robots.ensure_kinematics()  # the start check; the host kinematics current for the row layout
        self.device, self.model, self.data = backend.device, backend.model, backend._d
        self.nworld, self.nv, self.meq, self.dt = robots.n, robots.nv, controller.meq, float(controller.dt)
        cap = getattr(controller.qp, "max_iterations", None)
        self.max_iterations = int(cap or 10 * (self.nv + self.meq) + 20)  # WarpQP's default
        self.captured, self.host_worlds = False, np.zeros(0, dtype=np.int64)
        self._graph, self._runs = None, 0
        with wp.ScopedDevice(self.device):
            self._allocate(controller)
            self._tasks = [_KINDS[type(task)](self, k, task) for k, task in enumerate(controller.tasks)]
            self._limits = [_PositionLimitBox(self, lim) for lim in controller.limits if not lim.constant]
        offset = 0
        for rows in self._tasks:
            if rows.task.hard:
                rows.offset, offset = offset, offset + rows.task.dim
        # The controller's order: hard rows, joint-space tasks, then the other soft tasks.
        self._assembly = sorted(self._tasks, key=lambda r: 0 if r.task.hard else 1 if r.task.joint_space else 2)
        self._uses_rows = any(isinstance(t, EqualityTask) for t in controller.tasks)

    def _allocate(self, controller) -> None:
        n, nv, model = self.nworld, self.nv, self.model
        self.per_world = int(any(not t.hard and not t.joint_space for t in controller.tasks))
        self.H0 = wp.array(np.asarray(controller.H0, dtype=np.float64), dtype=F64)
        self.H = wp.array(np.broadcast_to(controller.H0, (n if self.per_world else 1, nv, nv)).copy(), dtype=F64)
        self.c, self.lb, self.ub, self.x = (wp.zeros((n, nv), dtype=F64) for _ in range(4))
        lb0, ub0 = np.full((n, nv), -np.inf), np.full((n, nv), np.inf)
        for limit in controller.limits:
            if limit.constant:
                limit.apply(self.dt, lb0, ub0)
        self.lb0, self.ub0 = wp.array(lb0, dtype=F64), wp.array(ub0, dtype=F64)
        rows = max(1, self.meq)
        self.A, self.b = wp.zeros((n, rows, nv), dtype=F64), wp.zeros((n, rows), dtype=F64)
        self.lm_total = wp.zeros(n, dtype=F64)
        (self.fault, self.empty, self.nan_data, self.mask, self.status, self.iterations, self.n_bound, self.n_warm,
         self.outcome, self.listed) = (wp.zeros(n, dtype=int) for _ in range(10))
        self.warm = wp.zeros((n, nv), dtype=int)
        self.work3, self.work2, self.active = warp_qp.workspace(n, nv, F64)
        self.listed_count = wp.zeros(1, dtype=int)
        self.summary = wp.zeros(1, dtype=int, device="cpu", pinned=self.device.is_cuda)
        self.joints = [wp.array(np.asarray(a, dtype=np.int32), dtype=int)
                       for a in (model.jnt_type, model.jnt_qposadr, model.jnt_dofadr)]
        self.qp_kernel = warp_qp.dual_active_set_kernel(F64)

    @property
    def q(self):
        """The float64 state on the device (N, nq) (the back-end's)."""
        return self.backend.device_qpos()

    # -- one step --------------------------------------------------------------------------
    def run(self) -> None:
        """One control step of every world on the device.

        Raises:
            WorldsFailed: some worlds have no answer (listed, with why; they kept their
                configuration); the others moved.
        """
        self._sync_inputs()
        with wp.ScopedDevice(self.device):
            self._replay()
            if self.device.is_cuda:
                wp.synchronize_device(self.device)
            count = int(self.summary.numpy()[0])
        self.backend.device_qpos_moved()
        self.controller.robots.kinematics_stale()
        self.host_worlds = np.zeros(0, dtype=np.int64)
        if count:
            self._host_fixup(count)

    def assemble(self) -> None:
        """Build every world's task rows, cost and box on the device at the current state,
        without solving or moving (for inspection: :meth:`task_rows`, :meth:`qp_data`)."""
        self._sync_inputs()
        with wp.ScopedDevice(self.device):
            self._launch_rows_and_box()
        self.backend._rows_current = False
        self.controller.robots.kinematics_stale()

    def _sync_inputs(self) -> None:
        self.q  # noqa: B018  (the host state goes up if it was touched)
        for rows in self._tasks:
            rows.sync()
        for box in self._limits:
            box.rates.sync()

    def _replay(self) -> None:
        """The step's launches: directly on the first step and on a CPU device, else the
        captured graph."""
        self._runs += 1
        if not self.device.is_cuda or self._runs == 1:
            self._launch()
            return
        if self._graph is None:
            with wp.ScopedCapture(device=self.device) as capture:
                self._launch()
            self._graph, self.captured = capture.graph, True
        wp.capture_launch(self._graph)

    def _launch(self) -> None:
        self._launch_rows_and_box()
        self._launch_solve_and_step()

    def _launch_rows_and_box(self) -> None:
        m, d, n, q = self.backend._m, self.data, self.nworld, self.q
        wp.launch(K.state_to_float32, dim=tuple(q.shape), inputs=[q, d.qpos])
        mjw.kinematics(m, d)
        mjw.com_pos(m, d)
        if self._uses_rows:
            if self.model.ntendon:
                mjw.tendon(m, d)
            mjw.make_constraint(m, d)
        wp.launch(K.cost_start, dim=n, inputs=[self.H0, self.per_world, self.H, self.c, self.lm_total, self.fault])
        for rows in self._tasks:
            rows.launch_rows()
        for rows in self._assembly:
            rows.launch_assembly()
        if self.per_world:
            wp.launch(K.cost_rescale, dim=n, inputs=[self.H, self.c, self.lm_total])
        wp.copy(self.lb, self.lb0)
        wp.copy(self.ub, self.ub0)
        for box in self._limits:
            box.launch()
        wp.launch(K.prepare_qp, dim=n, inputs=[self.c, self.A, self.b, self.meq, self.lb, self.ub, self.fault,
                                               self.empty, self.nan_data, self.mask])

    def _launch_solve_and_step(self) -> None:
        n = self.nworld
        wp.launch(self.qp_kernel, dim=n,
                  inputs=[self.H, self.per_world, self.c, self.A, self.b, self.lb, self.ub, self.mask, self.meq, self.nv,
                          self.max_iterations, self.warm, self.n_warm, self.x, self.status, self.iterations,
                          self.n_bound, *self.work3, *self.work2, self.active])
        self.listed_count.zero_()
        wp.launch(K.check_answers, dim=n, inputs=[self.x, self.status, self.A, self.b, self.meq, self.lb, self.ub,
                                                  TOLERANCE, self.fault, self.empty, self.nan_data, self.outcome,
                                                  self.listed_count, self.listed])
        wp.launch(K.integrate_solved, dim=n, inputs=[self.q, self.x, self.outcome, self.dt, *self.joints])
        wp.copy(self.summary, self.listed_count)

    # -- the worlds the device left to the host --------------------------------------------
    def _host_fixup(self, count: int) -> None:
        """DAQP for the listed worlds (or why they have no answer), their answers back
        to the device and their step."""
        n, nv, meq = count, self.nv, self.meq
        with wp.ScopedDevice(self.device):
            listed = self.listed[:n]
            rows = max(1, meq)
            packed = [wp.zeros(shape, dtype=F64) for shape in ((n, nv, nv), (n, nv), (n, rows, nv), (n, rows),
                                                               (n, nv), (n, nv))]
            codes = wp.zeros((n, 3), dtype=int)
            wp.launch(K.gather_listed, dim=n, inputs=[listed, self.H, self.per_world, self.c, self.A, self.b, self.lb,
                                                      self.ub, self.outcome, self.fault, self.empty, *packed, codes])
            H, c, A, b, lb, ub = (a.numpy() for a in packed)
            worlds, codes = listed.numpy().astype(np.int64), codes.numpy()
        answers, reasons = np.zeros((n, nv)), {}
        for k, w in enumerate(worlds):
            why = self._fault_reason(*codes[k], lb[k], ub[k])
            if why is None:
                answers[k], status, why = daqp_solve(H[k], c[k], A[k, :meq], b[k, :meq], lb[k], ub[k])
            if why:
                reasons[int(w)] = why
        with wp.ScopedDevice(self.device):
            host_answers = wp.array(answers, dtype=F64)
            wp.launch(K.apply_host_answers, dim=n, inputs=[listed, host_answers, self.x, self.q, self.dt, *self.joints])
        self.host_worlds = np.sort(worlds)
        if reasons:
            raise WorldsFailed(reasons, self.qdot(), "batch.QPController")

    def _fault_reason(self, outcome: int, fault: int, empty: int, lb: np.ndarray, ub: np.ndarray) -> str | None:
        """Why a world has no answer before any solver sees it (None: for DAQP)."""
        if outcome == K.FAULT:
            task = self.controller.tasks[fault // 2]
            if fault % 2:
                return (f"the {task.name}: MuJoCo Warp made other constraint rows in this world than those the "
                        "device step was built for (an equality switched off?)")
            return f"the {task.name}'s target velocity or Jacobian is NaN or inf (a NaN or inf target or configuration?)"
        if outcome == K.NAN_DATA:
            return "NaN or inf in the QP's data"
        if outcome == K.EMPTY_BOX:
            return f"empty box on variable {empty}: lower {lb[empty]:.6g} > upper {ub[empty]:.6g}"
        return None

    # -- inspection ------------------------------------------------------------------------
    def qdot(self) -> np.ndarray:
        """The last step's q̇ (N, nv), a host copy (zero in worlds with no answer)."""
        return self.x.numpy().astype(np.float64)

    def task_rows(self, task) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(error, Jacobian, target velocity) of ``task`` at the last step or
        :meth:`assemble`, host copies (a joint-space task's Jacobian is its selection)."""
        for rows in self._tasks:
            if rows.task is task:
                return rows.host_copies()
        raise InvalidInput(f"{task!r} is not one of this controller's tasks")

    def qp_data(self) -> dict[str, np.ndarray]:
        """The last QPs: H ((1 or N), nv, nv), c, A, b, lb, ub, host copies."""
        meq = self.meq
        return {"H": self.H.numpy(), "c": self.c.numpy(), "A": self.A.numpy()[:, :meq], "b": self.b.numpy()[:, :meq],
                "lb": self.lb.numpy(), "ub": self.ub.numpy()}



__all__ = ["DeviceStep", "unsupported"]
