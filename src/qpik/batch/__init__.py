"""qpik.batch: the engine's tasks, limits and controllers over N worlds of one model.

    from qpik import batch
    robots = batch.Robot.load("arm", n=1024)
    task = batch.PositionTask(robots, "end_effector", axes="xy", gain=500.0, hard=True)
    ctrl = batch.QPController(robots, [task, batch.DampingTask(robots)],
                              [batch.JointPositionLimit(robots), batch.JointVelocityLimit(robots)], dt=0.002)
    qdot = ctrl.compute_velocity()      # (N, nv)
    robots.integrate(qdot, 0.002)

The classes are the engine's (:mod:`qpik.engine`), the same ones a one-world
:class:`qpik.Robot` runs: each world's answer is the one its own one-world run gives.
What is batch-only here is the N-world robot (:class:`Robot`, its back-ends) and the
headless :func:`rollout`. Names load on first use: ``from qpik import batch`` imports
nothing heavy.
"""

from __future__ import annotations

import importlib

_TASKS, _LIMITS, _CONTROLLERS = "qpik.engine.tasks", "qpik.engine.limits", "qpik.engine.controllers"

# Public name -> module that defines it. An engine class ported later is one line here.
_EXPORTS = {
    # the N worlds and their rollouts
    "Robot": "qpik.batch.robot",
    "Frame": "qpik.batch.robot",
    "rollout": "qpik.batch.rollout",
    # the engine's tasks
    "Task": _TASKS,
    "JointSpaceTask": _TASKS,
    "PositionTask": _TASKS,
    "OrientationTask": _TASKS,
    "FrameTask": _TASKS,
    "PostureTask": _TASKS,
    "DampingTask": _TASKS,
    "ManipulabilityTask": _TASKS,
    "ManipulabilityMeasure": _TASKS,
    "SigmaProxy": _TASKS,
    "Yoshikawa": _TASKS,
    "ComTask": _TASKS,
    "EqualityTask": _TASKS,
    "RelativeFrameTask": _TASKS,
    "LookAtTask": _TASKS,
    "AxisAlignTask": _TASKS,
    "KineticEnergyRegularizationTask": _TASKS,
    "DofFreezingTask": _TASKS,
    # the engine's limits
    "Limit": _LIMITS,
    "JointPositionLimit": _LIMITS,
    "JointVelocityLimit": _LIMITS,
    "AccelerationLimit": _LIMITS,
    "FloatingBaseVelocityLimit": _LIMITS,
    "CollisionAvoidanceLimit": _LIMITS,
    # the engine's controllers
    "QPController": _CONTROLLERS,
    "HierarchicalController": _CONTROLLERS,
    "SNSController": _CONTROLLERS,
    "PseudoinverseController": _CONTROLLERS,
    "JacobianTransposeController": _CONTROLLERS,
    # errors and warnings
    "WorldsFailed": "qpik.errors",
    "InvalidWorlds": "qpik.errors",
    "HostStepWarning": "qpik.errors",
    "NotBatched": "qpik.batch.errors",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'qpik.batch' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
