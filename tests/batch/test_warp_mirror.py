"""The Warp back-end's mirror of the engine's primitives (qpik.batch.backends.warp_mirror):
each device function against the engine's NumPy primitive it mirrors, over N random worlds
(and worlds made to take every branch and every refusal), on Warp's CPU device.

Both sides compute in float64 with the same operations in the same order; they differ
only where NumPy hands a sum to einsum or BLAS (another summation order) and where libm's
atan2, sin and cos differ from NumPy's by an ulp. Each tolerance below is that rounding,
propagated: a few ε on entries of O(1), ε times the problem's condition number on a solve.
The refusal flags (not positive definite, singular, rows missed, outside the box) must
agree exactly: the cases are far from every threshold. One Warp module, compiled once.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest

wp = pytest.importorskip("warp", reason="the warp back-end needs the gpu extra (pip install -e \".[gpu]\")")

from qpik.batch.backends import warp_mirror as mirror  # noqa: E402
from qpik import numerics  # noqa: E402
from qpik.problem import closed_form  # noqa: E402
from qpik.problem.closed_form import (EQUALITY_TOLERANCE, REFINE_TOLERANCE, DampedLeastSquares, inside,  # noqa: E402
                                      rows_met)

from qpik.batch.backends.warp_mirror import F64, DampedLeastSquaresArrays  # noqa: E402

DEVICE = "cpu"
N = 64
EPS = np.finfo(float).eps
# Unit quaternions and rotations: entries of O(1), a few roundings apart (a norm summed in
# another order, an ulp of libm's sin/cos/atan2), each ulp carried through a few operations.
QUATERNION = 8 * EPS
# Rotation vectors: angles up to π, the same roundings scaled by them.
ROTATION_VECTOR = 8 * np.pi * EPS


def _device(a: np.ndarray, dtype=wp.float64):
    return wp.array(np.ascontiguousarray(a), dtype=dtype, device=DEVICE)


def _run(kernel, n: int, *inputs) -> None:
    wp.launch(kernel, dim=n, inputs=list(inputs), device=DEVICE)


def _output(n: int, dtype, shape=()):
    return wp.zeros((n, *shape) if shape else n, dtype=dtype, device=DEVICE)


def _unit_quaternions(rng, n: int) -> np.ndarray:
    """Random unit quaternions, the first four the identity and half turns about x, y, z
    (every branch of mat2quat, and its edges)."""
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[:4] = np.eye(4)
    return q


# -- one thread per world: each device function mapped over the worlds ----------------------------------------------------------------------
@wp.kernel
def normalize4_worlds(q: wp.array(dtype=wp.vec4d), out: wp.array(dtype=wp.vec4d)):
    w = wp.tid()
    out[w] = mirror.normalize4(q[w])


@wp.kernel
def mat2quat_worlds(R: wp.array(dtype=wp.mat33d), out: wp.array(dtype=wp.vec4d)):
    w = wp.tid()
    out[w] = mirror.mat2quat(R[w])


@wp.kernel
def quat_mul_worlds(a: wp.array(dtype=wp.vec4d), b: wp.array(dtype=wp.vec4d), out: wp.array(dtype=wp.vec4d)):
    w = wp.tid()
    out[w] = mirror.quat_mul(a[w], b[w])


@wp.kernel
def quat2vel_worlds(q: wp.array(dtype=wp.vec4d), out: wp.array(dtype=wp.vec3d)):
    w = wp.tid()
    out[w] = mirror.quat2vel(q[w])


@wp.kernel
def quat_integrate_worlds(quat: wp.array(dtype=wp.vec4d), velocity: wp.array(dtype=wp.vec3d), scale: F64,
                          out: wp.array(dtype=wp.vec4d)):
    w = wp.tid()
    out[w] = mirror.quat_integrate(quat[w], velocity[w], scale)


@wp.kernel
def quat2mat_worlds(q: wp.array(dtype=wp.vec4d), out: wp.array(dtype=wp.mat33d)):
    w = wp.tid()
    out[w] = mirror.quat2mat(q[w])


@wp.kernel
def rotation_error_worlds(desired: wp.array(dtype=wp.mat33d), current: wp.array(dtype=wp.mat33d), local: int,
                          out: wp.array(dtype=wp.vec3d)):
    w = wp.tid()
    out[w] = mirror.rotation_error(desired[w], current[w], local)


@wp.kernel
def configuration_difference_worlds(q_from: wp.array2d(dtype=F64), q_to: wp.array2d(dtype=F64),
                                    joint_type: wp.array(dtype=int), joint_qpos: wp.array(dtype=int),
                                    joint_dof: wp.array(dtype=int), out: wp.array2d(dtype=F64)):
    w = wp.tid()
    mirror.configuration_difference(q_from, q_to, w, joint_type, joint_qpos, joint_dof, out)


@wp.kernel
def cholesky_worlds(M: wp.array3d(dtype=F64), B: wp.array3d(dtype=F64), ratio: F64,
                          L: wp.array3d(dtype=F64), ok: wp.array(dtype=int)):
    w = wp.tid()
    ok[w] = mirror.cholesky_factor(M, w, L, ratio)
    mirror.cholesky_substitute(L, B, w)


@wp.kernel
def matvec_worlds(A: wp.array3d(dtype=F64), x: wp.array2d(dtype=F64), out: wp.array2d(dtype=F64)):
    w = wp.tid()
    mirror.matvec(A, x, w, out)


@wp.kernel
def vecmat_worlds(y: wp.array2d(dtype=F64), A: wp.array3d(dtype=F64), out: wp.array2d(dtype=F64)):
    w = wp.tid()
    mirror.vecmat(y, A, w, out)


@wp.kernel
def outer_product_worlds(A: wp.array3d(dtype=F64), B: wp.array3d(dtype=F64), out: wp.array3d(dtype=F64)):
    w = wp.tid()
    mirror.outer_product(A, B, w, out)


@wp.kernel
def skew_worlds(v: wp.array(dtype=wp.vec3d), out: wp.array(dtype=wp.mat33d)):
    w = wp.tid()
    out[w] = mirror.skew(v[w])


@wp.kernel
def all_finite_worlds(a: wp.array2d(dtype=F64), ok: wp.array(dtype=int)):
    w = wp.tid()
    ok[w] = mirror.all_finite(a, w)


@wp.kernel
def within_rounding_worlds(R: wp.array3d(dtype=F64), rhs: wp.array2d(dtype=F64), arrays: DampedLeastSquaresArrays,
                           met: wp.array(dtype=int)):
    w = wp.tid()
    met[w] = mirror._within_rounding(R, rhs, w, arrays)


@wp.kernel
def rows_met_worlds(Ax: wp.array2d(dtype=F64), b: wp.array2d(dtype=F64), tolerance: F64, met: wp.array(dtype=int)):
    w = wp.tid()
    met[w] = mirror.rows_met(Ax, b, w, tolerance)


@wp.kernel
def inside_worlds(x: wp.array2d(dtype=F64), box: wp.array3d(dtype=F64), G: wp.array3d(dtype=F64),
                  h: wp.array2d(dtype=F64), ok: wp.array(dtype=int)):
    w = wp.tid()
    ok[w] = mirror.inside(x, box, G, h, w)


@wp.kernel
def damped_least_squares_worlds(dinv: wp.array2d(dtype=F64), damping: wp.array2d(dtype=F64),
                                R: wp.array3d(dtype=F64), rhs: wp.array2d(dtype=F64), c: wp.array2d(dtype=F64),
                                fixed: wp.array2d(dtype=int), values: wp.array2d(dtype=F64), linear: int, held: int,
                                arrays: DampedLeastSquaresArrays, g: wp.array2d(dtype=F64), ok: wp.array(dtype=int)):
    """:func:`damped_least_squares_solve` then :func:`damped_least_squares_gradient` in every world."""
    w = wp.tid()
    ok[w] = mirror.damped_least_squares_solve(dinv, R, rhs, c, fixed, values, linear, held, w, arrays)
    mirror.damped_least_squares_gradient(damping, R, c, linear, w, arrays, g)


# -- quaternions and rotations ----------------------------------------------------------------
def test_quaternion_functions_equal_the_engines_in_every_branch():
    rng = np.random.default_rng(0)
    qa, qb = _unit_quaternions(rng, N), _unit_quaternions(rng, N)[::-1].copy()
    R = numerics.quat2mat(qa)
    trace = np.trace(R, axis1=1, axis2=2)
    assert (trace > 0).sum() > 4 and (trace <= 0).sum() > 4  # the first branch and the others

    out4, out3 = _output(N, wp.vec4d), _output(N, wp.vec3d)
    _run(mat2quat_worlds, N, _device(R, wp.mat33d), out4)
    np.testing.assert_allclose(out4.numpy(), numerics.mat2quat(R), rtol=0, atol=QUATERNION)
    _run(quat_mul_worlds, N, _device(qa, wp.vec4d), _device(qb, wp.vec4d), out4)
    np.testing.assert_allclose(out4.numpy(), numerics.mul(qa, qb), rtol=0, atol=QUATERNION)
    _run(quat2vel_worlds, N, _device(qa, wp.vec4d), out3)
    np.testing.assert_allclose(out3.numpy(), numerics.quat2vel(qa), rtol=0, atol=ROTATION_VECTOR)
    matrices = _output(N, wp.mat33d)
    _run(quat2mat_worlds, N, _device(qa, wp.vec4d), matrices)
    np.testing.assert_allclose(matrices.numpy(), R, rtol=0, atol=QUATERNION)

    raw = rng.normal(size=(N, 4)) * rng.uniform(0.5, 2.0, (N, 1))
    raw[0], raw[1] = 0.0, 1e-16  # below mjMINVAL: the identity
    _run(normalize4_worlds, N, _device(raw, wp.vec4d), out4)
    np.testing.assert_allclose(out4.numpy(), numerics.normalize4(raw), rtol=0, atol=QUATERNION)
    assert out4.numpy()[:2].tolist() == [[1.0, 0.0, 0.0, 0.0]] * 2


def test_quat_integrate_equals_the_engines_with_its_small_branch():
    rng = np.random.default_rng(1)
    quats = _unit_quaternions(rng, N)
    velocity = rng.normal(size=(N, 3))
    velocity[0], velocity[1] = 0.0, 1e-17  # no turn; below mjMINVAL: no turn either
    out = _output(N, wp.vec4d)
    for scale in (0.002, 0.7):
        _run(quat_integrate_worlds, N, _device(quats, wp.vec4d), _device(velocity, wp.vec3d), scale, out)
        np.testing.assert_allclose(out.numpy(), numerics.quat_integrate(quats, velocity, scale), rtol=0,
                                   atol=QUATERNION)


@pytest.mark.parametrize("local", [0, 1])
def test_rotation_error_equals_the_engines(local):
    rng = np.random.default_rng(2 + local)
    desired = numerics.quat2mat(_unit_quaternions(rng, N))
    current = numerics.quat2mat(_unit_quaternions(rng, N)[::-1].copy())
    out = _output(N, wp.vec3d)
    _run(rotation_error_worlds, N, _device(desired, wp.mat33d), _device(current, wp.mat33d), local, out)
    # rotated into world axes by R (entries <= 1): three more roundings of the same size
    np.testing.assert_allclose(out.numpy(), numerics.rotation_error(desired, current, bool(local)), rtol=0,
                               atol=2 * ROTATION_VECTOR)


_JOINTS = """<mujoco><worldbody>
  <body name="base"><freejoint name="root"/><geom size="0.1"/>
    <body name="b1" pos="0 0 0.2"><joint name="ball" type="ball"/><geom size="0.05"/>
      <body name="b2" pos="0 0 0.2"><joint name="hinge" axis="0 1 0"/><geom size="0.05"/>
        <body name="b3" pos="0 0 0.2"><joint name="slide" type="slide" axis="1 0 0"/><geom size="0.05"/>
          <body name="b4" pos="0 0 0.2"><joint name="wrist" type="ball"/><geom size="0.05"/></body>
        </body>
      </body>
    </body>
  </body>
</worldbody></mujoco>"""


def test_configuration_difference_equals_the_engines_on_every_joint_type():
    model = mujoco.MjModel.from_xml_string(_JOINTS)  # free, ball, hinge, slide, ball
    rng = np.random.default_rng(4)
    q_from, q_to = (rng.normal(size=(N, model.nq)) for _ in range(2))
    quaternion_slots = [3, 7, 13]  # the free joint's and the balls' quaternions
    for q in (q_from, q_to):
        for adr in quaternion_slots:
            q[:, adr:adr + 4] = _unit_quaternions(rng, N)
    expected = numerics.ConfigurationDifference(model, N)(q_from, q_to, np.empty((N, model.nv)))
    out = _output(N, wp.float64, (model.nv,))
    joints = [_device(a.astype(np.int32), wp.int32) for a in (model.jnt_type, model.jnt_qposadr, model.jnt_dofadr)]
    _run(configuration_difference_worlds, N, _device(q_from), _device(q_to), *joints, out)
    got = out.numpy()
    turns = np.r_[3:6, 6:9, 11:14]  # the quaternion joints' dofs (angles up to π)
    scalars = np.setdiff1d(np.arange(model.nv), turns)
    relative_w = [numerics.mul(q_from[:, a:a + 4] * [1, -1, -1, -1], q_to[:, a:a + 4])[:, 0] for a in quaternion_slots]
    assert (np.array(relative_w) < 0).sum() > 10  # turns past π: the wrap into (−π, π] is taken
    np.testing.assert_array_equal(got[:, scalars], expected[:, scalars])  # one subtraction each, both sides
    np.testing.assert_allclose(got[:, turns], expected[:, turns], rtol=0, atol=ROTATION_VECTOR)


# -- linear algebra ------------------------------------------------------------------------------
def _spd(rng, n: int, k: int) -> np.ndarray:
    J = rng.normal(size=(n, k + 2, k))
    return J.transpose(0, 2, 1) @ J + 1e-2 * np.eye(k)


def _cholesky(M: np.ndarray, B: np.ndarray, ratio: float) -> tuple[np.ndarray, np.ndarray]:
    n, k = M.shape[:2]
    X = _device(B)
    ok = _output(n, wp.int32)
    _run(cholesky_worlds, n, _device(M), X, ratio, _output(n, wp.float64, (k, k)), ok)
    return X.numpy(), ok.numpy().astype(bool)


@pytest.mark.parametrize("k, columns", [(1, 1), (2, 3), (7, 1), (7, 4)])
def test_cholesky_factor_and_substitute_equal_the_engines(k, columns):
    rng = np.random.default_rng(10 + k + columns)
    M, B = _spd(rng, N, k), rng.normal(size=(N, k, columns))
    X, ok = _cholesky(M, B, np.inf)
    factor, expected_ok = numerics.cholesky_factor(M)
    expected = numerics.cholesky_substitute(factor, B, expected_ok)
    assert ok.all() and expected_ok.all()
    # Two backward-stable solves: |X − X*| <= 10 k ε κ(M) |X*| per world (κ below 1e6 here).
    for x, e, m in zip(X, expected, M):
        assert np.linalg.norm(x - e) <= 10 * k * EPS * np.linalg.cond(m) * np.linalg.norm(e)


def test_cholesky_factor_refuses_what_the_engine_refuses():
    rng = np.random.default_rng(8)
    Q = np.linalg.qr(rng.normal(size=(5, 5)))[0][:3]  # three orthonormal rows of 5
    rows = np.diag([1e-6, 1.0, 1e5]) @ Q  # orthogonal, of wildly different scales: solved (scale-free)
    close = Q.copy()
    close[2] = Q[1] + 1e-8 * Q[2]  # nearly dependent rows: √M_22 / L_22 = 1e8 > 1e6, refused
    good = np.eye(3)
    M = np.stack([good, rows @ rows.T, np.diag([1.0, 1.0, np.inf]),  # inf: √inf <= ratio · inf, as the engine
                  np.diag([1.0, -1.0, 1.0]), np.zeros((3, 3)), close @ close.T, np.diag([1.0, np.nan, 1.0]),
                  2.0 * good])  # indefinite, singular, nearly dependent, NaN
    B = np.ones((len(M), 3, 1))
    X, ok = _cholesky(M, B, 1e6)
    with np.errstate(invalid="ignore"):  # the NaN world
        factor, expected = numerics.cholesky_factor(M, ratio=1e6)
        expected_X = numerics.cholesky_substitute(factor, B, expected)
    assert ok.tolist() == expected.tolist() == [True] * 3 + [False] * 4 + [True]
    np.testing.assert_allclose(X[[0, -1]], expected_X[[0, -1]], rtol=0, atol=2 * EPS)  # √2 · √2 rounded
    # The scaled rows' M is diagonal but for roundings: each X_i = 1 / M_ii to a few ε, relative.
    np.testing.assert_allclose(X[1], expected_X[1], rtol=8 * EPS, atol=0)
    X, ok = _cholesky(np.zeros((3, 0, 0)), np.zeros((3, 0, 1)), 1e6)  # no rows: solved
    assert ok.all() and X.shape == (3, 0, 1)


def test_products_equal_the_engines():
    rng = np.random.default_rng(7)
    A, x, y = rng.normal(size=(N, 3, 7)), rng.normal(size=(N, 7)), rng.normal(size=(N, 3))

    def assert_sums_close(got, expected, magnitudes, terms):
        # two orders of a sum of `terms` products: 2·terms·ε times the sum of their magnitudes
        assert np.linalg.norm(got - expected) <= 2 * terms * EPS * np.linalg.norm(magnitudes)

    out = _output(N, wp.float64, (3,))
    _run(matvec_worlds, N, _device(A), _device(x), out)
    assert_sums_close(out.numpy(), numerics.matvec(A, x, np.empty((N, 3))),
                      np.einsum("nij,nj->ni", np.abs(A), np.abs(x)), 7)
    out = _output(N, wp.float64, (7,))
    _run(vecmat_worlds, N, _device(y), _device(A), out)
    assert_sums_close(out.numpy(), numerics.vecmat(y, A, np.empty((N, 7))),
                      np.einsum("ni,nij->nj", np.abs(y), np.abs(A)), 3)
    for p in (3, 7):  # 3 x 3 (the engine's worlds-last path), 3 x 7 (its matmul)
        B = rng.normal(size=(N, p, 7))
        out = _output(N, wp.float64, (3, p))
        _run(outer_product_worlds, N, _device(A), _device(B), out)
        assert_sums_close(out.numpy(), numerics.outer_product(A, B, np.empty((N, 3, p))),
                          np.abs(A) @ np.abs(B).transpose(0, 2, 1), 7)

    v, columns = rng.normal(size=(N, 3)), rng.normal(size=(N, 3, 7))
    matrices = _output(N, wp.mat33d)
    _run(skew_worlds, N, _device(v, wp.vec3d), matrices)
    expected = numerics.skew(v, np.zeros((N, 3, 3)))
    np.testing.assert_array_equal(matrices.numpy(), expected)  # entries copied or negated: exact
    np.testing.assert_allclose(matrices.numpy() @ columns, np.cross(v[:, :, None], columns, axis=1), rtol=0,
                               atol=4 * EPS * np.abs(v).max() * np.abs(columns).max())


# -- the checks ----------------------------------------------------------------------------------
def test_all_finite_rows_met_and_inside_decide_as_the_engine():
    rng = np.random.default_rng(6)
    n, nv = 8, 4
    a = rng.normal(size=(n, nv))
    a[1, 2], a[2, 0], a[3, 3] = np.nan, np.inf, -np.inf
    flags = _output(n, wp.int32)
    _run(all_finite_worlds, n, _device(a), flags)
    assert flags.numpy().tolist() == [int(numerics.all_finite(row[None])) for row in a] == [1, 0, 0, 0, 1, 1, 1, 1]

    b = rng.normal(size=(n, 3))
    # residuals of 0.1, 0.5, 2 and 10 times the allowed miss, tolerance · sqrt(1 + |b|²)
    allowed = EQUALITY_TOLERANCE * np.sqrt(1.0 + (b * b).sum(axis=1))
    Ax = b + (np.array([0.1, 0.5, 2.0, 10.0, 0.0, 0.0, 0.0, 0.0]) * allowed)[:, None] / np.sqrt(3.0)
    Ax[5, 1], Ax[6, 0] = np.nan, np.inf
    _run(rows_met_worlds, n, _device(Ax), _device(b), EQUALITY_TOLERANCE, flags)
    expected = rows_met(Ax.copy(), b, EQUALITY_TOLERANCE)
    assert flags.numpy().astype(bool).tolist() == expected.tolist() == [True, True, False, False, True, False,
                                                                         False, True]

    box = np.stack([np.full((n, nv), -1.0), np.full((n, nv), 1.0)], axis=1)
    box[:, 0, 3], box[:, 1, 3] = -np.inf, np.inf  # dof 3 unbounded
    x = rng.uniform(-0.5, 0.5, (n, nv))
    x[1, 0], x[2, 1] = -1.0, 1.0  # on a bound: inside
    x[3, 2], x[4, 0] = 1.0 + 1e-15, np.nan
    x[5, 3], x[6, 3] = np.inf, -np.inf  # ±inf on the absent bound: outside
    G, h = rng.normal(size=(n, 2, nv)), np.full((n, 2), 10.0)
    h[7, 1] = -10.0  # a row that world 7 misses
    for rows in (None, (G, h)):
        _run(inside_worlds, n, _device(x), _device(box), _device(np.zeros((n, 0, nv)) if rows is None else G),
             _device(np.zeros((n, 0)) if rows is None else h), flags)
        with np.errstate(invalid="ignore"):  # ±inf − ±inf: NaN, outside
            expected = inside(x, box, *(rows or ()))
        assert flags.numpy().astype(bool).tolist() == expected.tolist() == [True, True, True, False, False, False,
                                                                             False, rows is None]


# -- the closed form -----------------------------------------------------------------------------
NV, BASE = 9, 6  # a floating base's 6 dofs and 3 joints


def _problems(rng, n: int, soft_rows: int, rows: int, held: bool):
    """n worlds of DampedLeastSquares.solve's and .gradient's arguments: random ones
    (0, 1 or 2 dofs held where ``held``), then a floating base's world (D = 1e-12 on the
    base, a posture's 1e-4 on the joints: solved only by refining where there are more rows
    than base dofs), one with dependent hard rows (singular) and one with a NaN in D⁻¹."""
    m = soft_rows + rows
    damping = rng.uniform(0.1, 2.0, (n, NV))
    damping[-3] = np.r_[np.full(BASE, 1e-12), np.full(NV - BASE, 1e-4)]
    dinv = 1.0 / damping
    dinv[-1, 2] = np.nan
    R, rhs, c = rng.normal(size=(n, m, NV)), rng.normal(size=(n, m)), rng.normal(size=(n, NV))
    c[-3] *= damping[-3]  # a posture's c: D (q − q_ref)
    if rows >= 2:
        R[-2, -1] = R[-2, -2]
    fixed, values = np.zeros((n, NV), dtype=bool), np.zeros((n, NV))
    if held:
        for w in range(n - 1):  # never dof 2 (the NaN world's)
            fixed[w, rng.choice([0, 4, 8], size=w % 3, replace=False)] = True
        values[fixed] = rng.uniform(-1.0, 1.0, fixed.sum())
    return dinv, damping, R, rhs, c, fixed, values


def _augmented(damping, R, soft_rows, fixed):
    """One world's solve as one system in (x, z): D x − Rᵀz = −c on the free dofs, x = v on
    the held ones, R x + [z₁; 0] = rhs."""
    m = len(R)
    top = np.hstack([np.diag(np.where(fixed, 1.0, damping)), -R.T * ~fixed[:, None]])
    return np.vstack([top, np.hstack([R, np.diag(np.arange(m) < soft_rows).astype(float)])])


@pytest.mark.parametrize("soft_rows, rows", [(8, 0), (0, 3), (6, 2), (0, 0)])
@pytest.mark.parametrize("linear", [False, True])
@pytest.mark.parametrize("held", [False, True])
def test_damped_least_squares_equals_the_engines(soft_rows, rows, linear, held, monkeypatch):
    n, m = 12, soft_rows + rows
    dinv, damping, R, rhs, c, fixed, values = _problems(np.random.default_rng(20), n, soft_rows, rows, held)
    arrays = mirror.damped_least_squares_arrays(n, NV, soft_rows, rows, DEVICE)
    g, ok = _output(n, wp.float64, (NV,)), _output(n, wp.int32)
    _run(damped_least_squares_worlds, n, _device(dinv), _device(damping), _device(R), _device(rhs),
         _device(c), _device(fixed.astype(np.int32), wp.int32), _device(values), int(linear), int(held), arrays, g, ok)
    x, z, g, ok = arrays.x.numpy(), arrays.z.numpy(), g.numpy(), ok.numpy().astype(bool)
    form, held_arguments = DampedLeastSquares(n, NV, soft_rows, rows), (fixed, values) if held else ()
    with np.errstate(invalid="ignore"):  # the NaN world
        expected_x, expected_z, expected_ok = (np.array(a) for a in form.solve(dinv, R, rhs, c if linear else None,
                                                                                 *held_arguments))
        expected_g = form.gradient(damping, R, c if linear else None).copy()
    refused = [n - 2] * (rows >= 2) + [n - 1]
    assert np.flatnonzero(~ok).tolist() == np.flatnonzero(~expected_ok).tolist() == refused
    if m > BASE:  # the floating-base world is solved only by refining
        monkeypatch.setattr(closed_form, "REFINEMENTS", 0)
        assert not form.solve(dinv, R, rhs, c if linear else None, *held_arguments)[2][n - 3]
    for w in np.flatnonzero(ok):
        # Each answer solves the augmented system A (x, z) = (−c, v, rhs) to within its
        # residual: REFINE_TOLERANCE (1 + |rhs|) on the rows (refinement's stop; every world
        # here reaches it), and a few roundings, 10 (nv + m) ε times the terms' magnitudes,
        # everywhere. So the two differ by at most twice that over A's least singular value;
        # the gradient [D, −Rᵀ] (x, z) + c by ‖[D, −Rᵀ]‖ times that, plus its own roundings.
        A = _augmented(damping[w], R[w], soft_rows, fixed[w])
        rounding = 10 * (NV + m) * EPS * (np.linalg.norm(R[w], 2) * (np.linalg.norm(expected_x[w]) +
                   np.linalg.norm(expected_z[w])) + damping[w].max() * np.linalg.norm(expected_x[w]) +
                   np.linalg.norm(c[w]) + np.linalg.norm(rhs[w]))
        miss = REFINE_TOLERANCE * (1.0 + np.linalg.norm(rhs[w])) + rounding
        bound = 2 * miss / np.linalg.svd(A, compute_uv=False)[-1]
        assert np.linalg.norm(x[w] - expected_x[w]) + np.linalg.norm(z[w] - expected_z[w]) <= bound
        gradient_bound = np.linalg.norm(np.hstack([np.diag(damping[w]), -R[w].T]), 2) * bound + rounding
        assert np.linalg.norm(g[w] - expected_g[w]) <= gradient_bound
        np.testing.assert_array_equal(x[w][fixed[w]], values[w][fixed[w]])  # x = v on the held dofs


def test_a_miss_at_its_rounding_decides_as_the_engine(monkeypatch):
    """A step of the any-robot fuzz (tests/data/fuzz_closed_form_steps.npz; see
    tests/core/test_closed_form.py): an answer kept by the verdict on what a float x can
    meet (a soft row at its rounding), in four worlds
    (the data alike, rounded apart by nothing): the same verdicts, the same answers to
    rounding carried by the solve (1e-9 of x: the engine's N = 1 and N = 4 answers agree
    to 1e-11)."""
    data = np.load(Path(__file__).parents[1] / "data" / "fuzz_closed_form_steps.npz")
    d = {key.split("_", 1)[1]: value for key, value in data.items() if key.startswith("8850")}
    R, rhs, damping, soft_rows = d["R"], d["rhs"], d["damping"], int(d["soft_rows"])
    n, nv, rows = 4, R.shape[1], len(R) - soft_rows
    tile = lambda a: np.ascontiguousarray(np.repeat(a[None], n, axis=0))  # noqa: E731
    fixed = d["held_lower"] | d["held_upper"]
    values = np.where(d["held_lower"], d["lower"], np.where(d["held_upper"], d["upper"], 0.0))
    linear = "linear" in d
    c = d["linear"] if linear else np.zeros(nv)
    taken = {"rounding": 0}
    engine_within = DampedLeastSquares._within_rounding

    def rounding(self, R, rhs, met):
        within = engine_within(self, R, rhs, met)
        taken["rounding"] += int(np.sum(within & ~met))
        return within

    monkeypatch.setattr(DampedLeastSquares, "_within_rounding", rounding)
    form = DampedLeastSquares(n, nv, soft_rows, rows)
    expected_x, _, expected_ok = form.solve(tile(1.0 / damping), tile(R), tile(rhs), tile(c) if linear else None,
                                            tile(fixed), tile(values))
    assert taken["rounding"] == n and np.asarray(expected_ok).all()
    arrays = mirror.damped_least_squares_arrays(n, nv, soft_rows, rows, DEVICE)
    g, ok = _output(n, wp.float64, (nv,)), _output(n, wp.int32)
    _run(damped_least_squares_worlds, n, _device(tile(1.0 / damping)), _device(tile(damping)), _device(tile(R)),
         _device(tile(rhs)), _device(tile(c)), _device(tile(fixed).astype(np.int32), wp.int32), _device(tile(values)),
         int(linear), 1, arrays, g, ok)
    assert ok.numpy().astype(bool).all()
    np.testing.assert_allclose(arrays.x.numpy(), expected_x, rtol=0, atol=1e-9 * np.abs(expected_x).max())


def test_the_hard_rows_miss_passes_together_only_row_by_row_too_as_the_engines():
    """A miss past 1e-10 per row passes "together" only under the solvers' rule, norm-wise
    and each row at its own scale (1 + |b_i| + |R_i||x|), on the device as in the engine:
    a row 1e8 away lets its neighbour miss by 1e-6 norm-wise (world 0: refused), its own
    miss of 1e-2 is 5e-11 of its scale (world 1: kept), and a miss past both (world 2)."""
    n, nv = 3, 2
    R, rhs = np.tile(np.eye(nv), (n, 1, 1)), np.tile([1e8, 1.0], (n, 1))
    x = np.array([[1e8, 1.0 + 1e-6], [1e8 + 1e-2, 1.0], [1e8 + 1.0, 1.0]])
    form = DampedLeastSquares(n, nv, 0, nv)
    form.x[...] = x
    form._fit[...] = np.einsum("nij,nj->ni", R, x) - rhs
    expected = form._within_rounding(R, rhs, np.zeros(n, dtype=bool))
    assert expected.tolist() == [False, True, False]
    arrays = mirror.damped_least_squares_arrays(n, nv, 0, nv, DEVICE)
    arrays.x, arrays.fit = _device(x), _device(form._fit)
    met = _output(n, wp.int32)
    _run(within_rounding_worlds, n, _device(R), _device(rhs), arrays, met)
    assert met.numpy().astype(bool).tolist() == expected.tolist()
