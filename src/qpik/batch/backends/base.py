r"""The two interfaces a batched back-end implements: kinematics, and the batched QP.

:mod:`qpik.batch` runs the same tasks, limits and controllers over N *worlds*: N copies
of one MuJoCo model, each with its own configuration and targets. Everything that
depends on where the arrays live (the CPU's memory, a GPU's) sits behind two classes:

- :class:`KinematicsBackend`: the N configurations, their kinematics (frame poses,
  Jacobians, centres of mass, equality-constraint rows), the integration
  :math:`q \leftarrow q \oplus \dot q\,\Delta t` and the physics step;
- :class:`BatchQP`: N strictly convex QPs of one size,

  .. math::
      \min_x \tfrac12 x^T H x + c^T x \quad\text{s.t.}\quad A x = b,\quad lb \le x \le ub,

  solved to the serial solvers' tolerances, every world's answer checked.

``backend="cpu"`` (:mod:`qpik.batch.backends.cpu`) is MuJoCo's own thread pool
(``mujoco.batch.Batch``) and NumPy; a GPU back-end (MuJoCo Warp) implements the same
two classes.

Conventions for every method below
----------------------------------
- ``N`` is ``nworld``; ``nq``, ``nv``, ``nu`` are the model's sizes.
- Arrays crossing the interface are C-contiguous NumPy ``float64`` arrays on the host
  (indices ``int64``, flags ``bool``). A device back-end copies to and from the host
  at these calls (or keeps a host mirror); the batched tasks and limits only ever see
  NumPy.
- *Owned by the back-end* means the back-end allocates the array once and overwrites
  it in place: a caller may keep a reference (it stays valid, and current after the
  next :meth:`KinematicsBackend.forward`) but must not write it, unless it is said to
  be writable. *Returned* arrays without that mention are new arrays the caller owns.
- ``ids`` (``int64``, sorted, unique) selects worlds; ``None`` means all N.
- Worlds are independent: a NaN in one world's state never changes another world's
  results.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import mujoco
import numpy as np

__all__ = ["BatchQP", "KinematicsBackend", "QPResult", "QPStatus"]


class KinematicsBackend(ABC):
    """N worlds of one model: their state, their kinematics, their physics.

    Life cycle of a control step (what :class:`qpik.batch.Robot` calls):

    1. the configurations ``qpos`` are written (``Robot.set_q``, :meth:`integrate`);
    2. :meth:`forward` computes every world's kinematics at ``qpos`` (position stage:
       body, site and geom poses, the centres of mass and the quantities Jacobians
       need) — once per control step, whatever the number of tasks;
    3. the getters below read them: they never run the kinematics again.

    Args (of a subclass's constructor, called by ``Robot``):
        model: the compiled model; the back-end keeps its own copy (or a device copy)
            and never writes the caller's.
        nworld: N, at least 1.
        options: back-end specific (``nthread`` on the CPU, ``device`` on a GPU).

    Attributes:
        name: the back-end's name (``"cpu"``, ``"warp"``).
        model: the host ``mujoco.MjModel`` (the caller's object: read sizes, ids,
            ranges from it; the back-end never writes it).
        nworld: N.
        qpos: ``(N, nq)`` float64, owned by the back-end and **writable**: the worlds'
            configurations. Writing it marks nothing: the caller calls
            :meth:`forward` before reading kinematics again.
    """

    name = "base"
    model: mujoco.MjModel
    nworld: int
    qpos: np.ndarray

    # -- kinematics ------------------------------------------------------------------
    @abstractmethod
    def forward(self) -> None:
        """Compute the kinematics of every world at its ``qpos`` (no dynamics needed:
        ``mj_kinematics`` and ``mj_comPos``, or their device equivalents). A world
        whose ``qpos`` is not finite gets non-finite kinematics, the others are
        unaffected."""

    @abstractmethod
    def frame_pose(self, frame_type: str, frame_id: int) -> tuple[np.ndarray, np.ndarray]:
        """World pose of a site, body (its origin) or geom in every world.

        Args:
            frame_type: ``"site"``, ``"body"`` or ``"geom"``.
            frame_id: the object's id in the model.

        Returns:
            ``(position (N, 3), rotation (N, 3, 3))``, owned by the back-end (current
            after every :meth:`forward`; read-only).
        """

    @abstractmethod
    def jacobian(self, body: int, points: np.ndarray, out_p: np.ndarray | None = None,
                 out_r: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """MuJoCo's ``mj_jac`` in every world: translational and rotational Jacobians
        of a point fixed on ``body``.

        Args:
            body: the body id.
            points: ``(N, 3)`` world positions of the point (e.g. a site's position
                from :meth:`frame_pose`).
            out_p, out_r: optional ``(N, 3, nv)`` arrays to write into.

        Returns:
            ``(jacp (N, 3, nv), jacr (N, 3, nv))``: ``out_p``/``out_r`` when given,
            else new arrays. Equal to ``mj_jac`` of each world to rounding.
        """

    @abstractmethod
    def subtree_com(self, body: int) -> np.ndarray:
        """``(N, 3)`` centre of mass of ``body``'s subtree (``data.subtree_com``), owned
        by the back-end, read-only."""

    @abstractmethod
    def subtree_com_jacobian(self, body: int, out: np.ndarray | None = None) -> np.ndarray:
        """``(N, 3, nv)`` Jacobian of :meth:`subtree_com` (``mj_jacSubtreeCom``), into
        ``out`` when given."""

    @abstractmethod
    def equality_rows(self, equalities: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Residuals and Jacobians of equality constraints, in MuJoCo's row layout
        (``efc_pos``, ``efc_J`` of ``mj_makeConstraint``): 3 rows per ``connect``, 6 per
        ``weld`` (position, then orientation scaled by its torquescale), 1 per
        ``joint`` coupling, in the order of ``equalities``.

        Args:
            equalities: ``int64`` equality ids, ascending.

        Returns:
            ``(residual (N, m), jacobian (N, m, nv))``, new arrays.

        Raises:
            qpik.batch.NotBatched: an equality type the back-end cannot write rows for.
        """

    # -- state -------------------------------------------------------------------------
    @abstractmethod
    def integrate(self, qvel: np.ndarray, dt: float, ids: np.ndarray | None = None) -> None:
        """``qpos ← qpos ⊕ qvel·dt`` on the configuration manifold, as
        ``mj_integratePos`` (quaternions of ball and free joints integrated and
        normalised), in place.

        Args:
            qvel: ``(N, nv)``, or ``(len(ids), nv)`` with ``ids``; finite (the caller
                checks).
            dt: the step, positive and finite.
            ids: the worlds to move, or None for all.
        """

    # -- physics -----------------------------------------------------------------------
    @abstractmethod
    def physics_reset(self, qpos: np.ndarray, ctrl: np.ndarray) -> None:
        """Start the physics worlds at ``qpos (N, nq)`` with zero velocity and
        ``ctrl (N, nu)`` applied (the kinematic worlds are not touched)."""

    @abstractmethod
    def physics_step(self, ctrl: np.ndarray, nstep: int) -> tuple[np.ndarray, np.ndarray]:
        """Apply ``ctrl (N, nu)`` and advance every physics world by ``nstep``
        ``mj_step`` calls.

        Returns:
            ``(qpos (N, nq), unstable (N,) bool)``: the physics worlds'
            configurations (owned by the back-end, read-only), and which worlds
            MuJoCo found unstable (a warning counter rose: it then resets such a
            world, so its state means nothing).
        """


class QPStatus:
    """Per-world outcome codes of :meth:`BatchQP.solve` (``int8``)."""

    SOLVED = 0  # the checked minimiser: hard rows to 1e-9 relative, bounds to 1e-9
    INFEASIBLE = 1  # no point meets the hard rows and the box (or the box is empty)
    FAILED = 2  # no solver found the minimiser (non-finite data, ill-conditioned rows)
    SKIPPED = 3  # not solved: the caller masked the world out (``active`` False)

    LABELS = {SOLVED: "solved", INFEASIBLE: "infeasible", FAILED: "solver failure", SKIPPED: "skipped"}


@dataclass
class QPResult:
    """What :meth:`BatchQP.solve` returns.

    Attributes:
        x: ``(N, nv)`` float64, owned by the solver (overwritten by the next solve):
            the minimiser of each SOLVED world; **zero** in every other world (never
            NaN).
        status: ``(N,)`` int8, :class:`QPStatus` codes.
        reasons: world id → a one-line reason, for every world not SOLVED.
        closed_form: ``(N,)`` bool: the world's answer is the equality-constrained
            closed form (no bound active).
        fallback: ``(N,)`` bool: the world was solved by the serial solver (DAQP)
            because the batched active set did not settle.
        iterations: active-set iterations of the batched method (the largest over
            the worlds that needed it; 0 when every world was closed form).
    """

    x: np.ndarray
    status: np.ndarray
    reasons: dict[int, str]
    closed_form: np.ndarray
    fallback: np.ndarray
    iterations: int = 0


class BatchQP(ABC):
    r"""N strictly convex QPs of one size, solved exactly:

    .. math::
        \min_x \tfrac12 x^T H_k x + c_k^T x \quad\text{s.t.}\quad
        A_k x = b_k,\quad lb_k \le x \le ub_k,\qquad k = 1..N.

    The promise is each world's exact minimiser (the one the serial controller's
    closed form or DAQP returns, to their tolerances), checked: hard rows met to
    ``1e-9 (1 + |b|)``, bounds to ``1e-9``. A world that cannot keep it is
    INFEASIBLE or FAILED with a reason, its ``x`` zero; the others are unaffected.

    A solver keeps per-world state between calls (the last active set, for a warm
    start); :meth:`reset` forgets it.

    Args (of a subclass's constructor):
        nworld: N.
        nv: variables per world.
        meq: equality rows per world (0 allowed).
    """

    name = "base"

    def __init__(self, nworld: int, nv: int, meq: int):
        self.nworld, self.nv, self.meq = int(nworld), int(nv), int(meq)

    @abstractmethod
    def solve(self, H: np.ndarray, c: np.ndarray, A: np.ndarray, b: np.ndarray, lb: np.ndarray,
              ub: np.ndarray, active: np.ndarray | None = None) -> QPResult:
        """Solve every world.

        Args:
            H: ``(nv, nv)`` shared by all worlds, or ``(N, nv, nv)``; symmetric positive
                definite (the controller's regulariser makes it so).
            c: ``(N, nv)``.
            A: ``(N, meq, nv)`` (``meq`` may be 0).
            b: ``(N, meq)``.
            lb, ub: ``(N, nv)``, ``±inf`` where a variable is unbounded.
            active: ``(N,)`` bool, the worlds to solve (None: all); the others are
                SKIPPED with ``x`` zero.

        Inputs are read, never written, and not kept after the call.

        Returns:
            A :class:`QPResult`.
        """

    def reset(self) -> None:
        """Forget every world's warm start."""
