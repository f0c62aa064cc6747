"""Limits over N worlds: one concept per module, all sharing :class:`~qpik.engine.limits.limit.Limit`."""

from .joint_position import JointPositionLimit
from .joint_velocity import JointVelocityLimit
from .limit import Limit, order_limits

__all__ = ["JointPositionLimit", "JointVelocityLimit", "Limit", "order_limits"]
