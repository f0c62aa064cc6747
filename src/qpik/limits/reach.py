r"""How far a geom can move in one control step: a bound from the speed box alone.

Over a step the configuration runs along :math:`q(t) = q \oplus \dot q\,t`,
:math:`t \in [0, \Delta t]`, :math:`\dot q` inside the box :math:`[l, u]`. A point p of a
geom moves at :math:`|\dot p| \le \sum_k |\dot q_k|\,\ell_k`, the sum over the dofs of its
body's chain, with the lever :math:`\ell_k = 1` for a translation (a slide, a free
joint's linear dofs) and, for a rotation (a hinge, a ball or a free joint's angular dofs,
:math:`|\omega| \le \sum |\dot q_k|`), the distance from the dof's centre of rotation to p.
That distance is bounded in every configuration by :math:`L_k`: the rigid path from the
centre to the geom's centre through the joint centres below it (each segment fixed in
its body) plus the geom's bounding radius ``geom_rbound`` (a plane: no bound); a slide
on the chain stretches the path by :math:`|q_s - q_{0,s}|`, at most
:math:`|q_s(0) - q_{0,s}| + \Delta t\,|\dot q_s|` during the step. Hence the reach
(:math:`L_k = 1` for a translation)

.. math::
    \|p(\Delta t) - p(0)\| \le \Delta t \Bigl(\sum_k s_k L_k
        + \sum_{k\ \text{rot.}} s_k \sum_{\text{slides}} \bigl(|q_s - q_{0,s}| + \Delta t\, s_s\bigr)\Bigr),
    \qquad s_k = \max(-l_k, u_k),

for the true motion over the step (not only its linearisation), in every world. A
speed or lever beyond :data:`UNBOUNDED` (a dof without speed limit, a plane on a moving
body) counts as that: every pair is then within reach.
"""

from __future__ import annotations

import mujoco
import numpy as np

# A speed or lever arm without bound counts as this (products and sums stay finite).
UNBOUNDED = 1e150

_J = mujoco.mjtJoint


def _anchor(model: mujoco.MjModel, joint: int) -> np.ndarray:
    """The joint's centre of rotation in its body's frame (a free joint turns about the
    body's origin)."""
    return np.zeros(3) if model.jnt_type[joint] == _J.mjJNT_FREE else model.jnt_pos[joint]


def _chain(model: mujoco.MjModel, body: int) -> list[int]:
    """The bodies from the root down to ``body`` (the world left out)."""
    bodies = []
    while body:
        bodies.append(body)
        body = int(model.body_parentid[body])
    return bodies[::-1]


def _tail_lengths(model: mujoco.MjModel, geom: int) -> dict[int, float]:
    """{joint: the rigid path length from its centre to the geom's centre} for the joints
    on the geom's chain (slides at their reference ``qpos0``). Body by body from the geom
    up, in each body's frame: where the path leaves the body (the next body's origin, or
    the geom's centre), its joints' centres from the last to the first, its origin."""
    bodies = _chain(model, int(model.geom_bodyid[geom]))
    lengths, tail = {}, 0.0
    for k in range(len(bodies) - 1, -1, -1):
        body = bodies[k]
        previous = model.geom_pos[geom] if k == len(bodies) - 1 else model.body_pos[bodies[k + 1]]
        first = int(model.body_jntadr[body])
        for joint in range(first + int(model.body_jntnum[body]) - 1, first - 1, -1):
            anchor = _anchor(model, joint)
            tail += float(np.linalg.norm(previous - anchor))
            lengths[joint] = tail
            previous = anchor
        tail += float(np.linalg.norm(previous))
    return lengths


def _levers(model: mujoco.MjModel, geom: int, slides: list[int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A geom's levers (nv,), its rotational dofs (nv,) and which of ``slides`` are on
    its chain (bool)."""
    radius = UNBOUNDED if model.geom_type[geom] == mujoco.mjtGeom.mjGEOM_PLANE else float(model.geom_rbound[geom])
    levers, rotational = np.zeros(model.nv), np.zeros(model.nv, dtype=bool)
    on_chain = np.zeros(len(slides), dtype=bool)
    for joint, tail in _tail_lengths(model, geom).items():
        kind, dof = model.jnt_type[joint], int(model.jnt_dofadr[joint])
        arm = min(tail + radius, UNBOUNDED)
        if kind == _J.mjJNT_SLIDE:
            levers[dof] = 1.0
            on_chain[slides.index(joint)] = True
        elif kind == _J.mjJNT_HINGE:
            levers[dof], rotational[dof] = arm, True
        elif kind == _J.mjJNT_BALL:
            levers[dof:dof + 3], rotational[dof:dof + 3] = arm, True
        else:  # free: linear dofs, then angular ones about the body's origin
            levers[dof:dof + 3] = 1.0
            levers[dof + 3:dof + 6], rotational[dof + 3:dof + 6] = arm, True
    return levers, rotational, on_chain


class PairReach:
    """The reach of each geom pair (its two geoms' reaches summed) in every world, as the
    module's description says.

    Args:
        model: the model.
        pairs: (g1, g2) geom ids.
        n: the worlds.
    """

    def __init__(self, model: mujoco.MjModel, pairs, n: int):
        nv, count = model.nv, len(pairs)
        joints = [j for j in range(model.njnt) if model.jnt_type[j] == _J.mjJNT_SLIDE]
        self._slide_q = np.array([model.jnt_qposadr[j] for j in joints], dtype=int)
        self._slide_v = np.array([model.jnt_dofadr[j] for j in joints], dtype=int)
        sides = [[_levers(model, int(pair[side]), joints) for pair in pairs] for side in (0, 1)]
        # (nv, P): the pairs' summed levers, so that Σ_k s_k L_k = speeds @ levers.
        self.levers = np.array([a[0] + b[0] for a, b in zip(*sides)]).T.reshape(nv, count)
        # Per side where a slide stretches a rotational lever: the side's rotational dofs
        # (nv, P) and the slides on its chain (slides, P), as 0/1.
        stretch = [(np.array([r for _, r, _ in side], dtype=float).T.reshape(nv, count),
                    np.array([c for _, _, c in side], dtype=float).T.reshape(len(joints), count)) for side in sides]
        self._stretch = [(r, c) for r, c in stretch if (r.any(axis=0) & c.any(axis=0)).any()]
        self._qpos0 = np.tile(model.qpos0[self._slide_q], (n, 1))
        self._offsets = np.empty((n, len(joints)))
        self._turning, self._stretching = np.empty((n, count)), np.empty((n, count))
        self._speeds = np.empty((n, nv))

    def reach(self, dt: float, lower: np.ndarray | None, upper: np.ndarray | None, qpos: np.ndarray,
              out: np.ndarray) -> np.ndarray:
        """Write each pair's reach over a step of ``dt`` in the box [lower, upper] (N, nv)
        (None: no bound) at the configurations ``qpos`` (N, nq) into ``out`` (N, P)."""
        speeds = self._speeds
        if lower is None:
            speeds.fill(UNBOUNDED)
        else:
            np.negative(lower, speeds)
            np.maximum(speeds, upper, speeds)
            np.minimum(speeds, UNBOUNDED, speeds)
        np.matmul(speeds, self.levers, out)
        if self._stretch:
            self._add_stretch(dt, speeds, qpos, out)
        np.multiply(out, dt, out)
        return out

    def _add_stretch(self, dt: float, speeds: np.ndarray, qpos: np.ndarray, out: np.ndarray) -> None:
        """The slides' stretch of the rotational levers, added to ``out`` (before × Δt)."""
        offsets = self._offsets
        np.subtract(qpos[:, self._slide_q], self._qpos0, offsets)
        np.abs(offsets, offsets)
        offsets += dt * speeds[:, self._slide_v]
        for rotational, slides in self._stretch:
            np.matmul(speeds, rotational, self._turning)
            np.matmul(offsets, slides, self._stretching)
            self._turning *= self._stretching
            out += self._turning
