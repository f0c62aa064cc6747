r"""MuJoCo's equality constraints (closed chains, welds, coupled joints and tendons) as task
rows, in every world."""

from __future__ import annotations

from typing import Sequence

import mujoco
import numpy as np

from ..equalities import SUPPORTED, active_equalities, equality_label, equality_row_ids
from ..errors import InvalidInput, ModelError
from .inputs import feedback_gain, positive_scalar
from .task import ScalarGain, Task


class EqualityTask(ScalarGain, Task):
    r"""The model's equality constraints (``connect``, ``weld``, ``joint``, ``tendon``) as rows

    .. math::
        J_e\,\dot q = -K\,e_e,

    hard (the default: closed kinematic chains stay closed) or soft, in every world.
    :math:`e_e` and :math:`J_e` are MuJoCo's own constraint residual and Jacobian
    (``efc_pos``, ``efc_J`` of ``mj_makeConstraint``, every other constraint type
    disabled), as the robot's :meth:`equality_rows` gives them: a ``connect`` gives the 3
    rows :math:`p_1 - p_2`, a ``weld`` 6 (position, then orientation scaled by its
    ``torquescale``), a ``joint`` or ``tendon`` coupling 1 (its polynomial residual).
    Rows follow the equalities' ids. On N worlds (:class:`qpik.batch.Robot`) the
    back-end writes the types it batches and MuJoCo's C the others, world by world
    (:meth:`qpik.batch.Robot.equality_rows` says which).

    ``error`` holds the residual :math:`e_e` (zero when the constraints hold).

    Args:
        robot: the robot (one world or N).
        equalities: names of the equalities to enforce (default: every equality active
            when the task is built, ``data.eq_active``, that acts on a dof: MuJoCo makes
            no row for one that does not, such as a weld of a jointless body to the world).
        gain: K (1/s), one number; by default 1/Δt of the controller the task is given to
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

    The set of active equalities is read when the task is built (on world 0); switching
    one on or off later (``data.eq_active``) makes :meth:`update` raise ModelError.
    """

    name = "equality task"
    gain_label = "equality task gain"

    def __init__(self, robot, equalities: Sequence[str] | None = None, gain: float | None = None,
                 hard: bool = True, weight=1.0):
        robot.update_kinematics()
        world = robot.world(0)  # world 0 as a one-world robot (its MjData), kinematics current
        ids = self._chosen(robot, equalities, active_equalities(robot.model, world.data))
        if gain is not None:
            gain = positive_scalar(gain, self.gain_label, allow_zero=True)
        efc_id = equality_row_ids(robot.model, world.data)  # where each equality's rows lie
        ids = self._acting(robot, ids, efc_id, named=equalities is not None)
        self.equalities = tuple(ids)  # model equality ids, in row order
        sizes = [int(np.count_nonzero(efc_id == i)) for i in ids]
        super().__init__(robot, sum(sizes), weight, hard)
        self.dead_beat = gain is None
        self.set_gain(feedback_gain(gain, self.dim, f"{self.name} gain"))  # NaN until attach() when dead-beat
        self._starts = np.cumsum([0] + sizes[:-1])  # each equality's first row
        robot.equality_rows(self.equalities)  # the rows' layout read now: a later change is refused

    def _chosen(self, robot, equalities, active: list[int]) -> list[int]:
        """The ids of the named equalities (ascending; default: the active ones), checked."""
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
        unsupported = [i for i in ids if int(robot.model.eq_type[i]) not in SUPPORTED]
        if unsupported:
            kind = mujoco.mjtEq(int(robot.model.eq_type[unsupported[0]])).name
            raise ModelError(f"{self.name}: equality {equality_label(robot.model, unsupported[0])!r} is a {kind}; "
                             f"supported: {[name for name, _ in SUPPORTED.values()]}")
        return ids

    def _acting(self, robot, ids: list[int], efc_id: np.ndarray, named: bool) -> list[int]:
        """The equalities MuJoCo makes rows for: one that acts on no dof (a weld of a
        jointless body to the world) has none, and no velocity can change its residual;
        left out of the default set, refused when named."""
        idle = [i for i in ids if i not in efc_id]
        if idle and named:
            labels = [equality_label(robot.model, i) for i in idle]
            raise ModelError(f"{self.name}: equalities {labels} act on no dof (their bodies, joints or "
                             "tendons move with no joint): MuJoCo makes no row for them")
        acting = [i for i in ids if i not in idle]
        if not acting:
            raise ModelError(f"{self.name}: model {robot.name!r} has no active equality constraint that acts "
                             "on a dof")
        return acting

    # -- every step -------------------------------------------------------------------------
    def measure_rows(self) -> None:
        residual, jacobian = self.robot.equality_rows(self.equalities)
        np.copyto(self.errors, residual)
        np.copyto(self.jacobians, jacobian)

    def track(self) -> None:
        """v = −K e in every world."""
        np.multiply(self.gains, self.errors, self.target_velocities)
        np.negative(self.target_velocities, self.target_velocities)

    # -- diagnostics --------------------------------------------------------------------------
    def _residual_norms(self, robot) -> np.ndarray:
        """(N, k) the norm of each equality's residual in every world of ``robot``."""
        robot.ensure_kinematics()
        residual = robot.equality_rows(self.equalities)[0]
        return np.sqrt(np.add.reduceat(residual * residual, self._starts, axis=1))

    def residuals(self, robot=None) -> np.ndarray:
        """The norm of each equality's residual (its units: m, rad, ...), in row order, at
        the configuration of the bound robot or of another robot of the same model: (k,)
        for one robot, (N, k) for N worlds (the robot's kinematics brought up to date; its
        constraint rows rewritten).

        Raises:
            ModelError: the robot's active equalities differ from the task's.
        """
        robot = robot or self.robot
        return robot.present(self._residual_norms(robot))

    def max_residual(self, robot=None):
        """The largest residual norm of :meth:`residuals` (e.g. a loop-closure gap in m): a
        float for one robot, (N,) for N worlds."""
        robot = robot or self.robot
        return robot.present(self._residual_norms(robot).max(axis=1))
