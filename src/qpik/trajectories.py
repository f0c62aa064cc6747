r"""Reference trajectories: time laws and paths giving desired position and velocity.

A time law maps t ∈ [0, T] to the path fraction s ∈ [0, 1] with zero end velocities:

- cubic (the source's): s = 3τ² − 2τ³, τ = t/T. On the source's segment of length
  L = √2 and T = 5 s this is s(t)·L = −(2√2/125) t³ + (3√2/25) t².
- quintic: s = 10τ³ − 15τ⁴ + 6τ⁵ (zero end accelerations too).

Before t = 0 and after T the reference holds its end point with zero velocity.

Every trajectory samples one time (``sample(t)``) or a whole array of times in one
vectorised pass (``sample_many(times)``, rows in the order of ``times``), with the same
floating-point operations in the same order, so both give the same bits; a rollout
samples its whole reference before the first step (:func:`sample_many`).
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from .errors import InvalidInput


def _time(t: float) -> float:
    if not np.isfinite(t):
        raise InvalidInput(f"time must be finite, got {t}")
    return float(t)


def _times(times) -> np.ndarray:
    arr = np.asarray(times, dtype=float)
    if arr.ndim != 1:
        raise InvalidInput(f"times must be a 1-D array, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InvalidInput("times contain NaN or inf")
    return arr


class TimeLaw:
    """Normalised time law s(τ), ds/dτ on τ ∈ [0, 1], held constant outside."""

    name = "time law"

    def __init__(self, duration: float):
        if not (np.isfinite(duration) and duration > 0):
            raise InvalidInput(f"duration must be positive, got {duration}")
        self.duration = float(duration)

    def _shape(self, tau: float) -> tuple[float, float]:
        raise NotImplementedError

    def __call__(self, t: float) -> tuple[float, float]:
        """Path fraction s and its rate ds/dt at time t."""
        tau = _time(t) / self.duration
        if tau <= 0.0:
            return 0.0, 0.0
        if tau >= 1.0:
            return 1.0, 0.0
        s, ds = self._shape(tau)
        return s, ds / self.duration

    def many(self, times) -> tuple[np.ndarray, np.ndarray]:
        """s and ds/dt at each of ``times`` (arrays; the same values as calling the law)."""
        tau = _times(times) / self.duration
        s = np.where(tau <= 0.0, 0.0, 1.0)
        ds = np.zeros_like(tau)
        inside = (tau > 0.0) & (tau < 1.0)
        s_in, ds_in = self._shape(tau[inside])
        s[inside] = s_in
        ds[inside] = ds_in / self.duration
        return s, ds


class CubicTimeLaw(TimeLaw):
    """s = 3τ² − 2τ³: zero velocity at both ends (the source's law)."""

    name = "cubic"

    def _shape(self, tau: float) -> tuple[float, float]:
        return tau * tau * (3.0 - 2.0 * tau), 6.0 * tau * (1.0 - tau)


class QuinticTimeLaw(TimeLaw):
    """s = 10τ³ − 15τ⁴ + 6τ⁵: zero velocity and acceleration at both ends."""

    name = "quintic"

    def _shape(self, tau: float) -> tuple[float, float]:
        t2 = tau * tau
        # float_power: C's pow, as Python's ** on a float (NumPy's ** squares instead,
        # which differs in the last bit now and then), for the same bits on arrays.
        return t2 * tau * (10.0 + tau * (-15.0 + 6.0 * tau)), 30.0 * t2 * np.float_power(1.0 - tau, 2.0)


TIME_LAWS = {"cubic": CubicTimeLaw, "quintic": QuinticTimeLaw}


def make_time_law(name: str, duration: float) -> TimeLaw:
    if name not in TIME_LAWS:
        raise InvalidInput(f"unknown time law {name!r}; known: {sorted(TIME_LAWS)}")
    return TIME_LAWS[name](duration)


class Trajectory(Protocol):
    """Anything that gives a desired position and velocity at time t."""

    dim: int
    duration: float

    def sample(self, t: float) -> tuple[np.ndarray, np.ndarray]: ...


def sample_many(trajectory: Trajectory, times) -> tuple[np.ndarray, np.ndarray]:
    """Positions and velocities (len(times) x dim) of any trajectory: its own vectorised
    ``sample_many`` when it has one, else one ``sample`` per time.

    Raises:
        InvalidInput: a non-finite time, or a sample that is not finite or not of the
            trajectory's dimension.
    """
    times = _times(times)
    if hasattr(trajectory, "sample_many"):
        positions, velocities = trajectory.sample_many(times)
    else:
        samples = [trajectory.sample(t) for t in times]
        positions = np.array([p for p, _ in samples], dtype=float).reshape(len(times), -1)
        velocities = np.array([v for _, v in samples], dtype=float).reshape(len(times), -1)
    dim = trajectory.dim
    if positions.shape != (len(times), dim) or velocities.shape != (len(times), dim):
        raise InvalidInput(f"trajectory samples must have {dim} coordinates, got {positions.shape[1:]}")
    if not (np.all(np.isfinite(positions)) and np.all(np.isfinite(velocities))):
        raise InvalidInput("trajectory samples contain NaN or inf")
    return positions, velocities


def _point(value, what: str) -> np.ndarray:
    # A copy: a path built from a task's live target array (task.target) must not move
    # when the task's target is set.
    arr = np.array(value, dtype=float)
    if arr.ndim != 1 or arr.size == 0:
        raise InvalidInput(f"{what} must be a vector, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InvalidInput(f"{what} contains NaN or inf: {arr}")
    return arr


class Segment:
    """Straight segment from ``start`` to ``end`` under a time law."""

    def __init__(self, start, end, duration: float, time_law: str = "cubic"):
        self.start = _point(start, "segment start")
        self.end = _point(end, "segment end")
        if self.start.shape != self.end.shape:
            raise InvalidInput("segment start and end must have the same size")
        self.dim = self.start.size
        self.law = make_time_law(time_law, duration)
        self.duration = self.law.duration

    def sample(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        s, ds = self.law(t)
        delta = self.end - self.start
        return self.start + s * delta, ds * delta

    def sample_many(self, times) -> tuple[np.ndarray, np.ndarray]:
        s, ds = self.law.many(times)
        delta = self.end - self.start
        return self.start + s[:, None] * delta, ds[:, None] * delta


class Circle:
    """Circle of ``radius`` about ``center`` in the plane spanned by unit vectors u, w.

    p = c + r (cos φ u + sin φ w), φ = φ0 + 2π·turns·s(t); the start point is at φ0.
    """

    def __init__(self, center, radius: float, duration: float, u=(1.0, 0.0, 0.0), w=(0.0, 1.0, 0.0),
                 start_angle: float = 0.0, turns: float = 1.0, time_law: str = "quintic"):
        self.center = _point(center, "circle centre")
        self.u = _point(u, "circle axis u")
        self.w = _point(w, "circle axis w")
        if not (self.center.shape == self.u.shape == self.w.shape):
            raise InvalidInput("circle centre and axes must have the same size")
        if not (np.isfinite(radius) and radius > 0):
            raise InvalidInput(f"circle radius must be positive, got {radius}")
        if abs(np.linalg.norm(self.u) - 1) > 1e-9 or abs(np.linalg.norm(self.w) - 1) > 1e-9 or abs(self.u @ self.w) > 1e-9:
            raise InvalidInput("circle axes u, w must be orthonormal")
        self.radius = float(radius)
        self.start_angle = float(start_angle)
        self.turns = float(turns)
        self.dim = self.center.size
        self.law = make_time_law(time_law, duration)
        self.duration = self.law.duration

    def angle(self, t: float) -> tuple[float, float]:
        """φ(t) and φ̇(t)."""
        s, ds = self.law(t)
        sweep = 2.0 * np.pi * self.turns
        return self.start_angle + sweep * s, sweep * ds

    def angle_many(self, times) -> tuple[np.ndarray, np.ndarray]:
        """φ and φ̇ at each of ``times``."""
        s, ds = self.law.many(times)
        sweep = 2.0 * np.pi * self.turns
        return self.start_angle + sweep * s, sweep * ds

    def sample(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        phi, dphi = self.angle(t)
        c, s = np.cos(phi), np.sin(phi)
        position = self.center + self.radius * (c * self.u + s * self.w)
        velocity = self.radius * dphi * (-s * self.u + c * self.w)
        return position, velocity

    def sample_many(self, times) -> tuple[np.ndarray, np.ndarray]:
        phi, dphi = self.angle_many(times)
        c, s = np.cos(phi)[:, None], np.sin(phi)[:, None]
        position = self.center + self.radius * (c * self.u + s * self.w)
        velocity = (self.radius * dphi)[:, None] * (-s * self.u + c * self.w)
        return position, velocity


class Hold:
    """A constant target (set-point regulation)."""

    def __init__(self, point, duration: float):
        self.point = _point(point, "target")
        self.dim = self.point.size
        if not (np.isfinite(duration) and duration > 0):
            raise InvalidInput(f"duration must be positive, got {duration}")
        self.duration = float(duration)
        self._zero = np.zeros(self.dim)

    def sample(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        _time(t)
        return self.point, self._zero

    def sample_many(self, times) -> tuple[np.ndarray, np.ndarray]:
        n = len(_times(times))
        return np.tile(self.point, (n, 1)), np.zeros((n, self.dim))


def rpy_rotation_and_rate(rpy_deg: np.ndarray, rpy_rate_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """R = Rz(θz) Ry(θy) Rx(θx) and its world angular velocity from the angle rates.

    ω = θ̇z e_z + θ̇y Rz e_y + θ̇x Rz Ry e_x (degrees in, radians out).
    """
    a, b, c = np.radians(rpy_deg)
    da, db, dc = np.radians(rpy_rate_deg)
    ca, sa, cb, sb, cc, sc = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(c), np.sin(c)
    Rz = np.array([[cc, -sc, 0.0], [sc, cc, 0.0], [0.0, 0.0, 1.0]])
    Ry = np.array([[cb, 0.0, sb], [0.0, 1.0, 0.0], [-sb, 0.0, cb]])
    Rx = np.array([[1.0, 0.0, 0.0], [0.0, ca, -sa], [0.0, sa, ca]])
    omega = dc * np.array([0.0, 0.0, 1.0]) + db * Rz[:, 1] + da * (Rz @ Ry)[:, 0]
    return Rz @ Ry @ Rx, omega


def rpy_rotations_and_rates(rpy_deg: np.ndarray, rpy_rate_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`rpy_rotation_and_rate` of each row: (n, 3) angles and rates -> (n, 3, 3), (n, 3)."""
    a, b, c = np.radians(rpy_deg).T
    da, db, dc = np.radians(rpy_rate_deg).T
    ca, sa, cb, sb, cc, sc = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(c), np.sin(c)
    zero, one = np.zeros_like(a), np.ones_like(a)
    Rz = np.stack([cc, -sc, zero, sc, cc, zero, zero, zero, one], axis=-1).reshape(-1, 3, 3)
    Ry = np.stack([cb, zero, sb, zero, one, zero, -sb, zero, cb], axis=-1).reshape(-1, 3, 3)
    Rx = np.stack([one, zero, zero, zero, ca, -sa, zero, sa, ca], axis=-1).reshape(-1, 3, 3)
    omega = dc[:, None] * np.array([0.0, 0.0, 1.0]) + db[:, None] * Rz[:, :, 1] + da[:, None] * (Rz @ Ry)[:, :, 0]
    return Rz @ Ry @ Rx, omega


class CircularTilt:
    """A tilt that follows a circle's phase: [θx, θy, θz] = A (sin Δφ, 1 − cos Δφ, 0).

    Zero at the circle's start and end, so the pose path starts and stops at rest.
    """

    def __init__(self, circle: Circle, amplitude_deg: float):
        if not np.isfinite(amplitude_deg):
            raise InvalidInput(f"tilt amplitude must be finite, got {amplitude_deg}")
        self.circle = circle
        self.amplitude = float(amplitude_deg)
        self.dim = 3
        self.duration = circle.duration

    def sample(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        phi, dphi = self.circle.angle(t)
        delta = phi - self.circle.start_angle
        rpy = self.amplitude * np.array([np.sin(delta), 1.0 - np.cos(delta), 0.0])
        rate = self.amplitude * dphi * np.array([np.cos(delta), np.sin(delta), 0.0])
        return rpy, rate

    def sample_many(self, times) -> tuple[np.ndarray, np.ndarray]:
        phi, dphi = self.circle.angle_many(times)
        delta = phi - self.circle.start_angle
        zero = np.zeros_like(delta)
        rpy = self.amplitude * np.stack([np.sin(delta), 1.0 - np.cos(delta), zero], axis=-1)
        rate = (self.amplitude * dphi)[:, None] * np.stack([np.cos(delta), np.sin(delta), zero], axis=-1)
        return rpy, rate


class PoseTrajectory:
    """A position trajectory plus an orientation path of [θx, θy, θz] (deg) and rates: any
    3-D trajectory (a :class:`Segment` of angles, a :class:`CircularTilt`). Past its
    duration (the position path's) each part holds its end, as every time law does.
    """

    def __init__(self, position: Trajectory, rpy: Trajectory | None = None):
        if position.dim != 3:
            raise InvalidInput(f"a pose trajectory needs a 3-D position path, got {position.dim}-D")
        if rpy is not None and rpy.dim != 3:
            raise InvalidInput(f"roll-pitch-yaw angles must have 3 components, got {rpy.dim}")
        self.position = position
        self.rpy = rpy
        self.dim = 3
        self.duration = position.duration

    def sample(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        return self.position.sample(t)

    def sample_many(self, times) -> tuple[np.ndarray, np.ndarray]:
        return sample_many(self.position, times)

    def sample_pose_many(self, times) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`sample_pose` at each of ``times``: (n, 3), (n, 3), (n, 3, 3), (n, 3).

        Raises:
            InvalidInput: a non-finite time or sample.
        """
        p, v = sample_many(self.position, times)
        n = len(p)
        if self.rpy is None:
            return p, v, np.tile(np.eye(3), (n, 1, 1)), np.zeros((n, 3))
        rpy, rate = sample_many(self.rpy, times)
        R, omega = rpy_rotations_and_rates(rpy, rate)
        return p, v, R, omega

    def sample_pose(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Position, linear velocity, rotation matrix, angular velocity (world)."""
        p, v = self.position.sample(t)
        if self.rpy is None:
            return p, v, np.eye(3), np.zeros(3)
        rpy, rate = self.rpy.sample(t)
        R, omega = rpy_rotation_and_rate(rpy, rate)
        return p, v, R, omega
