r"""The interface a batched back-end implements: the N worlds' state and kinematics.

:mod:`qpik.batch` runs qpik's tasks, limits and controllers (written once over N worlds)
over N *worlds*: N copies of one MuJoCo model, each with its own configuration and
targets. What depends on where the worlds live (the CPU's memory, a GPU's) sits behind
:class:`KinematicsBackend`: the N configurations, their kinematics (frame poses,
Jacobians, centres of mass, equality-constraint rows), the integration
:math:`q \leftarrow q \oplus \dot q\,\Delta t` and the physics step. The step's math
(the tasks' rows, the limits, the solve) is the engine's, on the host, for every
back-end.

``backend="cpu"`` (:mod:`qpik.batch.backends.cpu`) is MuJoCo's own thread pool
(``mujoco.batch.Batch``) and NumPy; ``backend="warp"``
(:mod:`qpik.batch.backends.warp`) is MuJoCo Warp on a Warp device.

Conventions for every method below
----------------------------------
- ``N`` is ``nworld``; ``nq``, ``nv``, ``nu`` are the model's sizes.
- Arrays crossing the interface are C-contiguous NumPy ``float64`` arrays on the host
  (indices ``int64``, flags ``bool``). A device back-end copies to and from the host
  at these calls (or keeps a host mirror); the engine's tasks and limits only ever see
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

import mujoco
import numpy as np

__all__ = ["KinematicsBackend"]


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
        device: where the kinematics run when not on the host: a device back-end's
            device (the engine's step then runs on the host and says so:
            :class:`~qpik.errors.HostStepWarning`); None on the CPU.
        model: the host ``mujoco.MjModel`` (the caller's object: read sizes, ids,
            ranges from it; the back-end never writes it).
        nworld: N.
        qpos: ``(N, nq)`` float64, owned by the back-end and **writable**: the worlds'
            configurations. Writing it marks nothing: the caller calls
            :meth:`forward` before reading kinematics again.
    """

    name = "base"
    device = None
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
    def frame_pose(self, frame_type: str, frame_id: int,
                   rotation: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        """World pose of a site, body (its origin) or geom in every world.

        Args:
            frame_type: ``"site"``, ``"body"`` or ``"geom"``.
            frame_id: the object's id in the model.
            rotation: False: the position only (rotation None, except a geom's): no field copied out unread.

        Returns:
            ``(position (N, 3), rotation (N, 3, 3))``, owned by the back-end (current
            after every :meth:`forward`; read-only).
        """

    @abstractmethod
    def jacobian(self, body: int, points: np.ndarray, out_p: np.ndarray | None = None,
                 out_r: np.ndarray | None = None, rotational: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        """MuJoCo's ``mj_jac`` in every world: translational and rotational Jacobians
        of a point fixed on ``body``.

        Args:
            body: the body id.
            points: ``(N, 3)`` world positions of the point (e.g. a site's position
                from :meth:`frame_pose`).
            out_p, out_r: optional ``(N, 3, nv)`` arrays to write into.
            rotational: False: the translational Jacobian only (jacr None, ``out_r`` unread).

        Returns:
            ``(jacp (N, 3, nv), jacr (N, 3, nv))``: ``out_p``/``out_r`` when given,
            else new arrays. Equal to ``mj_jac`` of each world to rounding.
        """

    def _field(self, name: str) -> np.ndarray:
        """A MjData field of every world on the host, ``(N, ...)`` float64, current after
        every :meth:`forward` (read by the methods written here once for every back-end)."""
        raise NotImplementedError

    @abstractmethod
    def subtree_com(self, body: int) -> np.ndarray:
        """``(N, 3)`` centre of mass of ``body``'s subtree (``data.subtree_com``), owned
        by the back-end, read-only."""

    def subtree_com_jacobian(self, body: int, out: np.ndarray | None = None) -> np.ndarray:
        """``(N, 3, nv)`` Jacobian of :meth:`subtree_com` (``mj_jacSubtreeCom``), into
        ``out`` when given: the mass-weighted :meth:`jacobian` of each massive body's
        centre of mass in the subtree (``_field("xipos")``, ``_subtrees`` a dict)."""
        m, n = self.model, self.nworld
        if body not in self._subtrees:
            members = [b for b in range(body, m.nbody) if _descends(m, b, body)]
            self._subtrees[body] = [b for b in members if m.body_mass[b] > 0.0]
        xipos = self._field("xipos").reshape(n, -1, 3)
        total = np.zeros((n, 3, m.nv)) if out is None else out
        total.fill(0.0)
        jacp = np.empty((n, 3, m.nv))
        for b in self._subtrees[body]:
            self.jacobian(b, xipos[:, b], jacp, rotational=False)
            jacp *= m.body_mass[b]
            total += jacp
        total *= 1.0 / m.body_subtreemass[body]
        return total

    @abstractmethod
    def equality_rows(self, equalities: np.ndarray, out=None) -> tuple[np.ndarray, np.ndarray]:
        """Residuals and Jacobians of equality constraints, in MuJoCo's row layout
        (``efc_pos``, ``efc_J`` of ``mj_makeConstraint``): 3 rows per ``connect``, 6 per
        ``weld`` (position, then orientation scaled by its torquescale), 1 per
        ``joint`` coupling, in the order of ``equalities``.

        Args:
            equalities: ``int64`` equality ids, ascending.
            out: ``(residual, jacobian)`` to write into (the Jacobian's entries off the
                equalities' dofs left as they are: zeros the caller made once), or None.

        Returns:
            ``(residual (N, m), jacobian (N, m, nv))``: ``out``, or new arrays.

        Raises:
            qpik.batch.NotBatched: an equality type the back-end cannot write rows for.
        """

    # -- state -------------------------------------------------------------------------
    def integrate(self, qvel: np.ndarray, dt: float, ids: np.ndarray | None = None) -> None:
        """``qpos ← qpos ⊕ qvel·dt`` on the configuration manifold, as
        ``mj_integratePos`` (quaternions of ball and free joints integrated and
        normalised), in place, on the host (``_integration``: the model's
        :class:`~qpik.batch.backends.cpu._Integration`).

        Args:
            qvel: ``(N, nv)``, or ``(len(ids), nv)`` with ``ids``; finite (the caller
                checks).
            dt: the step, positive and finite.
            ids: the worlds to move, or None for all.
        """
        if ids is None:
            self._integration.apply(self.qpos, qvel, dt)
        else:
            qpos = self.qpos[ids]
            self._integration.apply(qpos, qvel, dt)
            self.qpos[ids] = qpos

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


def _descends(model: mujoco.MjModel, body: int, ancestor: int) -> bool:
    while body > ancestor:
        body = int(model.body_parentid[body])
    return body == ancestor
