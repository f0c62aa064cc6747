r"""Collision avoidance between geom pairs: one inequality row per pair, in every world.

For a pair at signed distance :math:`d` (``mj_geomDistance``, with the closest points
:math:`p_1`, :math:`p_2` and the unit normal :math:`n` from :math:`p_1` to :math:`p_2`),
the distance rate is :math:`\dot d = n^T (J_{p_2} - J_{p_1}) \dot q`. Within the
detection distance :math:`d_i` the limit keeps

.. math::
    -\dot d \le \frac{\gamma}{\Delta t} (d - d_s)
    \qquad\Bigl(\text{and} \le \xi\,\frac{d - d_s}{d_i - d_s}\ \text{with a damper rate } \xi\Bigr),

a velocity damper (Faverjon & Tournassoud 1987; Kanoun, Lamiraux & Wieber 2011): the
geoms may approach, more slowly the closer they are, and never come nearer than the
safety distance :math:`d_s` (γ ∈ (0, 1] is the fraction of the remaining margin one step
may close, as mink's ``gain``). Once at or below :math:`d_s` they may not approach at all
(bound 0 + ``bound_relaxation``).

**No pair is crossed in one step from beyond** :math:`d_i`. A pair farther than
:math:`d_i` still gets its row when one step could bring it there: when
:math:`d < d_i + r`, with :math:`r` the reach of the pair (how far its two geoms can move
in one step at any :math:`\dot q` in the speed box the limit is given,
:mod:`~qpik.limits.reach`: a bound on the true motion). Beyond :math:`d_i` that
row is the step bound alone, :math:`-\dot d \le \gamma (d - d_s)/\Delta t` (the damper
starts at :math:`d_i`, as before), which binds only when the step would otherwise close
more than γ of the margin. A pair left without a row (:math:`d \ge d_i + r`, the row
0 ≤ +inf) ends the step at least :math:`d_i` apart, whatever the step. Without speed
limits every pair is within reach (a row each step). The reach is taken from the box as
written when the limit applies (the speed limits, and the limits listed before it).

Distances are computed per world on the host, in MuJoCo's C: on a :class:`qpik.Robot`
on its own data; on a :class:`qpik.batch.Robot` from each world's geom poses, which its
back-end computes, written into one scratch ``MjData``
(:class:`qpik.batch.robot.GeomDistances`). Distances come from MuJoCo's native convex
collision even where the model turns it off (the fallback's mesh distances are
centimetres off near contact: docs/controllers.md).
"""

from __future__ import annotations

from typing import Sequence

import mujoco
import numpy as np

from ..errors import InvalidInput
from ..numerics import MINVAL, all_finite
from ..tasks.inputs import positive_scalar
from .geom_pairs import GeomGroup, geom_pairs
from .limit import Limit
from .reach import PairReach

NATIVE_CCD_OFF = int(mujoco.mjtDisableBit.mjDSBL_NATIVECCD)
_X_AXIS = np.array([1.0, 0.0, 0.0])  # mju_normalize3's answer for a vector shorter than mjMINVAL


class CollisionAvoidanceLimit(Limit):
    """Keep geom pairs apart: one row :math:`-\\dot d \\le` bound per pair, in every world
    (see the module's description, and for the pairs beyond :math:`d_i` that one step
    could bring near).

    Args:
        robot: the robot (one world or N).
        geom_pairs: pairs of geom groups; every geom of the first group is kept away
            from every geom of the second. A group lists geom names or ids; a body name
            stands for all the body's geoms. Pairs on the same body (or welded
            together), on parent and child bodies, or that fail MuJoCo's
            contype/conaffinity test are left out, as MuJoCo's collision detection does.
        minimum_distance: safety distance :math:`d_s` (m); negative allows penetration.
        detection_distance: :math:`d_i` (m): the damper acts on pairs nearer than this;
            farther pairs get a row only when one step could bring them nearer.
        gain: γ ∈ (0, 1]: fraction of the remaining margin one step may close.
        damper_rate: ξ (m/s): at most ξ (d − d_s)/(d_i − d_s) of approach speed, the
            velocity damper (the tighter of the two bounds holds); ``None`` leaves only
            the per-step bound γ (d − d_s)/Δt, as mink does.
        bound_relaxation: added to every active bound (m/s).

    Attributes:
        pair_distances: (N, P) each pair's distance at the last step, or the distance it
            was searched up to (``cutoffs``, at least :math:`d_i`) when farther;
            ``distances`` is what a user reads of it (world 0's for one robot).
        cutoffs: (N, P) :math:`d_i` + the pair's reach at the last step.

    Raises:
        UnknownName: a geom or body name the model lacks (close matches listed).
        InvalidInput: no pair left, or a parameter out of range (a distance or a
            relaxation beyond 1e12 in magnitude or not finite, a gain outside (0, 1], a
            damper rate not positive or beyond 1e12, a detection distance not above the
            minimum distance).
    """

    def __init__(self, robot, geom_pairs: Sequence[tuple[GeomGroup, GeomGroup]],
                 minimum_distance: float = 0.005, detection_distance: float = 0.1, gain: float = 0.85,
                 damper_rate: float | None = 0.5, bound_relaxation: float = 0.0):
        self._check(minimum_distance, detection_distance, gain, damper_rate, bound_relaxation)
        self.robot = robot
        self.pairs = _pairs(robot.model, geom_pairs)
        n, count = robot.n, len(self.pairs)
        self.inequality_rows = count
        self.pair_distances = np.full((n, count), np.inf)
        self.distances = robot.present(self.pair_distances)
        self.cutoffs = np.empty((n, count))
        self._reach = PairReach(robot.model, self.pairs, n)
        self._fromto = np.zeros((n, count, 6))
        self._measure = robot.distance_filler(self.pairs, self.cutoffs, self.pair_distances, self._fromto)
        self._normals, self._norms, self._inverse = np.empty((n, count, 3)), np.empty((n, count)), np.empty((n, count))
        # Views for one product per pair in every world: nᵀn, and nᵀ(J₂ − J₁) below.
        self._normal_rows, self._normal_columns = self._normals[:, :, None, :], self._normals[:, :, :, None]
        self._norm_squares, self._inverse_rows = self._norms[:, :, None, None], self._inverse[:, :, None]
        self._active, self._ahead, self._near, self._inactive, self._coincident = (np.empty((n, count), dtype=bool)
                                                                                  for _ in range(5))
        self._inactive_rows, self._coincident_rows = self._inactive[:, :, None], self._coincident[:, :, None]
        self._margins, self._damped = np.empty((n, count)), np.empty((n, count))
        # Each pair's Jacobians at its closest points (those of a pair without a row: stale).
        self._jac1, self._jac2 = np.zeros((n, count, 3, robot.nv)), np.zeros((n, count, 3, robot.nv))
        self._jac_difference = np.empty((n, count, 3, robot.nv))
        bodies = robot.model.geom_bodyid
        self._jacobians = [(robot.point_jacobian_filler(int(bodies[g1]), self._fromto[:, p, :3], self._jac1[:, p]),
                            robot.point_jacobian_filler(int(bodies[g2]), self._fromto[:, p, 3:], self._jac2[:, p]))
                           for p, (g1, g2) in enumerate(self.pairs)]
        self._rows = (None, None)  # (the G it was last given, its (N, P, 1, nv) view)

    def _check(self, minimum_distance, detection_distance, gain, damper_rate, bound_relaxation) -> None:
        d_s = _signed(minimum_distance, "minimum distance")
        d_i = _signed(detection_distance, "detection distance")
        if not d_i > d_s:
            raise InvalidInput(f"the detection distance ({d_i}) must exceed the minimum distance ({d_s})")
        gain = positive_scalar(gain, "collision-avoidance gain")
        if gain > 1.0:
            raise InvalidInput(f"collision-avoidance gain must lie in (0, 1], got {gain}")
        if damper_rate is not None:
            damper_rate = positive_scalar(damper_rate, "damper rate")
            if not np.isfinite(damper_rate / (d_i - d_s)):
                raise InvalidInput(f"the damper rate over (detection − minimum distance) overflows: "
                                   f"{damper_rate} / {d_i - d_s}; widen the detection distance")
        self.minimum_distance, self.detection_distance, self.gain = d_s, d_i, gain
        self.damper_rate = damper_rate
        self.bound_relaxation = _signed(bound_relaxation, "bound relaxation")

    def apply(self, dt: float, lower: np.ndarray | None, upper: np.ndarray | None, G: np.ndarray | None = None,
              h: np.ndarray | None = None) -> None:
        """Write one row per pair into G (N, pairs, nv) and h (N, pairs); the box is read
        (the pairs' reach), not written (None: no speed bound)."""
        self._reach.reach(dt, lower, upper, self.robot.qpos, self.cutoffs)
        self.cutoffs += self.detection_distance
        self._measure_distances()
        distances = self.pair_distances
        if not (all_finite(distances) and all_finite(self.robot.qpos)):  # MuJoCo finds no pair in NaN poses
            self._non_finite()
        np.less(distances, self.cutoffs, self._active)
        np.logical_not(self._active, self._inactive)
        self._write_normals()
        pairs = np.flatnonzero(self._active.any(axis=0)).tolist()
        if pairs:
            self._write_rows(pairs, G)
        self._write_bounds(dt, h)
        np.copyto(G, 0.0, where=self._inactive_rows)

    def _measure_distances(self) -> None:
        """Every pair's distance in every world, with MuJoCo's native convex collision."""
        options = self.robot.model.opt
        flags = options.disableflags
        if not flags & NATIVE_CCD_OFF:
            self._measure()
            return
        options.disableflags = flags & ~NATIVE_CCD_OFF
        try:
            self._measure()
        finally:
            options.disableflags = flags

    def _write_normals(self) -> None:
        r"""The unit normals from :math:`p_1` to :math:`p_2` (``mju_normalize3``: (1, 0, 0)
        for points closer than mjMINVAL), negated where the geoms are apart, so that each
        row is :math:`-\dot d`: the points run the other way once the geoms penetrate."""
        normals, norms = self._normals, self._norms
        np.subtract(self._fromto[:, :, 3:], self._fromto[:, :, :3], normals)
        np.matmul(self._normal_rows, self._normal_columns, self._norm_squares)
        np.sqrt(norms, norms)
        # Coincident points (and a pair without a row: its points are zero).
        np.less(norms, MINVAL, self._coincident)
        np.copyto(normals, _X_AXIS, where=self._coincident_rows)
        np.copyto(norms, 1.0, where=self._coincident)
        np.divide(1.0, norms, self._inverse)
        np.greater_equal(self.pair_distances, 0.0, self._ahead)
        np.negative(self._inverse, self._inverse, where=self._ahead)
        np.multiply(normals, self._inverse_rows, normals)

    def _write_rows(self, pairs: list[int], G: np.ndarray) -> None:
        r"""The rows :math:`\mp n^T (J_{p_2} - J_{p_1})` of every pair in every world, the
        Jacobians measured for the ``pairs`` with a row in some world."""
        for p in pairs:
            for fill in self._jacobians[p]:
                fill()
        if self._rows[0] is not G:
            self._rows = (G, G[:, :, None, :])
        np.subtract(self._jac2, self._jac1, self._jac_difference)
        np.matmul(self._normal_rows, self._jac_difference, self._rows[1])

    def _write_bounds(self, dt: float, h: np.ndarray) -> None:
        """The bounds: the step bound, the damper's within d_i, 0 at or below d_s, +inf
        where the pair has no row."""
        margins = self._margins
        np.subtract(self.pair_distances, self.minimum_distance, margins)
        np.multiply(margins, self.gain / dt, h)
        if self.damper_rate is not None:
            np.multiply(margins, self.damper_rate / (self.detection_distance - self.minimum_distance), self._damped)
            np.less(self.pair_distances, self.detection_distance, self._near)
            np.minimum(h, self._damped, h, where=self._near)
        np.maximum(h, 0.0, h)
        np.add(h, self.bound_relaxation, h)
        np.copyto(h, np.inf, where=self._inactive)

    def _non_finite(self) -> None:
        robot = self.robot
        worlds = np.flatnonzero(~np.isfinite(robot.qpos).all(axis=1))
        if len(worlds):
            where = f" of world {int(worlds[0])}" if robot.batched else ""
            raise InvalidInput(f"the configuration{where} is not finite: no distance can be measured")
        worlds, pairs = np.nonzero(~np.isfinite(self.pair_distances))
        g1, g2 = self.pairs[int(pairs[0])]
        where = f" in world {int(worlds[0])}" if robot.batched else ""
        raise InvalidInput(f"the distance between geoms {robot.model.geom(g1).name or g1!r} and "
                           f"{robot.model.geom(g2).name or g2!r} is not finite{where}")


def _pairs(model: mujoco.MjModel, groups) -> list[tuple[int, int]]:
    pairs = geom_pairs(model, groups)
    if not pairs:
        raise InvalidInput("no geom pair left to keep apart (same or welded bodies, parent and child, "
                           "or contype/conaffinity excluded them all)")
    return pairs


def _signed(value, what: str) -> float:
    """A finite number of magnitude at most 1e12 (either sign), else InvalidInput."""
    if isinstance(value, (str, bytes, bool)) or np.ndim(value) != 0:
        raise InvalidInput(f"{what} must be a number, got {value!r}")
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise InvalidInput(f"{what} must be a number, got {value!r}") from None
    positive_scalar(abs(number), f"the magnitude of the {what}", allow_zero=True)
    return number
