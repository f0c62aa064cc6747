"""qpik.batch: the engine's tasks, limits and controllers over N worlds of one model.

    from qpik import batch
    robots = batch.Robot.load("arm", n=1024)
    task = batch.PositionTask(robots, "end_effector", axes="xy", gain=500.0, hard=True)
    ctrl = batch.QPController(robots, [task, batch.DampingTask(robots)],
                              [batch.JointPositionLimit(robots), batch.JointVelocityLimit(robots)], dt=0.002)
    qdot = ctrl.compute_velocity()      # (N, nv)
    robots.integrate(qdot, 0.002)

The tasks, limits and controllers are qpik's own (:mod:`qpik.tasks`, :mod:`qpik.limits`,
:mod:`qpik.controllers`), each written once over a leading world axis: the classes a
one-world :class:`qpik.Robot` runs, and each world's answer is the one its own one-world
run gives.
What is batch-only here is the N-world robot (:class:`Robot`, its back-ends) and the
headless :func:`rollout`. Names load on first use: ``from qpik import batch`` imports
nothing heavy.
"""

from __future__ import annotations

import importlib

# Public name -> module that defines it. An engine class ported later is one word here.
_EXPORTS = {name: f"qpik.{module}" for module, names in (
    ("batch.robot", "Robot Frame"),  # the N worlds and their rollouts
    ("batch.rollout", "rollout"),
    ("tasks", "Task JointSpaceTask PositionTask OrientationTask FrameTask PostureTask DampingTask ManipulabilityTask "
              "ManipulabilityMeasure SigmaProxy Yoshikawa ComTask EqualityTask RelativeFrameTask LookAtTask "
              "AxisAlignTask KineticEnergyRegularizationTask DofFreezingTask"),  # the engine's
    ("limits", "Limit JointPositionLimit JointVelocityLimit AccelerationLimit FloatingBaseVelocityLimit "
               "CollisionAvoidanceLimit"),
    ("controllers", "QPController HierarchicalController SNSController PseudoinverseController "
                    "JacobianTransposeController"),
    ("errors", "WorldsFailed InvalidWorlds HostStepWarning"),  # errors and warnings
    ("batch.errors", "NotBatched"),
) for name in names.split()}

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
