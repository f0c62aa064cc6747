"""qpik.linalg: the NumPy implementations of the three LAPACK calls give SciPy's answers
and report failures the same way, the closed form and SNS give the same steps on either,
and ``import qpik`` with a QP step works where SciPy cannot be imported.

Tolerances: both paths are backward-stable solvers of the same system, so their answers
differ by the rounding of a backward-stable solve amplified by the system's condition
number κ: ``ROUNDING * eps * κ`` relative (the arm and hexapod scenarios stay below
0.6 eps κ; ROUNDING leaves room for the system's size and the BLAS kernel)."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from scipy.linalg import lapack

from qpik import linalg
from qpik.problem.closed_form import closed_form_step
from qpik.scenario import build_scenario

EPS = np.finfo(float).eps
ROUNDING = 64


@pytest.fixture
def numpy_and_scipy():
    """The two implementations, as ``linalg`` gives them; the module's choice restored."""
    previous = linalg.use("numpy")
    numpy_path = (linalg.dposv, linalg.dgesv, linalg.dgesvd)
    linalg.use("scipy")
    scipy_path = (linalg.dposv, linalg.dgesv, linalg.dgesvd)
    yield numpy_path, scipy_path
    linalg.use(previous)


def _spd(rng, n, condition):
    """A symmetric positive definite matrix with the given condition number."""
    q, _ = np.linalg.qr(rng.normal(size=(n, n)))
    return (q * np.geomspace(1.0, 1.0 / condition, n)) @ q.T


def _rows(rng, m, n, condition):
    """An m×n matrix (m ≤ n) whose singular values span ``condition``."""
    u, _ = np.linalg.qr(rng.normal(size=(m, m)))
    v, _ = np.linalg.qr(rng.normal(size=(n, m)))
    return (u * np.geomspace(1.0, 1.0 / condition, m)) @ v.T


def test_scipy_is_the_default_where_it_is_installed():
    assert linalg.available() == ("scipy", "numpy")
    assert linalg.BACKEND == "scipy" and linalg.dposv is lapack.dposv


@pytest.mark.parametrize("n", [2, 4, 7, 30])
@pytest.mark.parametrize("condition", [1.0, 1e4, 1e8, 1e11])
def test_cholesky_and_lu_solves_agree(numpy_and_scipy, n, condition):
    (np_posv, np_gesv, _), (sp_posv, sp_gesv, _) = numpy_and_scipy
    rng = np.random.default_rng(n)
    for _ in range(5):
        a = _spd(rng, n, condition)
        a[np.tril_indices(n, -1)] += 1e-3  # rounding-like asymmetry: both read the upper triangle
        b = rng.normal(size=n)
        (f1, x1, info1), (f2, x2, info2) = sp_posv(a, b), np_posv(a, b)
        assert info1 == info2 == 0
        tolerance = ROUNDING * EPS * condition
        assert np.abs(x1 - x2).max() <= tolerance * np.abs(x1).max()
        # The factor's diagonal is what the caller's singularity test reads (the factor's
        # perturbation bound: ‖ΔL‖ ≲ eps κ ‖L‖).
        np.testing.assert_allclose(f2.diagonal(), f1.diagonal(), rtol=0,
                                   atol=tolerance * f1.diagonal().max())
        general = a + rng.normal(size=(n, n)) / condition ** 0.5
        (lu1, piv1, y1, info1), (lu2, piv2, y2, info2) = sp_gesv(general, b), np_gesv(general, b)
        kappa = np.linalg.cond(general)
        assert info1 == info2 == 0 and np.array_equal(piv1, piv2)
        assert np.abs(y1 - y2).max() <= ROUNDING * EPS * kappa * np.abs(y1).max()
        pivots = np.abs(lu1.diagonal())
        np.testing.assert_allclose(np.abs(lu2.diagonal()), pivots, rtol=0, atol=ROUNDING * EPS * kappa * pivots.max())


def test_failures_are_reported_alike(numpy_and_scipy):
    (np_posv, np_gesv, np_svd), (sp_posv, sp_gesv, sp_svd) = numpy_and_scipy
    indefinite = np.array([[1.0, 2.0], [2.0, 1.0]])
    assert sp_posv(indefinite, np.ones(2))[2] > 0 and np_posv(indefinite, np.ones(2))[2] > 0
    singular = np.array([[1.0, 2.0, 0.0], [2.0, 4.0, 0.0], [0.0, 0.0, 1.0]])
    assert sp_gesv(singular, np.ones(3))[3] > 0 and np_gesv(singular, np.ones(3))[3] > 0
    # A non-finite matrix: the caller (SNS) reads info != 0 or a non-finite σ as failure.
    for svd in (sp_svd, np_svd):
        u, s, vt, info = svd(np.array([[np.nan, 1.0, 0.0]]))
        assert info != 0 or not np.isfinite(s[0])


@pytest.mark.parametrize("shape", [(1, 4), (2, 4), (3, 4), (4, 4), (6, 24), (3, 3)])
def test_svd_agrees_up_to_the_signs_of_the_singular_vectors(numpy_and_scipy, shape):
    (_, _, np_svd), (_, _, sp_svd) = numpy_and_scipy
    rng = np.random.default_rng(shape[0])
    a = rng.normal(size=shape)
    a[-1] = a[0] + 1e-9 * a[-1] if shape[0] > 1 else a[-1]  # nearly dependent rows
    (u1, s1, vt1, i1), (u2, s2, vt2, i2) = sp_svd(a), np_svd(a)
    assert i1 == i2 == 0 and u1.shape == u2.shape and vt1.shape == vt2.shape
    np.testing.assert_allclose(s2, s1, rtol=0, atol=ROUNDING * EPS * s1[0])
    # The pseudoinverse does not depend on the singular vectors' signs.
    rank = int(np.count_nonzero(s1 > 1e-10 * s1[0]))
    pinv1 = vt1[:rank].T @ (u1[:, :rank].T / s1[:rank, None])
    pinv2 = vt2[:rank].T @ (u2[:, :rank].T / s2[:rank, None])
    kappa = s1[0] / s1[rank - 1]
    assert np.abs(pinv1 - pinv2).max() <= ROUNDING * EPS * kappa * np.abs(pinv1).max()


@pytest.mark.parametrize("meq", [3, 4, 7])
@pytest.mark.parametrize("hessian", ["dense", "per-call"])
def test_the_closed_form_step_agrees_on_random_problems(numpy_and_scipy, meq, hessian):
    """meq = 7 = nv is the LU path (x = A⁻¹b), the others Cholesky of H and of S. Hard rows
    with κ up to 1e2 are solved alike; at κ = 1e9 (S past the singular ratio) both leave
    the step to the solver. κ in between, where S (κ(A)² κ(H)) nears the threshold, is
    left out: the decision there rests on the last digits."""
    rng = np.random.default_rng(meq)
    nv = 7
    for condition in (1.0, 1e2, 1e9):
        M = rng.normal(size=(nv, nv))
        H = M @ M.T + 0.1 * np.eye(nv)
        A = _rows(rng, meq, nv, condition)
        Ac, b = np.vstack([A, rng.normal(size=nv)]), rng.normal(size=meq)
        answers = []
        for backend in ("scipy", "numpy"):
            linalg.use(backend)
            answers.append(closed_form_step(nv, meq, None if hessian == "per-call" else H).solve(H, Ac, b))
        x1, x2 = answers
        if condition > 1e6:
            assert x1 is None and x2 is None
            continue
        assert x1 is not None and x2 is not None
        kkt = np.block([[H, A.T], [A, np.zeros((meq, meq))]])
        assert np.abs(x1 - x2).max() <= ROUNDING * EPS * np.linalg.cond(kkt) * (1.0 + np.abs(x1).max())


def _condition(controller, setup, kind: str) -> float:
    """κ of the system the step solves: the KKT matrix of the QP's equality-constrained
    problem, or the worst task Jacobian for SNS."""
    if kind == "qp":
        m = controller.A.shape[0]
        return float(np.linalg.cond(np.block([[controller.H, controller.A.T], [controller.A, np.zeros((m, m))]])))
    return max(float(np.linalg.cond(task.jacobian)) for task in setup.hierarchy)


# The scenarios and controllers whose steps call LAPACK (the arm's one- and two-row levels
# are solved in floats and never do).
LAPACK_STEPS = [("unreachable", "qp"), ("unreachable", "sns"), ("three-tasks", "qp"), ("hexapod-circle", "qp"),
                ("hexapod-circle", "sns"), ("hexapod-position-only", "qp"), ("hexapod-position-only", "sns")]


@pytest.mark.parametrize("scenario, kind", LAPACK_STEPS)
def test_steps_agree_along_a_rollout(numpy_and_scipy, scenario, kind):
    """The rollout runs on SciPy; at each state the NumPy path computes the step too (a
    profiler hook records that its functions ran)."""
    numpy_functions = {function.__code__ for function in numpy_and_scipy[0]}
    calls = set()
    reference, other = build_scenario(scenario), build_scenario(scenario)
    first, second = reference.controller(kind), other.controller(kind)
    worst = 0.0
    for k in range(int(round(reference.duration / reference.dt))):
        for setup in (reference, other):
            setup.reference.apply(k * reference.dt)
        other.robot.set_q(reference.robot.q)
        linalg.use("scipy")
        x = first.compute_velocity()
        linalg.use("numpy")
        sys.setprofile(lambda frame, event, _: event == "call" and frame.f_code in numpy_functions
                       and calls.add(frame.f_code.co_name))
        try:
            y = second.compute_velocity()
        finally:
            sys.setprofile(None)
        difference = np.abs(x - y).max() / (1.0 + np.abs(x).max())
        worst = max(worst, difference / (EPS * _condition(first, reference, kind)))
        reference.robot.integrate(x, reference.dt)
    assert calls, "the NumPy path was never called"
    assert worst <= ROUNDING



@pytest.mark.parametrize("choice, printed", [("numpy", "numpy"), ("scipy", "scipy"), ("", "scipy")])
def test_the_environment_chooses_the_backend(choice, printed):
    done = subprocess.run([sys.executable, "-c", "from qpik import linalg; print(linalg.BACKEND)"],
                          capture_output=True, text=True, env={**_environment(), "QPIK_LINALG": choice})
    assert done.returncode == 0 and done.stdout.strip() == printed, done.stderr


def test_an_unknown_backend_is_refused():
    from qpik.errors import InvalidInput

    with pytest.raises(InvalidInput, match="unknown linear algebra back-end 'lapack'"):
        linalg.use("lapack")
    done = subprocess.run([sys.executable, "-c", "import qpik.linalg"], capture_output=True, text=True,
                          env={**_environment(), "QPIK_LINALG": "lapack"})
    assert done.returncode != 0 and "InvalidInput" in done.stderr


def _environment():
    import os

    return {key: value for key, value in os.environ.items() if key != "QPIK_LINALG"}
