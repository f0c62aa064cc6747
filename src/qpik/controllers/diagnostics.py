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
from ..problem.cost import tame
from ..controllers.fallbacks import has_feasible_point
from ..controllers.labels import task_label

ELASTIC_WEIGHT = 1e6


def explain_infeasibility(controller, world: int = 0, variable: int | None = None) -> str:
    """One paragraph naming the binding limits and the unmet hard tasks of a world's last step."""
    robot, qp = controller.robot, controller.world_qp(world)
    if variable is not None:
        joint = robot.dof_name(variable)
        return (f"the limits leave joint {joint} no admissible velocity: lower bound "
                f"{qp.lb[variable]:.6g} > upper bound {qp.ub[variable]:.6g} "
                f"(position limit and speed limit disagree, e.g. the joint starts outside its range); "
                f"widen the range or the speed limit of {joint}")
    nv = robot.nv
    H = np.array(qp.H)
    c = qp.c.copy()
    A, b = qp.A, qp.b
    hessian_scale = max(1.0, float(np.trace(H)) / nv)
    scale = ELASTIC_WEIGHT * hessian_scale
    magnitude = float(np.abs(c).max()) if nv else 0.0
    if magnitude > hessian_scale:  # a far target's cost (up to 1e29) would drown the elastic rows
        c *= hessian_scale / magnitude
    H += scale * (A.T @ A)
    c -= scale * (A.T @ b)
    c = tame(c, float(H.diagonal().max()))  # a hard target far away: a vertex of the box, found
    elastic = make_backend("daqp", nv, 0, qp.G.shape[0])
    elastic.lb[:], elastic.ub[:] = qp.lb, qp.ub
    elastic.G[:], elastic.h[:] = qp.G, qp.h
    try:
        x = elastic.solve(H, c)
    except QpikError:
        if not has_feasible_point(elastic):
            return ("the limits alone cannot be met together (the box and the general inequality rows, e.g. "
                    "collision avoidance, exclude each other): " + _row_limit_names(controller) + "; relax them")
        return ("the solvers found no point meeting the constraints, and the closest point to the hard tasks "
                "could not be computed either: the problem is badly conditioned; add a DampingTask or try "
                "another solver")
    unmet = _unmet_tasks(controller, qp, x)
    if not unmet:
        return "the solver found no point meeting the constraints, but their elastic version is met: " \
               "the problem is badly conditioned; add a DampingTask or try another solver"
    binding = _binding_limits(controller, world, qp, x)
    text = "cannot meet " + "; ".join(unmet)
    if binding:
        return (text + " within the limits: " + ", ".join(binding) + ". Make the task soft (hard=False) to let "
                "it degrade, lower its gain, or relax those limits.")
    return (text + ", with no limit in the way: the hard tasks ask for motions no joint velocity gives together "
            "(they contradict each other, or the robot is at a singularity of their Jacobian). Make one of "
            "them soft (hard=False) or give it a lower priority.")


def _unmet_tasks(controller, qp, x: np.ndarray) -> list[str]:
    """Each hard task that the elastic solution misses, with its frame and by how much."""
    A, b = qp.A, qp.b
    unmet = []
    for task, rows in controller.cost.hard_task_rows:
        residual = A[rows] @ x - b[rows]
        worst = float(np.max(np.abs(residual))) if residual.size else 0.0
        if worst > 1e-6 * (1.0 + float(np.max(np.abs(b[rows])))):
            unmet.append(f"{task_label(task)} (misses its target velocity by {worst:.3g} at best)")
    return unmet


def _binding_limits(controller, world: int, qp, x: np.ndarray, tol: float = 1e-9) -> list[str]:
    """The bounds and general rows the elastic solution sits on, named."""
    robot, problem = controller.robot, controller.problem
    binding = []
    for dof in range(robot.nv):
        for side, bound, constant in (("lower", qp.lb[dof], problem.box0[world, 0, dof]),
                                      ("upper", qp.ub[dof], problem.box0[world, 1, dof])):
            if np.isfinite(bound) and abs(x[dof] - bound) <= tol * (1.0 + abs(bound)):
                kind = "speed" if bound == constant else "position"
                binding.append(f"joint {robot.dof_name(dof)} at its {side} {kind} limit ({bound:.6g})")
    if qp.G.shape[0]:
        finite = np.isfinite(qp.h)
        active = np.zeros(len(qp.h), dtype=bool)
        active[finite] = qp.G[finite] @ x >= qp.h[finite] - tol * (1.0 + np.abs(qp.h[finite]))
        for limit, rows in problem.row_limits:
            count = int(np.count_nonzero(active[rows]))
            if count:
                binding.append(f"{count} row(s) of the {type(limit).__name__}")
    return binding


def _row_limit_names(controller) -> str:
    names = [type(limit).__name__ for limit, _ in controller.problem.row_limits]
    return "the joint box" + (" and the rows of the " + ", ".join(names) if names else "")
