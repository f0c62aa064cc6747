"""The host's side of a device QP: the promise every answer is checked against, and
DAQP for the worlds a device method left (the warp back-end's ``WarpQP`` and its
device-resident step both use them)."""

from __future__ import annotations

import ctypes

import numpy as np

from .base import QPStatus

# Hard rows and bounds are checked to this (relative to 1 + |value|), as the CPU back-end.
TOLERANCE = 1e-9


def answers_hold(x, A, b, lb, ub, box_tolerance: float = TOLERANCE) -> np.ndarray:
    """Per world: x finite, hard rows to 1e-9 (1 + |b|), bounds to ``box_tolerance``
    (1 + |bound|) (the caller then clips x into the box)."""
    ok = np.isfinite(x).all(axis=1)
    if A.shape[1]:
        residual = np.abs(np.einsum("nij,nj->ni", A, x) - b)
        ok &= (residual <= TOLERANCE * (1.0 + np.abs(b))).all(axis=1)
    with np.errstate(invalid="ignore"):
        ok &= (x >= lb - box_tolerance * (1.0 + np.abs(lb))).all(axis=1)
        ok &= (x <= ub + box_tolerance * (1.0 + np.abs(ub))).all(axis=1)
    return ok


_DAQP_INF = 1e30
DAQP_PRIMAL_TOLERANCE = 1e-6


def daqp_solve(H, c, A, b, lb, ub) -> tuple[np.ndarray, int, str]:
    """One world by DAQP: (x, status, reason), checked as the device answers are."""
    import daqp

    n, m = len(c), len(b)
    rows = np.vstack([A, np.eye(n)])
    upper = np.concatenate([b, np.minimum(ub, _DAQP_INF)])
    lower = np.concatenate([b, np.maximum(lb, -_DAQP_INF)])
    sense = np.zeros(m + n, dtype=ctypes.c_int)
    sense[:m] = 5  # DAQP's "equality, immutable"
    x, _, exitflag, _ = daqp.solve(np.ascontiguousarray(H), np.ascontiguousarray(c), rows, upper, lower, sense)
    x = np.asarray(x, dtype=np.float64)
    if exitflag in (-1, -2):  # DAQP's infeasible and overdetermined initial active set
        return np.zeros(n), QPStatus.INFEASIBLE, "no point meets the hard rows inside the box (DAQP)"
    # DAQP meets the bounds to its primal tolerance, 1e-6: such a point is clipped into the
    # box, as the serial solver layer does, and must then still meet the hard rows.
    if exitflag >= 1 and answers_hold(x[None], A[None], b[None], lb[None], ub[None], DAQP_PRIMAL_TOLERANCE)[0]:
        x = np.clip(x, lb, ub)
    if exitflag < 1 or not answers_hold(x[None], A[None], b[None], lb[None], ub[None])[0]:
        return np.zeros(n), QPStatus.FAILED, f"neither the device active set nor DAQP (exit {exitflag}) solved it"
    return x, QPStatus.SOLVED, ""
