"""Limits: one concept per module, all sharing the :class:`~qpik.limits.limit.Limit` interface."""

from .collision_avoidance import CollisionAvoidanceLimit
from .joint_position import JointPositionLimit
from .joint_velocity import JointVelocityLimit
from .limit import Limit, order_limits

__all__ = ["CollisionAvoidanceLimit", "JointPositionLimit", "JointVelocityLimit", "Limit", "order_limits"]
