r"""The 6-PUS Gough–Stewart hexapod: geometry, analytic IK, FK and Jacobians (docs/hexapod.md).

Leg i joins an actuated slider on the base to the moving platform:

.. math::

    S_i = S_{0,i} + q_i s_i, \qquad P_i = p + R\,b_i, \qquad
    L_i = P_i - S_i, \qquad L_i^\top L_i = l_i^2,

with slider home point :math:`S_{0,i}`, unit slider axis :math:`s_i`, stroke
:math:`q_i \in [0, q_{max}]`, platform point :math:`b_i` (platform frame) and leg length
:math:`l_i`. The platform pose is ``(p, R)``, ``R = Rz(θz) Ry(θy) Rx(θx)`` (fixed axes,
angles in degrees ``[θx, θy, θz]`` where angles are used).

Every function takes the geometry from one :class:`HexapodGeometry`, so a calibration
can evaluate the same kinematics with perturbed leg lengths, slider offsets or platform
points (``with_*`` helpers).

Assembly modes: the sliders lie in the plane z = 0, so a pose (p, R) and its mirror
image through that plane, (M p, M R M) with M = diag(1, 1, −1), have identical strokes.
Forward kinematics follows the branch of its starting pose (by default the home pose,
above the plane), or returns the assembly nearest to a given pose, or the one on a given
side of the plane. The source's calibration pose 4 (z = −0.02 m) lies below the plane.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ...errors import ConvergenceError, InvalidInput, UnreachablePose
from .rotations import matrix_from_rotvec, matrix_from_rpy, rotvec_from_matrix, rpy_from_matrix

N_LEGS = 6
SIDES = ("above", "below")  # assembly sides of the slider plane
CHARACTERISTIC_LENGTH_M = 0.1  # platform radius: makes a rotation commensurate with a shift
NEAR_START_SHIFT_M = 0.002  # FK ``near``: extra starts this far from the given pose,
NEAR_START_TILT_DEG = 1.0  # and tilted this much about each axis

# Slider i (1-based) is tied to the platform point at this polar angle (degrees). The
# source lists two legs on one point; of the 6! assignments of its six distinct points, 12
# reach all four calibration poses, and this one has the widest stroke margin over them
# (23.6 mm). docs/hexapod.md, "The platform-point inconsistency".
PLATFORM_POINT_ANGLES_DEG = (10.0, 230.0, 130.0, -10.0, 110.0, 250.0)


class Assembly(tuple):
    """A forward-kinematics solution: unpacks as ``position, R`` and tells its branch.

    Attributes:
        position: platform position (3,), m.
        rotation: platform rotation (3, 3).
        side: ``"above"`` or ``"below"`` the slider plane.
        method: how it was found (continuation, nearest to a pose, mirrored).
    """

    def __new__(cls, position: np.ndarray, rotation: np.ndarray, side: str, method: str):
        self = super().__new__(cls, (position, rotation))
        self.position, self.rotation, self.side, self.method = position, rotation, side, method
        return self

    def __repr__(self) -> str:
        return f"Assembly(position={self.position.tolist()}, side={self.side!r}, method={self.method!r})"


def rotation_from_rpy(rpy_deg) -> np.ndarray:
    """R = Rz(θz) Ry(θy) Rx(θx) from ``[θx, θy, θz]`` in degrees (fixed-axes x, y, z)."""
    rpy = _finite(rpy_deg, (3,), "rpy_deg")
    return matrix_from_rpy(np.radians(rpy))


def rpy_from_rotation(R: np.ndarray) -> np.ndarray:
    """Inverse of :func:`rotation_from_rpy`: ``[θx, θy, θz]`` in degrees."""
    return np.degrees(rpy_from_matrix(_rotation(R)))


def _finite(value, shape: tuple[int, ...], what: str) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if arr.shape != shape:
        raise InvalidInput(f"{what} must have shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InvalidInput(f"{what} contains NaN or inf: {arr.tolist()}")
    return arr


def _rotation(R) -> np.ndarray:
    R = _finite(R, (3, 3), "rotation matrix")
    if np.max(np.abs(R.T @ R - np.eye(3))) > 1e-6 or np.linalg.det(R) <= 0:
        raise InvalidInput(f"not a rotation matrix (RᵀR ≠ I or det ≤ 0): {R.tolist()}")
    return R


def _frozen(value, shape: tuple[int, ...], what: str) -> np.ndarray:
    arr = _finite(value, shape, what).copy()
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class HexapodGeometry:
    """Geometric parameters of the hexapod, in metres (row i = leg i + 1).

    Attributes:
        slider_origins: S0,i, slider point at zero stroke (6, 3), world frame.
        slider_axes: unit slider directions s_i (6, 3).
        platform_points: b_i, the point leg i is tied to, in the platform frame (6, 3).
        leg_lengths: l_i (6,).
        stroke_min, stroke_max: stroke range of every slider.
        leg_side: +1 where the slider point lies at larger x than its platform point
            (legs 1, 3, 4 of the source), −1 where at smaller x (legs 2, 5, 6).
        home_position: platform position of the home pose (rotation = identity).
    """

    slider_origins: np.ndarray
    slider_axes: np.ndarray
    platform_points: np.ndarray
    leg_lengths: np.ndarray
    leg_side: np.ndarray
    home_position: np.ndarray
    stroke_min: float = 0.0
    stroke_max: float = 0.35

    def __post_init__(self) -> None:
        fields = {
            "slider_origins": (N_LEGS, 3), "slider_axes": (N_LEGS, 3),
            "platform_points": (N_LEGS, 3), "leg_lengths": (N_LEGS,),
            "leg_side": (N_LEGS,), "home_position": (3,),
        }
        for name, shape in fields.items():
            object.__setattr__(self, name, _frozen(getattr(self, name), shape, name))
        norms = np.linalg.norm(self.slider_axes, axis=1)
        if np.max(np.abs(norms - 1.0)) > 1e-9:
            raise InvalidInput(f"slider axes must be unit vectors, norms {norms.tolist()}")
        if not np.all(self.leg_lengths > 0):
            raise InvalidInput(f"leg lengths must be positive, got {self.leg_lengths.tolist()}")
        if not set(self.leg_side.tolist()) <= {-1.0, 1.0}:
            raise InvalidInput(f"leg_side entries must be +1 or -1, got {self.leg_side.tolist()}")
        if not (np.isfinite(self.stroke_min) and np.isfinite(self.stroke_max)
                and self.stroke_min < self.stroke_max):
            raise InvalidInput(f"bad stroke range [{self.stroke_min}, {self.stroke_max}]")

    @classmethod
    def default(cls) -> HexapodGeometry:
        """The source's values (docs/hexapod.md); home = identity rotation at (0.08, 0.02, 0.11) m.

        The home position maximises the manipulability of :meth:`Hexapod.manipulability`
        over y and z (it does not depend on x: all sliders run along x), with x chosen
        to centre the strokes in [0, 0.35]: they span 0.147–0.210 m. Legs rise at about
        33°, far from the singular plane z = 0 where all legs would lie flat.
        """
        angles = np.radians(PLATFORM_POINT_ANGLES_DEG)
        return cls(
            slider_origins=[[0.15, -0.05, 0.0], [-0.27, 0.05, 0.0], [0.0, 0.15, 0.0],
                            [0.10, -0.10, 0.0], [-0.28, 0.10, 0.0], [-0.25, -0.15, 0.0]],
            slider_axes=np.tile([1.0, 0.0, 0.0], (N_LEGS, 1)),
            platform_points=0.1 * np.stack([np.cos(angles), np.sin(angles), np.zeros(N_LEGS)], axis=1),
            leg_lengths=np.full(N_LEGS, 0.2),
            leg_side=[1.0, -1.0, 1.0, 1.0, -1.0, -1.0],
            home_position=[0.08, 0.02, 0.11],
        )

    def replace(self, **changes) -> HexapodGeometry:
        """A copy with some fields replaced (validated like the constructor)."""
        return dataclasses.replace(self, **changes)

    def with_leg_length_errors(self, dl) -> HexapodGeometry:
        """Leg lengths l_i + dl_i (the source's error model, docs/calibration.md)."""
        return self.replace(leg_lengths=self.leg_lengths + _finite(dl, (N_LEGS,), "dl"))

    def with_slider_home_offsets(self, dq0) -> HexapodGeometry:
        """Slider home points shifted along their axes: S0,i + dq0_i s_i (encoder zero errors)."""
        dq0 = _finite(dq0, (N_LEGS,), "dq0")
        return self.replace(slider_origins=self.slider_origins + dq0[:, None] * self.slider_axes)

    def with_platform_point_errors(self, db) -> HexapodGeometry:
        """Platform points b_i + db_i (platform frame)."""
        return self.replace(platform_points=self.platform_points + _finite(db, (N_LEGS, 3), "db"))


class Hexapod:
    """Kinematics of the 6-PUS hexapod on one :class:`HexapodGeometry`.

    Attributes:
        geometry: the parameters.
        home_strokes: IK of the home pose, the start of FK continuation.
    """

    def __init__(self, geometry: HexapodGeometry | None = None):
        self.geometry = HexapodGeometry.default() if geometry is None else geometry
        self.home_strokes = self.inverse_kinematics_matrix(self.geometry.home_position, np.eye(3))

    # Inverse kinematics ------------------------------------------------------------
    def inverse_kinematics(self, position, rpy_deg) -> np.ndarray:
        """Strokes (6,) of the pose ``position``, ``R = Rz(θz) Ry(θy) Rx(θx)`` (degrees)."""
        return self.inverse_kinematics_matrix(position, rotation_from_rpy(rpy_deg))

    def inverse_kinematics_matrix(self, position, R) -> np.ndarray:
        r"""Strokes (6,) of the pose (position, R), with the source's root rules (docs/hexapod.md).

        The slider line :math:`S_{0,i} + q s_i` meets the sphere of radius :math:`l_i`
        about :math:`P_i` where, with :math:`d = P_i - S_{0,i}`,

        .. math:: q = s_i^\top d \pm \sqrt{(s_i^\top d)^2 - (\|d\|^2 - l_i^2)}.

        A root is admissible if it lies in [stroke_min, stroke_max] and puts the slider
        point on its leg's side of the platform point in x (``leg_side``); if both are
        (possible only for tilted axes) the one farther on its side is kept.

        Raises:
            UnreachablePose: naming the first leg without an admissible root and why.
        """
        g = self.geometry
        position = _finite(position, (3,), "position")
        P = position + g.platform_points @ _rotation(R).T
        d = P - g.slider_origins
        sd = np.einsum("ij,ij->i", g.slider_axes, d)
        disc = sd**2 - (np.einsum("ij,ij->i", d, d) - g.leg_lengths**2)
        roots = sd[:, None] + np.array([-1.0, 1.0]) * np.sqrt(np.maximum(disc, 0.0))[:, None]
        slider_x = g.slider_origins[:, None, 0] + roots * g.slider_axes[:, None, 0]
        margin = g.leg_side[:, None] * (slider_x - P[:, None, 0])
        in_range = (roots >= g.stroke_min) & (roots <= g.stroke_max)
        ok = in_range & (margin > 0) & (disc >= 0)[:, None]
        bad = np.flatnonzero(~ok.any(axis=1))
        if bad.size:
            i = bad[0]
            raise UnreachablePose(f"pose at {np.round(position, 6).tolist()} m "
                                  f"is unreachable: {self._unreachable_reason(i, disc[i], d[i], roots[i], margin[i])}")
        pick = np.argmax(np.where(ok, margin, -np.inf), axis=1)
        return roots[np.arange(N_LEGS), pick]

    def _unreachable_reason(self, i: int, disc: float, d: np.ndarray, roots: np.ndarray,
                            margin: np.ndarray) -> str:
        g = self.geometry
        leg = f"leg {i + 1}"
        if disc < 0:
            gap = np.sqrt(d @ d - (g.slider_axes[i] @ d) ** 2)
            return (f"{leg} is too short to reach: its platform point is {gap:.6g} m from the "
                    f"slider line, the leg length is {g.leg_lengths[i]:.6g} m")
        sided = roots[margin > 0]
        if sided.size == 0:
            return (f"{leg} would stand on the wrong side: neither root {roots.tolist()} m puts "
                    f"its slider point at {'larger' if g.leg_side[i] > 0 else 'smaller'} x than "
                    f"its platform point")
        return (f"{leg} stroke {', '.join(f'{s:.6g}' for s in sided)} m (on its side) "
                f"is outside [{g.stroke_min:g}, {g.stroke_max:g}] m")

    # Forward kinematics ------------------------------------------------------------
    def leg_residuals(self, q, position, R) -> np.ndarray:
        """Length residuals ‖P_i − S_i‖ − l_i (m) of a pose under strokes q."""
        return np.linalg.norm(self.legs(q, position, R)[0], axis=1) - self.geometry.leg_lengths

    def forward_kinematics(self, q, *, initial: tuple[np.ndarray, np.ndarray] | None = None,
                           near: tuple[np.ndarray, np.ndarray] | None = None, side: str | None = None,
                           steps: int = 10, tol: float = 1e-12, max_iter: int = 30) -> Assembly:
        r"""Platform pose (position (3,), R (3, 3)) of the strokes q: which of the assemblies.

        Six strokes admit several platform poses (assembly modes; see
        ``docs/hexapod.md``). Which one is returned is chosen by:

        - default, or ``initial``: Newton with continuation from a known pose (home by
          default): the strokes go from IK(initial) to q in ``steps`` equal steps, each
          solved from the previous pose, so the result stays on the starting pose's
          branch as long as the path meets no singularity;
        - ``near``: the assembly nearest to a pose you know approximately (a measurement,
          the previous control step): damped Newton (Levenberg–Marquardt) from ``near``
          and from 12 starts 2 mm / 1° around it; of the assemblies found, the one with
          the smallest :math:`\|Δp\| + c\,|Δθ|` (c = 0.1 m, the platform radius);
        - ``side``: ``"above"`` or ``"below"`` the plane of the sliders; if the pose found
          lies on the other side, the nearest assembly to its mirror image through that
          plane (the mirror has the same strokes when sliders and platform points are
          coplanar, as in the default geometry).

        Newton: unknowns p and a rotation increment δθ about the current estimate,
        :math:`R \leftarrow \exp([δθ]_\times) R` (no singularity of the parametrisation).
        Residuals :math:`g_i = \|L_i\| - l_i` have Jacobian rows
        :math:`\partial g_i / \partial(p, δθ) = [u_i^\top, (r_i \times u_i)^\top]`,
        :math:`u_i = L_i/\|L_i\|`, :math:`r_i = R b_i`.

        Args:
            q: six strokes (m); their range is not checked (FK is pure geometry).
            initial: a reachable pose (position, R) to continue from (default: home).
            near: an approximate pose (position, R); exclusive with ``initial``.
            side: ``"above"`` or ``"below"`` the slider plane.
            steps: number of continuation steps (1: plain Newton from ``initial``).
            tol: convergence threshold on max |g_i| (m).

        Returns:
            :class:`Assembly`: unpacks as ``position, R``; ``.side`` says which side of
            the slider plane it lies on, ``.method`` how it was found.

        Raises:
            InvalidInput: bad shape or non-finite q, steps < 1, bad ``side``, both
                ``initial`` and ``near``.
            ConvergenceError: no assembly found (none exists, a singularity on the
                way), or none on the requested side, or the pose reached violates the
                leg-side rule.
        """
        q = _finite(q, (N_LEGS,), "strokes q")
        if steps < 1:
            raise InvalidInput(f"steps must be at least 1, got {steps}")
        if side not in (None, *SIDES):
            raise InvalidInput(f"side must be one of {SIDES}, got {side!r}")
        if near is not None and initial is not None:
            raise InvalidInput("give initial (continue from a pose) or near (nearest to a pose), not both")
        if near is not None:
            p0, R0 = _finite(near[0], (3,), "near position"), _rotation(near[1])
            p, R = self._nearest_assembly(q, p0, R0, tol)
            method = "nearest to the given pose"
        else:
            p, R = self._continuation(q, initial, steps, tol, max_iter)
            method = "continuation from home" if initial is None else "continuation from the initial pose"
        if side is not None and self.side_of(p) != side:
            p, R = self._nearest_assembly(q, *self.mirror_pose(p, R), tol)
            method += ", then nearest to its mirror image"
            if self.side_of(p) != side:
                raise ConvergenceError(f"forward kinematics: no assembly {side} the slider plane found "
                                       f"for strokes {q.tolist()}")
        return Assembly(p, R, self.side_of(p), method)

    def side_of(self, position) -> str:
        """``"above"`` or ``"below"`` the plane of the sliders (their home points' mean z)."""
        return "above" if position[2] >= float(np.mean(self.geometry.slider_origins[:, 2])) else "below"

    def mirror_pose(self, position, R) -> tuple[np.ndarray, np.ndarray]:
        """The pose mirrored through the slider plane: (M p, M R M), M = diag(1, 1, −1) about
        the plane's height; it has the same strokes when sliders and platform points are coplanar."""
        M = np.diag([1.0, 1.0, -1.0])
        height = float(np.mean(self.geometry.slider_origins[:, 2]))
        p = np.asarray(position, dtype=float).copy()
        p[2] = 2 * height - p[2]
        return p, M @ np.asarray(R, dtype=float) @ M

    def _continuation(self, q: np.ndarray, initial, steps: int, tol: float, max_iter: int):
        if initial is None:
            p, R, q0 = self.geometry.home_position.copy(), np.eye(3), self.home_strokes
        else:
            p, R = _finite(initial[0], (3,), "initial position").copy(), _rotation(initial[1])
            q0 = self.inverse_kinematics_matrix(p, R)
        for k in range(1, steps + 1):
            qk = q0 + (k / steps) * (q - q0)
            p, R = self._newton(qk, p, R, tol, max_iter, f"continuation step {k}/{steps}")
        L, S, P = self.legs(q, p, R)
        wrong = np.flatnonzero(self.geometry.leg_side * (S[:, 0] - P[:, 0]) <= 0)
        if wrong.size:
            raise ConvergenceError(f"forward kinematics reached a pose where leg {wrong[0] + 1} "
                                   f"violates the leg-side rule (p = {p.tolist()})")
        return p, R

    def _nearest_assembly(self, q: np.ndarray, p0: np.ndarray, R0: np.ndarray, tol: float):
        """Of the assemblies damped Newton reaches from p0, R0 and 12 starts around it, the
        nearest to (p0, R0) that obeys the leg-side rule."""
        starts = [(p0, R0)]
        for k in range(6):
            for sign in (-1.0, 1.0):
                step = np.zeros(6)
                step[k] = sign * (NEAR_START_SHIFT_M if k < 3 else np.radians(NEAR_START_TILT_DEG))
                starts.append((p0 + step[:3], matrix_from_rotvec(step[3:]) @ R0))
        best, best_distance = None, np.inf
        for p_start, R_start in starts:
            found = self._damped_newton(q, p_start, R_start, tol)
            if found is None:
                continue
            p, R = found
            L, S, P = self.legs(q, p, R)
            if np.any(self.geometry.leg_side * (S[:, 0] - P[:, 0]) <= 0):
                continue
            angle = np.linalg.norm(rotvec_from_matrix(R0.T @ R))
            distance = np.linalg.norm(p - p0) + CHARACTERISTIC_LENGTH_M * angle
            if distance < best_distance:
                best, best_distance = (p, R), distance
        if best is None:
            raise ConvergenceError(f"forward kinematics: no assembly found near {np.round(p0, 6).tolist()} m "
                                   f"for strokes {q.tolist()}")
        return best

    def _damped_newton(self, q: np.ndarray, p: np.ndarray, R: np.ndarray, tol: float,
                       max_iter: int = 200) -> tuple[np.ndarray, np.ndarray] | None:
        """Levenberg–Marquardt on the leg residuals (Marquardt's diagonal scaling); None if it stalls."""
        g = self.geometry

        def residual(p, R):
            L = self.legs(q, p, R)[0]
            n = np.linalg.norm(L, axis=1)
            return L, n, n - g.leg_lengths

        L, n, r = residual(p, R)
        damping = 1e-6
        for _ in range(max_iter):
            if not np.all(np.isfinite(r)):
                return None
            if np.max(np.abs(r)) <= tol:
                return p, R
            u = L / n[:, None]
            A = np.hstack([u, np.cross(R @ g.platform_points.T, u.T, axis=0).T])
            H, gradient = A.T @ A, A.T @ r
            while True:
                try:
                    dx = np.linalg.solve(H + damping * np.diag(np.diag(H)), -gradient)
                except np.linalg.LinAlgError:
                    return None
                p_try = p + dx[:3]
                R_try = matrix_from_rotvec(dx[3:]) @ R
                L_try, n_try, r_try = residual(p_try, R_try)
                if r_try @ r_try < r @ r:
                    p, R, L, n, r = p_try, R_try, L_try, n_try, r_try
                    damping = max(damping / 10, 1e-12)
                    break
                damping *= 10
                if damping > 1e12:
                    return None
        return None

    def _newton(self, q: np.ndarray, p: np.ndarray, R: np.ndarray, tol: float, max_iter: int,
                where: str) -> tuple[np.ndarray, np.ndarray]:
        g = self.geometry
        for _ in range(max_iter):
            L = self.legs(q, p, R)[0]
            n = np.linalg.norm(L, axis=1)
            residual = n - g.leg_lengths
            if not np.all(np.isfinite(residual)):
                break
            if np.max(np.abs(residual)) <= tol:
                return p, R
            u = L / n[:, None]
            A = np.hstack([u, np.cross(R @ g.platform_points.T, u.T, axis=0).T])
            try:
                dx = np.linalg.solve(A, -residual)
            except np.linalg.LinAlgError:
                raise ConvergenceError(f"forward kinematics: singular constraint Jacobian at {where}") from None
            p = p + dx[:3]
            R = matrix_from_rotvec(dx[3:]) @ R
        raise ConvergenceError(f"forward kinematics did not converge at {where} within {max_iter} "
                               f"Newton iterations (strokes {q.tolist()}: no assembly nearby?)")

    def legs(self, q, position, R) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Leg vectors L = P − S, slider points S and platform points P (world), each (6, 3)."""
        g = self.geometry
        P = np.asarray(position, dtype=float) + g.platform_points @ np.asarray(R, dtype=float).T
        S = g.slider_origins + np.asarray(q, dtype=float)[:, None] * g.slider_axes
        return P - S, S, P

    # Differential kinematics -------------------------------------------------------
    def inverse_jacobian(self, position, R) -> np.ndarray:
        r"""Jinv (6×6) with q̇ = Jinv [v; ω]: v of the platform origin, ω, both in world.

        Differentiating :math:`L_i^\top L_i = l_i^2` with
        :math:`\dot L_i = v + ω \times r_i - \dot q_i s_i` gives
        :math:`\dot q_i = \big(L_i^\top v + (r_i \times L_i)^\top ω\big) / (L_i^\top s_i)`.
        A row blows up when a leg is perpendicular to its slider (the boundary of the
        leg-side rule); Jinv is singular where the platform gains a free motion.
        """
        R = _rotation(R)
        q = self.inverse_kinematics_matrix(position, R)
        L = self.legs(q, position, R)[0]
        r = self.geometry.platform_points @ R.T
        rows = np.hstack([L, np.cross(r, L)])
        return rows / np.einsum("ij,ij->i", L, self.geometry.slider_axes)[:, None]

    def stroke_sensitivity_to_leg_length(self, position, R) -> np.ndarray:
        r"""∂q_i/∂l_i (6,) at a pose: from :math:`\|d - q s\|^2 = l^2`, ∂q/∂l = −l / (L^\top s)."""
        R = _rotation(R)
        q = self.inverse_kinematics_matrix(position, R)
        L = self.legs(q, position, R)[0]
        return -self.geometry.leg_lengths / np.einsum("ij,ij->i", L, self.geometry.slider_axes)

    def manipulability(self, position, R, characteristic_length: float = 0.1) -> float:
        r"""Inverse condition number σmin/σmax ∈ [0, 1] of the scaled forward Jacobian.

        The forward Jacobian J = Jinv⁻¹ maps q̇ to [v; ω]; its angular rows are made
        commensurate with the linear ones by a characteristic length c (default the
        platform radius, 0.1 m): J_c = diag(I, c I) J. Since cond(J_c) = cond(J_c⁻¹) and
        J_c⁻¹ = Jinv diag(I, I/c), no inversion is needed. It is 0 at both kinds of
        singularity (Jinv singular, or a row of Jinv unbounded) and 1 for an isotropic
        mechanism; at home it is about 0.06.
        """
        scaled = self.inverse_jacobian(position, R) * np.repeat([1.0, 1.0 / characteristic_length], 3)
        sigma = np.linalg.svd(scaled, compute_uv=False)
        return float(sigma[-1] / sigma[0])
