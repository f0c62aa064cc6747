"""Tasks over N worlds: one concept per module, all sharing :class:`~qpik.engine.tasks.task.Task`."""

from .damping import DampingTask
from .frame import FrameTask
from .manipulability import ManipulabilityMeasure, ManipulabilityTask, SigmaProxy
from .orientation import OrientationTask
from .position import PositionTask
from .posture import PostureTask
from .task import JointSpaceTask, Task

__all__ = ["DampingTask", "FrameTask", "JointSpaceTask", "ManipulabilityMeasure", "ManipulabilityTask",
           "OrientationTask", "PositionTask", "PostureTask", "SigmaProxy", "Task"]
