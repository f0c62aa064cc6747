r"""The batched QP on the CPU: the closed form for every world, an exact active set where
a bound binds, DAQP for a world the active set cannot settle.

Every world solves

.. math::
    \min_x \tfrac12 x^T H x + c^T x \quad\text{s.t.}\quad A x = b,\quad lb \le x \le ub,

H positive definite. Three stages, each vectorised over the worlds that reach it:

1. **Closed form** (all worlds): the equality-constrained minimiser from the KKT system,
   :math:`x = -H^{-1}(c + A^T\lambda)`, :math:`\lambda = -S^{-1}(b + A H^{-1} c)`,
   :math:`S = A H^{-1} A^T` (with as many independent rows as variables, :math:`x = A^{-1}b`).
   A world whose x meets its rows to ``1e-10 (1 + |b|)`` and lies inside its box (exact
   comparisons, as the serial controller's closed form) is done: the QP is strictly
   convex, so its unconstrained-by-bounds minimiser is *the* minimiser.
2. **Active set** (the worlds where a bound binds), exact and vectorised: first each
   world's last active set (a warm start: a bound that binds usually still binds): the
   reduced KKT system with those bounds held, accepted when its answer meets the QP's
   optimality conditions — the rows, the box, the multipliers' signs — which make it
   *the* minimiser. Else Goldfarb–Idnani's dual active set from the closed form: add the
   most violated bound; a partial step drops a bound whose multiplier would turn
   negative; stop when no bound is violated; the final set is verified as above.
3. **DAQP** (the serial solver), world by world, for any world left: no violated-bound
   free set within ``max_iterations`` rounds, a singular reduced system (dependent
   rows), or an answer that fails the checks. DAQP also certifies infeasibility.

Checks on every answer returned: hard rows to ``1e-9 (1 + |b|)`` (the serial
solvers' promise), inside the box to ``1e-9``. A world none of the stages solves is
INFEASIBLE (DAQP certifies it, or the box is empty) or FAILED, with x = 0.
"""

from __future__ import annotations

from ctypes import c_int

import numpy as np

from .backends.base import BatchQP, QPResult, QPStatus
from .linalg import cholesky_solve_last, worlds_last

# As the serial controller's closed form (qpik.controllers.closed_form.EQUALITY_TOLERANCE).
CLOSED_FORM_TOLERANCE = 1e-10
# The serial solvers' promise on hard rows (qpik.solvers.base.EXACT_EQUALITY_TOLERANCE).
EQUALITY_TOLERANCE = 1e-9
BOUND_TOLERANCE = 1e-9
# A free variable this far (relative) past a bound is fixed at it; closer, it is rounding
# and the variable is clipped onto the bound at the end.
ACTIVATION_TOLERANCE = 1e-12
# A fixed variable whose multiplier is below −this (relative to the gradient's scale) is freed.
MULTIPLIER_TOLERANCE = 1e-12
# S counts as singular (dependent hard rows) past this conditioning, as in the serial
# closed form (qpik.controllers.closed_form.SINGULAR_RATIO).
SINGULAR_RATIO = 1e6
# DAQP's settings in the serial back-end (qpik.solvers.base).
DAQP_ITERATIONS = 10000
DAQP_TIME_LIMIT = 1.0
DAQP_EXIT = {-1: "primal infeasible", -2: "cycling detected", -3: "unbounded problem", -4: "iteration limit reached",
             -5: "nonconvex problem", -6: "overdetermined initial active set", -7: "time limit reached"}


def stacked_solve(M: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Solve M_k X_k = B_k for a stack; (X, ok): a singular M_k gives ok False (X zero)."""
    try:
        return np.linalg.solve(M, B), np.ones(len(M), dtype=bool)
    except np.linalg.LinAlgError:
        X = np.zeros(np.broadcast_shapes(M.shape[:-2], B.shape[:-2]) + B.shape[-2:])
        ok = np.ones(len(X), dtype=bool)
        for k in range(len(X)):
            try:
                X[k] = np.linalg.solve(M[k] if M.ndim == 3 else M, B[k])
            except np.linalg.LinAlgError:
                ok[k] = False
        return X, ok


def rows_met(A: np.ndarray, x: np.ndarray, b: np.ndarray, tolerance: float) -> np.ndarray:
    """Per world, whether |Ax − b| <= tolerance (1 + |b|) (Euclidean), as the serial check."""
    if A.shape[1] == 0:
        return np.ones(len(x), dtype=bool)
    residual = matvec(A, x) - b
    return square_sum(residual) <= tolerance * tolerance * (1.0 + square_sum(b))


def matvec(A: np.ndarray, x: np.ndarray) -> np.ndarray:
    """(k, m): A_k x_k of every world, A (k, m, n), x (k, n)."""
    return np.einsum("kij,kj->ki", A, x)


def square_sum(r: np.ndarray) -> np.ndarray:
    """(k,): the squared norm of each row of r (k, m); columns added one by one, since
    NumPy's reduction over a short last axis costs more than m additions."""
    total = r[:, 0] * r[:, 0] if r.shape[1] else np.zeros(len(r))
    for i in range(1, r.shape[1]):
        total = total + r[:, i] * r[:, i]
    return total


def spd_solve(S: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Solve S_k y_k = r_k, S_k (m, m) symmetric positive definite, in every world;
    S (N, m, m), r (N, m). See :func:`spd_solve_last`."""
    y, ok = spd_solve_last(worlds_last(S), np.ascontiguousarray(r.T))
    return y.T, ok


def spd_solve_last(S: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Solve S_k y_k = r_k with the worlds along the last axis: S (m, m, N), r (m, N);
    ok False where S_k is not positive definite, or too ill-conditioned for its solution
    to mean anything (the serial closed form's test: cond(S) > 1e12 for one or two
    rows, Cholesky pivots further apart than 1e6 beyond)."""
    m = S.shape[0]
    if m == 1:
        s = S[0, 0]
        ok = s > 0.0
        return r / np.where(ok, s, 1.0), ok
    if m == 2:
        a, off, d = S[0, 0], S[0, 1], S[1, 1]
        det = a * d - off * off
        ok = (det * SINGULAR_RATIO ** 2 > a * d) & (a > 0.0)
        det = np.where(ok, det, 1.0)
        y = np.empty_like(r)
        y[0] = (d * r[0] - off * r[1]) / det
        y[1] = (a * r[1] - off * r[0]) / det
        return y, ok
    y, pivots = cholesky_solve_last(S, r[:, None, :])
    low = pivots.min(axis=0)
    return y[:, 0], (low > 0.0) & (pivots.max(axis=0) <= SINGULAR_RATIO * low)


def reduced_kkt(H: np.ndarray, c: np.ndarray, A: np.ndarray, b: np.ndarray, fixed: np.ndarray,
                values: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The equality-constrained minimiser with the ``fixed`` variables held at ``values``.

    With x = values + y, y zero on the fixed variables: H's fixed rows and columns become
    the identity's, the fixed entries of c + H·values and the fixed columns of A zero, and
    the KKT system of the rest is solved by its Schur complement.

    Returns:
        (x, λ, ok): ok False where a reduced system is singular.
    """
    k, nv = c.shape
    free = ~fixed
    pair = free[:, :, None] & free[:, None, :]
    Hk = np.broadcast_to(H, (k, nv, nv))
    shifted = c + np.einsum("kij,kj->ki", Hk, values)
    reduced = np.where(pair, Hk, 0.0)
    reduced[:, np.arange(nv), np.arange(nv)] += fixed
    cr = np.where(free, shifted, 0.0)
    Ar = np.where(free[:, None, :], A, 0.0)
    br = b - np.einsum("kij,kj->ki", A, values)
    meq = A.shape[1]
    rhs = np.concatenate([Ar.transpose(0, 2, 1), cr[:, :, None]], axis=2)
    scaled, ok = stacked_solve(reduced, rhs)  # H⁻¹ [Aᵀ c]
    if meq:
        S = np.einsum("kij,kjl->kil", Ar, scaled[:, :, :meq])
        r = br + np.einsum("kij,kj->ki", Ar, scaled[:, :, meq])
        lam, ok_s = stacked_solve(S, -r[:, :, None])
        lam = lam[:, :, 0]
        ok &= ok_s
        y = -scaled[:, :, meq] - np.einsum("kij,kj->ki", scaled[:, :, :meq], lam)
    else:
        lam = np.zeros((k, 0))
        y = -scaled[:, :, 0]
    x = values + np.where(free, y, 0.0)
    ok &= np.isfinite(x).all(axis=1) & np.isfinite(lam).all(axis=1)
    return x, lam, ok


class ActiveSetQP(BatchQP):
    """The CPU's batched QP (see the module's description).

    Args:
        nworld, nv, meq: the sizes.
        max_iterations: dual active-set rounds before the worlds still running go to DAQP
            (default ``2 nv + 10``).
    """

    name = "active-set"

    def __init__(self, nworld: int, nv: int, meq: int, max_iterations: int | None = None):
        super().__init__(nworld, nv, meq)
        self.max_iterations = 2 * nv + 10 if max_iterations is None else int(max_iterations)
        self._lower = np.zeros((nworld, nv), dtype=bool)  # the last step's active sets
        self._upper = np.zeros((nworld, nv), dtype=bool)
        self.x = np.zeros((nworld, nv))
        self.stats = {"closed_form": 0, "active_set": 0, "daqp": 0, "iterations": 0}
        self._shared = None  # (H, 1/diag(H) or None, H⁻¹ or None) of the last shared H

    def reset(self) -> None:
        self._lower.fill(False)
        self._upper.fill(False)

    def solve(self, H, c, A, b, lb, ub, active=None) -> QPResult:
        n = self.nworld
        x = self.x
        x.fill(0.0)
        status = np.full(n, QPStatus.SKIPPED, dtype=np.int8)
        reasons: dict[int, str] = {}
        closed = np.zeros(n, dtype=bool)
        fallback = np.zeros(n, dtype=bool)
        todo = np.ones(n, dtype=bool) if active is None else np.asarray(active, dtype=bool).copy()
        self._screen(H, c, A, b, lb, ub, todo, status, reasons)
        ids = np.flatnonzero(todo)
        if not len(ids):
            return QPResult(x, status, reasons, closed, fallback)
        every = len(ids) == n  # then whole arrays, not copies of their rows
        pick = (lambda a: a) if every else (lambda a: a[ids])
        Hs = H if H.ndim == 2 else pick(H)
        lo, hi = pick(lb), pick(ub)
        xc, ok = self._closed_form(Hs, pick(c), pick(A), pick(b))
        if every and ok.all() and not (xc < lo).any() and not (xc > hi).any():
            # the common step: no bound binds anywhere
            x[:] = xc
            status.fill(QPStatus.SOLVED)
            closed.fill(True)
            self._lower.fill(False)
            self._upper.fill(False)
            self.stats["closed_form"] += n
            return QPResult(x, status, reasons, closed, fallback)
        inside = ok & (xc >= lo).all(axis=1) & (xc <= hi).all(axis=1)
        done = ids[inside]
        x[done] = xc[inside]
        status[done] = QPStatus.SOLVED
        closed[done] = True
        self._lower[done] = False
        self._upper[done] = False
        rest = ids[~inside]
        iterations = 0
        if len(rest):
            start = xc[~inside]
            start[~ok[~inside]] = 0.0
            unsettled, iterations = self._active_set(H, c, A, b, lb, ub, rest, start, x, status)
            if len(unsettled):
                fallback[unsettled] = True
                self._daqp(H, c, A, b, lb, ub, unsettled, x, status, reasons)
        self.stats["closed_form"] += len(done)
        self.stats["active_set"] += len(rest) - int(fallback.sum())
        self.stats["daqp"] += int(fallback.sum())
        self.stats["iterations"] = max(self.stats["iterations"], iterations)
        return QPResult(x, status, reasons, closed, fallback, iterations)

    def _screen(self, H, c, A, b, lb, ub, todo, status, reasons) -> None:
        """Worlds with non-finite data or an empty box are not solved (reasons given)."""
        # One sum per array settles the usual case; a sum that overflows only sends the
        # check to the per-world test.
        finite_sums = [c.sum(), b.sum(), A.sum()] + ([H.sum()] if H.ndim == 3 else [])
        if not np.isfinite(finite_sums).all() or np.isnan(lb).any() or np.isnan(ub).any():
            finite = np.isfinite(c).all(axis=1) & np.isfinite(b).all(axis=1) & np.isfinite(A).all(axis=(1, 2))
            if H.ndim == 3:
                finite &= np.isfinite(H).all(axis=(1, 2))
            finite &= ~np.isnan(lb).any(axis=1) & ~np.isnan(ub).any(axis=1)
            for w in np.flatnonzero(todo & ~finite):
                status[w] = QPStatus.FAILED
                reasons[int(w)] = "the QP's data contain NaN or inf (a target, a task velocity or a bound)"
            todo &= finite
        crossed = lb > ub
        if not crossed.any():
            return
        empty = todo & crossed.any(axis=1)
        for w in np.flatnonzero(empty):
            i = int(np.argmax(lb[w] > ub[w]))
            status[w] = QPStatus.INFEASIBLE
            reasons[int(w)] = f"QP infeasible: variable {i} must lie in the empty interval [{lb[w, i]:.6g}, {ub[w, i]:.6g}]"
        todo &= ~empty

    def _shared_inverse(self, H: np.ndarray) -> tuple[np.ndarray | None, np.ndarray | None]:
        """(1/diag(H), None) for a diagonal H shared by every world, else (None, H⁻¹);
        computed once while H stays the same."""
        cached = self._shared
        if cached is None or not np.array_equal(cached[0], H):
            diagonal = np.diag(H).copy()
            if np.count_nonzero(H - np.diag(diagonal)) == 0 and np.all(diagonal > 0):
                cached = (H.copy(), 1.0 / diagonal, None)
            else:
                cached = (H.copy(), None, np.linalg.inv(H))
            self._shared = cached
        return cached[1], cached[2]

    def _closed_form(self, H, c, A, b) -> tuple[np.ndarray, np.ndarray]:
        """The equality-constrained minimiser of every world (no bound held):
        x = −H⁻¹(c + Aᵀλ) with S λ = −r, S = A H⁻¹ Aᵀ, r = b + A H⁻¹ c. H⁻¹[Aᵀ c]
        comes from H's cached inverse when H is shared (a diagonal one elementwise),
        else from one Cholesky solve across worlds; S is solved in closed form for
        one or two rows (as the serial controller's closed form), by Cholesky beyond.
        Computed with the worlds along the last axis (one pass per operation)."""
        k, nv = c.shape
        meq = self.meq
        if meq == nv:  # a single feasible point: x = A⁻¹b
            xs, ok = stacked_solve(A, b[:, :, None])
            x = xs[:, :, 0]
            if not np.isfinite(x.sum()):
                ok &= np.isfinite(x).all(axis=1)
            return x, ok & rows_met(A, x, b, CLOSED_FORM_TOLERANCE)
        At, bt = worlds_last(A), np.ascontiguousarray(b.T)  # (meq, nv, k), (meq, k)
        xt, HAt, ok = self._scaled(H, c, At)  # H⁻¹c (nv, k), A H⁻¹ (meq, nv, k)
        if meq:
            S = np.empty((meq, meq, k))
            for i in range(meq):
                for j in range(i, meq):
                    S[i, j] = S[j, i] = (HAt[i] * At[j]).sum(axis=0)
            lam, ok_s = spd_solve_last(S, -(bt + (At * xt).sum(axis=1)))
            ok &= ok_s
            for i in range(meq):
                xt += lam[i] * HAt[i]
        xt = -xt
        if not np.isfinite(xt.sum()):
            ok &= np.isfinite(xt).all(axis=0)
        if meq:
            residual = (At * xt).sum(axis=1) - bt
            ok &= (residual * residual).sum(axis=0) <= CLOSED_FORM_TOLERANCE ** 2 * (1.0 + (bt * bt).sum(axis=0))
        return xt.T, ok

    def _scaled(self, H, c, At) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(H⁻¹c (nv, k), A H⁻¹ (meq, nv, k), ok) of every world, worlds last; the first
        is a new array."""
        k = len(c)
        if H.ndim == 2:
            dinv, inverse = self._shared_inverse(H)
            if dinv is not None:
                return c.T * dinv[:, None], At * dinv[:, None], np.ones(k, dtype=bool)
            return inverse @ c.T, np.matmul(inverse, At), np.ones(k, dtype=bool)  # H symmetric
        rhs = np.concatenate([c.T[:, None, :], At.transpose(1, 0, 2)], axis=1)  # (nv, 1 + meq, k)
        solved, pivots = cholesky_solve_last(worlds_last(H), rhs)
        return solved[:, 0].copy(), solved[:, 1:].transpose(1, 0, 2), (pivots > 0.0).all(axis=0)

    def _active_set(self, H, c, A, b, lb, ub, ids, start, x, status) -> tuple[np.ndarray, int]:
        """The worlds ``ids`` whose closed form crossed a bound: first their last step's
        active set, verified; then a dual active set (Goldfarb–Idnani) from the closed
        form for those it does not fit. Returns the worlds left to DAQP."""
        lower = self._lower[ids] & np.isfinite(lb[ids])
        upper = self._upper[ids] & np.isfinite(ub[ids]) & ~lower
        warm = (lower | upper).any(axis=1)
        if warm.any():
            self._accept(H, c, A, b, lb, ub, ids[warm], lower[warm], upper[warm], x, status)
        cold = ids[status[ids] != QPStatus.SOLVED]
        iterations = 0
        if len(cold):
            mask = np.isin(ids, cold)
            iterations = self._dual(H, c, A, b, lb, ub, cold, start[mask], x, status)
        unsettled = ids[status[ids] != QPStatus.SOLVED]
        self._lower[unsettled] = False
        self._upper[unsettled] = False
        return unsettled, iterations

    def _accept(self, H, c, A, b, lb, ub, ids, lower, upper, x, status) -> np.ndarray:
        """Solve with the bounds ``lower``/``upper`` held and keep the worlds whose answer
        meets the QP's optimality conditions: the rows, the box, the multipliers' signs."""
        Hs = H if H.ndim == 2 else H[ids]
        lo, hi = lb[ids], ub[ids]
        fixed = lower | upper
        values = np.where(lower, lo, np.where(upper, hi, 0.0))
        xs, lam, ok = reduced_kkt(Hs, c[ids], A[ids], b[ids], fixed, values)
        gradient = np.einsum("kij,kj->ki", np.broadcast_to(Hs, (len(ids),) + Hs.shape[-2:]), xs) + c[ids]
        if self.meq:
            gradient += np.einsum("kji,kj->ki", A[ids], lam)
        scale = MULTIPLIER_TOLERANCE * (1.0 + np.abs(c[ids]).max(axis=1, initial=0.0))[:, None]
        margin = BOUND_TOLERANCE
        good = ok & ~(lower & (gradient < -scale)).any(axis=1) & ~(upper & (gradient > scale)).any(axis=1)
        good &= ((xs >= lo - margin) & (xs <= hi + margin)).all(axis=1)
        xs = np.clip(xs, lo, hi)
        good &= rows_met(A[ids], xs, b[ids], EQUALITY_TOLERANCE)
        chosen = ids[good]
        x[chosen] = xs[good]
        status[chosen] = QPStatus.SOLVED
        self._lower[chosen], self._upper[chosen] = lower[good], upper[good]
        return good

    def _dual(self, H, c, A, b, lb, ub, ids, start, x, status) -> int:
        """Goldfarb–Idnani's dual active set on the box, vectorised over ``ids``: from the
        closed form (the equality rows always active), add the most violated bound, with
        partial steps that drop a bound whose multiplier would turn negative. The final
        set is verified by :meth:`_accept`."""
        k, nv = len(ids), self.nv
        xs = start.copy()
        lower = np.zeros((k, nv), dtype=bool)
        upper = np.zeros((k, nv), dtype=bool)
        mu = np.zeros((k, nv))
        chosen = np.full(k, -1)  # the bound being added, per world (-1: pick one)
        side = np.zeros(k)
        mu_new = np.zeros(k)
        lo_all, hi_all = lb[ids], ub[ids]
        pending = np.ones(k, dtype=bool)
        finished = np.zeros(k, dtype=bool)
        iterations = 0
        for iterations in range(1, self.max_iterations + 1):
            # Worlds without a bound to add pick their most violated one, or are done.
            pick = pending & (chosen < 0)
            if pick.any():
                rows = np.flatnonzero(pick)
                free = ~(lower[rows] | upper[rows])
                lo, hi, xr = lo_all[rows], hi_all[rows], xs[rows]
                below = free & (xr < lo - ACTIVATION_TOLERANCE * (1.0 + np.abs(np.where(free, lo, 0.0))))
                above = free & (xr > hi + ACTIVATION_TOLERANCE * (1.0 + np.abs(np.where(free, hi, 0.0))))
                below, above = _most_violated(xr, lo, hi, below, above)
                any_violated = (below | above).any(axis=1)
                done = rows[~any_violated]
                finished[done] = True
                pending[done] = False
                rows, below, above = rows[any_violated], below[any_violated], above[any_violated]
                chosen[rows] = np.argmax(below | above, axis=1)
                side[rows] = np.where(below.any(axis=1), 1.0, -1.0)
                mu_new[rows] = 0.0
            step = np.flatnonzero(pending)
            if not len(step):
                break
            self._dual_step(H, A, ids, step, xs, lower, upper, mu, chosen, side, mu_new, lo_all, hi_all, pending)
        verify = np.flatnonzero(finished)
        if len(verify):
            self._accept(H, c, A, b, lb, ub, ids[verify], lower[verify], upper[verify], x, status)
        return iterations

    def _dual_step(self, H, A, ids, step, xs, lower, upper, mu, chosen, side, mu_new, lo_all, hi_all, pending):
        """One Goldfarb–Idnani step for the worlds ``step`` (rows of the local arrays)."""
        w = ids[step]
        n = len(step)
        nv = self.nv
        Hs = H if H.ndim == 2 else H[w]
        fixed = lower[step] | upper[step]
        normal = np.zeros((n, nv))
        normal[np.arange(n), chosen[step]] = side[step]
        # z: the step in the null space of the active rows; r: how the multipliers change.
        z, _, ok = reduced_kkt(Hs, -normal, A[w], np.zeros((n, self.meq)), fixed, np.zeros((n, nv)))
        Hk = np.broadcast_to(Hs, (n, nv, nv))
        residual = normal - np.einsum("kij,kj->ki", Hk, z)  # = Aᵀλ_r + Σ r_i s_i e_i on the fixed dofs
        signs = np.where(lower[step], 1.0, np.where(upper[step], -1.0, 0.0))
        r = _fixed_multipliers(residual, A[w], fixed, signs, self.meq)
        zn = side[step] * z[np.arange(n), chosen[step]]
        scale = 1.0 + np.abs(normal).max(axis=1)
        z_zero = ~(np.abs(zn) > 1e-14 * scale * (1.0 + np.abs(z).max(axis=1)))
        p = chosen[step]
        bound = np.where(side[step] > 0, lo_all[step, p], hi_all[step, p])
        slack = side[step] * (xs[step, p] - bound)  # < 0: violated
        t2 = np.where(z_zero, np.inf, -slack / np.where(z_zero, 1.0, zn))
        blocking = fixed & (r > 1e-14)
        ratios = np.where(blocking, mu[step] / np.where(blocking, r, 1.0), np.inf)
        drop = np.argmin(ratios, axis=1)
        t1 = ratios[np.arange(n), drop]
        stuck = ~ok | (z_zero & ~np.isfinite(t1))  # infeasible or singular: DAQP decides
        t = np.minimum(t1, t2)
        t = np.where(stuck, 0.0, t)
        move = ~z_zero & ~stuck
        xs[step[move]] += t[move, None] * z[move]
        mu[step] -= np.where(fixed, t[:, None] * r, 0.0)
        mu_new[step] += t
        full = ~stuck & (t2 <= t1)
        add = step[full]
        pa = chosen[add]
        xs[add, pa] = np.where(side[add] > 0, lo_all[add, pa], hi_all[add, pa])
        lower[add, pa] = side[add] > 0
        upper[add, pa] = side[add] < 0
        mu[add, pa] = mu_new[add]
        chosen[add] = -1
        part = step[~stuck & ~full]
        dk = drop[~stuck & ~full]
        lower[part, dk] = False
        upper[part, dk] = False
        mu[part, dk] = 0.0
        pending[step[stuck]] = False

    def _daqp(self, H, c, A, b, lb, ub, ids, x, status, reasons) -> None:
        """The serial solver, world by world, for the worlds the active set left."""
        import daqp

        nv, meq = self.nv, self.meq
        sense = np.zeros(nv + meq, dtype=c_int)
        sense[nv:] = 5  # equality rows
        for w in ids:
            Hw = np.ascontiguousarray(H if H.ndim == 2 else H[w])
            upper = np.concatenate([ub[w], b[w]])
            lower = np.concatenate([lb[w], b[w]])
            xw, _, exitflag, _ = daqp.solve(Hw, np.ascontiguousarray(c[w]), np.ascontiguousarray(A[w]), upper, lower,
                                            sense.copy(), iter_limit=DAQP_ITERATIONS, time_limit=DAQP_TIME_LIMIT)
            if exitflag < 1:
                status[w] = QPStatus.INFEASIBLE if exitflag == -1 else QPStatus.FAILED
                reasons[int(w)] = f"QP {'infeasible' if exitflag == -1 else 'not solved'} (daqp: " \
                                  f"{DAQP_EXIT.get(exitflag, f'exit flag {exitflag}')})"
                continue
            xw = np.asarray(xw, dtype=float)
            outside = max(float(np.max(lb[w] - xw)), float(np.max(xw - ub[w])), 0.0)
            xw = np.clip(xw, lb[w], ub[w])
            if outside > 1e-5 or not rows_met(A[w][None], xw[None], b[w][None], EQUALITY_TOLERANCE)[0]:
                status[w] = QPStatus.FAILED
                reasons[int(w)] = "QP not solved: daqp's answer misses the hard rows or the box"
                continue
            x[w] = xw
            status[w] = QPStatus.SOLVED


def _most_violated(x, lo, hi, below, above):
    """Of each world's violated bounds, only the most violated (relative to 1 + |bound|)."""
    excess = np.where(below, (lo - x) / (1.0 + np.abs(np.where(below, lo, 0.0))), 0.0)
    excess = np.maximum(excess, np.where(above, (x - hi) / (1.0 + np.abs(np.where(above, hi, 0.0))), 0.0))
    pick = np.zeros_like(below)
    worst = np.argmax(excess, axis=1)
    rows = np.flatnonzero(excess[np.arange(len(x)), worst] > 0.0)
    pick[rows, worst[rows]] = True
    return below & pick, above & pick


def _fixed_multipliers(residual, A, fixed, signs, meq):
    """The change r of the active bounds' multipliers: ``residual`` = n_p − Hz equals
    Aᵀλ + Σ r_i s_i e_i over the fixed dofs; on the free dofs it is Aᵀλ alone, which gives
    λ (least squares over the free dofs), and r_i = s_i (residual − Aᵀλ)_i."""
    if meq:
        free = ~fixed
        Af = np.where(free[:, None, :], A, 0.0)  # (k, meq, nv)
        gram = np.einsum("kij,klj->kil", Af, Af)
        rhs = np.einsum("kij,kj->ki", Af, residual)
        lam, _ = stacked_solve(gram, rhs[:, :, None])
        residual = residual - np.einsum("kji,kj->ki", A, lam[:, :, 0])
    return np.where(fixed, signs * residual, 0.0)
