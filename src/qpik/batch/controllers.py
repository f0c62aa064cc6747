r"""Batched controllers: the serial QP and pseudoinverse laws over N worlds.

:class:`QPController` builds, every step, each world's QP exactly as the serial
:class:`qpik.QPController` does — H = εI + the joint-space tasks' weights on the
diagonal + Σ JᵀWJ of the other soft tasks (+ the Levenberg–Marquardt terms, with the same
rescaling), c = −Σ JᵀWv, the hard tasks' rows A q̇ = b and the limits' box — and solves
all of them with the batched QP (:mod:`qpik.batch.qp`). :class:`PseudoinverseController`
is the classical law :math:`J^\dagger v + (I - J^\dagger J)\dot q_0`.

A world whose data are not finite (a NaN target) or whose QP has no answer gets zero
velocity; the others are solved, then :class:`~qpik.batch.WorldsFailed` names the
failing worlds and why (its ``qdot`` holds every world's answer).
"""

from __future__ import annotations

import warnings
from typing import Sequence

import numpy as np

from ..errors import InvalidInput
from ..problem.problem import check_dt
from .errors import HostStepWarning, NotBatched, WorldsFailed
from .limits import Limit
from .qp import ActiveSetQP
from .robot import Robot
from .tasks import Task

# The serial controller's constants (qpik.controllers.qp, qpik.controllers.pinv).
LM_RESCALE = 1e6
DIVERGED_SPEED = 1e100


def check_same_robots(robots: Robot, items, what: str) -> None:
    for item in items:
        if getattr(item, "robots", robots) is not robots:
            raise InvalidInput(f"{what}: {getattr(item, 'name', type(item).__name__)!r} was built on other "
                               "batch.Robot worlds: build every task and limit on the controller's robots")


def non_finite_worlds(tasks: Sequence[Task], reasons: dict[int, str]) -> np.ndarray:
    """(N,) bool: worlds where a task's velocity or Jacobian is not finite, each named in
    ``reasons`` with the first such task."""
    bad = np.zeros(len(tasks[0].target_velocity), dtype=bool)
    for task in tasks:
        # A sum is finite when every entry is (an overflowing sum only sends it on to
        # the per-world test).
        arrays = [task.target_velocity] + ([] if task.joint_space else [task.jacobian])
        if np.isfinite([a.sum() for a in arrays]).all():
            continue
        rows = ~np.isfinite(task.target_velocity).all(axis=1)
        if not task.joint_space:
            rows |= ~np.isfinite(task.jacobian).all(axis=(1, 2))
        for w in np.flatnonzero(rows):
            reasons.setdefault(int(w), f"the {task.name}'s target velocity or Jacobian is NaN or inf "
                                       "(a NaN or inf target or configuration?)")
        bad |= rows
    return bad


class QPController:
    """Batched :class:`qpik.QPController` (one QP per world, each exact).

    Args:
        robots: the worlds.
        tasks: batched tasks (hard or soft).
        limits: batched limits (boxes).
        dt: the control period (s).
        regularization: ε on H's diagonal (the serial default).
        max_iterations: the batched active set's rounds before DAQP takes a world.
    """

    kind = "qp"
    step_path: str | None = None  # how step() runs: "device" or "host" (None before the first step)
    host_step_reason: str | None = None
    device_step = None  # the back-end's device-resident step, when step() runs there

    def __init__(self, robots: Robot, tasks: Sequence[Task], limits: Sequence[Limit] = (), dt: float | None = None,
                 regularization: float = 1e-12, max_iterations: int | None = None):
        if not tasks:
            raise InvalidInput("a QPController needs at least one task")
        self.dt = check_dt(dt)
        check_same_robots(robots, [*tasks, *limits], "batch.QPController")
        self.robots, self.tasks = robots, list(tasks)
        for task in self.tasks:
            task.attach(self.dt)
        self.limits = sorted(limits, key=lambda lim: 0 if lim.constant else 1)
        n, nv = robots.n, robots.nv
        self._hard = [t for t in self.tasks if t.hard]
        soft = [t for t in self.tasks if not t.hard]
        self._diagonal = [t for t in soft if t.joint_space]
        self._general = [t for t in soft if not t.joint_space]
        self.meq = sum(t.dim for t in self._hard)
        self.H0 = np.eye(nv) * float(regularization)
        for task in self._diagonal:
            self.H0[task.dofs, task.dofs] += task.weight
        self._H0_diagonal = np.diag(self.H0).copy()
        if self._general:  # H per world, built in place every step
            self._H = np.empty((n, nv, nv))
            self._product = np.empty((n, nv, nv)) if len(self._general) > 1 else None
        self._lb0, self._ub0 = np.full((n, nv), -np.inf), np.full((n, nv), np.inf)
        for limit in self.limits:
            if limit.constant:
                limit.apply(self.dt, self._lb0, self._ub0)
        self._dynamic = [lim for lim in self.limits if not lim.constant]
        # A device back-end solves the QPs where its kinematics live (make_qp); the CPU's
        # are solved in NumPy.
        make_qp = getattr(robots.backend, "make_qp", None)
        self.qp = make_qp(nv, self.meq, max_iterations) if make_qp else ActiveSetQP(n, nv, self.meq, max_iterations)
        self.qdot = np.zeros((n, nv))
        self.result = None  # the last step's QPResult

    def compute_velocity(self) -> np.ndarray:
        """Every world's q̇ (N, nv).

        Raises:
            WorldsFailed: some worlds have no answer (listed, with why); the others are
                solved and on the exception's ``qdot``.
        """
        self.robots.ensure_kinematics()
        for task in self.tasks:
            task.update()
        reasons: dict[int, str] = {}
        bad = non_finite_worlds(self.tasks, reasons)
        H, c = self._cost()
        A = np.concatenate([t.jacobian for t in self._hard], axis=1) if self._hard else np.zeros((self.robots.n, 0, self.robots.nv))
        b = np.concatenate([t.target_velocity for t in self._hard], axis=1) if self._hard else np.zeros((self.robots.n, 0))
        lb, ub = self._lb0.copy(), self._ub0.copy()
        for limit in self._dynamic:
            limit.apply(self.dt, lb, ub)
        self.lb, self.ub = lb, ub
        with np.errstate(invalid="ignore", over="ignore"):
            result = self.qp.solve(H, c, A, b, lb, ub, active=~bad)
        self.result = result
        self.qdot = result.x.copy()
        reasons.update(result.reasons)
        if reasons:
            raise WorldsFailed(reasons, self.qdot, "batch.QPController")
        return self.qdot

    def step(self) -> None:
        """One control step of every world: q ← q ⊕ q̇·dt.

        On a back-end with a device-resident step (warp) and tasks and limits it covers,
        the whole step stays on the device (``device_step``); otherwise it is
        :meth:`compute_velocity` and ``robots.integrate``, and on a device back-end a
        :class:`~qpik.batch.HostStepWarning` says why (``step_path``, ``host_step_reason``).

        Raises:
            WorldsFailed: some worlds have no answer (listed, with why): they keep their
                configuration, the others moved.
        """
        if self.step_path is None:
            self._choose_step_path()
        if self.device_step is not None:
            self.device_step.run()
            return
        try:
            qdot = self.compute_velocity()
        except WorldsFailed as failed:
            self.robots.integrate(failed.qdot, self.dt)
            raise
        self.robots.integrate(qdot, self.dt)

    def _choose_step_path(self) -> None:
        backend = self.robots.backend
        self.step_path, self.host_step_reason = "host", f"the {backend.name} back-end steps on the host"
        if backend.name != "warp":
            return
        from .backends.warp_step import DeviceStep  # the warp back-end's device-resident step

        try:
            self.device_step, self.step_path, self.host_step_reason = DeviceStep(backend, self), "device", None
        except NotBatched as why:
            self.host_step_reason = str(why)
            warnings.warn(f"batch.QPController.step runs on the host: {why}", HostStepWarning, stacklevel=3)

    def _cost(self) -> tuple[np.ndarray, np.ndarray]:
        """H ((nv, nv) shared, or (N, nv, nv) with general soft tasks) and c (N, nv)."""
        n, nv = self.robots.n, self.robots.nv
        c = np.zeros((n, nv))
        for task in self._diagonal:
            c[:, task.dofs] -= task.weight * task.target_velocity
        if not self._general:
            return self.H0, c
        H = self._H
        lm_total = np.zeros(n)
        diagonal = H.reshape(n, nv * nv)[:, ::nv + 1]
        for k, task in enumerate(self._general):
            weighted = task.weight[None, :, None] * task.jacobian
            if k == 0:  # H = H0 + JᵀWJ, H0 diagonal
                np.matmul(task.jacobian.transpose(0, 2, 1), weighted, out=H)
                diagonal += self._H0_diagonal
            else:
                H += np.matmul(task.jacobian.transpose(0, 2, 1), weighted, out=self._product)
            c -= np.einsum("nk,nkj->nj", task.target_velocity, weighted)
            if task.lm_damping:
                lm = task.lm_damping * np.einsum("nk,k,nk->n", task.error, task.weight, task.error)
                diagonal += lm[:, None]
                lm_total += lm
        big = lm_total > LM_RESCALE
        if big.any():
            scale = 1.0 / (1.0 + lm_total[big])
            H[big] *= scale[:, None, None]
            c[big] *= scale[:, None]
        return H, c


class PseudoinverseController:
    """Batched :class:`qpik.PseudoinverseController`: q̇ = J†v + (I − J†J) q̇0 with
    J† = Jᵀ(JJᵀ + λ²I)⁻¹, the primary tasks stacked, q̇0 a joint-space task's velocity.
    No limits: that is the point of the comparison."""

    kind = "pinv"

    def __init__(self, robots: Robot, primary: Sequence[Task], secondary: Task | None = None, damping: float = 0.0):
        if not primary:
            raise InvalidInput("the controller needs at least one primary task")
        check_same_robots(robots, [*primary, *([secondary] if secondary else [])], "batch.PseudoinverseController")
        for task in primary:
            if task.needs_period:
                raise InvalidInput(f"{task.name}: its default gain is 1/dt of a QP controller's period; this law "
                                   "has none: give the task a gain (1/s)")
        for task in (*primary, *([secondary] if secondary else [])):
            task.attach(None)
        if secondary is not None and not secondary.joint_space:
            raise InvalidInput(f"the secondary task must be a joint-space task (J = I[dofs]), not a {secondary.name}")
        if not (np.isfinite(damping) and damping >= 0):
            raise InvalidInput(f"damping must be finite and >= 0, got {damping}")
        self.robots, self.primary, self.secondary, self.damping = robots, list(primary), secondary, float(damping)

    def compute_velocity(self) -> np.ndarray:
        """Every world's q̇ (N, nv); WorldsFailed for singular or diverged worlds."""
        robots = self.robots
        robots.ensure_kinematics()
        for task in self.primary:
            task.update()
        reasons: dict[int, str] = {}
        bad = non_finite_worlds(self.primary, reasons)
        J = np.concatenate([t.jacobian for t in self.primary], axis=1)
        v = np.concatenate([t.target_velocity for t in self.primary], axis=1)
        qdot0 = np.zeros((robots.n, robots.nv))
        rhs = v
        if self.secondary is not None:
            self.secondary.update()
            qdot0[:, self.secondary.dofs] = self.secondary.target_velocity
            rhs = v - np.einsum("nij,nj->ni", J, qdot0)
        gram = np.einsum("nik,njk->nij", J, J)
        if self.damping:
            gram += self.damping ** 2 * np.eye(gram.shape[1])
        J, gram, rhs = (np.where(bad[:, None, None], 0.0, J), np.where(bad[:, None, None], np.eye(gram.shape[1]), gram),
                        np.where(bad[:, None], 0.0, rhs))
        y, ok = _solve(gram, rhs)
        qdot = np.einsum("nji,nj->ni", J, y) + qdot0
        diverged = ~ok | ~(np.abs(qdot).max(axis=1, initial=0.0) <= DIVERGED_SPEED)
        for w in np.flatnonzero(diverged & ~bad):
            reasons[int(w)] = "pseudoinverse: J Jᵀ is singular or the velocity diverged (a singularity): give the law some damping"
        qdot[bad | diverged] = 0.0
        self.qdot = qdot
        if reasons:
            raise WorldsFailed(reasons, qdot, "batch.PseudoinverseController")
        return qdot


def _solve(M: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    from .qp import stacked_solve

    y, ok = stacked_solve(M, r[:, :, None])
    return y[:, :, 0], ok
