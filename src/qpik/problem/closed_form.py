r"""The QP's minimiser in closed form, in every world: the fast path of a control step.

When no limit binds, the QP's minimiser is that of :math:`\min \tfrac12 x^THx + c^Tx`
s.t. :math:`Ax = b`: :math:`x = H^{-1}(A^Ty - c)`, :math:`Sy = b + AH^{-1}c`,
:math:`S = AH^{-1}A^T`; the QP being strictly convex, an x that also meets every
inequality *is* its solution. Where bounds bind, :class:`HeldBounds` holds them: the
held dofs become :math:`x_i = v_i` (their bound's value) beside the hard rows, the rest
is the same closed form, and the answer is the QP's minimiser when it is inside every
limit, meets the hard rows and each held bound's multiplier has the sign of an active
bound. A wrong-signed bound is released, a crossed one held, and the system solved again
(``HELD_TRIES`` at most); the worlds left go to the solver, which also decides the worlds
whose general rows bind. Every answer is checked against the hard rows
(``EQUALITY_TOLERANCE``).
"""

from __future__ import annotations

import numpy as np

from ..numerics import both, cholesky_solve, everywhere, matvec, nowhere, outer_product, vecmat

# S is treated as singular (dependent hard rows) when its Cholesky factor's diagonal spans
# more than this ratio (the condition number of S is the square of it: 1e12).
SINGULAR_RATIO = 1e6
# Equality residual (relative to 1 + |b|) a closed-form step may leave, checked on every
# answer as the solvers' are: a nearly singular H or S loses digits no cheaper test foresees.
EQUALITY_TOLERANCE = 1e-10
# Closed forms a step may try with held bounds before the solver takes the world.
HELD_TRIES = 3
# A bound is active at a solver's answer within this (relative to 1 + |bound|).
ACTIVE_TOLERANCE = 1e-9


class EqualityQP:
    """The minimiser of ½xᵀHx + cᵀx s.t. Ax = b in ``n`` worlds of ``nv`` dofs and ``meq``
    rows, in closed form, optionally with some dofs held at given values, and its checks,
    with their buffers (allocated once)."""

    def __init__(self, n: int, nv: int, meq: int):
        self.meq = meq
        self.scaled, self.S = np.empty((n, meq, nv)), np.empty((n, meq, meq))  # Ã H̃⁻¹, Ã H̃⁻¹ Ãᵀ
        self.shift, self.x = np.empty((n, nv)), np.empty((n, nv))  # H̃⁻¹ c̃ (−v on held dofs), x
        self._r, self._residual = np.empty((n, meq)), np.empty((n, meq))  # b + A s (then y), A x
        self._x_row = self.x[:, None, :]
        self._everywhere = everywhere(n)
        self._gap, self._sides = np.empty((n, 2, nv)), np.tile(_SIDES, (n, 1, nv))
        self._held_inverse, self._gradient, self._multiplied = np.empty((n, nv)), np.empty((n, nv)), np.empty((n, nv))
        self._inverse = (None, None)  # (an inverse diagonal, its (N, 1, nv) view)

    def solve(self, inverse_diagonal, H, c, A, b, fixed=None, values=None):
        """``(x (N, nv), y (N, meq), ok (N,))``: ``ok`` where H is positive definite, S is not
        singular and x is finite and meets the rows to :data:`EQUALITY_TOLERANCE`; x and y
        mean nothing elsewhere (x is a buffer, overwritten by the next solve).

        Args:
            inverse_diagonal: (N, nv) H⁻¹ where H is diagonal, else None.
            H: (N, nv, nv) where it is not (read when ``inverse_diagonal`` is None).
            c: (N, nv); A: (N, meq, nv); b: (N, meq).
            fixed, values: (N, nv) the dofs held and their values (zero elsewhere), or None.

        With dofs held the free ones solve the same problem with the held ones' columns of
        A moved to b: x = (Ã H̃⁻¹)ᵀ y − s, S = Ã H̃⁻¹ Ãᵀ, S y = b + A s, where Ã is A without
        the held columns, H̃ is H with the identity's rows and columns on the held dofs and
        s = H̃⁻¹ c̃ holds −v there (so x = v on them).
        """
        meq, scaled, shift, x = self.meq, self.scaled, self.shift, self.x
        if inverse_diagonal is not None:
            ok = self._everywhere
            if fixed is not None:  # H̃⁻¹ zero on the held dofs, s = H̃⁻¹c − v
                inverse_diagonal = np.copyto(self._held_inverse, inverse_diagonal) or self._held_inverse
                np.copyto(inverse_diagonal, 0.0, where=fixed)
            np.multiply(A, self._rows_view(inverse_diagonal), scaled)
            np.multiply(inverse_diagonal, c, shift)
            if fixed is not None:
                np.subtract(shift, values, shift)
        else:
            ok = self._factor_dense(H, c, A, fixed, values)
        if not meq:
            np.negative(shift, x)
            return x, self._r, both(ok, np.isfinite(x).all(axis=1))
        outer_product(scaled, A, self.S)
        y = matvec(A, shift, self._r)
        np.add(y, b, y)
        _, solved_rows = cholesky_solve(self.S, y, SINGULAR_RATIO, in_place=True)
        vecmat(y, scaled, x)
        np.subtract(x, shift, x)
        met = rows_met(matvec(A, x, self._residual), b, EQUALITY_TOLERANCE, self._everywhere)
        if solved_rows is ok is met:
            return x, y, ok
        return x, y, both(solved_rows, ok, met)

    def _factor_dense(self, H, c, A, fixed, values) -> np.ndarray:
        """``scaled`` and ``shift`` of a dense H (held dofs: H̃, c̃ and Ã as in :meth:`solve`)."""
        meq = self.meq
        if fixed is not None:
            free = ~fixed
            c = np.where(fixed, -values, c + np.matmul(H, values[:, :, None])[:, :, 0])
            H = np.where(free[:, :, None] & free[:, None, :], H, 0.0)
            np.einsum("nii->ni", H)[...] += fixed
            A = A * free[:, None, :]
        solved, ok = cholesky_solve(H, np.concatenate([A.transpose(0, 2, 1), c[:, :, None]], axis=2))
        self.scaled[...], self.shift[...] = solved[:, :, :meq].transpose(0, 2, 1), solved[:, :, meq]
        return ok

    def gradient(self, inverse_diagonal, H, c, A, y) -> np.ndarray:
        """Hx + c − Aᵀy of the last x (the original H, c, A): on a held dof, the bound's
        multiplier (>= 0 at a lower bound, <= 0 at an upper one at the minimiser)."""
        g = self._gradient
        if inverse_diagonal is not None:
            np.divide(self.x, inverse_diagonal, g)
        else:
            matvec(H, self.x, g)
        np.add(g, c, g)
        if self.meq:
            g -= vecmat(y, A, self._multiplied)
        return g

    def _rows_view(self, inverse_diagonal: np.ndarray) -> np.ndarray:
        """``inverse_diagonal[:, None, :]``, kept while the same array comes."""
        if self._inverse[0] is not inverse_diagonal:
            self._inverse = (inverse_diagonal, inverse_diagonal[:, None, :])
        return self._inverse[1]

    def admits(self, box: np.ndarray, G: np.ndarray | None, h: np.ndarray | None) -> np.ndarray:
        """(N,) whether the last x is in the box and under the rows (:func:`inside`)."""
        return inside(self.x, box, G, h, self._gap, self._x_row, self._sides)


def equality_minimiser(inverse_diagonal, H, c, A, b):
    """:meth:`EqualityQP.solve` with buffers of its own."""
    return EqualityQP(len(c), c.shape[1], A.shape[1]).solve(inverse_diagonal, H, c, A, b)


def rows_met(Ax: np.ndarray, b: np.ndarray, tolerance: float, all_worlds: np.ndarray | None = None) -> np.ndarray:
    """(N,) whether |Ax − b| <= tolerance (1 + |b|) in each world (Euclidean norms; NaN
    fails), from A x (N, meq) (overwritten with the residual); ``all_worlds``: what to
    return when every world meets them (default ``everywhere``)."""
    if len(b) == 1:  # one world: in floats (cheaper than any NumPy call on a few rows)
        miss = scale = 0.0
        for value, target in zip(Ax[0].tolist(), b[0].tolist()):
            miss += (value - target) * (value - target)
            scale += target * target
        met = miss <= tolerance * tolerance * (1.0 + scale)
        return (everywhere(1) if all_worlds is None else all_worlds) if met else nowhere(1)
    np.subtract(Ax, b, Ax)
    if np.vdot(Ax, Ax) <= tolerance * tolerance:  # every world's miss is below the least bound
        return everywhere(len(b)) if all_worlds is None else all_worlds
    miss = np.einsum("ni,ni->n", Ax, Ax)
    return miss <= tolerance * tolerance * (1.0 + np.einsum("ni,ni->n", b, b))


_SIDES = np.array([1.0, -1.0])[None, :, None]  # x − lower >= 0, upper − x >= 0
_INF = float("inf")


def inside(x: np.ndarray, box: np.ndarray, G: np.ndarray | None = None, h: np.ndarray | None = None,
           gap: np.ndarray | None = None, x_row: np.ndarray | None = None, sides: np.ndarray = _SIDES) -> np.ndarray:
    """(N,) whether x is finite, in the box (N, 2, nv) and under the rows (exact
    comparisons: a point on a bound is inside; NaN, and ±inf on an absent bound, are not).
    One comparison decides the usual step where every world is inside; one world's, in floats."""
    if len(x) == 1 and G is None:
        lower, upper = box[0].tolist()
        for value, low, high in zip(x[0].tolist(), lower, upper):
            if not low <= value <= high or abs(value) == _INF:  # ±inf meets an absent bound's ±inf
                return nowhere(1)
        return everywhere(1)
    with np.errstate(invalid="ignore"):  # ±inf on an absent bound: inf − inf, NaN, outside
        gap = np.subtract(x[:, None, :] if x_row is None else x_row, box, gap)
    np.multiply(gap, sides, gap)
    ok = everywhere(len(x)) if gap.min(initial=np.inf) >= 0.0 else gap.reshape(len(x), -1).min(axis=1) >= 0.0
    if G is None or not G.shape[1]:
        return ok
    if ok is everywhere(len(x)):
        return (np.matmul(G, x[:, :, None])[:, :, 0] <= h).all(axis=1)
    worlds = np.flatnonzero(ok)  # the rows of the worlds in the box only (x finite there)
    ok[worlds] = (np.matmul(G[worlds], x[worlds, :, None])[:, :, 0] <= h[worlds]).all(axis=1)
    return ok


class HeldBounds:
    """The bounds held at each world's last answer, and the closed form that holds them
    (see the module's description). ``hold`` False: the plain closed form only (a
    tolerance-based solver's answers stay its own)."""

    def __init__(self, n: int, nv: int, meq: int, hold: bool = True):
        self.hold, self.meq = hold, meq
        self._qps: dict[int, EqualityQP] = {}
        self.lower = np.zeros((n, nv), dtype=bool)  # dofs held at their lower bound
        self.upper = np.zeros((n, nv), dtype=bool)
        self.holding = False  # whether any world holds a bound

    def remember(self, worlds: np.ndarray, x: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> None:
        """The bounds active at answers x (len(worlds), nv) of some worlds, held next step."""
        if not self.hold:
            return
        at_lower = np.isfinite(lower) & (np.abs(x - lower) <= ACTIVE_TOLERANCE * (1.0 + np.abs(lower)))
        at_upper = np.isfinite(upper) & ~at_lower & (np.abs(x - upper) <= ACTIVE_TOLERANCE * (1.0 + np.abs(upper)))
        self.lower[worlds], self.upper[worlds] = at_lower, at_upper
        self.holding = bool(self.lower.any() or self.upper.any())

    def solve(self, cost, A, b, box, G=None, h=None, worlds=None):
        """The QP's minimiser by closed forms with bounds held, in ``worlds`` (an index
        array, None: all).

        Returns:
            ``(x (len, nv), solved (len,))``: ``solved`` where x is the checked minimiser.
        """
        data = (cost.inverse_diagonal, cost.H, cost.c, A, b, box, G, h)
        if worlds is not None:
            data = tuple(None if a is None else a[worlds] for a in data)
        if not self.holding:  # the plain closed form first: most steps end here
            qp = self._qp(len(data[2]))
            x, _, ok = qp.solve(*data[:5])
            inside_box = qp.admits(*data[5:])
            if ok is inside_box:  # both everywhere: every world settled
                return x, ok
            solved = both(ok, inside_box)
            if not self.hold:
                return x, solved
            x, solved = x.copy(), np.array(solved)
            if solved.all():
                return x, solved
            ids = np.arange(len(x)) if worlds is None else worlds
            start = np.flatnonzero(ok & ~solved)  # held from the bounds it crossed
            box = data[5][start]
            self.lower[ids[start]], self.upper[ids[start]] = x[start] < box[:, 0], x[start] > box[:, 1]
        else:
            ids = np.arange(len(data[2])) if worlds is None else worlds
            x, solved, start = np.zeros((len(ids), A.shape[2])), np.zeros(len(ids), dtype=bool), np.arange(len(ids))
        self._held(data, ids, start, x, solved)
        self.holding = bool(self.lower.any() or self.upper.any())
        return x, solved

    def _qp(self, count: int) -> EqualityQP:
        """The closed form's buffers for ``count`` worlds."""
        if count not in self._qps:
            self._qps[count] = EqualityQP(count, self.lower.shape[1], self.meq)
        return self._qps[count]

    def _held(self, data, ids, todo, x, solved) -> None:
        """Closed forms with bounds held in the worlds ``todo`` (positions in ``ids``),
        until their answer is the minimiser, the held set stops changing or the tries run out."""
        for _ in range(HELD_TRIES):
            if not len(todo):
                return
            worlds = ids[todo]
            part = tuple(None if a is None else a[todo] for a in data)
            attempt, kept, (held_lower, held_upper, changed) = _attempt(self._qp(len(todo)), part, self.lower[worlds],
                                                                        self.upper[worlds])
            x[todo[kept]], solved[todo[kept]] = attempt[kept], True
            self.lower[worlds], self.upper[worlds] = held_lower, held_upper
            todo = todo[~kept & changed]  # the worlds whose held set changed: try again


def _attempt(qp: EqualityQP, data, held_lower, held_upper):
    """One closed form with the given bounds held: (x, kept (count,), (held lower, held
    upper, changed (count,)))."""
    inverse_diagonal, H, c, A, b, box, G, h = data
    lower, upper = box[:, 0], box[:, 1]
    fixed = held_lower | held_upper
    values = np.zeros_like(c)
    np.copyto(values, lower, where=held_lower)
    np.copyto(values, upper, where=held_upper)
    x, y, ok = qp.solve(inverse_diagonal, H, c, A, b, fixed, values)
    gradient = qp.gradient(inverse_diagonal, H, c, A, y)
    wrong = (held_lower & (gradient < 0.0)) | (held_upper & (gradient > 0.0))
    kept = ok & ~wrong.any(axis=1) & qp.admits(box, G, h)
    if kept.all():
        return x, kept, (held_lower, held_upper, ~kept)
    below, above = ~fixed & (x < lower), ~fixed & (x > upper)
    changed = ok & ~kept & (wrong | below | above).any(axis=1)
    return x, kept, ((held_lower & ~wrong) | below, (held_upper & ~wrong) | above, changed)
