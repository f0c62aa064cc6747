"""Independent references for the engine's tests (loaded by each test file from its own
folder): what a task, a limit or a controller must give, computed here from MuJoCo's own
functions, SciPy's rotations, NumPy's linear algebra and DAQP called directly, never from
the engine's code (the tasks' measured rows are read where a controller is checked: a
controller is checked on the problem its tasks gave it; the rows themselves are checked
against MuJoCo in the task tests).

- Kinematics: a fresh ``MjData`` at q, ``mj_kinematics`` and ``mj_comPos``, then
  ``mj_jacSite``/``mj_jacBody``/``mj_jacGeom``/``mj_jacSubtreeCom`` and the poses.
- Rotations: SciPy's rotation vectors (``Rotation.as_rotvec``), MuJoCo's ``mju_quat2Mat``.
- QPs: ``min ½‖Rx − r‖² s.t. Ax = b, lb ≤ x ≤ ub, Gx ≤ h`` with the cost's rows R, r
  written out from the tasks (H = RᵀR, c = −Rᵀr), solved by DAQP through ``daqp.solve``
  at tight settings for its active set, then made exact on that active set by a
  null-space least-squares solve (NumPy's SVD and ``lstsq``: no normal equations), its
  KKT conditions checked.
"""

from __future__ import annotations

from typing import Sequence

import daqp
import mujoco
import numpy as np
from scipy.optimize import nnls
from scipy.spatial.transform import Rotation

# -- kinematics ---------------------------------------------------------------------------
_FRAMES = {
    "site": (mujoco.mjtObj.mjOBJ_SITE, "site_xpos", "site_xmat", mujoco.mj_jacSite),
    "body": (mujoco.mjtObj.mjOBJ_BODY, "xpos", "xmat", mujoco.mj_jacBody),
    "geom": (mujoco.mjtObj.mjOBJ_GEOM, "geom_xpos", "geom_xmat", mujoco.mj_jacGeom),
}


def mujoco_data(model: mujoco.MjModel, q: np.ndarray) -> mujoco.MjData:
    """A fresh MjData at q, its kinematics and CoM quantities computed by MuJoCo."""
    data = mujoco.MjData(model)
    data.qpos[:] = q
    mujoco.mj_kinematics(model, data)
    mujoco.mj_comPos(model, data)
    return data


def frame_state(model: mujoco.MjModel, q: np.ndarray, name: str, kind: str = "site"):
    """(p (3,), R (3, 3), J_p (3, nv), J_ω (3, nv)) of a site, body or geom at q, MuJoCo's."""
    obj, position, rotation, jacobian = _FRAMES[kind]
    data = mujoco_data(model, q)
    index = mujoco.mj_name2id(model, obj, name)
    assert index >= 0, name
    jacp, jacr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
    jacobian(model, data, jacp, jacr, index)
    return (getattr(data, position)[index].copy(), getattr(data, rotation)[index].reshape(3, 3).copy(), jacp, jacr)


def quaternion_matrix(quaternion) -> np.ndarray:
    """MuJoCo's rotation matrix of a w-x-y-z quaternion (normalised first)."""
    q = np.asarray(quaternion, dtype=float)
    matrix = np.zeros(9)
    mujoco.mju_quat2Mat(matrix, q / np.linalg.norm(q))
    return matrix.reshape(3, 3)


def rotation_vector(desired: np.ndarray, current: np.ndarray, local: bool = False) -> np.ndarray:
    """e with exp([e]) R = R_d (world axes), or R exp([e]) = R_d (the frame's axes): SciPy's."""
    relative = current.T @ desired if local else desired @ current.T
    return Rotation.from_matrix(relative).as_rotvec()


def axis_rows(axes: str) -> list[int]:
    return ["xyz".index(a) for a in axes]


def pose_rows(model, q, frame, gains, *, position=None, rotation=None, position_axes="xyz", orientation_axes="xyz",
              local=False, linear=None, angular=None):
    """(e, J, v) of a frame's pose task written out: position rows e = p_d − p, J = J_p,
    feed-forward ṗ_d; orientation rows e = rotation vector of R_d Rᵀ, J = J_ω, ω_d; in
    the frame's axes (``local``) each block rotated by Rᵀ; the masked rows kept;
    v = K e + feed-forward. ``position``/``rotation`` None: no such block."""
    p, R, Jp, Jr = frame_state(model, q, *frame)
    errors, jacobians, feedforward = [], [], []
    blocks = []
    if position is not None:
        blocks.append((np.asarray(position) - p, Jp, np.zeros(3) if linear is None else np.asarray(linear),
                       axis_rows(position_axes)))
    if rotation is not None:
        blocks.append((rotation_vector(rotation, R), Jr, np.zeros(3) if angular is None else np.asarray(angular),
                       axis_rows(orientation_axes)))
    for e, J, f, rows in blocks:
        if local:
            e, J, f = R.T @ e, R.T @ J, R.T @ f
        errors.append(e[rows])
        jacobians.append(J[rows])
        feedforward.append(f[rows])
    e, J, f = np.concatenate(errors), np.vstack(jacobians), np.concatenate(feedforward)
    return e, J, np.asarray(gains) * e + f


def skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


# -- QPs ----------------------------------------------------------------------------------
# DAQP's tightest sensible settings: constraints met to 1e-12 before it stops, no
# proximal iterations (H is positive definite here), a generous iteration cap.
DAQP_TIGHT = dict(primal_tol=1e-12, dual_tol=1e-12, eps_prox=0.0, iter_limit=100000)
# A constraint counts as active at DAQP's answer within this (relative to 1 + |bound|).
ACTIVE = 1e-9


class LeastSquaresQP:
    """min ½‖Rx − r‖² s.t. Ax = b, lb ≤ x ≤ ub, Gx ≤ h (any of them absent)."""

    def __init__(self, R, r, A=None, b=None, lb=None, ub=None, G=None, h=None):
        self.R, self.r = np.asarray(R, dtype=float), np.asarray(r, dtype=float)
        nv = self.R.shape[1]
        self.nv = nv
        self.A = np.zeros((0, nv)) if A is None else np.asarray(A, dtype=float).reshape(-1, nv)
        self.b = np.zeros(0) if b is None else np.asarray(b, dtype=float).reshape(-1)
        self.lb = np.full(nv, -np.inf) if lb is None else np.asarray(lb, dtype=float)
        self.ub = np.full(nv, np.inf) if ub is None else np.asarray(ub, dtype=float)
        self.G = np.zeros((0, nv)) if G is None else np.asarray(G, dtype=float).reshape(-1, nv)
        self.h = np.zeros(0) if h is None else np.asarray(h, dtype=float).reshape(-1)

    @property
    def H(self) -> np.ndarray:
        return self.R.T @ self.R

    @property
    def c(self) -> np.ndarray:
        return -self.R.T @ self.r

    def daqp(self) -> np.ndarray:
        """DAQP's answer, called directly: bounds as simple bounds, Ax = b by its sense."""
        nv, meq = self.nv, len(self.b)
        rows = np.vstack([self.A, self.G])
        upper = np.concatenate([self.ub, self.b, self.h])
        lower = np.concatenate([self.lb, self.b, np.full(len(self.h), -np.inf)])
        sense = np.zeros(nv + len(rows), dtype=np.intc)
        sense[nv:nv + meq] = 5
        x, _, exitflag, _ = daqp.solve(self.H, self.c, rows, upper, lower, sense, **DAQP_TIGHT)
        assert exitflag == 1, f"DAQP: exit flag {exitflag}"
        return np.asarray(x)

    def solve(self) -> np.ndarray:
        """The minimiser: DAQP's active set, solved exactly (see the module); its KKT
        conditions checked."""
        x0 = self.daqp()
        lower = np.isfinite(self.lb) & (x0 - self.lb <= ACTIVE * (1.0 + np.abs(self.lb)))
        upper = np.isfinite(self.ub) & ~lower & (self.ub - x0 <= ACTIVE * (1.0 + np.abs(self.ub)))
        rows = np.isfinite(self.h) & (self.h - self.G @ x0 <= ACTIVE * (1.0 + np.abs(self.h)))
        eye = np.eye(self.nv)
        E = np.vstack([self.A, eye[lower], eye[upper], self.G[rows]])
        e = np.concatenate([self.b, self.lb[lower], self.ub[upper], self.h[rows]])
        x = _equality_least_squares(self.R, self.r, E, e)
        self._check(x, E, len(self.b), lower.sum(), upper.sum())
        return x

    def _check(self, x, E, meq: int, n_lower: int, n_upper: int) -> None:
        """Feasible, and stationary with multipliers of the right sign on the active
        inequalities: Hx + c + Aᵀλ − Σ μ_l e_i + Σ μ_u e_i + G_aᵀμ_g = 0, μ >= 0, found by
        SciPy's non-negative least squares (λ = λ⁺ − λ⁻), so that a degenerate vertex
        (more active constraints than dofs) is judged by some valid multipliers."""
        scale = 1.0 + np.abs(x).max()
        assert np.all(x >= self.lb - 1e-12 * scale) and np.all(x <= self.ub + 1e-12 * scale), "outside the box"
        assert np.all(self.G @ x <= self.h + 1e-12 * (1.0 + np.abs(self.h))), "a row crossed"
        if len(self.b):
            assert np.linalg.norm(self.A @ x - self.b) <= 1e-10 * (1.0 + np.linalg.norm(self.b)), "rows missed"
        gradient = self.R.T @ (self.R @ x - self.r)  # Hx + c
        if not len(E):
            assert np.linalg.norm(gradient) <= 1e-7 * (1.0 + np.linalg.norm(self.R.T @ self.r)), "not stationary"
            return
        equalities, lower = E[:meq], E[meq:meq + n_lower]
        upper, rows = E[meq + n_lower:meq + n_lower + n_upper], E[meq + n_lower + n_upper:]
        columns = np.vstack([equalities, -equalities, -lower, upper, rows]).T
        _, residual = nnls(columns, -gradient, maxiter=100 * columns.shape[1])
        assert residual <= 1e-7 * (1.0 + np.linalg.norm(gradient)), f"no multipliers of the right sign: {residual:.1e}"


def _equality_least_squares(R, r, E, e) -> np.ndarray:
    """min ‖Rx − r‖ s.t. Ex = e (consistent rows, possibly dependent): x = x_p + Z y with
    x_p E's minimum-norm solution and Z a basis of its null space (SVD), y by ``lstsq``."""
    if not len(E):
        return np.linalg.lstsq(R, r, rcond=None)[0]
    _, singular, vt = np.linalg.svd(E)
    rank = int(np.sum(singular > 1e-12 * singular[0])) if singular.size and singular[0] > 0 else 0
    particular = np.linalg.lstsq(E, e, rcond=1e-12)[0]
    Z = vt[rank:].T
    if Z.shape[1] == 0:
        return particular
    y = np.linalg.lstsq(R @ Z, r - R @ particular, rcond=None)[0]
    return particular + Z @ y


def cost_rows(tasks: Sequence, world: int, nv: int, regularization: float):
    """(R, r) of the QP's cost in world ``world``, written out from the soft tasks' rows:
    √w_i (J_i, v_i) per row, √(ε + Σ μ eᵀWe) I (the regulariser and the
    Levenberg–Marquardt damping). Joint-space tasks are rows like any other."""
    blocks, rhs = [], []
    damping = float(regularization)
    for task in tasks:
        if task.hard:
            continue
        root = np.sqrt(np.asarray(task.weight, dtype=float))
        J = np.asarray(task.jacobians[world], dtype=float)
        blocks.append(root[:, None] * J)
        rhs.append(root * task.target_velocities[world])
        e = task.errors[world]
        damping += task.lm_damping * float(np.sum(task.weight * e * e))
    blocks.append(np.sqrt(damping) * np.eye(nv))
    rhs.append(np.zeros(nv))
    return np.vstack(blocks), np.concatenate(rhs)


def hard_rows(tasks: Sequence, world: int, nv: int):
    """(A, b): the hard tasks' rows J q̇ = v in world ``world``."""
    rows = [(np.asarray(t.jacobians[world]), np.asarray(t.target_velocities[world])) for t in tasks if t.hard]
    if not rows:
        return np.zeros((0, nv)), np.zeros(0)
    return np.vstack([J for J, _ in rows]), np.concatenate([v for _, v in rows])


def qp_answer(tasks: Sequence, world: int, nv: int, box, rows=(None, None), regularization: float = 1e-12):
    """The QP controller's minimiser in world ``world`` on the tasks' current rows, the
    box (lb, ub) and general rows (G, h) of that world."""
    R, r = cost_rows(tasks, world, nv, regularization)
    A, b = hard_rows(tasks, world, nv)
    return LeastSquaresQP(R, r, A, b, box[0], box[1], *rows).solve()


def limits_box(limits: Sequence, dt: float, n: int, nv: int):
    """(lower, upper, G, h) of the limits applied into fresh arrays: the constant ones
    first (the speed box a position limit clips into), then the others in order. For
    limits whose box depends on q alone (not an AccelerationLimit, which remembers)."""
    lower, upper = np.full((n, nv), -np.inf), np.full((n, nv), np.inf)
    count = sum(limit.inequality_rows for limit in limits)
    G, h = np.zeros((n, count, nv)), np.zeros((n, count))
    start = 0
    for limit in [lim for lim in limits if lim.constant] + [lim for lim in limits if not lim.constant]:
        rows = limit.inequality_rows
        if rows:
            limit.apply(dt, lower, upper, G[:, start:start + rows], h[:, start:start + rows])
        else:
            limit.apply(dt, lower, upper)
        start += rows
    return lower, upper, G, h


def close(actual, expected, tolerance: float, floor: float = 1e-3) -> bool:
    """‖actual − expected‖ <= tolerance · max(‖expected‖, floor) (floor: an answer at rest)."""
    actual, expected = np.asarray(actual, dtype=float), np.asarray(expected, dtype=float)
    return float(np.linalg.norm(actual - expected)) <= tolerance * max(float(np.linalg.norm(expected)), floor)


# -- limits' rules, written out -----------------------------------------------------------
def position_limit_box(limit, q: np.ndarray, dt: float, lower: np.ndarray, upper: np.ndarray):
    """A JointPositionLimit's rule joint by joint (its parameters read from the limit): the
    step q + q̇Δt inside the range pulled in by the margin, covering a fraction ``gain`` of
    the distance per step; within ``influence`` of a bound the damper's rate
    min(ξ/influence, gain/Δt); a joint outside brought back no faster than the incoming
    box allows. Returns new (lower, upper) (nv,)."""
    lower, upper = np.array(lower, dtype=float), np.array(upper, dtype=float)
    step_rate = limit.gain / dt
    damped = min(limit.damper_rate / limit.influence, step_rate) if limit.influence > 0 else step_rate
    ranges = limit.limits
    for qi, di, low_end, high_end in zip(ranges.qpos_index, ranges.dof_index, ranges.lower, ranges.upper):
        low, high = low_end + limit.margin - q[qi], high_end - limit.margin - q[qi]
        low *= damped if abs(low) < limit.influence else step_rate
        high *= damped if abs(high) < limit.influence else step_rate
        low, high = min(low, upper[di]), max(high, lower[di])
        lower[di], upper[di] = max(lower[di], low), min(upper[di], high)
    return lower, upper


def collision_rows(model, q, pairs, dt: float, minimum_distance: float, detection_distance: float,
                   gain: float = 0.85, damper_rate: float | None = 0.5, bound_relaxation: float = 0.0,
                   search: float = 10.0):
    """A CollisionAvoidanceLimit's rows written out, pair by pair, on MuJoCo's own distance
    (``mj_geomDistance`` with native convex collision, on a copy of the model) and point
    Jacobians (``mj_jac`` at the closest points): d, the row −ḋ/q̇ = −n̂ᵀ(J₂ − J₁) with n̂
    from p₁ to p₂ (+ once the geoms penetrate: the points then run the other way) and its
    bound γ(d − d_s)/Δt, the damper's ξ(d − d_s)/(d_i − d_s) below d_i if tighter, at
    least 0, plus the relaxation. Returns (d (P,), G (P, nv), h (P,)) for every pair
    (whether the limit keeps a pair's row depends on its reach: the test decides)."""
    model = native_collision(model)
    data = mujoco_data(model, q)
    distances, G, h = np.zeros(len(pairs)), np.zeros((len(pairs), model.nv)), np.zeros(len(pairs))
    for p, (g1, g2) in enumerate(pairs):
        fromto = np.zeros(6)
        d = mujoco.mj_geomDistance(model, data, g1, g2, search, fromto)
        jacobians = []
        for body, point in ((model.geom_bodyid[g1], fromto[:3]), (model.geom_bodyid[g2], fromto[3:])):
            jacp = np.zeros((3, model.nv))
            mujoco.mj_jac(model, data, jacp, None, point, body)
            jacobians.append(jacp)
        normal = (fromto[3:] - fromto[:3]) / np.linalg.norm(fromto[3:] - fromto[:3])
        G[p] = (-1.0 if d >= 0 else 1.0) * normal @ (jacobians[1] - jacobians[0])
        bound = gain * (d - minimum_distance) / dt
        if damper_rate is not None and d < detection_distance:
            bound = min(bound, damper_rate * (d - minimum_distance) / (detection_distance - minimum_distance))
        distances[p], h[p] = d, max(bound, 0.0) + bound_relaxation
    return distances, G, h


def native_collision(model: mujoco.MjModel) -> mujoco.MjModel:
    """The model itself, or a copy with MuJoCo's native convex collision turned on."""
    off = int(mujoco.mjtDisableBit.mjDSBL_NATIVECCD)
    if not model.opt.disableflags & off:
        return model
    import copy

    copied = copy.deepcopy(model)
    copied.opt.disableflags &= ~off
    return copied


# -- the hierarchy, level by level ----------------------------------------------------------
def row_basis(rows: np.ndarray, tolerance: float = 1e-10) -> np.ndarray:
    """An orthonormal basis of the row space of ``rows`` (NumPy's SVD; singular values
    below ``tolerance`` of the largest dropped)."""
    if not len(rows):
        return rows
    _, singular, vt = np.linalg.svd(rows, full_matrices=False)
    rank = int(np.sum(singular > tolerance * singular[0])) if singular[0] > 0 else 0
    return vt[:rank]


def level_regularization(soft: Sequence, nv: int, regularization: float) -> float:
    """The ε of a level's cost (the hierarchy's documented choice): 1 for hard tasks alone
    (the minimum-norm point), 0 where joint-space soft tasks weigh every dof, else ε."""
    if not soft:
        return 1.0
    covered = np.zeros(nv, dtype=bool)
    for task in soft:
        if task.joint_space:
            covered[np.asarray(task.dofs)[np.asarray(task.weight) > 0]] = True
    return 0.0 if covered.all() else regularization


def level_rows(level: Sequence, world: int):
    """(J, v) of a level's rows: every row of a hard task, the rows of positive weight of a
    soft one (a zero weight masks a row)."""
    blocks = []
    for task in level:
        keep = np.arange(task.dim) if task.hard else np.flatnonzero(np.asarray(task.weight) > 0)
        blocks.append((np.asarray(task.jacobians[world])[keep], np.asarray(task.target_velocities[world])[keep]))
    return np.vstack([J for J, _ in blocks]), np.concatenate([v for _, v in blocks])


def hierarchy_answers(levels: Sequence[Sequence], world: int, nv: int, box, rows=(None, None),
                      regularization: float = 1e-10) -> list[np.ndarray]:
    """Each level's minimiser in turn (Kanoun et al. 2011), solved independently: level k
    minimises its soft tasks' cost (ε of :func:`level_regularization`, the tasks'
    Levenberg–Marquardt damping) s.t. the rows of every level above keep the velocity
    they had at q̇*_{k−1} (an orthonormal basis of their row space, so dependent rows
    above are one constraint each), its hard rows, the box and the general rows."""
    above, answers, previous = np.zeros((0, nv)), [], np.zeros(nv)
    for level in levels:
        soft = [task for task in level if not task.hard]
        R, r = cost_rows(soft, world, nv, level_regularization(soft, nv, regularization))
        A, b = hard_rows(level, world, nv)
        basis = row_basis(above)
        A, b = np.vstack([basis, A]), np.concatenate([basis @ previous, b])
        previous = LeastSquaresQP(R, r, A, b, box[0], box[1], *rows).solve()
        answers.append(previous)
        above = np.vstack([above, level_rows(level, world)[0]])
    return answers
