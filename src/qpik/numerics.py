r"""The engine's small numerical primitives, each over a leading world axis N.

Every task, cost and solve is written once over (N, ...) arrays. For one world (a
:class:`qpik.Robot`) NumPy's per-call cost outweighs the arithmetic of a control step's
tiny systems, so a few primitives take MuJoCo's own routines when N = 1 — the same
formulas, in C: the rotation error (``mju_mat2Quat``/``mju_subQuat``), :math:`AB^T`
(``mju_mulMatMatT``), small dot products (``mju_dot``) and the Cholesky factor and solve
(``mju_cholFactor``/``mju_cholSolve``: BLAS's and LAPACK's blocked routines pack these
small matrices first, which costs more than the arithmetic). Above one world the
arithmetic runs across worlds with the world axis last, one vector operation per step of
the algorithm (NumPy's stacked routines call LAPACK once per matrix, which on these sizes
is mostly overhead).
"""

from __future__ import annotations

import functools
import math

import mujoco
import numpy as np
from scipy.linalg.lapack import dgesv, dpotrs

MINVAL = 1e-15  # mjMINVAL
_TINY = 5e-324  # the least positive float
SMALL_NORM, SMALL_DOT = 64, 4096  # entries up to which a norm is Python's hypot, then one MuJoCo dot (see norm)

__all__ = ["cholesky_factor", "cholesky_substitute", "mat2quat", "mul", "normalize4", "quat2mat",
           "quat2vel", "quat_integrate", "rotation_error", "worlds_last"]


@functools.cache
def everywhere(n: int) -> np.ndarray:
    """(n,) True, read-only: what a check returns when one comparison settled every world."""
    flags = np.ones(n, dtype=bool)
    flags.setflags(write=False)
    return flags


@functools.cache
def nowhere(n: int) -> np.ndarray:
    """(n,) False, read-only."""
    flags = np.zeros(n, dtype=bool)
    flags.setflags(write=False)
    return flags


def both(*flags: np.ndarray) -> np.ndarray:
    """The worlds where every check holds: :func:`everywhere` itself when each check is
    (one comparison settled every world, and the caller may test ``is``)."""
    result = None
    for flag in flags:
        if flag is not everywhere(len(flag)):
            result = flag if result is None else result & flag
    return everywhere(len(flags[0])) if result is None else result


def worlds_last(a: np.ndarray) -> np.ndarray:
    """(N, ...) -> (..., N), contiguous (``transpose`` costs less than ``np.moveaxis``)."""
    return a.transpose(*range(1, a.ndim), 0).copy()


def worlds_first(a: np.ndarray) -> np.ndarray:
    """(..., N) -> (N, ...), a view."""
    return a.transpose(a.ndim - 1, *range(a.ndim - 1))


# -- Cholesky solves ------------------------------------------------------------------
def cholesky_factor(M: np.ndarray, ratio: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
    """Every world's Cholesky factor L (L Lᵀ = M_k; only M's lower triangle is read, M is
    not written), kept for :func:`cholesky_substitute` (a refinement solves again with it).

    Args:
        M: (N, k, k).
        ratio: the most any √M_ii / L_ii may be for a world to count as factored: 1 where
            M's rows are orthogonal, growing as a row depends on those before it (whatever
            the rows' scales; a refused M scaled to a unit diagonal has a condition number
            past ratio², an accepted one may too: a lower bound, not an estimate).

    Returns:
        ``(factor, ok (N,))``: ``ok`` where M is numerically positive definite (every pivot
        > 0) within ``ratio`` (:func:`everywhere` itself when that holds in every world).
        The factor is MuJoCo's (k, k) for one world, (k, k, N) with the worlds last for N.
    """
    if len(M) == 1 and M.shape[1]:
        return _cholesky_factor_one(M[0], ratio)
    # (k, k, N) (a view where M is stored worlds last: it is only read)
    Mt = np.ascontiguousarray(M.transpose(1, 2, 0))
    # A world not positive definite runs to NaN, one that overflows to inf or NaN, silently,
    # as LAPACK gives one robot (its caller refuses it): no warning its one-world run lacks.
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        Lt = _cholesky_factor_last(Mt)
        # Every pivot within ratio (NaN fails; a zero pivot fails against the least positive M_jj).
        pivots = np.einsum("iin->in", Lt)  # (k, N), NaN (or 0) from the first non-positive one on
        met = ratio * ratio * pivots * pivots >= np.maximum(np.einsum("iin->in", Mt), _TINY)
    return Lt, (everywhere(Mt.shape[2]) if met.all() else met.all(axis=0))


def cholesky_substitute(factor: np.ndarray, B: np.ndarray, ok: np.ndarray, in_place: bool = False) -> np.ndarray:
    """X with L Lᵀ X_k = B_k in every world, from :func:`cholesky_factor`'s ``factor`` and
    ``ok``, B (N, k) or (N, k, m): the worlds not ``ok`` get zero (finite, so that no
    caller's arithmetic warns on a refused world). ``in_place``: X is written into B."""
    if factor.ndim == 2:
        X = _cholesky_substitute_one(factor, B[0], in_place)
        if ok is not everywhere(1):
            X[...] = 0.0
        return B if in_place else X[None]
    if not B.shape[1]:  # no rows (a level whose rows are all masked): nothing to solve
        return B if in_place else B.copy()
    Xt = worlds_last(B[..., None] if B.ndim == 2 else B)  # (k, m, N)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):  # as for the factor
        _substitute(factor, Xt)
    X = worlds_first(Xt[:, 0] if B.ndim == 2 else Xt)
    if ok is not everywhere(len(X)):
        X[~ok] = 0.0
    if in_place:
        B[...] = X
        return B
    return X


def lu_solve(M: np.ndarray, B: np.ndarray, out: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Solve M_k X_k = B_k in every world by LU with partial pivoting (LAPACK's ``gesv``),
    M (N, k, k) square, B and ``out`` (N, k): ``(out, ok (N,))``, ``ok`` where M is not
    singular (:func:`everywhere` when no world is); out means nothing elsewhere."""
    if len(M) == 1:
        _, _, x, info = dgesv(M[0], B[0])
        out[0] = x
        return out, everywhere(1) if info == 0 else nowhere(1)
    try:
        np.copyto(out, np.linalg.solve(M, B[..., None])[..., 0])
        return out, everywhere(len(M))
    except np.linalg.LinAlgError:  # some world is singular: solve them one by one
        ok = np.ones(len(M), dtype=bool)
        for w in range(len(M)):
            try:
                out[w] = np.linalg.solve(M[w], B[w])
            except np.linalg.LinAlgError:
                ok[w] = False
        return out, ok


def _cholesky_factor_one(M: np.ndarray, ratio: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`cholesky_factor` of one world: MuJoCo's, on a copy of M (MuJoCo factors in
    place; a copy of its own keeps threads apart)."""
    factor = M.copy()
    ok = mujoco.mju_cholFactor(factor, _TINY) == len(M)  # a pivot below _TINY lowers the rank
    square = ratio * ratio  # M_jj <= ratio² L_jj² on every pivot, in floats (NaN fails)
    for diagonal, pivot in zip(M.diagonal().tolist(), factor.diagonal().tolist()):
        if not diagonal <= square * pivot * pivot:
            ok = False
            break
    return factor, everywhere(1) if ok else nowhere(1)


def _cholesky_substitute_one(factor: np.ndarray, b: np.ndarray, in_place: bool) -> np.ndarray:
    """One world's solve with its MuJoCo factor: b (k,) by MuJoCo, b (k, m) by LAPACK's
    ``potrs`` (which reads the same lower triangle)."""
    if b.ndim == 2:
        X, _ = dpotrs(factor, b, lower=1)
        if in_place:
            b[...] = X
            return b
        return X
    X = b if in_place else np.empty(len(b))
    mujoco.mju_cholSolve(X, factor, b)
    return X


def _cholesky_factor_last(Mt: np.ndarray) -> np.ndarray:
    """L (lower, L Lᵀ = M) of every world with the worlds along the last axis, Mt (k, k, N),
    one vector operation over the worlds per column (NumPy's stacked LAPACK call costs more
    on a step's small systems, and stops at the first world that is not positive
    definite). Where a Schur complement is not positive the pivot is NaN (or 0), and so is
    the rest of that world's L (the caller refuses it, under ``errstate``, and zeroes its
    answer)."""
    n = Mt.shape[0]
    L = np.zeros_like(Mt)
    for j in range(n):
        d = Mt[j, j] - np.einsum("jn,jn->n", L[j, :j], L[j, :j]) if j else Mt[j, j]
        root = np.sqrt(d, out=L[j, j])
        if j + 1 < n:
            column = Mt[j + 1:, j] - np.einsum("ijn,jn->in", L[j + 1:, :j], L[j, :j]) if j else Mt[j + 1:, j]
            np.divide(column, root, out=L[j + 1:, j])
    return L


def _substitute(Lt: np.ndarray, Xt: np.ndarray) -> None:
    """Solve L Lᵀ X = B in every world in place (``Xt`` holds B, then X), by forward then
    back substitution with the worlds along the last axis (one vector operation over the
    worlds per row): Lt (k, k, N), Xt (k, m, N)."""
    n = Lt.shape[0]
    for j in range(n):  # L Y = B
        if j:
            Xt[j] -= np.einsum("in,imn->mn", Lt[j, :j], Xt[:j])
        Xt[j] /= Lt[j, j]
    for j in range(n - 1, -1, -1):  # Lᵀ X = Y, from the last row up
        if j < n - 1:
            Xt[j] -= np.einsum("in,imn->mn", Lt[j + 1:, j], Xt[j + 1:])
        Xt[j] /= Lt[j, j]


# -- Rotations (MuJoCo's quaternion routines across worlds) ----------------------------
# mju_mat2Quat's four branches, by the largest component: (that component, the signs of
# m0, m4, m8 under its square root), then for each other component (index, a, b, sign):
# 0.25 (m[a] + sign m[b]) / the largest.
_MAT2QUAT = (
    ((0, 1.0, 1.0, 1.0), ((1, 7, 5, -1), (2, 2, 6, -1), (3, 3, 1, -1))),
    ((1, 1.0, -1.0, -1.0), ((0, 7, 5, -1), (2, 1, 3, 1), (3, 2, 6, 1))),
    ((2, -1.0, 1.0, -1.0), ((0, 2, 6, -1), (1, 1, 3, 1), (3, 5, 7, 1))),
    ((3, -1.0, -1.0, 1.0), ((0, 3, 1, -1), (1, 2, 6, 1), (2, 5, 7, 1))),
)


def mat2quat(R: np.ndarray) -> np.ndarray:
    """``mju_mat2Quat``: unit quaternions (N, 4), w-x-y-z, of rotation matrices (N, 3, 3).
    The usual step, every trace positive (rotations within a half turn of the identity),
    takes the first branch for all worlds at once, without selecting rows."""
    m = R.reshape(-1, 9)
    q = np.empty((len(m), 4))
    trace = m[:, 0] + m[:, 4] + m[:, 8]
    first = trace > 0
    branch = None if first.all() else np.select([first, (m[:, 0] > m[:, 4]) & (m[:, 0] > m[:, 8]),
                                                 m[:, 4] > m[:, 8]], [0, 1, 2], default=3)
    with np.errstate(divide="ignore", invalid="ignore"):
        for k, ((index, s0, s4, s8), others) in enumerate(_MAT2QUAT):
            if branch is None:
                rows, mk, out = None, m, q
            else:
                rows = branch == k
                if not rows.any():
                    continue
                mk = m[rows]
                out = np.empty((len(mk), 4))
            main = 0.5 * np.sqrt(1.0 + s0 * mk[:, 0] + s4 * mk[:, 4] + s8 * mk[:, 8])
            out[:, index] = main
            for target, a, b, sign in others:
                out[:, target] = 0.25 * (mk[:, a] + sign * mk[:, b]) / main
            if rows is None:
                break
            q[rows] = out
    return normalize4(q)


def normalize4(q: np.ndarray) -> np.ndarray:
    """``mju_normalize4`` (a quaternion of norm < mjMINVAL becomes the identity)."""
    norm = np.sqrt(np.einsum("ni,ni->n", q, q))
    small = norm < MINVAL
    out = q / np.where(small, 1.0, norm)[:, None]
    out[small] = (1.0, 0.0, 0.0, 0.0)
    return out


def mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``mju_mulQuat`` of (N, 4) quaternions (either may be (1, 4))."""
    shape = np.broadcast_shapes(a.shape, b.shape)
    (a0, a1, a2, a3), (b0, b1, b2, b3) = np.broadcast_to(a, shape).T, np.broadcast_to(b, shape).T
    out = np.empty((4, shape[0]))
    out[0] = a0 * b0 - a1 * b1 - a2 * b2 - a3 * b3
    out[1] = a0 * b1 + a1 * b0 + a2 * b3 - a3 * b2
    out[2] = a0 * b2 - a1 * b3 + a2 * b0 + a3 * b1
    out[3] = a0 * b3 + a1 * b2 - a2 * b1 + a3 * b0
    return out.T


def quat2vel(q: np.ndarray) -> np.ndarray:
    """``mju_quat2Vel`` (dt = 1): the rotation vectors of unit quaternions (N, 4)."""
    w, axis = q[:, 0], np.array(q[:, 1:].T)
    sin_half = np.sqrt(axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2])
    small = sin_half < MINVAL
    axis /= np.where(small, 1.0, sin_half)
    if small.any():
        axis[:, small] = ((1.0,), (0.0,), (0.0,))
    speed = 2.0 * np.arctan2(sin_half, w)
    speed = np.where(speed > np.pi, speed - 2.0 * np.pi, speed)
    axis *= speed
    return axis.T


def quat_integrate(quat: np.ndarray, velocity: np.ndarray, scale: float) -> np.ndarray:
    r"""``mju_quatIntegrate`` across worlds: unit quaternions (N, 4) turned by the rotation
    vectors ``velocity`` (N, 3) times ``scale``, normalised (``mju_normalize4``):

    .. math::
        q \leftarrow q \otimes \big(\cos\tfrac{\theta}{2},\ \hat\omega \sin\tfrac{\theta}{2}\big),
        \qquad \theta = s\,\lVert\omega\rVert,

    the identity where :math:`\lVert\omega\rVert < ` mjMINVAL (MuJoCo's branch)."""
    norm = np.sqrt(np.einsum("ni,ni->n", velocity, velocity))
    small = norm < MINVAL
    axis = velocity * np.where(small, 0.0, 1.0 / np.where(small, 1.0, norm))[:, None]
    angle = scale * np.where(small, 0.0, norm)
    half = 0.5 * angle
    rotation = np.empty_like(quat)
    rotation[:, 0] = np.cos(half)
    rotation[:, 1:] = axis * np.sin(half)[:, None]
    rotation[angle == 0.0] = (1.0, 0.0, 0.0, 0.0)
    return normalize4(mul(quat, rotation))


def quat2mat(q: np.ndarray) -> np.ndarray:
    """``mju_quat2Mat`` (N, 4) -> (N, 3, 3)."""
    w, x, y, z = q.T
    ww, xx, yy, zz = w * w, x * x, y * y, z * z
    R = np.empty((len(q), 3, 3))
    R[:, 0, 0] = ww + xx - yy - zz
    R[:, 1, 1] = ww - xx + yy - zz
    R[:, 2, 2] = ww - xx - yy + zz
    R[:, 0, 1] = 2 * (x * y - w * z)
    R[:, 0, 2] = 2 * (x * z + w * y)
    R[:, 1, 0] = 2 * (x * y + w * z)
    R[:, 1, 2] = 2 * (y * z - w * x)
    R[:, 2, 0] = 2 * (x * z - w * y)
    R[:, 2, 1] = 2 * (y * z + w * x)
    return R


_CONJUGATE = np.array([1.0, -1.0, -1.0, -1.0])


class RotationError:
    """e with R exp([e]) = R_d (the current frame's axes) or exp([e]) R = R_d (world axes)
    in every world: the rotation vector (``mju_quat2Vel``) of the relative rotation
    RᵀR_d, or R_d Rᵀ (``mju_mat2Quat``). One instance per task (its scratch arrays); at
    N = 1 MuJoCo's routines do it, on views of the arrays made once (kept while the same
    arrays come)."""

    def __init__(self, n: int):
        self.n = n
        self._relative, self._quaternion = np.empty((3, 3)), np.empty(4)
        self._relative_entries = self._relative.reshape(9)  # the same memory, as mju_mat2Quat takes it
        self._arrays, self._views = (None, None, None), None

    def __call__(self, desired: np.ndarray, current: np.ndarray, out: np.ndarray, local: bool = False) -> np.ndarray:
        """Write the errors of rotations (N, 3, 3) into ``out`` (N, 3)."""
        if self.n == 1:
            arrays = self._arrays
            if arrays[0] is not desired or arrays[1] is not current or arrays[2] is not out:
                self._arrays = (desired, current, out)
                self._views = (np.ascontiguousarray(desired[0]), np.ascontiguousarray(current[0]), out[0],
                               desired.flags.c_contiguous and current.flags.c_contiguous)
            desired0, current0, out0, stable = self._views
            if not stable:  # copies, refreshed every call
                desired0[...], current0[...] = desired[0], current[0]
            if local:
                mujoco.mju_mulMatTMat(self._relative, current0, desired0)
            else:
                mujoco.mju_mulMatMatT(self._relative, desired0, current0)
            mujoco.mju_mat2Quat(self._quaternion, self._relative_entries)
            mujoco.mju_quat2Vel(out0, self._quaternion, 1.0)
            return out
        current_t = current.transpose(0, 2, 1)
        relative = product3(current_t, desired) if local else product3(desired, current_t)
        out[...] = quat2vel(mat2quat(relative))
        return out


def product3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a b of (N, 3, 3) matrices, each entry summed in MuJoCo's order (``mju_mulMatMatT``'s
    bits: a world's error is the same at N = 1 and among N)."""
    return (a[:, :, 0, None] * b[:, None, 0] + a[:, :, 1, None] * b[:, None, 1]) + a[:, :, 2, None] * b[:, None, 2]


def rotation_error(desired: np.ndarray, current: np.ndarray, local: bool = False) -> np.ndarray:
    """:class:`RotationError` of (N, 3, 3) rotations, a new (N, 3) array."""
    desired, current = np.ascontiguousarray(desired), np.ascontiguousarray(current)
    return RotationError(len(current))(desired, current, np.empty((len(current), 3)), local)


class ConfigurationDifference:
    """``mj_differentiatePos`` (dt = 1) in every world: the velocity (N, nv) taking
    q_from to q_to in unit time (scalar joints subtract, ball and free joints take the
    quaternion difference). At N = 1, MuJoCo's own call."""

    def __init__(self, model: mujoco.MjModel, n: int):
        self.model, self.n = model, n
        self._arrays, self._views = (None, None, None), None  # world 0's views, kept while the same arrays come
        J = mujoco.mjtJoint
        self.scalar_q, self.scalar_v, self.linear, self.quats = [], [], [], []
        for j in range(model.njnt):
            kind, qadr, vadr = int(model.jnt_type[j]), int(model.jnt_qposadr[j]), int(model.jnt_dofadr[j])
            if kind in (int(J.mjJNT_HINGE), int(J.mjJNT_SLIDE)):
                self.scalar_q.append(qadr)
                self.scalar_v.append(vadr)
            elif kind == int(J.mjJNT_FREE):
                self.linear.append((qadr, vadr))
                self.quats.append((qadr + 3, vadr + 3))
            else:
                self.quats.append((qadr, vadr))

    def __call__(self, q_from: np.ndarray, q_to: np.ndarray, out: np.ndarray) -> np.ndarray:
        if self.n == 1:
            if self._arrays[0] is not q_from or self._arrays[1] is not q_to or self._arrays[2] is not out:
                self._arrays, self._views = (q_from, q_to, out), (q_from[0], q_to[0], out[0])
            mujoco.mj_differentiatePos(self.model, self._views[2], 1.0, self._views[0], self._views[1])
            return out
        out[:, self.scalar_v] = q_to[:, self.scalar_q] - q_from[:, self.scalar_q]
        for qadr, vadr in self.linear:
            out[:, vadr:vadr + 3] = q_to[:, qadr:qadr + 3] - q_from[:, qadr:qadr + 3]
        for qadr, vadr in self.quats:
            difference = mul(q_from[:, qadr:qadr + 4] * _CONJUGATE, q_to[:, qadr:qadr + 4])
            out[:, vadr:vadr + 3] = quat2vel(difference)
        return out


def norm(a: np.ndarray) -> float:
    """The Euclidean norm of a contiguous array's entries (NaN if one is): Python's ``hypot``
    of a small one's list, MuJoCo's dot on a mid-sized one (a NumPy or MuJoCo call costs
    more than its arithmetic), NumPy's own loop on a large one (BLAS's dot wakes its
    threads past ~10,000 entries, which on a busy machine costs milliseconds)."""
    if a.size <= SMALL_NORM:
        return math.hypot(*a.ravel().tolist())
    flat = a.reshape(-1)
    return math.sqrt(mujoco.mju_dot(flat, flat) if a.size <= SMALL_DOT else np.einsum("i,i->", flat, flat))


def all_finite(a: np.ndarray) -> bool:
    """Whether every entry is finite: one MuJoCo sum on a small contiguous array (NaN or
    inf makes it so), NumPy's pass otherwise."""
    if a.size <= 64:
        try:
            return math.isfinite(mujoco.mju_sum(a.reshape(-1)))
        except TypeError:  # not contiguous: MuJoCo takes no strided array
            pass
    return bool(np.isfinite(a).all())


# -- Products of every world's small matrices --------------------------------------------
# NumPy's stacked matmul calls its inner loop once per world: on a control step's small
# matrices that is mostly overhead. One world: the 2-D product of its views; N worlds: one
# einsum pass (products with a vector), or the worlds along the last axis for small
# matrix products (each product one vector operation over every world).
SMALL_PRODUCT = 16  # rows x columns of a product computed with the worlds last


def matvec(A: np.ndarray, x: np.ndarray, out: np.ndarray) -> np.ndarray:
    """``out`` (N, m) = A x in every world, A (N, m, k), x (N, k)."""
    if len(A) == 1:
        A[0].dot(x[0], out[0])
        return out
    return np.einsum("nij,nj->ni", A, x, out=out)


def vecmat(y: np.ndarray, A: np.ndarray, out: np.ndarray) -> np.ndarray:
    """``out`` (N, k) = Aᵀ y in every world, y (N, m), A (N, m, k)."""
    if len(A) == 1:
        y[0].dot(A[0], out[0])
        return out
    return np.einsum("ni,nij->nj", y, A, out=out)


def outer_product(A: np.ndarray, B: np.ndarray, out: np.ndarray) -> np.ndarray:
    """``out`` (N, m, p) = A Bᵀ in every world, A (N, m, k), B (N, p, k)."""
    if len(A) == 1:
        mujoco.mju_mulMatMatT(out[0], A[0], B[0])
    elif A.shape[1] * B.shape[1] > SMALL_PRODUCT:  # a new array, copied (matmul writes a strided out slowly)
        out[...] = np.matmul(A, B.transpose(0, 2, 1))
    else:  # (m, k, N) times (p, k, N), worlds last
        (worlds_last(A)[:, None] * worlds_last(B)[None]).sum(axis=2, out=out.transpose(1, 2, 0))
    return out


# -- Cross products as matrices (the tasks' Jacobians: relative frame, look-at, axis-align) --
def skew(vectors: np.ndarray, out: np.ndarray) -> np.ndarray:
    r"""The cross-product matrices :math:`[v]_\times` (:math:`[v]_\times c = v \times c`) of
    every world's vector (N, 3), written into ``out`` (N, 3, 3); a product
    ``np.matmul(out, columns)`` then crosses v with every column of a Jacobian.

    Only the six off-diagonal entries are written: ``out`` is made once with
    ``np.zeros`` (its diagonal stays zero), as the tasks preallocate it.
    """
    x, y, z = vectors[:, 0], vectors[:, 1], vectors[:, 2]
    np.negative(z, out[:, 0, 1])
    out[:, 0, 2] = y
    out[:, 1, 0] = z
    np.negative(x, out[:, 1, 2])
    np.negative(y, out[:, 2, 0])
    out[:, 2, 1] = x
    return out
