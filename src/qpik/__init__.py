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
_EXPORTS = {
    # robot and errors
    "Robot": "qpik.robot",
    "Frame": "qpik.robot",
    "JointLimits": "qpik.robot",
    "load_model": "qpik.robot",
    "QpikError": "qpik.errors",
    "InvalidInput": "qpik.errors",
    "UnknownName": "qpik.errors",
    "ModelError": "qpik.errors",
    "OutsideJointLimits": "qpik.errors",
    "MissingExtra": "qpik.errors",
    "UnreachablePose": "qpik.errors",
    "InfeasibleProblem": "qpik.errors",
    "SolverError": "qpik.errors",
    "ConvergenceError": "qpik.errors",
    "DivergenceError": "qpik.errors",
    "GainWarning": "qpik.errors",
    # tasks
    "Task": "qpik.tasks",
    "JointSpaceTask": "qpik.tasks",
    "PositionTask": "qpik.tasks",
    "FrameTask": "qpik.tasks",
    "PostureTask": "qpik.tasks",
    "DampingTask": "qpik.tasks",
    "ManipulabilityTask": "qpik.tasks",
    "ManipulabilityMeasure": "qpik.tasks",
    "SigmaProxy": "qpik.tasks",
    "Yoshikawa": "qpik.tasks",
    "OrientationTask": "qpik.tasks",
    "RelativeFrameTask": "qpik.tasks",
    "ComTask": "qpik.tasks",
    "EqualityTask": "qpik.tasks",
    "LookAtTask": "qpik.tasks",
    "AxisAlignTask": "qpik.tasks",
    "DofFreezingTask": "qpik.tasks",
    "KineticEnergyRegularizationTask": "qpik.tasks",
    # limits
    "Limit": "qpik.limits",
    "CollisionAvoidanceLimit": "qpik.limits",
    "JointPositionLimit": "qpik.limits",
    "JointVelocityLimit": "qpik.limits",
    "FloatingBaseVelocityLimit": "qpik.limits",
    "AccelerationLimit": "qpik.limits",
    # controllers and solvers
    "QPController": "qpik.controllers",
    "HierarchicalController": "qpik.controllers",
    "SNSController": "qpik.controllers",
    "PseudoinverseController": "qpik.controllers",
    "JacobianTransposeController": "qpik.controllers",
    "available_solvers": "qpik.solvers",
    # trajectories, rollouts, scenarios
    "Segment": "qpik.trajectories",
    "Circle": "qpik.trajectories",
    "Hold": "qpik.trajectories",
    "PoseTrajectory": "qpik.trajectories",
    "simulate": "qpik.rollout",
    "RolloutLog": "qpik.rollout",
    "PositionReference": "qpik.rollout",
    "Setup": "qpik.scenario",
    "build_scenario": "qpik.scenario",
    "scenarios": "qpik.scenario",
}

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
    from .controllers import (
        HierarchicalController,
        JacobianTransposeController,
        PseudoinverseController,
        QPController,
        SNSController,
    )
    from .errors import (
        ConvergenceError,
        DivergenceError,
        GainWarning,
        InfeasibleProblem,
        InvalidInput,
        MissingExtra,
        ModelError,
        OutsideJointLimits,
        QpikError,
        SolverError,
        UnknownName,
        UnreachablePose,
    )
    from .limits import (
        AccelerationLimit,
        CollisionAvoidanceLimit,
        FloatingBaseVelocityLimit,
        JointPositionLimit,
        JointVelocityLimit,
        Limit,
    )
    from .robot import Frame, JointLimits, Robot, load_model
    from .rollout import PositionReference, RolloutLog, simulate
    from .scenario import Setup, build_scenario, scenarios
    from .solvers import available_solvers
    from .tasks import (
        AxisAlignTask,
        ComTask,
        DampingTask,
        DofFreezingTask,
        EqualityTask,
        FrameTask,
        JointSpaceTask,
        KineticEnergyRegularizationTask,
        LookAtTask,
        ManipulabilityMeasure,
        ManipulabilityTask,
        OrientationTask,
        PositionTask,
        PostureTask,
        RelativeFrameTask,
        SigmaProxy,
        Task,
        Yoshikawa,
    )
    from .trajectories import Circle, Hold, PoseTrajectory, Segment
