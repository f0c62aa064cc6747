"""Limits: one concept per module, all sharing :class:`~qpik.limits.limit.Limit`, each written once over a leading world axis N."""

from .acceleration import AccelerationLimit
from .collision_avoidance import CollisionAvoidanceLimit
from .floating_base_velocity import FloatingBaseVelocityLimit
from .joint_position import JointPositionLimit
from .joint_velocity import JointVelocityLimit
from .limit import Limit, order_limits

__all__ = ["AccelerationLimit", "CollisionAvoidanceLimit", "FloatingBaseVelocityLimit", "JointPositionLimit",
           "JointVelocityLimit", "Limit", "order_limits"]
