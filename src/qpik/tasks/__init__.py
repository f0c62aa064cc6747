"""Tasks: one concept per module, all sharing the :class:`~qpik.tasks.task.Task` interface."""

from .com import ComTask
from .damping import DampingTask
from .equality import EqualityTask
from .frame import FrameTask
from .manipulability import ManipulabilityMeasure, ManipulabilityTask, SigmaProxy, Yoshikawa
from .orientation import OrientationTask
from .position import PositionTask
from .posture import PostureTask
from .relative_frame import RelativeFrameTask
from .task import JointSpaceTask, Task, rotation_error

__all__ = [
    "ComTask",
    "DampingTask",
    "EqualityTask",
    "FrameTask",
    "JointSpaceTask",
    "ManipulabilityMeasure",
    "ManipulabilityTask",
    "OrientationTask",
    "PositionTask",
    "PostureTask",
    "RelativeFrameTask",
    "SigmaProxy",
    "Task",
    "Yoshikawa",
    "rotation_error",
]
