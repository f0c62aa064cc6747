"""Limits: one concept per module, all sharing the :class:`~qpik.limits.limit.Limit` interface."""

from .joint_position import JointPositionLimit
from .joint_velocity import JointVelocityLimit
from .limit import Limit, order_limits

__all__ = ["JointPositionLimit", "JointVelocityLimit", "Limit", "order_limits"]
