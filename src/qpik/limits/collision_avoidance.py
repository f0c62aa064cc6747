r"""Collision avoidance between geom pairs: one inequality row per pair.

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
(bound 0 + ``bound_relaxation``). Farther than :math:`d_i` a pair's row is inactive
(0 ≤ +inf).

Why the damper is on by default, and why distances come from MuJoCo's native convex
collision even where the model turns it off: docs/controllers.md.
"""

from __future__ import annotations

import itertools
from typing import Sequence

import mujoco
import numpy as np

from ..errors import InvalidInput, UnknownName
from ..robot import Robot, name_hint
from .limit import Limit

NATIVE_CCD_OFF = int(mujoco.mjtDisableBit.mjDSBL_NATIVECCD)

GeomGroup = Sequence[str | int]


class CollisionAvoidanceLimit(Limit):
    """Keep geom pairs apart: one row :math:`-\\dot d \\le` bound per pair.

    Args:
        robot: the robot.
        geom_pairs: pairs of geom groups; every geom of the first group is kept away
            from every geom of the second. A group lists geom names or ids; a body name
            stands for all the body's geoms. Pairs on the same body (or welded
            together), on parent and child bodies, or that fail MuJoCo's
            contype/conaffinity test are left out, as MuJoCo's collision detection does.
        minimum_distance: safety distance :math:`d_s` (m); negative allows penetration.
        detection_distance: :math:`d_i` (m): pairs farther apart add no constraint.
        gain: γ ∈ (0, 1]: fraction of the remaining margin one step may close.
        damper_rate: ξ (m/s): at most ξ (d − d_s)/(d_i − d_s) of approach speed, the
            velocity damper (the tighter of the two bounds holds); ``None`` leaves only
            the per-step bound γ (d − d_s)/Δt, as mink does.
        bound_relaxation: added to every active bound (m/s).

    Raises:
        UnknownName: a geom or body name the model lacks (close matches listed).
        InvalidInput: no pair left, or parameters out of range.
    """


    def __init__(self, robot: Robot, geom_pairs: Sequence[tuple[GeomGroup, GeomGroup]],
                 minimum_distance: float = 0.005, detection_distance: float = 0.1, gain: float = 0.85,
                 damper_rate: float | None = 0.5, bound_relaxation: float = 0.0):
        if not np.isfinite(minimum_distance) or not np.isfinite(detection_distance) \
                or detection_distance <= minimum_distance:
            raise InvalidInput(f"the detection distance ({detection_distance}) must exceed the minimum distance "
                               f"({minimum_distance}), both finite")
        if not 0.0 < gain <= 1.0:
            raise InvalidInput(f"collision-avoidance gain must lie in (0, 1], got {gain}")
        if damper_rate is not None and not (np.isfinite(damper_rate) and damper_rate > 0):
            raise InvalidInput(f"damper rate must be positive and finite, got {damper_rate}")
        if not np.isfinite(bound_relaxation):
            raise InvalidInput(f"bound relaxation must be finite, got {bound_relaxation}")
        self.robot = robot
        self.minimum_distance = float(minimum_distance)
        self.detection_distance = float(detection_distance)
        self.gain = float(gain)
        self.damper_rate = None if damper_rate is None else float(damper_rate)
        self.bound_relaxation = float(bound_relaxation)
        self.pairs = self._geom_id_pairs(robot.model, geom_pairs)
        if not self.pairs:
            raise InvalidInput("no geom pair left to keep apart (same or welded bodies, parent and child, "
                               "or contype/conaffinity excluded them all)")
        self.inequality_rows = len(self.pairs)
        self.distances = np.full(len(self.pairs), np.inf)  # the last step's, for logs and tests
        self._fromto = np.zeros(6)
        self._normal = np.zeros(3)
        self._jac1 = np.zeros((3, robot.nv))
        self._jac2 = np.zeros((3, robot.nv))

    def apply(self, dt: float, lb: np.ndarray, ub: np.ndarray, G: np.ndarray | None = None,
              h: np.ndarray | None = None) -> None:
        """Write one row per pair into G (pairs x nv) and h (the box is left as it is)."""
        flags = self.robot.model.opt.disableflags
        if not flags & NATIVE_CCD_OFF:
            self._fill(dt, G, h)
            return
        self.robot.model.opt.disableflags = flags & ~NATIVE_CCD_OFF  # exact distances (module docstring)
        try:
            self._fill(dt, G, h)
        finally:
            self.robot.model.opt.disableflags = flags

    def _fill(self, dt: float, G: np.ndarray, h: np.ndarray) -> None:
        model, data = self.robot.model, self.robot.data
        d_s, d_i = self.minimum_distance, self.detection_distance
        step_rate = self.gain / dt
        damper = None if self.damper_rate is None else self.damper_rate / (d_i - d_s)
        fromto, normal, jac1, jac2 = self._fromto, self._normal, self._jac1, self._jac2
        for row, (g1, g2) in enumerate(self.pairs):
            distance = mujoco.mj_geomDistance(model, data, g1, g2, d_i, fromto)
            self.distances[row] = distance
            if distance >= d_i:
                G[row] = 0.0
                h[row] = np.inf
                continue
            np.subtract(fromto[3:], fromto[:3], out=normal)
            mujoco.mju_normalize3(normal)
            mujoco.mj_jac(model, data, jac2, None, fromto[3:], model.geom_bodyid[g2])
            mujoco.mj_jac(model, data, jac1, None, fromto[:3], model.geom_bodyid[g1])
            jac2 -= jac1
            # fromto runs from geom 1 to geom 2; once they penetrate it runs the other way.
            np.matmul(normal, jac2, out=G[row])
            if distance >= 0.0:
                G[row] *= -1.0
            margin = distance - d_s
            if margin > 0.0:
                bound = step_rate * margin
                if damper is not None:
                    bound = min(bound, damper * margin)
            else:
                bound = 0.0
            h[row] = bound + self.bound_relaxation

    # Pairs -----------------------------------------------------------------------
    @staticmethod
    def _geoms(model: mujoco.MjModel, group: GeomGroup) -> list[int]:
        if isinstance(group, (str, int)):
            raise InvalidInput(f"a geom group is a list of geom (or body) names, got {group!r}")
        ids = []
        for entry in group:
            if isinstance(entry, (int, np.integer)):
                if not 0 <= entry < model.ngeom:
                    raise UnknownName(f"geom id {entry} out of range (the model has {model.ngeom} geoms)")
                ids.append(int(entry))
                continue
            geom = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, entry)
            if geom >= 0:
                ids.append(geom)
                continue
            body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, entry)
            if body >= 0:
                ids.extend(int(g) for g in np.flatnonzero(model.geom_bodyid == body))
                continue
            names = [model.geom(g).name for g in range(model.ngeom)] + [model.body(b).name for b in range(model.nbody)]
            raise UnknownName(f"no geom or body named {entry!r} in the model; {name_hint(entry, names, 'geom or body')}")
        return ids

    @classmethod
    def _geom_id_pairs(cls, model: mujoco.MjModel, geom_pairs) -> list[tuple[int, int]]:
        pairs = set()
        for group1, group2 in geom_pairs:
            for g1, g2 in itertools.product(cls._geoms(model, group1), cls._geoms(model, group2)):
                if g1 != g2 and _may_collide(model, g1, g2):
                    pairs.add((min(g1, g2), max(g1, g2)))
        return sorted(pairs)


def _may_collide(model: mujoco.MjModel, g1: int, g2: int) -> bool:
    """MuJoCo's own exclusions: same weld, parent and child welds, contype/conaffinity."""
    weld1, weld2 = model.body_weldid[model.geom_bodyid[g1]], model.body_weldid[model.geom_bodyid[g2]]
    if weld1 == weld2:
        return False
    parent1 = model.body_weldid[model.body_parentid[weld1]]
    parent2 = model.body_weldid[model.body_parentid[weld2]]
    if weld1 == parent2 or weld2 == parent1:
        return False
    return bool(model.geom_contype[g1] & model.geom_conaffinity[g2]) or \
        bool(model.geom_contype[g2] & model.geom_conaffinity[g1])
