"""Joint velocity limits |q̇| ≤ q̇max."""

from __future__ import annotations

from typing import Mapping

import numpy as np

from ..errors import InvalidInput, ModelError
from ..robot import VELOCITY_LIMIT_PREFIX
from ..tasks.inputs import as_floats
from .limit import Limit, checked_bounds


class JointVelocityLimit(Limit):
    r"""Speed bounds :math:`|\dot q_i| \le \dot q_{max,i}` on the dofs that have one.

    MJCF has no joint speed limit; the values come from one of

    - a dict ``{joint name: vmax}``: a number for the joint's every dof (a ball or free
      joint's 3 or 6 too) or one value per dof; joints left out are unbounded;
    - an (nv,) array, ``inf`` where a dof is unbounded;
    - ``None``: the scene's custom numerics ``qpik_velocity_limit_<joint>`` (the bundled
      robots declare them): ``<custom><numeric name="qpik_velocity_limit_joint1"
      data="2.175"/></custom>``.

    Args:
        robot: the robot (one world or N: the same bounds in every world).
        values: the bounds, as above.

    Raises:
        ModelError: ``values`` is None and the model declares no speed limit.
        UnknownName: a joint name the model does not have (the closest are listed).
        InvalidInput: a bound that is not positive (NaN, zero, negative) or is finite
            beyond 1e12, a wrong shape.
    """

    constant = True  # the same bounds every step: the controller applies them once

    def __init__(self, robot, values: Mapping[str, float] | np.ndarray | None = None):
        if values is None:
            vmax = robot.velocity_limits.copy()
            if not np.any(np.isfinite(vmax)):
                raise ModelError(
                    f"model {robot.name!r} declares no joint speed limit: give them, "
                    "JointVelocityLimit(robot, {'joint': vmax, ...}) or an (nv,) array, or declare "
                    f"<custom><numeric name=\"{VELOCITY_LIMIT_PREFIX}<joint>\" data=\"vmax\"/></custom> in the MJCF")
        elif isinstance(values, Mapping):
            vmax = np.full(robot.nv, np.inf)
            for joint, value in values.items():
                dofs = robot.joint_dofs(joint)
                bound = as_floats(value, f"speed limit of joint {joint!r}")
                if bound.ndim > 1 or bound.size not in (1, len(dofs)):
                    raise InvalidInput(f"speed limit of joint {joint!r}: one number or {len(dofs)} (one per dof), "
                                       f"got {value!r}")
                vmax[dofs] = bound
        else:
            vmax = as_floats(values, "velocity limits").copy()
            if vmax.shape != (robot.nv,):
                raise InvalidInput(f"velocity limits must be a dict of joint names or an array of shape "
                                   f"({robot.nv},), got shape {vmax.shape}")
        self.robot = robot
        self.max_velocity = checked_bounds(vmax, "velocity limits", vmax)

    def apply(self, dt: float, lower: np.ndarray, upper: np.ndarray, G=None, h=None) -> None:
        np.maximum(lower, -self.max_velocity, out=lower)
        np.minimum(upper, self.max_velocity, out=upper)

