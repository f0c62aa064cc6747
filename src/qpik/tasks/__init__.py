"""Tasks: one concept per module, all sharing :class:`~qpik.tasks.task.Task`, each written once over a leading world axis N."""

from .axis_align import AxisAlignTask
from .com import ComTask
from .damping import DampingTask
from .dof_freezing import DofFreezingTask
from .equality import EqualityTask
from .frame import FrameTask
from .kinetic_energy import KineticEnergyRegularizationTask
from .look_at import LookAtTask
from .manipulability import ManipulabilityMeasure, ManipulabilityTask, SigmaProxy
from .orientation import OrientationTask
from .position import PositionTask
from .posture import PostureTask
from .relative_frame import RelativeFrameTask
from .task import JointSpaceTask, Task
from .yoshikawa import Yoshikawa

__all__ = ["AxisAlignTask", "ComTask", "DampingTask", "DofFreezingTask", "EqualityTask", "FrameTask",
           "JointSpaceTask", "KineticEnergyRegularizationTask", "LookAtTask", "ManipulabilityMeasure",
           "ManipulabilityTask", "OrientationTask", "PositionTask", "PostureTask", "RelativeFrameTask",
           "SigmaProxy", "Task", "Yoshikawa"]
