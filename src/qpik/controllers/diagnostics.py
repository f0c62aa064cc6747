"""Why a QP step failed, in words a user can act on.

When the hard tasks and the limits cannot all be met, :func:`explain_infeasibility`
solves the elastic version of the step (every hard row turned into a heavily weighted
cost, the limits kept) and reads off which hard task rows stay unmet and which limits
bind at that closest point: those are the rows in conflict.
"""

from __future__ import annotations

import numpy as np

from ..errors import QpikError
from ..solvers import make_backend

ELASTIC_WEIGHT = 1e6


def explain_infeasibility(controller, variable: int | None = None) -> str:
    """One paragraph naming the binding limits and the unmet hard tasks of the last step."""
    robot = controller.robot
    if variable is not None:
        joint = robot.dof_name(variable)
        return (f"the limits leave joint {joint} no admissible velocity: lower bound "
                f"{controller.lb[variable]:.6g} > upper bound {controller.ub[variable]:.6g} "
                f"(position limit and speed limit disagree, e.g. the joint starts outside its range); "
                f"widen the range or the speed limit of {joint}")
    nv = robot.nv
    H = controller.H.copy()
    c = controller.c.copy()
    A, b = controller.A, controller.b
    hessian_scale = max(1.0, float(np.trace(H)) / nv)
    scale = ELASTIC_WEIGHT * hessian_scale
    magnitude = float(np.abs(c).max()) if nv else 0.0
    if magnitude > hessian_scale:  # a far target's cost (up to 1e29) would drown the elastic rows
        c *= hessian_scale / magnitude
    H += scale * (A.T @ A)
    c -= scale * (A.T @ b)
    elastic = make_backend("daqp", nv, 0, controller.G.shape[0])
    elastic.lb[:], elastic.ub[:] = controller.lb, controller.ub
    elastic.G[:], elastic.h[:] = controller.G, controller.h
    try:
        x = elastic.solve(H, c)
    except QpikError:
        return ("the limits alone cannot be met together (the box and the general inequality rows, e.g. "
                "collision avoidance, exclude each other); relax them")
    unmet = []
    for task, rows in zip(controller._hard, controller._rows):
        residual = A[rows] @ x - b[rows]
        worst = float(np.max(np.abs(residual))) if residual.size else 0.0
        if worst > 1e-6 * (1.0 + float(np.max(np.abs(b[rows])))):
            unmet.append(f"{_task_label(task)} (misses its target velocity by {worst:.3g} at best)")
    binding = []
    tol = 1e-9
    for dof in range(nv):
        for side, value, bound, constant in (("lower", x[dof], controller.lb[dof], controller._lb0[dof]),
                                             ("upper", x[dof], controller.ub[dof], controller._ub0[dof])):
            if np.isfinite(bound) and abs(value - bound) <= tol * (1.0 + abs(bound)):
                kind = "speed" if bound == constant else "position"
                binding.append(f"joint {robot.dof_name(dof)} at its {side} {kind} limit")
    if controller.G.shape[0]:
        active = controller.G @ x >= controller.h - tol * (1.0 + np.abs(controller.h))
        for limit, rows in zip(controller._row_limits, controller._inequality_slices):
            count = int(np.count_nonzero(active[rows]))
            if count:
                binding.append(f"{count} row(s) of the {type(limit).__name__}")
    if not unmet:
        return "the solver found no point meeting the constraints, but their elastic version is met: " \
               "the problem is badly conditioned; add a DampingTask or try another solver"
    text = "cannot meet " + "; ".join(unmet)
    if binding:
        text += " within the limits: " + ", ".join(binding)
    return text + ". Make the task soft (hard=False) to let it degrade, lower its gain, or relax those limits."


def _task_label(task) -> str:
    frame = getattr(task, "frame", None) or getattr(task, "site", None)
    return f"hard {task.name}" + (f" on {frame!r}" if isinstance(frame, str) else "")
