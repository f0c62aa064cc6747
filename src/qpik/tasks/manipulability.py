r"""Manipulability measures (the σ proxy here; Yoshikawa's in :mod:`.yoshikawa`) and the task
that climbs their gradient in the null space."""

from __future__ import annotations

from typing import Protocol, Sequence

import mujoco
import numpy as np

from ..errors import DivergenceError, InvalidInput
from ..numerics import all_finite
from .inputs import as_index, positive_scalar
from .task import JointSpaceTask

_ROTATING = (int(mujoco.mjtJoint.mjJNT_BALL), int(mujoco.mjtJoint.mjJNT_FREE))
OVERFLOWED = ("the manipulability gradient overflowed (the configuration diverged, e.g. an unlimited joint "
              "extending): add joint limits")


class ManipulabilityMeasure(Protocol):
    """A scalar measure m(q) of dexterity and its gradient over the dofs."""

    label: str

    def value(self, robot=None):
        """m(q) as a user reads it (a number for one robot, (N,) for N worlds), of the
        bound robot or of another robot on the same model."""
        ...

    def gradient(self) -> np.ndarray:
        """∂m/∂q (N, nv) of every world at the bound robot's current kinematics: an array
        of the measure's, overwritten by the next call."""
        ...


class SigmaProxy:
    r"""The proxy :math:`\sigma(q) = \tfrac12 \sum_j \sin^2 q_j` over chosen hinge joints
    (maximum at :math:`\pm\pi/2`), :math:`\partial\sigma/\partial q_j = \sin q_j \cos q_j`.
    On the arm, with joints θ2 and θ3, σ = ½(sin²θ2 + sin²θ3), the source's measure.

    Args:
        robot: the robot (one world or N).
        joints: the hinge or slide joints it sums over (no default: which joints make a
            robot dexterous is the robot's own business).

    Raises:
        UnknownName: an unknown joint (the closest are listed).
        InvalidInput: no joint, the same joint twice, or a ball or free joint.
    """

    label = "sigma"

    def __init__(self, robot, joints: Sequence[str]):
        if isinstance(joints, str) or not len(joints):
            raise InvalidInput(f"SigmaProxy needs a list of joint names, got {joints!r}")
        if len(set(joints)) != len(joints):
            raise InvalidInput(f"a joint is named twice in {list(joints)}")
        ids = [robot.joint_id(j) for j in joints]
        rotating = [j for j, i in zip(joints, ids) if int(robot.model.jnt_type[i]) in _ROTATING]
        if rotating:
            raise InvalidInput(f"SigmaProxy sums sin² of scalar joints; {rotating} are ball or free joints")
        self.robot = robot
        self.joints = tuple(joints)
        self.qpos_index = np.array([robot.model.jnt_qposadr[i] for i in ids], dtype=int)
        self.dof_index = np.array([robot.model.jnt_dofadr[i] for i in ids], dtype=int)
        self._gradient = np.zeros((robot.n, robot.nv))  # zero off the measure's dofs
        self._angles = np.zeros((robot.n, len(ids)))
        self._qpos, self._dofs = as_index(self.qpos_index), as_index(self.dof_index)  # slices where consecutive

    def values(self, qpos: np.ndarray) -> np.ndarray:
        """σ of configurations (N, nq), (N,)."""
        s = np.sin(qpos[:, self.qpos_index])
        return 0.5 * np.einsum("ni,ni->n", s, s)

    def value(self, robot=None):
        """σ as a user reads it: of the bound robot or another of the same model."""
        robot = robot or self.robot
        return robot.present(self.values(robot.qpos))

    def gradient(self) -> np.ndarray:
        """∂σ/∂q (N, nv) of every world: ½ sin 2q_j on the measure's joints (an array of the
        measure's, overwritten by the next call)."""
        angles = self._angles
        np.multiply(self.robot.qpos[:, self._qpos], 2.0, angles)
        np.sin(angles, angles)
        np.multiply(angles, 0.5, angles)
        self._gradient[:, self._dofs] = angles
        return self._gradient


class ManipulabilityTask(JointSpaceTask):
    """Posture task toward the manipulability gradient: cost ½ w ‖q̇ − k0 ∇m(q)‖².

    Written as a quadratic in q̇ with J = I (not as a bare linear term -w k0 ∇mᵀq̇,
    which with a tiny regulariser drives the null-space velocity to its bounds).
    With a hard primary task this is exactly the null-space law
    q̇ = J†v + (I − J†J) k0 ∇m.

    Args:
        robot: the robot (one world or N).
        measure: the measure m whose gradient (over every dof) the task follows.
        gain: k0.
        weight: cost weight.
        joints: joints whose dofs the task covers (default: every hinge and slide joint).
    """

    name = "manipulability task"

    def __init__(self, robot, measure: ManipulabilityMeasure, gain: float = 5.0, weight=1.0,
                 joints: Sequence[str] | None = None):
        super().__init__(robot, joints, weight)
        self.measure = measure
        self.gain = gain
        self._dofs = as_index(self.dofs)

    @property
    def gain(self) -> float:
        return self._gain

    @gain.setter
    def gain(self, value) -> None:
        self._gain = positive_scalar(value, "manipulability gain", allow_zero=True)
        self._k = np.array(self._gain)

    def track(self) -> None:
        """v = k0 ∇m on the task's dofs, in every world."""
        gradient = self.measure.gradient()
        part = gradient[:, self._dofs] if isinstance(self._dofs, slice) else gradient.take(self._dofs, 1)
        np.multiply(part, self._k, self.target_velocities)
        if not all_finite(self.target_velocities):
            raise DivergenceError(f"{self.name}: {OVERFLOWED}")
