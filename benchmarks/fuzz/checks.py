"""The fuzz's independent checks of a step: hard rows met, limits kept, and an LP (HiGHS via
``scipy.optimize.linprog``) that tells an infeasible step from a failed solve.

Nothing here reads a controller's own problem: the box and rows are rebuilt from the
limits, and the hard rows from the tasks, as a user would write them down.
"""

from __future__ import annotations

from fractions import Fraction

import numpy as np

from scipy.optimize import linprog

from qpik.limits import JointPositionLimit, JointVelocityLimit, order_limits

# The LP's box and rows pulled in by this much (relative to each bound's size): a step
# feasible with this margin is feasible for every solver's tolerance (1e-9 to 1e-6).
LP_MARGIN = 1e-5
# A point meets the hard rows when |A q̇ − b| <= tolerance (1 + |b|) (Euclidean norms), as
# the controllers promise (docs/controllers.md, "answers checked"). With a margin it must
# meet them ten times better than the exact solvers' 1e-9; without, to 1e-7, the loosest
# tolerance at which the controllers call a set feasible (their phase-1 problem).
LP_EQUALITY_TOLERANCE = {True: 1e-10, False: 1e-7}


def hard_residual(task, qdot: np.ndarray) -> float:
    """|J q̇ − v|∞ of a hard task, relative to the rows' scale (|v|, |J||q̇|, 1)."""
    jacobian, velocity = task.jacobian, task.target_velocity
    residual = jacobian @ qdot - velocity
    scale = max(1.0, float(np.max(np.abs(velocity), initial=0.0)),
                float(np.max(np.abs(jacobian), initial=0.0)) * float(np.max(np.abs(qdot), initial=0.0)))
    return float(np.max(np.abs(residual), initial=0.0)) / scale


def crossing(robot, limits, q_before: np.ndarray, qdot: np.ndarray, dt: float) -> float:
    """How far q + q̇Δt lies beyond a position limit's range (a joint that started outside
    may not move farther out), in joint units; 0 when kept."""
    worst = 0.0
    for limit in limits:
        if not isinstance(limit, JointPositionLimit):
            continue
        ranges = limit.limits
        q0 = q_before[ranges.qpos_index]
        q1 = q0 + qdot[ranges.dof_index] * dt
        low, high = np.minimum(ranges.lower, q0), np.maximum(ranges.upper, q0)
        if len(q1):
            worst = max(worst, float(np.max(np.maximum(low - q1, q1 - high))))
    return worst


def velocity_excess(limits, qdot: np.ndarray) -> float:
    """How far |q̇| exceeds a velocity limit, relative to max(1, the limit)."""
    worst = 0.0
    for limit in limits:
        if isinstance(limit, JointVelocityLimit):
            box = np.full((1, len(qdot)), -np.inf), np.full((1, len(qdot)), np.inf)  # one world's (1, nv)
            limit.apply(1.0, *box)
            lb, ub = box[0][0], box[1][0]
            scale = np.maximum(1.0, np.maximum(np.abs(lb), np.abs(ub)))
            scale[~np.isfinite(scale)] = 1.0
            worst = max(worst, float(np.max(np.maximum(lb - qdot, qdot - ub) / scale)))
    return worst


def box_and_rows(robot, hard_tasks, limits, dt: float):
    """(A, b, lb, ub, G, h) of a step at the robot's configuration: the hard rows A q̇ = b
    of the tasks (already updated), the box of the limits and their general rows."""
    nv = robot.nv
    A = np.vstack([t.jacobian for t in hard_tasks]) if hard_tasks else np.zeros((0, nv))
    b = np.concatenate([t.target_velocity for t in hard_tasks]) if hard_tasks else np.zeros(0)
    lower, upper = np.full((1, nv), -np.inf), np.full((1, nv), np.inf)  # one world's box, as a limit writes it
    rows = []
    for limit in order_limits(limits):
        G, h = np.zeros((1, limit.inequality_rows, nv)), np.zeros((1, limit.inequality_rows))
        limit.apply(dt, lower, upper, G, h)
        if limit.inequality_rows:
            rows.append((G[0], h[0]))
    lb, ub = lower[0], upper[0]
    G = np.vstack([g for g, _ in rows]) if rows else np.zeros((0, nv))
    h = np.concatenate([v for _, v in rows]) if rows else np.zeros(0)
    return A, b, lb, ub, G, h


def lp_feasible(A, b, lb, ub, G, h, margin: bool) -> bool:
    """Whether some q̇ meets A q̇ = b, G q̇ ≤ h and lb ≤ q̇ ≤ ub — with every inequality
    pulled in by :data:`LP_MARGIN` (relative) when ``margin``.

    A hard row can be met only as well as floating point evaluates it: to about
    ε Σ|A_ij||q̇_j|, which a point 1e6 rad/s away on a row of entries 1e6 puts far above
    the promised 1e-9 (1 + |b|). So the LP asks for the point whose entries weigh least on
    the rows (min Σ (1 + max_i |A_ij|) |q̇_j|), moves it onto A q̇ = b by least squares,
    back into the box, and checks it as a controller's answer is checked: the rows to
    :data:`LP_EQUALITY_TOLERANCE` (the residual of that floating-point point summed
    exactly, :func:`exact_residual_norm`, so that the verdict holds on every BLAS kernel)
    and the inequality rows. HiGHS gets the hard rows as
    bands whose widths add up to that tolerance (the promise bounds the residual vector's
    norm, relative to |b|): its own tolerance is absolute (1e-7), and dependent rows of
    |b| ~ 1e9 that disagree by 1e-9 of it (rounding) would otherwise have no common point."""
    if not (np.all(np.isfinite(A)) and np.all(np.isfinite(b)) and np.all(np.isfinite(G))):
        return False
    finite_h = np.isfinite(h)
    G, h = G[finite_h], h[finite_h]
    delta = LP_MARGIN * np.maximum(1.0, np.maximum(np.abs(np.where(np.isfinite(lb), lb, 0)),
                                                   np.abs(np.where(np.isfinite(ub), ub, 0)))) if margin else 0.0
    low, high = lb + delta, ub - delta
    if np.any(low > high):
        return False
    h_margin = h - (LP_MARGIN * np.maximum(1.0, np.abs(h)) if margin else 0.0)
    # Rows within this of b (each) are within the tolerance together (Euclidean norm).
    band = LP_EQUALITY_TOLERANCE[margin] * (1.0 + np.linalg.norm(b)) / np.sqrt(max(1, len(b)))
    x = _lightest_point(A, b, band, low, high, G, h_margin)
    if x is None:
        return False
    slack = 0.0 if margin else LP_EQUALITY_TOLERANCE[False] * (1.0 + np.abs(h))
    return any(exact_residual_norm(A, y, b) <= LP_EQUALITY_TOLERANCE[margin] * (1.0 + np.linalg.norm(b))
               and (not len(h) or np.all(G @ y <= h + slack)) for y in _on_rows(A, b, x, lb, ub))


def _on_rows(A, b, x, lb, ub) -> list[np.ndarray]:
    """HiGHS's point x, and x moved onto A x = b by least squares over the dofs strictly
    inside the box: a dof HiGHS left on a bound stays there (clipping a move back into the
    box would undo it by up to the move's size, times rows of entries 1e6: any-robot case
    3636, whose point met the rows to 9.8e-8 and, moved 5e-9 past a bound and clipped,
    missed them by 9e-3)."""
    if not len(b):
        return [x]
    free = (x > lb) & (x < ub)
    moved = x.copy()
    moved[free] += np.linalg.lstsq(A[:, free], b - A @ x, rcond=None)[0]
    return [x, np.clip(moved, lb, ub)]


def exact_residual_norm(A: np.ndarray, x: np.ndarray, b: np.ndarray) -> float:
    """|A x − b| of the floating-point point x, each row summed in exact (rational)
    arithmetic: how a BLAS kernel rounds A @ x (with or without FMA, in which order) cannot
    turn a point that misses a row into one that meets it, nor the other way round."""
    point = [Fraction(v) for v in x.tolist()]
    rows = [float(sum((Fraction(a) * v for a, v in zip(row, point)), Fraction(0)) - Fraction(target))
            for row, target in zip(A.tolist(), b.tolist())]
    return float(np.linalg.norm(rows))


def _lightest_point(A, b, band: float, low, high, G, h) -> np.ndarray | None:
    """HiGHS's point of |A x − b| <= band (each row), G x <= h, low <= x <= high minimising
    Σ (1 + max_i |A_ij|) |x_j| (through s >= |x|), or None where it finds none."""
    nv = len(low)
    weight = 1.0 + (np.abs(A).max(axis=0) if len(b) else np.zeros(nv))
    identity = np.eye(nv)
    rows = [np.hstack([identity, -identity]), np.hstack([-identity, -identity]),
            np.hstack([A, np.zeros_like(A)]), np.hstack([-A, np.zeros_like(A)])]
    if len(h):
        rows.append(np.hstack([G, np.zeros_like(G)]))
    bounds = [(None if not np.isfinite(lo) else lo, None if not np.isfinite(hi) else hi) for lo, hi in zip(low, high)]
    answer = linprog(np.concatenate([np.zeros(nv), weight]), A_ub=np.vstack(rows),
                     b_ub=np.concatenate([np.zeros(2 * nv), b + band, band - b, h]),
                     bounds=bounds + [(0, None)] * nv, method="highs")
    return answer.x[:nv] if answer.status == 0 else None
