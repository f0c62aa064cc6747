"""Tasks: one concept per module, all sharing the :class:`~qpik.tasks.task.Task` interface."""

from .damping import DampingTask
from .equality import LoopClosureTask
from .frame import FrameTask, rotation_error
from .manipulability import ManipulabilityMeasure, ManipulabilityTask, SigmaProxy, Yoshikawa
from .position import PositionTask
from .posture import PostureTask
from .task import JointSpaceTask, Task

__all__ = [
    "DampingTask",
    "FrameTask",
    "JointSpaceTask",
    "LoopClosureTask",
    "ManipulabilityMeasure",
    "ManipulabilityTask",
    "PositionTask",
    "PostureTask",
    "SigmaProxy",
    "Task",
    "Yoshikawa",
    "rotation_error",
]
