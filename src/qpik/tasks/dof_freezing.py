"""Hold chosen degrees of freedom still: hard rows q̇_i = 0, in every world."""

from __future__ import annotations

from typing import Sequence

from ..errors import InvalidInput
from .task import JointSpaceTask


class DofFreezingTask(JointSpaceTask):
    r"""The listed joints' dofs held at zero velocity, as equality rows
    :math:`\dot q_i = 0` (mink's ``DofFreezingTask``): hard, so the QP meets them to
    the solver's accuracy whatever the other tasks ask, and the rest of the robot
    moves around them.

    A joint-space task: J is the selection ``I[dofs]`` and ``dofs`` says which; e and v
    are zero in every world, written once. In a hierarchy give it ``priority=0`` so
    nothing above it moves the frozen joints.

    Args:
        robot: the robot (one world or N).
        joints: names of the joints to freeze (all dofs of a free or ball joint).
        priority: its level in a strict hierarchy (0 the highest).

    Raises:
        UnknownName: a joint the model does not have.
        InvalidInput: no joint named, or a joint named twice.
    """

    name = "DoF freezing task"

    def __init__(self, robot, joints: Sequence[str], priority: int = 0):
        if joints is None or (not isinstance(joints, str) and len(joints) == 0):
            raise InvalidInput(f"{self.name}: name the joints to freeze")
        super().__init__(robot, joints, hard=True, priority=priority)

    def track(self) -> None:
        """v = 0: nothing to track."""
