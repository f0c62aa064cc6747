"""qpik: QP-based differential inverse kinematics on MuJoCo models.

The public API is importable from here (``from qpik import Robot, FrameTask, QPController``).
Names load on first use, so ``import qpik`` (and the ``qpik`` command's help) does not pay
for MuJoCo, SciPy or the solvers until they are needed.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

__version__ = "0.1.0"

# Public name -> module that defines it.
_EXPORTS = {name: f"qpik.{module}" for module, names in (
    ("robot", "Robot Frame JointLimits load_model"),
    ("errors", "QpikError InvalidInput UnknownName ModelError OutsideJointLimits MissingExtra UnreachablePose "
               "InfeasibleProblem SolverError ConvergenceError DivergenceError GainWarning"),
    ("tasks", "Task JointSpaceTask PositionTask FrameTask PostureTask DampingTask ManipulabilityTask "
              "ManipulabilityMeasure SigmaProxy Yoshikawa OrientationTask RelativeFrameTask ComTask EqualityTask "
              "LookAtTask AxisAlignTask DofFreezingTask KineticEnergyRegularizationTask"),
    ("limits", "Limit CollisionAvoidanceLimit JointPositionLimit JointVelocityLimit FloatingBaseVelocityLimit "
               "AccelerationLimit"),
    ("controllers", "QPController HierarchicalController SNSController PseudoinverseController "
                    "JacobianTransposeController"),
    ("solvers", "available_solvers"),
    ("trajectories", "Segment Circle Hold PoseTrajectory"),  # trajectories, rollouts, scenarios
    ("rollout", "simulate RolloutLog PositionReference"),
    ("scenario", "Setup build_scenario scenarios"),
) for name in names.split()}

__all__ = sorted(_EXPORTS) + ["__version__"]


def __getattr__(name: str):
    if name == "batch":  # the batched engine, a subpackage: loaded on first use
        return importlib.import_module("qpik.batch")
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'qpik' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # later lookups skip this function
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


if TYPE_CHECKING:  # static type checkers see the real imports
    from .controllers import (HierarchicalController, JacobianTransposeController, PseudoinverseController,
                              QPController, SNSController)
    from .errors import (ConvergenceError, DivergenceError, GainWarning, InfeasibleProblem, InvalidInput,
                         MissingExtra, ModelError, OutsideJointLimits, QpikError, SolverError, UnknownName,
                         UnreachablePose)
    from .limits import (AccelerationLimit, CollisionAvoidanceLimit, FloatingBaseVelocityLimit, JointPositionLimit,
                         JointVelocityLimit, Limit)
    from .robot import Frame, JointLimits, Robot, load_model
    from .rollout import PositionReference, RolloutLog, simulate
    from .scenario import Setup, build_scenario, scenarios
    from .solvers import available_solvers
    from .tasks import (AxisAlignTask, ComTask, DampingTask, DofFreezingTask, EqualityTask, FrameTask, JointSpaceTask,
                        KineticEnergyRegularizationTask, LookAtTask, ManipulabilityMeasure, ManipulabilityTask,
                        OrientationTask, PositionTask, PostureTask, RelativeFrameTask, SigmaProxy, Task, Yoshikawa)
    from .trajectories import Circle, Hold, PoseTrajectory, Segment
