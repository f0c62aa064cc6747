"""The planar RRR+P arm's Denavit–Hartenberg model (docs/arm.md), independent of MuJoCo.

DH rows (a, alpha, d, theta): (a1, 0, 0, θ1), (a2, 0, 0, θ2), (0, π/2, 0, θ3), (0, 0, d4, 0).
Used to cross-check the MJCF scene: MuJoCo's site position and Jacobian must equal
these formulas.
"""

from __future__ import annotations

import numpy as np

from ...errors import InvalidInput

A1 = 1.0
A2 = 1.0


def _q(q) -> np.ndarray:
    q = np.asarray(q, dtype=float)
    if q.shape != (4,) or not np.all(np.isfinite(q)):
        raise InvalidInput(f"arm configuration must be 4 finite values [θ1, θ2, θ3, d4], got {q}")
    return q


def dh_table(q, a1: float = A1, a2: float = A2) -> np.ndarray:
    """Rows (a, alpha, d, theta) for configuration q."""
    t1, t2, t3, d4 = _q(q)
    return np.array([[a1, 0.0, 0.0, t1], [a2, 0.0, 0.0, t2], [0.0, np.pi / 2, 0.0, t3], [0.0, 0.0, d4, 0.0]])


def dh_transform(a: float, alpha: float, d: float, theta: float) -> np.ndarray:
    """Homogeneous transform Rz(θ) Tz(d) Tx(a) Rx(α) of one DH row."""
    ct, st, ca, sa = np.cos(theta), np.sin(theta), np.cos(alpha), np.sin(alpha)
    return np.array([[ct, -st * ca, st * sa, a * ct], [st, ct * ca, -ct * sa, a * st], [0.0, sa, ca, d], [0.0, 0.0, 0.0, 1.0]])


def forward_kinematics(q, a1: float = A1, a2: float = A2) -> np.ndarray:
    """Base-to-end-effector transform, the product of the DH transforms."""
    T = np.eye(4)
    for row in dh_table(q, a1, a2):
        T = T @ dh_transform(*row)
    return T


def end_effector_position(q, a1: float = A1, a2: float = A2) -> np.ndarray:
    """Closed form: px = a1 c1 + a2 c12 + d4 s123, py = a1 s1 + a2 s12 − d4 c123."""
    t1, t2, t3, d4 = _q(q)
    t12, t123 = t1 + t2, t1 + t2 + t3
    return np.array([a1 * np.cos(t1) + a2 * np.cos(t12) + d4 * np.sin(t123),
                     a1 * np.sin(t1) + a2 * np.sin(t12) - d4 * np.cos(t123)])


def position_jacobian(q, a1: float = A1, a2: float = A2) -> np.ndarray:
    """The 2x4 position Jacobian, with the signs the source misprints corrected (docs/arm.md)."""
    t1, t2, t3, d4 = _q(q)
    s1, c1 = np.sin(t1), np.cos(t1)
    s12, c12 = np.sin(t1 + t2), np.cos(t1 + t2)
    s123, c123 = np.sin(t1 + t2 + t3), np.cos(t1 + t2 + t3)
    return np.array([
        [-a1 * s1 - a2 * s12 + d4 * c123, -a2 * s12 + d4 * c123, d4 * c123, s123],
        [a1 * c1 + a2 * c12 + d4 * s123, a2 * c12 + d4 * s123, d4 * s123, -c123],
    ])


def prismatic_axis(q) -> np.ndarray:
    """z3 = (s123, −c123, 0), the prismatic axis in the base frame."""
    t1, t2, t3, _ = _q(q)
    t123 = t1 + t2 + t3
    return np.array([np.sin(t123), -np.cos(t123), 0.0])


def sigma(q) -> float:
    """The source's manipulability proxy σ = ½(sin²θ2 + sin²θ3)."""
    _, t2, t3, _ = _q(q)
    return 0.5 * (np.sin(t2) ** 2 + np.sin(t3) ** 2)


def sigma_gradient(q) -> np.ndarray:
    """∇σ = [0, sinθ2 cosθ2, sinθ3 cosθ3, 0]."""
    _, t2, t3, _ = _q(q)
    return np.array([0.0, np.sin(t2) * np.cos(t2), np.sin(t3) * np.cos(t3), 0.0])


def closest_reachable_point(target, reach: float) -> np.ndarray:
    """The point of the disc of radius ``reach`` nearest to ``target`` (planar)."""
    target = np.asarray(target, dtype=float)
    norm = np.linalg.norm(target)
    return target.copy() if norm <= reach else target * (reach / norm)
