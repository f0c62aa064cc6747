"""Limits over N worlds: one concept per module, all sharing :class:`~qpik.engine.limits.limit.Limit`."""

from .acceleration import AccelerationLimit
from .collision_avoidance import CollisionAvoidanceLimit
from .floating_base_velocity import FloatingBaseVelocityLimit
from .joint_position import JointPositionLimit
from .joint_velocity import JointVelocityLimit
from .limit import Limit, order_limits

__all__ = ["AccelerationLimit", "CollisionAvoidanceLimit", "FloatingBaseVelocityLimit", "JointPositionLimit",
           "JointVelocityLimit", "Limit", "order_limits"]
