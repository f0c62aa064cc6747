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



import warp as wp

# Status codes, the same as qpik.batch.backends.base.QPStatus.
SOLVED, INFEASIBLE, FAILED, SKIPPED = 0, 1, 2, 3


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
    - workspace: ``L, Q, R, W (N, n, n)``, ``g, z, u, r, tmp (N, n)``, ``act (N, n)``.
    """
    big = scalar(1e300) if scalar == wp.float64 else scalar(1e30)
    # A bound counts as violated beyond this (times 1 + |bound|); an added column as
    # dependent below this fraction of its norm.
    violation_tol = scalar(1e-11) if scalar == wp.float64 else scalar(1e-5)
    dependence_tol = scalar(1e-12) if scalar == wp.float64 else scalar(1e-6)
    zero = scalar(0.0)
    one = scalar(1.0)

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
    def back_solve_transposed(L: wp.array3d(dtype=scalar), w: int, src: wp.array2d(dtype=scalar),
                              dst: wp.array2d(dtype=scalar), n: int):
        """dst = L^-T src."""
        for jj in range(n):
            j = n - 1 - jj
            s = src[w, j]
            for k in range(j + 1, n):
                s = s - L[w, k, j] * dst[w, k]
            dst[w, j] = s / L[w, j, j]

    @wp.func
    def row_column(L: wp.array3d(dtype=scalar), w: int, A: wp.array3d(dtype=scalar), p: int, m: int, n: int,
                   W: wp.array3d(dtype=scalar), slot: int):
        """W[slot] = L^-1 n_p, the active column of row p (forward substitution)."""
        if p < m:
            for j in range(n):
                s = A[w, p, j]
                for k in range(j):
                    s = s - L[w, j, k] * W[w, slot, k]
                W[w, slot, j] = s / L[w, j, j]
        else:
            i = p - m
            sign = one
            if i >= n:
                i = i - n
                sign = -one
            for j in range(n):
                s = zero
                if j == i:
                    s = sign
                if j >= i:
                    for k in range(i, j):
                        s = s - L[w, j, k] * W[w, slot, k]
                    s = s / L[w, j, j]
                W[w, slot, j] = s

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

    @wp.func
    def orthogonalize(W: wp.array3d(dtype=scalar), Q: wp.array3d(dtype=scalar), R: wp.array3d(dtype=scalar),
                      w: int, k: int, n: int) -> int:
        """Append column W[k] to Q R = W[:k]; 0 when it depends on the first k."""
        norm0 = zero
        for j in range(n):
            Q[w, k, j] = W[w, k, j]
            norm0 = norm0 + W[w, k, j] * W[w, k, j]
        for i in range(k):
            R[w, i, k] = zero
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
        """Remove active slot ``slot`` and refactor; returns the new count."""
        for k in range(slot, nact - 1):
            act[w, k] = act[w, k + 1]
            u[w, k] = u[w, k + 1]
            for j in range(n):
                W[w, k, j] = W[w, k + 1, j]
        for k in range(slot, nact - 1):
            orthogonalize(W, Q, R, w, k, n)
        return nact - 1

    @wp.func
    def equality_minimiser(L: wp.array3d(dtype=scalar), Q: wp.array3d(dtype=scalar), R: wp.array3d(dtype=scalar),
                           act: wp.array2d(dtype=int), u: wp.array2d(dtype=scalar), g: wp.array2d(dtype=scalar),
                           tmp: wp.array2d(dtype=scalar), z: wp.array2d(dtype=scalar), x: wp.array2d(dtype=scalar),
                           b: wp.array2d(dtype=scalar), lb: wp.array2d(dtype=scalar), ub: wp.array2d(dtype=scalar),
                           w: int, nact: int, m: int, n: int):
        """x and u of min 1/2|y|^2 + g^T y s.t. W^T y = beta: h = R^-T beta + Q^T g,
        u = R^-1 h, y = Q h - g, x = L^-T y."""
        for k in range(nact):
            s = bound_value(b, lb, ub, w, act[w, k], m, n)
            for i in range(k):
                s = s - R[w, i, k] * tmp[w, i]
            tmp[w, k] = s / R[w, k, k]
        for k in range(nact):
            dot = zero
            for j in range(n):
                dot = dot + Q[w, k, j] * g[w, j]
            tmp[w, k] = tmp[w, k] + dot
        for kk in range(nact):
            k = nact - 1 - kk
            s = tmp[w, k]
            for i in range(k + 1, nact):
                s = s - R[w, k, i] * u[w, i]
            u[w, k] = s / R[w, k, k]
        for j in range(n):
            s = -g[w, j]
            for k in range(nact):
                s = s + Q[w, k, j] * tmp[w, k]
            z[w, j] = s
        back_solve_transposed(L, w, z, x, n)

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
        if best >= 0:
            for k in range(nact):
                if act[w, k] == best:  # rounding on an active row: never re-added
                    best = -1
        return best

    @wp.func
    def warm_start(L: wp.array3d(dtype=scalar), A: wp.array3d(dtype=scalar), b: wp.array2d(dtype=scalar),
                   lb: wp.array2d(dtype=scalar), ub: wp.array2d(dtype=scalar), W: wp.array3d(dtype=scalar),
                   Q: wp.array3d(dtype=scalar), R: wp.array3d(dtype=scalar), act: wp.array2d(dtype=int),
                   u: wp.array2d(dtype=scalar), g: wp.array2d(dtype=scalar), tmp: wp.array2d(dtype=scalar),
                   z: wp.array2d(dtype=scalar), x: wp.array2d(dtype=scalar), warm: wp.array2d(dtype=int),
                   n_warm: int, w: int, m: int, n: int) -> int:
        """The equality rows and the last active bounds, then bounds with negative
        multipliers dropped: a dual feasible start. Returns the active count."""
        nact = int(0)
        for p in range(m + n_warm):
            row = p
            if p >= m:
                row = warm[w, p - m]
            beta = bound_value(b, lb, ub, w, row, m, n)
            if nact < n and wp.abs(beta) < big:
                row_column(L, w, A, row, m, n, W, nact)
                if orthogonalize(W, Q, R, w, nact, n) == 1:
                    act[w, nact] = row
                    nact = nact + 1
        for _drop in range(n + 1):
            equality_minimiser(L, Q, R, act, u, g, tmp, z, x, b, lb, ub, w, nact, m, n)
            slot = int(-1)
            lowest = zero
            for k in range(nact):
                if act[w, k] >= m and u[w, k] < lowest:
                    lowest = u[w, k]
                    slot = k
            if slot < 0:
                return nact
            nact = drop(W, Q, R, act, u, w, slot, nact, n)
        return nact

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
        state = int(-1)  # until decided
        if mask[w] == 0:
            state = SKIPPED
        elif cholesky(H, w * h_step, L, w, n) == 0:
            state = FAILED
        if state < 0:
            for j in range(n):  # g = L^-1 c
                s = c[w, j]
                for k in range(j):
                    s = s - L[w, j, k] * g[w, k]
                g[w, j] = s / L[w, j, j]
            nact = warm_start(L, A, b, lb, ub, W, Q, R, act, u, g, tmp, z, x, warm, n_warm[w], w, m, n)
            count = int(0)
            while state < 0:
                p = most_violated(x, lb, ub, act, w, nact, m, n)
                if p < 0:
                    state = SOLVED
                up = zero
                added = int(0)
                while state < 0 and added == 0:
                    count = count + 1
                    if count > max_iterations:
                        state = FAILED
                        break
                    # w_p = L^-1 n_p in W[nact]; r = R^-1 Q^T w_p; z_y = w_p - Q Q^T w_p
                    row_column(L, w, A, p, m, n, W, nact)
                    for k in range(nact):
                        dot = zero
                        for j in range(n):
                            dot = dot + Q[w, k, j] * W[w, nact, j]
                        tmp[w, k] = dot
                    for kk in range(nact):
                        k = nact - 1 - kk
                        s = tmp[w, k]
                        for i in range(k + 1, nact):
                            s = s - R[w, k, i] * r[w, i]
                        r[w, k] = s / R[w, k, k]
                    zz = zero
                    ww = zero
                    for j in range(n):
                        s = W[w, nact, j]
                        ww = ww + s * s
                        for k in range(nact):
                            s = s - Q[w, k, j] * tmp[w, k]
                        z[w, j] = s
                        zz = zz + s * s
                    t1 = big
                    slot = int(-1)
                    for k in range(nact):
                        if act[w, k] >= m and r[w, k] > zero and u[w, k] / r[w, k] < t1:
                            t1 = u[w, k] / r[w, k]
                            slot = k
                    t2 = big
                    moves = zz > dependence_tol * dependence_tol * ww
                    if moves:
                        t2 = -slack(x, A, b, lb, ub, w, p, m, n) / zz
                    if slot < 0 and not moves:
                        state = INFEASIBLE
                        break
                    t = wp.min(t1, t2)
                    if moves:  # x += t L^-T z_y
                        back_solve_transposed(L, w, z, tmp, n)
                        for j in range(n):
                            x[w, j] = x[w, j] + t * tmp[w, j]
                    for k in range(nact):
                        u[w, k] = u[w, k] - t * r[w, k]
                    up = up + t
                    if moves and t2 <= t1:
                        orthogonalize(W, Q, R, w, nact, n)
                        act[w, nact] = p
                        u[w, nact] = up
                        nact = nact + 1
                        added = 1
                    else:
                        nact = drop(W, Q, R, act, u, w, slot, nact, n)
            iterations[w] = count
            if state == SOLVED:
                k_warm = int(0)
                for k in range(nact):
                    if act[w, k] >= m:
                        warm[w, k_warm] = act[w, k]
                        k_warm = k_warm + 1
                n_warm[w] = k_warm
                n_bound[w] = k_warm
            else:
                n_warm[w] = 0
        status[w] = state
        if state != SOLVED:
            for j in range(n):
                x[w, j] = zero

    return solve
