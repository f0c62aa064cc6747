r"""The engine's numerical primitives on a Warp device: one ``@wp.func`` per primitive of
:mod:`qpik.numerics` and of the closed form (:mod:`qpik.problem.closed_form`),
named after it, in float64, branch for branch and operation for operation as the NumPy
primitive computes one world (its N > 1 path: the world axis is the thread index here).

Each says which primitive it mirrors; docs/batch.md lists them and how
tests/batch/test_warp_mirror.py holds each to its primitive on Warp's CPU device (to
rounding: where NumPy sums through BLAS or ``einsum`` the device sums in index order).
No step calls them yet: the tasks' rows, the limits' boxes, the cost, the held-bounds
iteration and ``numerics.lu_solve`` have no device function, so the warp back-end runs the
step on the host over the device's kinematics and says so (:class:`~qpik.errors.HostStepWarning`).
"""

from __future__ import annotations

import math

import mujoco

from ...numerics import MINVAL as _MINVAL
from ...problem import closed_form as _closed_form
from ...extras import require

wp = require("warp", "the warp batch back-end", extra="gpu")

__all__ = ["DampedLeastSquaresArrays", "all_finite", "cholesky_factor", "cholesky_substitute",
           "configuration_difference", "damped_least_squares_arrays", "damped_least_squares_gradient",
           "damped_least_squares_solve", "inside",
           "mat2quat", "matvec", "normalize4", "outer_product", "quat2mat", "quat2vel", "quat_integrate", "quat_mul",
           "rotation_error", "rows_met", "skew", "vecmat"]

# Forward code only: nothing here is differentiated, and the adjoints would double the compile.
wp.set_module_options({"enable_backward": False})

F64 = wp.float64
MINVAL = wp.constant(F64(_MINVAL))  # mjMINVAL, as numerics.MINVAL
PI = wp.constant(F64(math.pi))
# The closed form's thresholds: the engine's own values.
EQUALITY_TOLERANCE = wp.constant(F64(_closed_form.EQUALITY_TOLERANCE))
REFINE_TOLERANCE = wp.constant(F64(_closed_form.REFINE_TOLERANCE))
SINGULAR_RATIO = wp.constant(F64(_closed_form.SINGULAR_RATIO))
REFINEMENTS = wp.constant(_closed_form.REFINEMENTS)
EPSILON = wp.constant(F64(_closed_form.EPSILON))
EXACT_EQUALITY_TOLERANCE = wp.constant(F64(_closed_form.EXACT_EQUALITY_TOLERANCE))
JOINT_FREE = wp.constant(int(mujoco.mjtJoint.mjJNT_FREE))
JOINT_BALL = wp.constant(int(mujoco.mjtJoint.mjJNT_BALL))


# -- quaternions (w, x, y, z) ------------------------------------------------------------
@wp.func
def normalize4(q: wp.vec4d) -> wp.vec4d:
    """``numerics.normalize4`` (``mju_normalize4``): q / |q|, the identity where
    |q| < mjMINVAL."""
    norm = wp.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    if norm < MINVAL:
        return wp.vec4d(F64(1.0), F64(0.0), F64(0.0), F64(0.0))
    return wp.vec4d(q[0] / norm, q[1] / norm, q[2] / norm, q[3] / norm)


@wp.func
def _quarter(a: F64, b: F64, main: F64) -> F64:
    """0.25 (a + b) / main: every non-largest component of ``mat2quat``."""
    return F64(0.25) * (a + b) / main


@wp.func
def mat2quat(R: wp.mat33d) -> wp.vec4d:
    """``numerics.mat2quat`` (``mju_mat2Quat``): its four branches, chosen by the trace and
    then the largest diagonal entry, then :func:`normalize4`."""
    m0 = R[0, 0]
    m1 = R[0, 1]
    m2 = R[0, 2]
    m3 = R[1, 0]
    m4 = R[1, 1]
    m5 = R[1, 2]
    m6 = R[2, 0]
    m7 = R[2, 1]
    m8 = R[2, 2]
    q = wp.vec4d()
    if m0 + m4 + m8 > F64(0.0):
        main = F64(0.5) * wp.sqrt(F64(1.0) + m0 + m4 + m8)
        q = wp.vec4d(main, _quarter(m7, -m5, main), _quarter(m2, -m6, main), _quarter(m3, -m1, main))
    elif m0 > m4 and m0 > m8:
        main = F64(0.5) * wp.sqrt(F64(1.0) + m0 - m4 - m8)
        q = wp.vec4d(_quarter(m7, -m5, main), main, _quarter(m1, m3, main), _quarter(m2, m6, main))
    elif m4 > m8:
        main = F64(0.5) * wp.sqrt(F64(1.0) - m0 + m4 - m8)
        q = wp.vec4d(_quarter(m2, -m6, main), _quarter(m1, m3, main), main, _quarter(m5, m7, main))
    else:
        main = F64(0.5) * wp.sqrt(F64(1.0) - m0 - m4 + m8)
        q = wp.vec4d(_quarter(m3, -m1, main), _quarter(m2, m6, main), _quarter(m5, m7, main), main)
    return normalize4(q)


@wp.func
def quat_mul(a: wp.vec4d, b: wp.vec4d) -> wp.vec4d:
    """``numerics.mul`` (``mju_mulQuat``): the product a ⊗ b."""
    return wp.vec4d(a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
                    a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
                    a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
                    a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0])


@wp.func
def _conjugate(q: wp.vec4d) -> wp.vec4d:
    return wp.vec4d(q[0], -q[1], -q[2], -q[3])


@wp.func
def quat2vel(q: wp.vec4d) -> wp.vec3d:
    """``numerics.quat2vel`` (``mju_quat2Vel``, dt = 1): the rotation vector
    2 atan2(|v|, w) v/|v| of a unit quaternion (w, v), the angle wrapped into (−π, π],
    the x axis where |v| < mjMINVAL."""
    sin_half = wp.sqrt(q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    axis = wp.vec3d(F64(1.0), F64(0.0), F64(0.0))
    if not (sin_half < MINVAL):
        axis = wp.vec3d(q[1] / sin_half, q[2] / sin_half, q[3] / sin_half)
    speed = F64(2.0) * wp.atan2(sin_half, q[0])
    if speed > PI:
        speed = speed - F64(2.0) * PI
    return wp.vec3d(axis[0] * speed, axis[1] * speed, axis[2] * speed)


@wp.func
def quat_integrate(quat: wp.vec4d, velocity: wp.vec3d, scale: F64) -> wp.vec4d:
    r"""``numerics.quat_integrate`` (``mju_quatIntegrate``): quat ⊗ (cos θ/2, ω̂ sin θ/2),
    θ = scale |ω|, normalised; no turn where |ω| < mjMINVAL."""
    norm = wp.sqrt(velocity[0] * velocity[0] + velocity[1] * velocity[1] + velocity[2] * velocity[2])
    inverse = F64(0.0)
    angle = F64(0.0)
    if not (norm < MINVAL):
        inverse = F64(1.0) / norm
        angle = scale * norm
    rotation = wp.vec4d(F64(1.0), F64(0.0), F64(0.0), F64(0.0))
    if angle != F64(0.0):
        half = F64(0.5) * angle
        s = wp.sin(half)
        rotation = wp.vec4d(wp.cos(half), velocity[0] * inverse * s, velocity[1] * inverse * s,
                            velocity[2] * inverse * s)
    return normalize4(quat_mul(quat, rotation))


@wp.func
def quat2mat(q: wp.vec4d) -> wp.mat33d:
    """``numerics.quat2mat`` (``mju_quat2Mat``)."""
    w = q[0]
    x = q[1]
    y = q[2]
    z = q[3]
    ww = w * w
    xx = x * x
    yy = y * y
    zz = z * z
    two = F64(2.0)
    return wp.mat33d(ww + xx - yy - zz, two * (x * y - w * z), two * (x * z + w * y),
                     two * (x * y + w * z), ww - xx + yy - zz, two * (y * z - w * x),
                     two * (x * z - w * y), two * (y * z + w * x), ww - xx - yy + zz)


@wp.func
def rotation_error(desired: wp.mat33d, current: wp.mat33d, local: int) -> wp.vec3d:
    """``numerics.RotationError``: e with R exp([e]) = R_d (``local``: the current frame's
    axes) or exp([e]) R = R_d (world axes): ``quat2vel(mat2quat(RᵀR_d))``, or of R_d Rᵀ."""
    if local != 0:
        return quat2vel(mat2quat(wp.transpose(current) @ desired))
    return quat2vel(mat2quat(desired @ wp.transpose(current)))


@wp.func
def _quat_at(q: wp.array2d(dtype=F64), w: int, adr: int) -> wp.vec4d:
    return wp.vec4d(q[w, adr], q[w, adr + 1], q[w, adr + 2], q[w, adr + 3])


@wp.func
def configuration_difference(q_from: wp.array2d(dtype=F64), q_to: wp.array2d(dtype=F64), w: int,
                             joint_type: wp.array(dtype=int), joint_qpos: wp.array(dtype=int),
                             joint_dof: wp.array(dtype=int), out: wp.array2d(dtype=F64)):
    """``numerics.ConfigurationDifference`` (``mj_differentiatePos``, dt = 1) of world w
    into out[w]: hinges and slides subtract; a free joint's position subtracts; ball and
    free joints' quaternions give ``quat2vel(conj(q_from) ⊗ q_to)``. The joints are the
    model's ``jnt_type``, ``jnt_qposadr``, ``jnt_dofadr``."""
    for joint in range(joint_type.shape[0]):
        kind = joint_type[joint]
        qadr = joint_qpos[joint]
        vadr = joint_dof[joint]
        if kind == JOINT_FREE:
            for i in range(3):
                out[w, vadr + i] = q_to[w, qadr + i] - q_from[w, qadr + i]
            qadr = qadr + 3
            vadr = vadr + 3
        if kind == JOINT_FREE or kind == JOINT_BALL:
            turn = quat2vel(quat_mul(_conjugate(_quat_at(q_from, w, qadr)), _quat_at(q_to, w, qadr)))
            for i in range(3):
                out[w, vadr + i] = turn[i]
        else:
            out[w, vadr] = q_to[w, qadr] - q_from[w, qadr]


# -- linear algebra ------------------------------------------------------------------------
@wp.func
def cholesky_factor(M: wp.array3d(dtype=F64), w: int, L: wp.array3d(dtype=F64), ratio: F64) -> int:
    """``numerics.cholesky_factor`` of world w: L (lower) with L Lᵀ = M[w] (its lower
    triangle read), a pivot of 1 where the Schur complement is not positive (the engine
    refuses such a world too); whether every pivot L_jj is positive with √M_jj <=
    ``ratio`` L_jj."""
    k = M.shape[1]
    ok = int(1)
    for j in range(k):
        s = F64(0.0)
        for i in range(j):
            s = s + L[w, j, i] * L[w, j, i]
        d = M[w, j, j] - s
        root = F64(1.0)
        if d > F64(0.0):
            root = wp.sqrt(d)
            if not (wp.sqrt(M[w, j, j]) <= ratio * root):
                ok = 0
        else:
            ok = 0
        L[w, j, j] = root
        for r in range(j + 1, k):
            t = F64(0.0)
            for i in range(j):
                t = t + L[w, r, i] * L[w, j, i]
            L[w, r, j] = (M[w, r, j] - t) / root
    return ok


@wp.func
def cholesky_substitute(L: wp.array3d(dtype=F64), B: wp.array3d(dtype=F64), w: int):
    """``numerics.cholesky_substitute`` of world w: B[w] (k, m) overwritten with X,
    L Lᵀ X = B[w], by L Y = B then Lᵀ X = Y (L from :func:`cholesky_factor`)."""
    k = L.shape[1]
    for c in range(B.shape[2]):
        for j in range(k):
            s = F64(0.0)
            for i in range(j):
                s = s + L[w, j, i] * B[w, i, c]
            B[w, j, c] = (B[w, j, c] - s) / L[w, j, j]
        for jj in range(k):
            j = k - 1 - jj
            s = F64(0.0)
            for i in range(j + 1, k):
                s = s + L[w, i, j] * B[w, i, c]
            B[w, j, c] = (B[w, j, c] - s) / L[w, j, j]


@wp.func
def all_finite(a: wp.array2d(dtype=F64), w: int) -> int:
    """``numerics.all_finite`` of world w's row a[w]: 1 where every entry is finite."""
    for i in range(a.shape[1]):
        if not wp.isfinite(a[w, i]):
            return 0
    return 1


@wp.func
def matvec(A: wp.array3d(dtype=F64), x: wp.array2d(dtype=F64), w: int, out: wp.array2d(dtype=F64)):
    """``numerics.matvec``: out[w] = A[w] x[w]."""
    for i in range(A.shape[1]):
        s = F64(0.0)
        for j in range(A.shape[2]):
            s = s + A[w, i, j] * x[w, j]
        out[w, i] = s


@wp.func
def vecmat(y: wp.array2d(dtype=F64), A: wp.array3d(dtype=F64), w: int, out: wp.array2d(dtype=F64)):
    """``numerics.vecmat``: out[w] = A[w]ᵀ y[w]."""
    for j in range(A.shape[2]):
        s = F64(0.0)
        for i in range(A.shape[1]):
            s = s + y[w, i] * A[w, i, j]
        out[w, j] = s


@wp.func
def outer_product(A: wp.array3d(dtype=F64), B: wp.array3d(dtype=F64), w: int, out: wp.array3d(dtype=F64)):
    """``numerics.outer_product``: out[w] = A[w] B[w]ᵀ."""
    for i in range(A.shape[1]):
        for p in range(B.shape[1]):
            s = F64(0.0)
            for k in range(A.shape[2]):
                s = s + A[w, i, k] * B[w, p, k]
            out[w, i, p] = s


@wp.func
def skew(v: wp.vec3d) -> wp.mat33d:
    """``numerics.skew``: the cross-product matrix [v]× ([v]× c = v × c)."""
    zero = F64(0.0)
    return wp.mat33d(zero, -v[2], v[1], v[2], zero, -v[0], -v[1], v[0], zero)


@wp.func
def rows_met(Ax: wp.array2d(dtype=F64), b: wp.array2d(dtype=F64), w: int, tolerance: F64) -> int:
    """``closed_form.rows_met``: 1 where every row's |Ax − b| <= tolerance (1 + |b|) (NaN
    fails)."""
    for i in range(b.shape[1]):
        if wp.abs(Ax[w, i] - b[w, i]) <= tolerance * (F64(1.0) + wp.abs(b[w, i])):
            continue
        return 0
    return 1


@wp.func
def inside(x: wp.array2d(dtype=F64), box: wp.array3d(dtype=F64), G: wp.array3d(dtype=F64),
           h: wp.array2d(dtype=F64), w: int) -> int:
    """``closed_form.inside``: 1 where x − lower >= 0, upper − x >= 0 (exact: a point on a
    bound is inside; NaN, and ±inf on an absent bound, are not) and G x <= h (G with no
    rows: none)."""
    for j in range(x.shape[1]):
        if not (x[w, j] - box[w, 0, j] >= F64(0.0)) or not (-(x[w, j] - box[w, 1, j]) >= F64(0.0)):
            return 0
    for r in range(G.shape[1]):
        s = F64(0.0)
        for j in range(x.shape[1]):
            s = s + G[w, r, j] * x[w, j]
        if not (s <= h[w, r]):
            return 0
    return 1


# -- the closed form -------------------------------------------------------------------------
@wp.struct
class DampedLeastSquaresArrays:
    """The buffers of :func:`damped_least_squares_solve` (a ``DampedLeastSquares``'s: N
    worlds of nv dofs, soft_rows rows R₁ then the hard rows R₂, m in all):
    :func:`damped_least_squares_arrays` allocates them."""

    soft_rows: int
    dinv: wp.array2d(dtype=F64)  # (N, nv): D⁻¹, zero on the held dofs
    scaled: wp.array3d(dtype=F64)  # (N, m, nv): R D⁻¹
    K: wp.array3d(dtype=F64)  # (N, m, m): R D⁻¹ Rᵀ + diag(I, 0)
    factor: wp.array3d(dtype=F64)  # (N, m, m): its Cholesky factor
    z: wp.array2d(dtype=F64)  # (N, m): the right-hand side, then z
    fit: wp.array2d(dtype=F64)  # (N, m): R v, R D⁻¹ c, the residual R x + [z₁; 0] − rhs, δz
    z_column: wp.array3d(dtype=F64)  # (N, m, 1): views of z and fit (Cholesky right-hand sides)
    fit_column: wp.array3d(dtype=F64)
    x: wp.array2d(dtype=F64)  # (N, nv)
    Rz: wp.array2d(dtype=F64)  # (N, nv): (R D⁻¹)ᵀ δz, Rᵀ z


def damped_least_squares_arrays(n: int, nv: int, soft_rows: int, rows: int, device) -> DampedLeastSquaresArrays:
    """:class:`DampedLeastSquaresArrays` for n worlds on ``device``."""
    m = soft_rows + rows
    arrays = DampedLeastSquaresArrays()
    arrays.soft_rows = soft_rows
    for name, shape in (("dinv", (n, nv)), ("scaled", (n, m, nv)), ("K", (n, m, m)), ("factor", (n, m, m)),
                        ("z", (n, m)), ("fit", (n, m)), ("x", (n, nv)), ("Rz", (n, nv))):
        setattr(arrays, name, wp.zeros(shape, dtype=F64, device=device))
    arrays.z_column, arrays.fit_column = arrays.z.reshape((n, m, 1)), arrays.fit.reshape((n, m, 1))
    return arrays


@wp.func
def _add(y: wp.array2d(dtype=F64), x: wp.array2d(dtype=F64), w: int, sign: F64):
    """y[w] += x[w] (``sign`` 1) or y[w] −= x[w] (−1: the same rounding)."""
    for i in range(y.shape[1]):
        y[w, i] = y[w, i] + sign * x[w, i]


@wp.func
def _fits(R: wp.array3d(dtype=F64), rhs: wp.array2d(dtype=F64), w: int, tolerance: F64,
          arrays: DampedLeastSquaresArrays) -> int:
    """``DampedLeastSquares._fits``: whether R x + [z₁; 0] meets rhs to ``tolerance`` row by
    row (:func:`rows_met`), the miss left in ``fit``."""
    matvec(R, arrays.x, w, arrays.fit)
    for i in range(arrays.soft_rows):
        arrays.fit[w, i] = arrays.fit[w, i] + arrays.z[w, i]
    met = rows_met(arrays.fit, rhs, w, tolerance)
    _add(arrays.fit, rhs, w, F64(-1.0))
    return met


@wp.func
def _within_rounding(R: wp.array3d(dtype=F64), rhs: wp.array2d(dtype=F64), w: int,
                     arrays: DampedLeastSquaresArrays) -> int:
    """``DampedLeastSquares._within_rounding``: 1 where each soft row's miss (in ``fit``)
    is within ``EQUALITY_TOLERANCE`` (1 + |r_i|) + nv·ε (|R_i||x| + |z_i|), every such term
    finite, and the hard rows' within ``EQUALITY_TOLERANCE`` (1 + |b_i|) each or together
    within ``EXACT_EQUALITY_TOLERANCE`` (1 + |b|) and each within it (1 + |b_i| + |R_i||x|)."""
    nv = R.shape[2]
    for i in range(arrays.soft_rows):
        terms = F64(0.0)
        for j in range(nv):
            terms = terms + wp.abs(R[w, i, j]) * wp.abs(arrays.x[w, j])
        terms = terms + wp.abs(arrays.z[w, i])
        if not wp.isfinite(terms):
            return 0
        allowed = EQUALITY_TOLERANCE * (F64(1.0) + wp.abs(rhs[w, i])) + F64(nv) * EPSILON * terms
        if not (wp.abs(arrays.fit[w, i]) <= allowed):
            return 0
    each = int(1)
    rowwise = int(1)
    miss = F64(0.0)
    size = F64(0.0)
    for i in range(arrays.soft_rows, rhs.shape[1]):
        if not (wp.abs(arrays.fit[w, i]) <= EQUALITY_TOLERANCE * (F64(1.0) + wp.abs(rhs[w, i]))):
            each = 0
        scale = F64(1.0) + wp.abs(rhs[w, i])
        for j in range(nv):
            scale = scale + wp.abs(R[w, i, j]) * wp.abs(arrays.x[w, j])
        if not (wp.abs(arrays.fit[w, i]) <= EXACT_EQUALITY_TOLERANCE * scale):
            rowwise = 0
        miss = miss + arrays.fit[w, i] * arrays.fit[w, i]
        size = size + rhs[w, i] * rhs[w, i]
    if each != 0:
        return 1
    if rowwise != 0 and miss <= EXACT_EQUALITY_TOLERANCE * EXACT_EQUALITY_TOLERANCE * (F64(1.0) + size):
        return 1
    return 0


@wp.func
def _refined(R: wp.array3d(dtype=F64), rhs: wp.array2d(dtype=F64), w: int, met: int,
             arrays: DampedLeastSquaresArrays) -> int:
    """``DampedLeastSquares._refined``: up to ``REFINEMENTS`` steps of iterative refinement
    while the residual misses ``REFINE_TOLERANCE``, K as factored by the solve; then 1
    where the residual is within ``EQUALITY_TOLERANCE`` or what a float x can meet
    (:func:`_within_rounding`)."""
    for _ in range(REFINEMENTS):
        if met == 0:  # K δz = residual; z −= δz, x −= (R D⁻¹)ᵀ δz
            cholesky_substitute(arrays.factor, arrays.fit_column, w)
            _add(arrays.z, arrays.fit, w, F64(-1.0))
            vecmat(arrays.fit, arrays.scaled, w, arrays.Rz)
            _add(arrays.x, arrays.Rz, w, F64(-1.0))
            met = _fits(R, rhs, w, REFINE_TOLERANCE, arrays)
    if met == 0:
        met = _fits(R, rhs, w, EQUALITY_TOLERANCE, arrays)
    if met == 0:
        met = _within_rounding(R, rhs, w, arrays)
    return met


@wp.func
def damped_least_squares_solve(dinv: wp.array2d(dtype=F64), R: wp.array3d(dtype=F64), rhs: wp.array2d(dtype=F64),
                               c: wp.array2d(dtype=F64), fixed: wp.array2d(dtype=int), values: wp.array2d(dtype=F64),
                               linear: int, held: int, w: int, arrays: DampedLeastSquaresArrays) -> int:
    """``closed_form.DampedLeastSquares.solve`` of world w: x = D⁻¹(Rᵀz − c) into
    ``arrays.x[w]`` and z, (R D⁻¹ Rᵀ + diag(I, 0)) z = rhs + R D⁻¹ c, into ``arrays.z[w]``,
    c read where ``linear`` (else zero), the dofs ``fixed`` held at ``values`` where
    ``held`` (D⁻¹ = 0 there, rhs − R values); then iterative refinement, ``REFINEMENTS``
    steps at most while the residual misses ``REFINE_TOLERANCE``. Returns 1 where the
    system is solved (within ``SINGULAR_RATIO``), x is finite and the residual is within
    ``EQUALITY_TOLERANCE``, or within what a float x can meet (:func:`_within_rounding`), else 0."""
    for j in range(dinv.shape[1]):
        arrays.dinv[w, j] = dinv[w, j]
        if held != 0 and fixed[w, j] != 0:
            arrays.dinv[w, j] = F64(0.0)
        for i in range(R.shape[1]):
            arrays.scaled[w, i, j] = R[w, i, j] * arrays.dinv[w, j]
    outer_product(arrays.scaled, R, w, arrays.K)
    for i in range(arrays.soft_rows):
        arrays.K[w, i, i] = arrays.K[w, i, i] + F64(1.0)
    for i in range(R.shape[1]):
        arrays.z[w, i] = rhs[w, i]
    if held != 0:
        matvec(R, values, w, arrays.fit)
        _add(arrays.z, arrays.fit, w, F64(-1.0))
    if linear != 0:
        matvec(arrays.scaled, c, w, arrays.fit)
        _add(arrays.z, arrays.fit, w, F64(1.0))
    solved = cholesky_factor(arrays.K, w, arrays.factor, SINGULAR_RATIO)
    cholesky_substitute(arrays.factor, arrays.z_column, w)
    vecmat(arrays.z, R, w, arrays.x)
    if linear != 0:
        _add(arrays.x, c, w, F64(-1.0))
    for j in range(dinv.shape[1]):
        arrays.x[w, j] = arrays.x[w, j] * arrays.dinv[w, j]
    if held != 0:
        _add(arrays.x, values, w, F64(1.0))
    met = _refined(R, rhs, w, _fits(R, rhs, w, REFINE_TOLERANCE, arrays), arrays)
    if solved != 0 and all_finite(arrays.x, w) != 0 and met != 0:
        return 1
    return 0


@wp.func
def damped_least_squares_gradient(damping: wp.array2d(dtype=F64), R: wp.array3d(dtype=F64),
                                  c: wp.array2d(dtype=F64), linear: int, w: int, arrays: DampedLeastSquaresArrays,
                                  g: wp.array2d(dtype=F64)):
    """``closed_form.DampedLeastSquares.gradient``: g[w] = D x + c − Rᵀz of the last solve
    (D = ``damping``, c zero unless ``linear``): on a held dof, its bound's multiplier."""
    for j in range(damping.shape[1]):
        g[w, j] = damping[w, j] * arrays.x[w, j]
    if linear != 0:
        _add(g, c, w, F64(1.0))
    vecmat(arrays.z, R, w, arrays.Rz)
    _add(g, arrays.Rz, w, F64(-1.0))
