"""qpik.batch: the same tasks, limits and controllers over N worlds of one model.

    from qpik import batch
    robots = batch.Robot.load("arm", n=1024)
    task = batch.PositionTask(robots, "end_effector", axes="xy", gain=500.0, hard=True)
    ctrl = batch.QPController(robots, [task, batch.DampingTask(robots)],
                              [batch.JointPositionLimit(robots), batch.JointVelocityLimit(robots)], dt=0.002)
    qdot = ctrl.compute_velocity()      # (N, nv)
    robots.integrate(qdot, 0.002)

Names load on first use: ``from qpik import batch`` imports nothing heavy.
"""

from __future__ import annotations

import importlib

_EXPORTS = {
    "Robot": "qpik.batch.robot",
    "Frame": "qpik.batch.robot",
    "Task": "qpik.batch.tasks",
    "FrameTask": "qpik.batch.tasks",
    "PositionTask": "qpik.batch.tasks",
    "OrientationTask": "qpik.batch.tasks",
    "RelativeFrameTask": "qpik.batch.tasks",
    "ComTask": "qpik.batch.tasks",
    "PostureTask": "qpik.batch.tasks",
    "DampingTask": "qpik.batch.tasks",
    "ManipulabilityTask": "qpik.batch.tasks",
    "SigmaProxy": "qpik.batch.tasks",
    "EqualityTask": "qpik.batch.tasks",
    "Limit": "qpik.batch.limits",
    "JointPositionLimit": "qpik.batch.limits",
    "JointVelocityLimit": "qpik.batch.limits",
    "AccelerationLimit": "qpik.batch.limits",
    "CollisionAvoidanceLimit": "qpik.batch.limits",
    "QPController": "qpik.batch.controllers",
    "PseudoinverseController": "qpik.batch.controllers",
    "ActiveSetQP": "qpik.batch.qp",
    "rollout": "qpik.batch.rollout",
    "NotBatched": "qpik.batch.errors",
    "WorldsFailed": "qpik.batch.errors",
    "InvalidWorlds": "qpik.batch.errors",
    "HostStepWarning": "qpik.batch.errors",
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
