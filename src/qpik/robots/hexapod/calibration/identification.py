r"""Kinematic calibration of the hexapod (docs/calibration.md): identify geometric errors from strokes.

Setting (the source's): the platform is driven to known poses :math:`x_k` (measured by an
external system) and the slider strokes are read. The "real" strokes are simulated:

.. math:: q^{meas}_k = \mathrm{IK}(x_k;\ \text{true geometry}) + c + ε_k,
          \qquad ε_k \sim \mathcal N(0, σ^2 I),

and the model predicts :math:`q_k(θ) = \mathrm{IK}(x_k;\ \text{nominal} ⊕ θ) + c(θ)`, where
θ collects the parameter errors (metres) of the chosen groups:

- ``legs``: leg lengths :math:`l_i + δl_i` (the source's only parameters);
- ``offsets``: slider home points moved along their axes, :math:`S_{0,i} + δq_{0,i} s_i`;
- ``points``: platform points :math:`b_i + δb_i` (platform frame, 3 components);
- ``zeros``: encoder zero errors :math:`c_i`, added to the stroke reading.

Identification solves :math:`\min_θ \sum_k \|q_k(θ) - q^{meas}_k\|^2`. Each stroke depends on
its own leg's parameters only; differentiating :math:`\|P_i - S_{0,i} - q_i s_i\|^2 = l_i^2`
(with :math:`L_i = P_i - S_i`) gives the identification Jacobian rows

.. math:: \frac{∂q_i}{∂l_i} = \frac{-l_i}{L_i^\top s_i},\quad
          \frac{∂q_i}{∂q_{0,i}} = -1,\quad
          \frac{∂q_i}{∂b_i} = \frac{(R^\top L_i)^\top}{L_i^\top s_i},\quad
          \frac{∂q_i}{∂c_i} = 1.

Methods: ``linear`` is the source's procedure, one least-squares solve of the first-order
model :math:`δq = J(0)\,θ` (for legs, J stacks the diagonal blocks
:math:`\mathrm{diag}(∂q_i/∂l_i)`); ``gauss-newton`` iterates
:math:`θ \leftarrow θ + J(θ)^+ (q^{meas} - q(θ))` with the Jacobian at the current
estimate, undamped (the residual is tiny and the model nearly linear, so the pure
Gauss–Newton step converges quadratically); ``lm`` is MINPACK's Levenberg–Marquardt
through :func:`scipy.optimize.least_squares`.

Identifiability (the SVD of the Jacobian in :func:`identifiability`; see the tests):

- legs with offsets: identifiable, since ∂q_i/∂l_i varies with the pose and ∂q_i/∂q_{0,i}
  does not;
- offsets with zeros: never separable, both are constant stroke offsets (−δq0 + c), null
  vector :math:`e_{q0,i} + e_{c,i}`: a slider moved along its own axis is an encoder zero
  error. The gauge keeps the offset (the earlier group) and fixes c = 0;
- platform points: :math:`b_i` enters through :math:`R b_i`, so at R = I, :math:`b_{i,x}`
  enters exactly as :math:`-q_{0,i}` (the x of :math:`P_i - S_{0,i}`). Only rotations tell
  them apart: with pure translations the null vectors are :math:`e_{q0,i} + e_{bx,i}`; with
  tilts of ±10° the rank is full but the conditioning is poor;
- each stroke depends on its own leg's parameters only, so every leg needs at least as
  many poses as it has parameters (the four seed poses cannot identify ``full``: 5 a leg);
- no global gauge: the poses are measured in the base frame, so even a common shift of
  all platform points changes the strokes (through R) and is identified.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from ....errors import ConvergenceError, InvalidInput, UnreachablePose
from ..kinematics import N_LEGS, Hexapod, HexapodGeometry, rotation_from_rpy

UM = 1e-6  # metres per micrometre; the solvers work in µm so tolerances are meaningful

# The source's poses [x, y, z (m), θx, θy, θz (deg)] and imposed leg-length errors (µm)
# (docs/calibration.md).
SEED_POSES = np.array([
    [0.15, 0.10, 0.05, -3.0, 2.0, 3.0],
    [0.07, 0.08, 0.04, 4.0, -3.0, -2.0],
    [-0.01, 0.02, 0.07, -2.0, 5.0, 8.0],
    [0.13, -0.06, -0.02, 5.0, -4.0, -1.0],
])
# Imposed errors (µm) per group; legs from the source, the others arbitrary, of the same order.
IMPOSED_UM = {
    "legs": [50.0, -20.0, -50.0, 20.0, 10.0, -10.0],
    "offsets": [30.0, -40.0, 15.0, -25.0, 35.0, -10.0],
    "points": [[40.0, -25.0, 15.0], [-30.0, 35.0, -20.0], [25.0, 20.0, -35.0],
               [-15.0, -40.0, 30.0], [-35.0, 15.0, 25.0], [-20.0, -30.0, -45.0]],
    "zeros": [-15.0, 25.0, -30.0, 10.0, -20.0, 40.0],
}
GROUP_COLUMNS = {"legs": ["l{}"], "offsets": ["q0_{}"], "points": ["b{}x", "b{}y", "b{}z"],
                 "zeros": ["c{}"]}
PARAMETER_SETS = {"legs": ("legs",), "legs+offsets": ("legs", "offsets"),
                  "full": ("legs", "offsets", "points")}
METHODS = ("linear", "gauss-newton", "lm")

# Random poses: uniform in a box about home, kept if reachable with the nominal and the
# true geometry and not near-singular. The box spans the seed poses' range of positions
# and tilts; the manipulability threshold is a third of home's (0.06), which rejects
# about a fifth of the reachable samples.
POSE_BOX_POSITION_M = (0.08, 0.06, 0.04)
POSE_BOX_RPY_DEG = 10.0
MIN_MANIPULABILITY = 0.02
# Gauss–Newton stops on a step below GN_XTOL·(1 + ‖θ‖/µm) µm (~1e-13 m): far below the
# 1e-4 % target (~1e-11 m), above the step's roundoff floor (cond(J) · 1e-17 m).
GN_XTOL = 1e-9
LM_TOL = 1e-15
RANK_RTOL = 1e-9  # singular values below RANK_RTOL·σmax count as zero (roundoff ~1e-15)


@dataclass(frozen=True)
class ParameterSet:
    """Which geometric errors are identified: an ordered tuple of groups (see module doc)."""

    groups: tuple[str, ...]

    @classmethod
    def parse(cls, text: str) -> ParameterSet:
        """Groups or named sets joined by '+': ``legs``, ``full+zeros``, ``offsets+points``, ..."""
        groups = tuple(g for token in text.split("+") for g in PARAMETER_SETS.get(token, (token,)))
        unknown = [g for g in groups if g not in GROUP_COLUMNS]
        if unknown or len(set(groups)) != len(groups):
            raise InvalidInput(f"bad parameter set {text!r}: join distinct groups ({', '.join(GROUP_COLUMNS)}) "
                               f"or sets ({', '.join(PARAMETER_SETS)}) with '+'")
        return cls(groups)

    @property
    def label(self) -> str:
        return "+".join(self.groups)

    @property
    def names(self) -> list[str]:
        """Parameter names, group by group, leg by leg (e.g. l1..l6, q0_1.., b1x, b1y, ...)."""
        return [col.format(i + 1) for g in self.groups for i in range(N_LEGS) for col in GROUP_COLUMNS[g]]

    @property
    def size(self) -> int:
        return len(self.names)

    @property
    def per_leg(self) -> int:
        """Parameters of each leg (every stroke depends on its own leg's only)."""
        return sum(len(GROUP_COLUMNS[g]) for g in self.groups)

    @property
    def leg_numbers(self) -> np.ndarray:
        """Leg (1-based) of every parameter."""
        return np.concatenate([np.repeat(np.arange(1, N_LEGS + 1), len(GROUP_COLUMNS[g])) for g in self.groups])

    def split(self, theta: np.ndarray) -> dict[str, np.ndarray]:
        """θ (metres) as {group: (6,) or (6, 3)}; absent groups are zero."""
        out = {g: np.zeros((N_LEGS, 3) if g == "points" else N_LEGS) for g in GROUP_COLUMNS}
        start = 0
        for g in self.groups:
            n = N_LEGS * len(GROUP_COLUMNS[g])
            out[g] = np.asarray(theta[start:start + n], dtype=float).reshape(out[g].shape)
            start += n
        return out

    def imposed(self) -> np.ndarray:
        """The default imposed errors θ (metres)."""
        return np.concatenate([np.ravel(IMPOSED_UM[g]) for g in self.groups]) * UM

    def geometry(self, nominal: HexapodGeometry, theta: np.ndarray) -> HexapodGeometry:
        """Nominal geometry with the errors θ applied (encoder zeros are not geometry)."""
        part = self.split(theta)
        return (nominal.with_leg_length_errors(part["legs"])
                .with_slider_home_offsets(part["offsets"])
                .with_platform_point_errors(part["points"]))


def validate_poses(poses) -> np.ndarray:
    """Poses as an (N, 6) float array [x, y, z (m), θx, θy, θz (deg)], N ≥ 1, finite."""
    arr = np.array(poses, dtype=float)
    if arr.ndim != 2 or arr.shape[1] != 6 or arr.shape[0] < 1:
        raise InvalidInput(f"poses must be a non-empty list of [x, y, z, thx, thy, thz], got shape {arr.shape}")
    bad = np.flatnonzero(~np.all(np.isfinite(arr), axis=1))
    if bad.size:
        raise InvalidInput(f"pose {bad[0] + 1} contains NaN or inf: {arr[bad[0]].tolist()}")
    return arr


class StrokeModel:
    """Predicted strokes q(θ) at fixed poses for one parameter set about a nominal geometry."""

    def __init__(self, nominal: HexapodGeometry, params: ParameterSet, poses: np.ndarray):
        self.nominal, self.params = nominal, params
        self.poses = validate_poses(poses)
        self.rotations = [rotation_from_rpy(p[3:]) for p in self.poses]

    def strokes(self, theta: np.ndarray) -> np.ndarray:
        """(N, 6) strokes of the geometry nominal ⊕ θ, plus encoder zeros.

        Raises:
            UnreachablePose: naming the pose (index and values) and the leg.
        """
        hexapod = Hexapod(self.params.geometry(self.nominal, theta))
        zeros = self.params.split(theta)["zeros"]
        q = np.empty((len(self.poses), N_LEGS))
        for k, (pose, R) in enumerate(zip(self.poses, self.rotations)):
            try:
                q[k] = hexapod.inverse_kinematics_matrix(pose[:3], R) + zeros
            except UnreachablePose as exc:
                raise UnreachablePose(f"pose {k + 1} {np.round(pose, 6).tolist()}: {exc}") from None
        return q

    def jacobian(self, theta: np.ndarray) -> np.ndarray:
        """∂q/∂θ (6N × P), rows pose-major (pose k, leg i → row 6k + i); see module doc."""
        from scipy.linalg import block_diag

        hexapod = Hexapod(self.params.geometry(self.nominal, theta))
        g = hexapod.geometry
        blocks = []
        for pose, R in zip(self.poses, self.rotations):
            q = hexapod.inverse_kinematics_matrix(pose[:3], R)
            L = hexapod.legs(q, pose[:3], R)[0]
            along = np.einsum("ij,ij->i", L, g.slider_axes)  # L_i·s_i
            per_group = {
                # ∂q_i/∂l_i = −l_i/(L_i·s_i), as Hexapod.stroke_sensitivity_to_leg_length
                "legs": np.diag(-g.leg_lengths / along),
                "offsets": -np.eye(N_LEGS),
                # Row i holds (RᵀL_i)ᵀ/(L_i·s_i) in columns 3i..3i+2.
                "points": block_diag(*(L @ R / along[:, None])),
                "zeros": np.eye(N_LEGS),
            }
            blocks.append(np.hstack([per_group[name] for name in self.params.groups]))
        return np.vstack(blocks)


@dataclass(frozen=True)
class Identifiability:
    r"""SVD of the identification Jacobian J = ∂q/∂θ (dimensionless: metres over metres).

    rank = #{σ > RANK_RTOL σmax}. The gauge keeps a parameter if its column raises the
    rank of the columns kept so far, so of a dependent pair the earlier group stays
    (offsets over zeros) and the later is fixed at 0. ``null_space`` (P × (P − rank))
    spans the null space of J in gauge form: column j is 1 on the j-th fixed parameter,
    0 on the other fixed ones, so it reads "this fixed parameter is indistinguishable
    from this combination of the kept ones". ``condition_number`` is σmax/σmin of the
    kept columns.
    """

    names: list[str]
    singular_values: np.ndarray
    rank: int
    null_space: np.ndarray
    free: np.ndarray  # bool (P,)
    condition_number: float

    @property
    def fixed(self) -> list[str]:
        return [n for n, f in zip(self.names, self.free) if not f]

    def null_vectors(self, min_weight: float = 1e-6) -> list[dict[str, float]]:
        """Each null-space direction as {parameter: coefficient} (|coefficient| > min_weight)."""
        return [{n: round(float(c), 6) for n, c in zip(self.names, v) if abs(c) > min_weight}
                for v in self.null_space.T]

    def in_gauge(self, theta: np.ndarray) -> np.ndarray:
        """θ moved along the null space until its fixed parameters are 0 (same first-order strokes)."""
        moved = theta - self.null_space @ theta[~self.free]
        moved[~self.free] = 0.0  # exactly, not to roundoff
        return moved


def identifiability(jacobian: np.ndarray, names: Sequence[str]) -> Identifiability:
    """Rank, singular values, null space and gauge (kept columns) of ``jacobian``."""
    _, s, vt = np.linalg.svd(jacobian)
    tol = RANK_RTOL * s[0]
    rank = int(np.sum(s > tol))
    free = np.zeros(jacobian.shape[1], dtype=bool)
    kept_rank = 0
    for j in range(jacobian.shape[1]):
        free[j] = True
        free[j] = np.linalg.matrix_rank(jacobian[:, free], tol=tol) > kept_rank
        kept_rank += int(free[j])
    null = vt[rank:].T
    # The kept columns are independent, so no null vector vanishes on all fixed ones and
    # null[fixed] (square) is invertible.
    null = null @ np.linalg.inv(null[~free]) if rank < len(free) else null
    sf = np.linalg.svd(jacobian[:, free], compute_uv=False)
    return Identifiability(list(names), s, rank, null, free, float(sf[0] / sf[-1]))


@dataclass(frozen=True)
class Fit:
    """An estimate θ (metres; gauge-fixed parameters are 0) and how it was reached."""

    theta: np.ndarray
    iterations: int  # Jacobian evaluations (linear: 1)
    evaluations: int  # stroke-model evaluations
    residual_rms: float  # metres, RMS of q_meas − q(θ)
    jacobian: np.ndarray  # ∂q/∂θ_free at the estimate


def fit(model: StrokeModel, measured: np.ndarray, method: str, free: np.ndarray,
        *, max_iter: int = 20) -> Fit:
    """Estimate the free parameters from measured strokes (N, 6); see module doc for methods.

    Gauss–Newton stops when a step is below GN_XTOL·(1 + ‖θ‖/µm) µm; Levenberg–Marquardt
    uses xtol = ftol = gtol = LM_TOL.

    Raises:
        ConvergenceError: no convergence within ``max_iter`` iterations.
    """
    if method not in METHODS:
        raise InvalidInput(f"unknown method {method!r}: use one of {', '.join(METHODS)}")
    P = model.params.size

    def full(x_um: np.ndarray) -> np.ndarray:
        theta = np.zeros(P)
        theta[free] = x_um * UM
        return theta

    def residual(x_um: np.ndarray) -> np.ndarray:  # µm
        return (model.strokes(full(x_um)) - measured).ravel() / UM

    def jac(x_um: np.ndarray) -> np.ndarray:
        return model.jacobian(full(x_um))[:, free]

    x = np.zeros(int(free.sum()))
    if method == "linear":
        x = np.linalg.lstsq(jac(x), -residual(x), rcond=None)[0]
        iterations, evaluations = 1, 1
    elif method == "gauss-newton":
        for iterations in range(1, max_iter + 1):
            step = np.linalg.lstsq(jac(x), -residual(x), rcond=None)[0]
            x = x + step
            if np.linalg.norm(step) <= GN_XTOL * (1.0 + np.linalg.norm(x)):
                break
        else:
            raise ConvergenceError(f"Gauss-Newton did not converge in {max_iter} iterations")
        evaluations = iterations
    else:
        from scipy.optimize import least_squares

        sol = least_squares(residual, x, jac=jac, method="lm", xtol=LM_TOL, ftol=LM_TOL, gtol=LM_TOL)
        if sol.status <= 0:
            raise ConvergenceError(f"Levenberg-Marquardt failed: {sol.message}")
        x, iterations, evaluations = sol.x, int(sol.njev), int(sol.nfev)
    r = residual(x)
    return Fit(full(x), iterations, evaluations + 1, float(np.sqrt(np.mean(r**2))) * UM, jac(x))


def sample_poses(n: int, rng: np.random.Generator, geometries: Sequence[HexapodGeometry],
                 max_attempts_per_pose: int = 200) -> tuple[np.ndarray, int]:
    """n random poses (uniform box about home) reachable by every geometry and well conditioned.

    Returns the poses (n, 6) and the number of candidates drawn.
    """
    if n < 1:
        raise InvalidInput(f"the number of poses must be at least 1, got {n}")
    hexapods = [Hexapod(g) for g in geometries]
    home = geometries[0].home_position
    half = np.concatenate([POSE_BOX_POSITION_M, np.full(3, POSE_BOX_RPY_DEG)])
    poses: list[np.ndarray] = []
    attempts = 0
    while len(poses) < n:
        if attempts >= max_attempts_per_pose * n:
            raise ConvergenceError(f"only {len(poses)} of {n} admissible poses in {attempts} samples")
        attempts += 1
        pose = np.concatenate([home, np.zeros(3)]) + rng.uniform(-half, half)
        R = rotation_from_rpy(pose[3:])
        try:
            if all(h.manipulability(pose[:3], R) >= MIN_MANIPULABILITY for h in hexapods):
                poses.append(pose)
        except UnreachablePose:
            continue
    return np.array(poses), attempts


@dataclass(frozen=True)
class Calibration:
    """One identification experiment: setup, estimate, identifiability and spread.

    ``reference`` is the imposed θ moved along the null space into the gauge (fixed
    parameters 0): the only value any estimator can return. It equals ``imposed`` when
    the set is identifiable.
    """

    method: str
    params: ParameterSet
    poses: np.ndarray
    pose_source: str
    noise_um: float
    seed: int
    imposed: np.ndarray
    reference: np.ndarray
    fit: Fit
    ident: Identifiability
    covariance_std: np.ndarray  # σ √diag((JᵀJ)⁻¹) (metres), NaN for fixed parameters
    monte_carlo: np.ndarray | None  # (repeats, P) estimates, metres

    @property
    def error(self) -> np.ndarray:
        return self.fit.theta - self.reference

    @property
    def relative_error_pct(self) -> np.ndarray:
        """|error| / |reference| · 100; NaN for gauge-fixed parameters (reference 0)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(self.ident.free, np.abs(self.error) / np.abs(self.reference) * 100, np.nan)

    @property
    def monte_carlo_std(self) -> np.ndarray | None:
        """Per-parameter standard deviation over the repeats (metres)."""
        return None if self.monte_carlo is None else self.monte_carlo.std(axis=0, ddof=1)


def resolve_poses(poses: str | int | np.ndarray | Sequence, rng: np.random.Generator,
                  geometries: Sequence[HexapodGeometry]) -> tuple[np.ndarray, str]:
    """``"seed"`` (the source's four), an int N (random, :func:`sample_poses`) or explicit poses."""
    if isinstance(poses, str):
        if poses == "seed":
            return SEED_POSES.copy(), "seed (the source's four poses)"
        raise InvalidInput(f"poses must be 'seed', a positive integer or a list of poses, got {poses!r}")
    if isinstance(poses, (int, np.integer)):
        sampled, attempts = sample_poses(int(poses), rng, geometries)
        return sampled, (f"{len(sampled)} random poses of {attempts} drawn uniformly in home "
                         f"± {list(POSE_BOX_POSITION_M)} m, ± {POSE_BOX_RPY_DEG:g} deg, reachable with "
                         f"nominal and true geometry, manipulability ≥ {MIN_MANIPULABILITY:g}")
    return validate_poses(poses), "given"


def calibrate(method: str = "linear", poses: str | int | np.ndarray | Sequence = "seed", *,
              params: str | ParameterSet = "legs", noise_um: float = 0.0, seed: int = 0,
              repeats: int = 1, nominal: HexapodGeometry | None = None,
              imposed: np.ndarray | None = None,
              progress: Callable[[int, int], None] | None = None) -> Calibration:
    """Simulate measurements with imposed errors, identify them, analyse the result.

    Args:
        method: ``linear``, ``gauss-newton`` or ``lm``.
        poses: ``"seed"``, a number of random poses, or an (N, 6) array.
        params: parameter set (:meth:`ParameterSet.parse`).
        noise_um: standard deviation σ of the Gaussian stroke noise (µm), ≥ 0.
        seed: seeds the pose sampling and the noise (repeat r uses child stream r).
        repeats: noise realisations (same poses) for the Monte-Carlo spread; the first
            gives the reported estimate.
        imposed: true θ (metres); default :meth:`ParameterSet.imposed`.
        progress: called as ``progress(r, repeats)`` after each noise realisation's fit.

    Raises:
        InvalidInput, UnreachablePose (naming pose and leg), ConvergenceError (also when the
        noise is so large that the fit leaves the geometries that reach the poses),
    """
    if not (np.isfinite(noise_um) and noise_um >= 0):
        raise InvalidInput(f"noise must be a finite standard deviation ≥ 0 µm, got {noise_um}")
    if repeats < 1:
        raise InvalidInput(f"repeats must be at least 1, got {repeats}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise InvalidInput(f"seed must be an integer ≥ 0 (numpy's SeedSequence), got {seed!r}")
    if method not in METHODS:
        raise InvalidInput(f"unknown method {method!r}: use one of {', '.join(METHODS)}")
    params = params if isinstance(params, ParameterSet) else ParameterSet.parse(params)
    nominal = HexapodGeometry.default() if nominal is None else nominal
    imposed = params.imposed() if imposed is None else np.asarray(imposed, dtype=float)
    pose_stream, *noise_streams = np.random.SeedSequence(seed).spawn(1 + repeats)
    pose_array, source = resolve_poses(poses, np.random.default_rng(pose_stream),
                                       [nominal, params.geometry(nominal, imposed)])
    model = StrokeModel(nominal, params, pose_array)
    model.strokes(np.zeros(params.size))  # reachability, nominal first; the error names pose and leg
    exact = model.strokes(imposed)
    ident = identifiability(model.jacobian(np.zeros(params.size)), params.names)
    reference = ident.in_gauge(imposed)
    sigma = noise_um * UM
    fits = []
    for r, stream in enumerate(noise_streams, 1):
        noise = sigma * np.random.default_rng(stream).standard_normal(exact.shape)
        try:
            fits.append(fit(model, exact + noise, method, ident.free))
        except (InvalidInput, UnreachablePose):  # raised by a candidate geometry, not the user's
            raise ConvergenceError(
                f"noise σ = {noise_um:g} µm is too large for the stroke model: the fit of noise draw {r} "
                "went through geometries that cannot reach the poses (legs too short or negative)") from None
        if progress is not None:
            progress(r, repeats)
    cov_std = np.full(params.size, np.nan)
    J = fits[0].jacobian
    cov_std[ident.free] = sigma * np.sqrt(np.diag(np.linalg.inv(J.T @ J)))
    return Calibration(method, params, pose_array, source, float(noise_um), seed, imposed, reference,
                       fits[0], ident, cov_std,
                       np.array([f.theta for f in fits]) if repeats > 1 else None)
