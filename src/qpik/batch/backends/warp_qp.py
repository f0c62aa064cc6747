r"""N small QPs on a Warp device: one Goldfarb–Idnani dual active set per world.

.. math::
    \min_x \tfrac12 x^T H x + c^T x \quad\text{s.t.}\quad A x = b,\quad lb \le x \le ub

One device thread solves one world, in the precision the kernels are built for
(:func:`dual_active_set_kernel`; the back-end uses float64, see ``docs/batch.md``).
The method is Goldfarb and Idnani's (Math. Programming 27, 1983), as quadprog and
qpmad implement it, with the box kept as implicit rows :math:`\pm e_i`:

1. :math:`H = L L^T` (Cholesky); in :math:`y = L^T x` the cost is
   :math:`\tfrac12\|y\|^2 + g^T y`, :math:`g = L^{-1} c`, and an active row
   :math:`n_i^T x \ge \beta_i` is the column :math:`w_i = L^{-1} n_i`. The active
   columns keep a QR factorisation :math:`W = Q R` (Gram–Schmidt, applied twice).
2. Start: the equality rows and the bounds active at the world's last solve (the warm
   start) are made active; the equality-constrained minimiser and its multipliers
   come from :math:`R` and :math:`Q`; a bound with a negative multiplier is dropped
   until every bound multiplier is >= 0 (a dual feasible start).
3. Repeat: take the most violated bound :math:`p`; the primal step
   :math:`z = L^{-T}(I - QQ^T)\,w_p` and the multipliers' change
   :math:`r = R^{-1} Q^T w_p`; step :math:`t = \min(t_1, t_2)`, :math:`t_2` the step
   that meets :math:`p`, :math:`t_1` the first active bound whose multiplier would
   turn negative (dropped). No step at all (:math:`z = 0` and no bound to drop) proves
   the rows infeasible.

Every iteration keeps the dual feasible and raises the cost: the method ends in a
finite number of iterations with the exact minimiser (to rounding), or a proof of
infeasibility; a cap on the iterations turns a numerical stall into FAILED.
"""



import functools

import warp as wp

# Status codes, the same as qpik.batch.backends.base.QPStatus.
SOLVED, INFEASIBLE, FAILED, SKIPPED = 0, 1, 2, 3


# Per precision: a bound counts as violated beyond VIOLATION (times 1 + |bound|); an
# added column as dependent below DEPENDENCE times its norm; BIG stands for infinity.
_CONSTANTS = {"float64": (1e-11, 1e-12, 1e300), "float32": (1e-5, 1e-6, 1e30)}


def _constants(scalar):
    violation, dependence, big = _CONSTANTS[scalar.__name__]
    return scalar(violation), scalar(dependence), scalar(big)


@functools.cache  # one set of functions per precision, compiled once
def _triangular(scalar):
    """Cholesky factor of H and the solves with it."""
    zero, one = scalar(0.0), scalar(1.0)

    @wp.func
    def cholesky(H: wp.array3d(dtype=scalar), hw: int, L: wp.array3d(dtype=scalar), w: int, n: int) -> int:
        ok = int(1)
        for j in range(n):
            s = H[hw, j, j]
            for k in range(j):
                s = s - L[w, j, k] * L[w, j, k]
            if not (s > zero):  # also NaN
                ok = 0
                s = one
            d = wp.sqrt(s)
            L[w, j, j] = d
            for i in range(j + 1, n):
                t = H[hw, i, j]
                for k in range(j):
                    t = t - L[w, i, k] * L[w, j, k]
                L[w, i, j] = t / d
        return ok

    @wp.func
    def forward_solve(L: wp.array3d(dtype=scalar), w: int, src: wp.array2d(dtype=scalar),
                      dst: wp.array2d(dtype=scalar), n: int):
        """dst = L^-1 src."""
        for j in range(n):
            s = src[w, j]
            for k in range(j):
                s = s - L[w, j, k] * dst[w, k]
            dst[w, j] = s / L[w, j, j]

    @wp.func
    def back_solve_transposed(L: wp.array3d(dtype=scalar), w: int, src: wp.array2d(dtype=scalar),
                              dst: wp.array2d(dtype=scalar), n: int):
        """dst = L^-T src."""
        for jj in range(n):
            j = n - 1 - jj
            s = src[w, j]
            for k in range(j + 1, n):
                s = s - L[w, k, j] * dst[w, k]
            dst[w, j] = s / L[w, j, j]

    return cholesky, forward_solve, back_solve_transposed


@functools.cache
def _rows(scalar):
    """The rows n_p^T x >= beta_p: p < m an equality row a_p, then x_i >= lb_i, then
    -x_i >= -ub_i."""
    zero, one = scalar(0.0), scalar(1.0)

    @wp.func
    def row_column(L: wp.array3d(dtype=scalar), w: int, A: wp.array3d(dtype=scalar), p: int, m: int, n: int,
                   W: wp.array3d(dtype=scalar), slot: int):
        """W[slot] = L^-1 n_p, the active column of row p (forward substitution)."""
        i = p - m
        sign = one
        if i >= n:
            i = i - n
            sign = -one
        for j in range(n):
            s = zero
            if p < m:
                s = A[w, p, j]
            elif j == i:
                s = sign
            for k in range(j):
                s = s - L[w, j, k] * W[w, slot, k]
            W[w, slot, j] = s / L[w, j, j]

    @wp.func
    def bound_value(b: wp.array2d(dtype=scalar), lb: wp.array2d(dtype=scalar), ub: wp.array2d(dtype=scalar),
                    w: int, p: int, m: int, n: int) -> scalar:
        """beta_p of the row n_p^T x >= beta_p (an equality row: a_p^T x = b_p)."""
        if p < m:
            return b[w, p]
        if p < m + n:
            return lb[w, p - m]
        return -ub[w, p - m - n]

    @wp.func
    def slack(x: wp.array2d(dtype=scalar), A: wp.array3d(dtype=scalar), b: wp.array2d(dtype=scalar),
              lb: wp.array2d(dtype=scalar), ub: wp.array2d(dtype=scalar), w: int, p: int, m: int, n: int) -> scalar:
        """n_p^T x - beta_p (negative: row p violated)."""
        if p < m:
            s = -b[w, p]
            for j in range(n):
                s = s + A[w, p, j] * x[w, j]
            return s
        if p < m + n:
            return x[w, p - m] - lb[w, p - m]
        return ub[w, p - m - n] - x[w, p - m - n]

    return row_column, bound_value, slack


@functools.cache
def _factorisation(scalar):
    """W = Q R of the active columns: a column appended, a column dropped."""
    _, dependence_tol, _ = _constants(scalar)
    zero = scalar(0.0)

    @wp.func
    def orthogonalize(W: wp.array3d(dtype=scalar), Q: wp.array3d(dtype=scalar), R: wp.array3d(dtype=scalar),
                      w: int, k: int, n: int) -> int:
        """Append column W[k] to Q R = W[:k] (Gram–Schmidt twice); 0 when it depends on them."""
        norm0 = zero
        for j in range(n):
            Q[w, k, j] = W[w, k, j]
            norm0 = norm0 + W[w, k, j] * W[w, k, j]
            R[w, j, k] = zero
        for _twice in range(2):
            for i in range(k):
                dot = zero
                for j in range(n):
                    dot = dot + Q[w, i, j] * Q[w, k, j]
                R[w, i, k] = R[w, i, k] + dot
                for j in range(n):
                    Q[w, k, j] = Q[w, k, j] - dot * Q[w, i, j]
        norm = zero
        for j in range(n):
            norm = norm + Q[w, k, j] * Q[w, k, j]
        norm = wp.sqrt(norm)
        if not (norm > dependence_tol * wp.sqrt(norm0)):
            return 0
        R[w, k, k] = norm
        for j in range(n):
            Q[w, k, j] = Q[w, k, j] / norm
        return 1

    @wp.func
    def drop(W: wp.array3d(dtype=scalar), Q: wp.array3d(dtype=scalar), R: wp.array3d(dtype=scalar),
             act: wp.array2d(dtype=int), u: wp.array2d(dtype=scalar), w: int, slot: int, nact: int, n: int) -> int:
        """Remove active slot ``slot`` and refactor the columns after it; the new count."""
        for k in range(slot, nact - 1):
            act[w, k] = act[w, k + 1]
            u[w, k] = u[w, k + 1]
            for j in range(n):
                W[w, k, j] = W[w, k + 1, j]
            orthogonalize(W, Q, R, w, k, n)
        return nact - 1

    return orthogonalize, drop


@functools.cache
def _upper(scalar):
    """Solves with the triangular R of the active columns."""

    @wp.func
    def upper_solve(R: wp.array3d(dtype=scalar), w: int, src: wp.array2d(dtype=scalar), dst: wp.array2d(dtype=scalar),
                    nact: int):
        """dst = R^-1 src on the first nact entries."""
        for kk in range(nact):
            k = nact - 1 - kk
            s = src[w, k]
            for i in range(k + 1, nact):
                s = s - R[w, k, i] * dst[w, i]
            dst[w, k] = s / R[w, k, k]

    return upper_solve


@functools.cache
def _minimiser(scalar):
    """The equality-constrained minimiser of the active rows and its multipliers."""
    zero = scalar(0.0)
    _, _, back_solve_transposed = _triangular(scalar)
    _, bound_value, _ = _rows(scalar)
    upper_solve = _upper(scalar)

    @wp.func
    def equality_minimiser(L: wp.array3d(dtype=scalar), Q: wp.array3d(dtype=scalar), R: wp.array3d(dtype=scalar),
                           act: wp.array2d(dtype=int), u: wp.array2d(dtype=scalar), g: wp.array2d(dtype=scalar),
                           tmp: wp.array2d(dtype=scalar), z: wp.array2d(dtype=scalar), x: wp.array2d(dtype=scalar),
                           b: wp.array2d(dtype=scalar), lb: wp.array2d(dtype=scalar), ub: wp.array2d(dtype=scalar),
                           w: int, nact: int, m: int, n: int):
        """min 1/2|y|^2 + g^T y s.t. W^T y = beta: h = R^-T beta + Q^T g, u = R^-1 h,
        y = Q h - g, x = L^-T y."""
        for k in range(nact):
            s = bound_value(b, lb, ub, w, act[w, k], m, n)
            for i in range(k):
                s = s - R[w, i, k] * tmp[w, i]
            dot = zero
            for j in range(n):
                dot = dot + Q[w, k, j] * g[w, j]
            tmp[w, k] = s / R[w, k, k]
            z[w, k] = dot  # Q^T g, added once every R^-T entry is known
        for k in range(nact):
            tmp[w, k] = tmp[w, k] + z[w, k]
        upper_solve(R, w, tmp, u, nact)
        for j in range(n):
            s = -g[w, j]
            for k in range(nact):
                s = s + Q[w, k, j] * tmp[w, k]
            z[w, j] = s
        back_solve_transposed(L, w, z, x, n)

    return equality_minimiser


@functools.cache
def _selection(scalar):
    """Which bound to add next, which to drop."""
    violation_tol, _, big = _constants(scalar)
    zero, one = scalar(0.0), scalar(1.0)

    @wp.func
    def most_violated(x: wp.array2d(dtype=scalar), lb: wp.array2d(dtype=scalar), ub: wp.array2d(dtype=scalar),
                      act: wp.array2d(dtype=int), w: int, nact: int, m: int, n: int) -> int:
        """The inactive bound row violated the most (beyond the tolerance), or -1."""
        best = int(-1)
        worst = zero
        for i in range(n):
            lo = lb[w, i]
            hi = ub[w, i]
            s_lo = x[w, i] - lo
            s_hi = hi - x[w, i]
            if lo > -big and s_lo < -violation_tol * (one + wp.abs(lo)) and s_lo < worst:
                worst = s_lo
                best = m + i
            if hi < big and s_hi < -violation_tol * (one + wp.abs(hi)) and s_hi < worst:
                worst = s_hi
                best = m + n + i
        for k in range(nact):
            if act[w, k] == best:  # rounding on an active row: never added twice
                best = -1
        return best

    @wp.func
    def most_negative(act: wp.array2d(dtype=int), u: wp.array2d(dtype=scalar), w: int, nact: int, m: int) -> int:
        """The active bound with the most negative multiplier, or -1."""
        slot = int(-1)
        lowest = zero
        for k in range(nact):
            if act[w, k] >= m and u[w, k] < lowest:
                lowest = u[w, k]
                slot = k
        return slot

    @wp.func
    def blocking(act: wp.array2d(dtype=int), u: wp.array2d(dtype=scalar), r: wp.array2d(dtype=scalar), w: int,
                 nact: int, m: int) -> int:
        """The active bound whose multiplier reaches zero first along -r (the partial
        step's ratio test), or -1."""
        t1 = big
        slot = int(-1)
        for k in range(nact):
            if act[w, k] >= m and r[w, k] > zero and u[w, k] / r[w, k] < t1:
                t1 = u[w, k] / r[w, k]
                slot = k
        return slot

    return most_violated, most_negative, blocking


@functools.cache
def _start(scalar):
    """The dual feasible start: equality rows and the last active bounds."""
    _, _, big = _constants(scalar)
    row_column, bound_value, _ = _rows(scalar)
    orthogonalize, drop = _factorisation(scalar)
    equality_minimiser = _minimiser(scalar)
    _, most_negative, _ = _selection(scalar)

    @wp.func
    def warm_start(L: wp.array3d(dtype=scalar), A: wp.array3d(dtype=scalar), b: wp.array2d(dtype=scalar),
                   lb: wp.array2d(dtype=scalar), ub: wp.array2d(dtype=scalar), W: wp.array3d(dtype=scalar),
                   Q: wp.array3d(dtype=scalar), R: wp.array3d(dtype=scalar), act: wp.array2d(dtype=int),
                   u: wp.array2d(dtype=scalar), g: wp.array2d(dtype=scalar), tmp: wp.array2d(dtype=scalar),
                   z: wp.array2d(dtype=scalar), x: wp.array2d(dtype=scalar), warm: wp.array2d(dtype=int),
                   n_warm: int, w: int, m: int, n: int) -> int:
        """Make the equality rows and the last active bounds active (dependent ones left
        out), then drop bounds with negative multipliers until none is left. Returns the
        active count; x is the minimiser on the active rows."""
        nact = int(0)
        for p in range(m + n_warm):
            row = p
            if p >= m:
                row = warm[w, p - m]
            if nact < n and wp.abs(bound_value(b, lb, ub, w, row, m, n)) < big:
                row_column(L, w, A, row, m, n, W, nact)
                if orthogonalize(W, Q, R, w, nact, n) == 1:
                    act[w, nact] = row
                    nact = nact + 1
        for _drop in range(n + 1):
            equality_minimiser(L, Q, R, act, u, g, tmp, z, x, b, lb, ub, w, nact, m, n)
            slot = most_negative(act, u, w, nact, m)
            if slot < 0:
                return nact
            nact = drop(W, Q, R, act, u, w, slot, nact, n)
        return nact

    return warm_start


@functools.cache
def _direction(scalar):
    """The step that adds row p: z (primal) and r (multipliers)."""
    _, dependence_tol, big = _constants(scalar)
    zero = scalar(0.0)
    row_column, _, slack = _rows(scalar)
    upper_solve = _upper(scalar)

    @wp.func
    def full_step(L: wp.array3d(dtype=scalar), A: wp.array3d(dtype=scalar), b: wp.array2d(dtype=scalar),
                  lb: wp.array2d(dtype=scalar), ub: wp.array2d(dtype=scalar), W: wp.array3d(dtype=scalar),
                  Q: wp.array3d(dtype=scalar), R: wp.array3d(dtype=scalar), r: wp.array2d(dtype=scalar),
                  z: wp.array2d(dtype=scalar), tmp: wp.array2d(dtype=scalar), x: wp.array2d(dtype=scalar),
                  w: int, p: int, nact: int, m: int, n: int) -> scalar:
        """W[nact] = w_p = L^-1 n_p, r = R^-1 Q^T w_p, z = w_p - Q Q^T w_p (in y = L^T x);
        returns t2, the step that meets row p (BIG when w_p lies in the active span)."""
        row_column(L, w, A, p, m, n, W, nact)
        for k in range(nact):
            dot = zero
            for j in range(n):
                dot = dot + Q[w, k, j] * W[w, nact, j]
            tmp[w, k] = dot
        upper_solve(R, w, tmp, r, nact)
        zz = zero
        ww = zero
        for j in range(n):
            s = W[w, nact, j]
            ww = ww + s * s
            for k in range(nact):
                s = s - Q[w, k, j] * tmp[w, k]
            z[w, j] = s
            zz = zz + s * s
        if zz > dependence_tol * dependence_tol * ww:
            return -slack(x, A, b, lb, ub, w, p, m, n) / zz
        return big

    return full_step


@functools.cache
def _addition(scalar):
    """Goldfarb and Idnani's step 2: make row p active, dropping bounds on the way."""
    _, _, big = _constants(scalar)
    zero = scalar(0.0)
    _, _, back_solve_transposed = _triangular(scalar)
    orthogonalize, drop = _factorisation(scalar)
    _, _, blocking = _selection(scalar)
    full_step = _direction(scalar)

    @wp.func
    def add_row(L: wp.array3d(dtype=scalar), A: wp.array3d(dtype=scalar), b: wp.array2d(dtype=scalar),
                lb: wp.array2d(dtype=scalar), ub: wp.array2d(dtype=scalar), W: wp.array3d(dtype=scalar),
                Q: wp.array3d(dtype=scalar), R: wp.array3d(dtype=scalar), act: wp.array2d(dtype=int),
                u: wp.array2d(dtype=scalar), r: wp.array2d(dtype=scalar), z: wp.array2d(dtype=scalar),
                tmp: wp.array2d(dtype=scalar), x: wp.array2d(dtype=scalar), iterations: wp.array(dtype=int),
                max_iterations: int, w: int, p: int, nact: int, m: int, n: int) -> int:
        """The new active count, or -INFEASIBLE - 1 (no step meets row p: the rows are
        infeasible) or -FAILED - 1 (the iteration cap)."""
        added = zero  # the new row's multiplier
        for _partial in range(max_iterations + 1):
            iterations[w] = iterations[w] + 1
            if iterations[w] > max_iterations:
                return -FAILED - 1
            t2 = full_step(L, A, b, lb, ub, W, Q, R, r, z, tmp, x, w, p, nact, m, n)
            slot = blocking(act, u, r, w, nact, m)
            t1 = big
            if slot >= 0:
                t1 = u[w, slot] / r[w, slot]
            elif t2 >= big:
                return -INFEASIBLE - 1
            t = wp.min(t1, t2)
            if t2 < big:  # x += t L^-T z
                back_solve_transposed(L, w, z, tmp, n)
                for j in range(n):
                    x[w, j] = x[w, j] + t * tmp[w, j]
            for k in range(nact):
                u[w, k] = u[w, k] - t * r[w, k]
            added = added + t
            if t2 < big and t2 <= t1:
                orthogonalize(W, Q, R, w, nact, n)
                act[w, nact] = p
                u[w, nact] = added
                return nact + 1
            nact = drop(W, Q, R, act, u, w, slot, nact, n)
        return -FAILED - 1

    return add_row


@functools.cache
def _iteration(scalar):
    """The whole method for one world, after the factorisation."""
    _, forward_solve, _ = _triangular(scalar)
    warm_start = _start(scalar)
    most_violated, _, _ = _selection(scalar)
    add_row = _addition(scalar)

    @wp.func
    def dual_active_set(L: wp.array3d(dtype=scalar), c: wp.array2d(dtype=scalar), A: wp.array3d(dtype=scalar),
                        b: wp.array2d(dtype=scalar), lb: wp.array2d(dtype=scalar), ub: wp.array2d(dtype=scalar),
                        W: wp.array3d(dtype=scalar), Q: wp.array3d(dtype=scalar), R: wp.array3d(dtype=scalar),
                        act: wp.array2d(dtype=int), u: wp.array2d(dtype=scalar), r: wp.array2d(dtype=scalar),
                        g: wp.array2d(dtype=scalar), z: wp.array2d(dtype=scalar), tmp: wp.array2d(dtype=scalar),
                        x: wp.array2d(dtype=scalar), warm: wp.array2d(dtype=int), n_warm: wp.array(dtype=int),
                        iterations: wp.array(dtype=int), n_bound: wp.array(dtype=int), max_iterations: int,
                        w: int, m: int, n: int) -> int:
        """The world's status; on SOLVED, x, and its active bounds kept for the next call."""
        forward_solve(L, w, c, g, n)  # g = L^-1 c
        nact = warm_start(L, A, b, lb, ub, W, Q, R, act, u, g, tmp, z, x, warm, n_warm[w], w, m, n)
        n_warm[w] = 0
        for _add in range(max_iterations + 1):
            p = most_violated(x, lb, ub, act, w, nact, m, n)
            if p < 0:
                count = int(0)
                for k in range(nact):
                    if act[w, k] >= m:
                        warm[w, count] = act[w, k]
                        count = count + 1
                n_warm[w] = count
                n_bound[w] = count
                return SOLVED
            nact = add_row(L, A, b, lb, ub, W, Q, R, act, u, r, z, tmp, x, iterations, max_iterations, w, p, nact,
                           m, n)
            if nact < 0:
                return -nact - 1
        return FAILED

    return dual_active_set


@functools.cache
def dual_active_set_kernel(scalar):
    """The solve kernel for one scalar type (``wp.float64`` or ``wp.float32``).

    Arrays (N worlds, n variables, m equality rows; ``m`` rows of ``A`` and ``b`` may be
    a dummy 1 when there are none):

    - inputs: ``H (NH, n, n)`` (NH = 1 when every world shares it, ``h_step`` = 0),
      ``c (N, n)``, ``A (N, m, n)``, ``b (N, m)``, ``lb, ub (N, n)`` (±inf: no bound),
      ``mask (N,)`` (0: skip the world);
    - warm start, read and written: ``warm (N, n)`` the bound rows active at the last
      solve (``n_warm (N,)`` of them; row ``m + i`` is ``x_i >= lb_i``, ``m + n + i``
      is ``x_i <= ub_i``);
    - outputs: ``x (N, n)`` (zero unless SOLVED), ``status (N,)``, ``iterations (N,)``,
      ``n_bound (N,)`` the number of active bounds at the solution;
    - workspace (:func:`workspace`): ``L, Q, R (N, n, n)``, ``W (N, n + 1, n)``,
      ``g, z, u, r, tmp (N, n)``, ``act (N, n)``.
    """
    zero = scalar(0.0)
    cholesky, _, _ = _triangular(scalar)
    dual_active_set = _iteration(scalar)

    @wp.kernel(module="unique")
    def solve(H: wp.array3d(dtype=scalar), h_step: int, c: wp.array2d(dtype=scalar), A: wp.array3d(dtype=scalar),
              b: wp.array2d(dtype=scalar), lb: wp.array2d(dtype=scalar), ub: wp.array2d(dtype=scalar),
              mask: wp.array(dtype=int), m: int, n: int, max_iterations: int,
              warm: wp.array2d(dtype=int), n_warm: wp.array(dtype=int),
              x: wp.array2d(dtype=scalar), status: wp.array(dtype=int), iterations: wp.array(dtype=int),
              n_bound: wp.array(dtype=int),
              L: wp.array3d(dtype=scalar), Q: wp.array3d(dtype=scalar), R: wp.array3d(dtype=scalar),
              W: wp.array3d(dtype=scalar), g: wp.array2d(dtype=scalar), z: wp.array2d(dtype=scalar),
              u: wp.array2d(dtype=scalar), r: wp.array2d(dtype=scalar), tmp: wp.array2d(dtype=scalar),
              act: wp.array2d(dtype=int)):
        w = wp.tid()
        iterations[w] = 0
        n_bound[w] = 0
        state = SKIPPED
        if mask[w] != 0:
            state = FAILED  # H not positive definite (or NaN)
            if cholesky(H, w * h_step, L, w, n) == 1:
                state = dual_active_set(L, c, A, b, lb, ub, W, Q, R, act, u, r, g, z, tmp, x, warm, n_warm,
                                        iterations, n_bound, max_iterations, w, m, n)
        status[w] = state
        if state != SOLVED:
            n_warm[w] = 0
            for j in range(n):
                x[w, j] = zero

    return solve


def workspace(nworld: int, n: int, scalar) -> tuple[list, list, wp.array]:
    """The solve kernel's workspace on the current device: ``[L, Q, R, W]``,
    ``[g, z, u, r, tmp]``, ``act``. W has n + 1 columns: the column of the row being
    added is formed before its step is known, when all n may already be active."""
    square = [wp.zeros((nworld, n, n), dtype=scalar) for _ in range(3)]
    columns = wp.zeros((nworld, n + 1, n), dtype=scalar)
    vectors = [wp.zeros((nworld, n), dtype=scalar) for _ in range(5)]
    return [*square, columns], vectors, wp.zeros((nworld, n), dtype=int)
