r"""The QP's minimiser in closed form, in every world: the fast path of a control step.

The cost is kept as rows: :math:`\tfrac12\|R_1x - r_1\|^2 + \tfrac12 x^TDx + c^Tx` with
:math:`R_1` the soft tasks' rows scaled by √w, D a positive diagonal (ε, the joint-space
tasks' weights, the Levenberg–Marquardt damping) and c the joint-space tasks' linear
term; the hard rows are :math:`R_2x = r_2`. When no limit binds, the QP's minimiser is

.. math::
    x = D^{-1}(R^T z - c),\qquad
    \big(R D^{-1} R^T + \mathrm{diag}(I, 0)\big)\, z = r + R D^{-1} c

(:class:`DampedLeastSquares`): one Cholesky solve of as many unknowns as rows. Where D is
only a tiny ε on joints the rows constrain (a floating base no posture covers), x loses
digits to cancellation; the residual of the system says so and a step or two of iterative
refinement with the same matrix brings them back. The QP being strictly convex, an x that also meets every inequality *is* its
solution. Where bounds bind, :class:`HeldBounds` holds them: a held dof has
:math:`D^{-1} = 0` and its bound's value moved to the right-hand side, so one shape serves
every active set, and the answer is the QP's minimiser when it is inside every limit,
meets the hard rows and each held bound's multiplier has the sign of an active bound. A
wrong-signed bound is released, a crossed one held, and the system solved again
(``HELD_TRIES`` at most); the worlds left go to the solver, which also decides the worlds
whose general rows bind. Every answer is checked against the hard rows
(``EQUALITY_TOLERANCE``).
"""

from __future__ import annotations

import math

import numpy as np

from ..solvers.base import EXACT_EQUALITY_TOLERANCE, misses_met
from ..numerics import (all_finite, both, cholesky_factor, cholesky_substitute, everywhere, lu_solve, matvec, nowhere,
                        outer_product, norm, vecmat, worlds_first)

# The system is treated as singular (dependent hard rows) when a Cholesky pivot falls
# below 1/this of its row's scale (its condition number is then past the square: 1e12).
SINGULAR_RATIO = 1e6
# Equality residual (relative to 1 + |b|) a closed-form step may leave, checked on every
# answer as the solvers' are: a nearly singular system loses digits no cheaper test foresees.
EQUALITY_TOLERANCE = 1e-10
# Past EQUALITY_TOLERANCE, a soft row's miss may be its rounding, nv·ε of its terms'
# sizes, and the hard rows' the solvers' promise (see _within_rounding).
EPSILON = float(np.finfo(float).eps)
# Closed forms a step may try with held bounds before the solver takes the world.
HELD_TRIES = 3
# Steps of iterative refinement a closed form may take while its residual is above
# REFINE_TOLERANCE (relative to 1 + |rhs|; a few roundings): a tiny ε on dofs the rows
# constrain loses digits in x = D⁻¹(...), which the residual shows.
REFINEMENTS, REFINE_TOLERANCE = 2, 1e-13
# A bound is active at a solver's answer within this (relative to 1 + |bound|).
ACTIVE_TOLERANCE = 1e-9
# A polished answer costing at most this fraction more than the solver's is as cheap: the
# cost is flat to rounding along directions only ε weighs (it lost by 4e-16 relative).
COST_ROUNDING = 1e-12


class DampedLeastSquares:
    """The minimiser above in ``n`` worlds of ``nv`` dofs, ``soft_rows`` rows R₁ and
    ``rows`` rows R₂ (the equalities), optionally with some dofs held at given values, and
    its checks, with their buffers (allocated once)."""

    def __init__(self, n: int, nv: int, soft_rows: int, rows: int):
        m = soft_rows + rows
        self.soft_rows, self.rows = soft_rows, rows
        # R D⁻¹, and R D⁻¹ Rᵀ + diag(I, 0) stored worlds last (as the products and solves form it)
        self.scaled, self.K = np.empty((n, m, nv)), worlds_first(np.empty((m, m, n)))
        self._soft_diagonal = np.einsum("nii->ni", self.K)[:, :soft_rows]  # a writable view
        self.z, self._Rv, self._fit = np.empty((n, m)), np.empty((n, m)), np.empty((n, m))
        self._soft_fit, self._soft_z = self._fit[:, :soft_rows], self.z[:, :soft_rows]
        self.x, self._held_inverse = np.empty((n, nv)), np.empty((n, nv))
        self._gradient, self._Rz = np.empty((n, nv)), np.empty((n, nv))
        self._gap, self._sides = np.empty((n, 2, nv)), np.tile(_SIDES, (n, 1, nv))
        self._x_row = self.x[:, None, :]
        self._everywhere = everywhere(n)
        self._square = not soft_rows and rows == nv  # the hard rows alone fix x (see _point)

    def solve(self, dinv, R, rhs, c=None, fixed=None, values=None):
        """``(x (N, nv), z (N, m) or None, ok (N,))``: ``ok`` where the system is numerically
        positive definite (:func:`~qpik.numerics.cholesky_factor` within ``SINGULAR_RATIO``),
        x is finite and the system's residual (the hard rows' miss among it) is within
        ``EQUALITY_TOLERANCE`` (1 + |rhs_i|) row by row, or within what a float x can meet
        (:meth:`_within_rounding`); x and z mean nothing elsewhere (buffers,
        overwritten by the next solve). z is None where the hard rows alone fix x
        (:meth:`_point`).

        Args:
            dinv: (N, nv) D⁻¹.
            R: (N, soft_rows + rows, nv) [R₁; R₂]; rhs: (N, soft_rows + rows) [r₁; r₂].
            c: (N, nv), or None for zero.
            fixed, values: (N, nv) the dofs held and their values (zero elsewhere), or None.
        """
        if self._square and fixed is None:
            return self._point(R, rhs)
        scaled, K, x, z = self.scaled, self.K, self.x, self.z
        right = rhs
        if fixed is not None:  # D⁻¹ = 0 on the held dofs, their values moved to the right
            np.copyto(self._held_inverse, dinv)
            dinv = self._held_inverse
            np.copyto(dinv, 0.0, where=fixed)
            right = np.subtract(rhs, matvec(R, values, self._Rv), self._Rv)
        np.multiply(R, dinv[:, None, :], scaled)
        outer_product(scaled, R, K)
        if self.soft_rows:
            self._soft_diagonal += 1.0
        if c is None:
            np.copyto(z, right)
        else:
            np.add(right, matvec(scaled, c, z), z)
        self._factor, solved = cholesky_factor(K, SINGULAR_RATIO)
        cholesky_substitute(self._factor, z, solved, in_place=True)
        vecmat(z, R, x)
        if c is not None:
            x -= c
        x *= dinv
        if fixed is not None:
            x += values
        met = self._fits(R, rhs, REFINE_TOLERANCE)
        if met is not self._everywhere:
            met = self._refined(R, rhs, met, solved)
        if R.shape[1]:  # a non-finite x leaves a non-finite residual (NaN even where R is 0)
            return x, z, solved if met is solved else both(solved, met)
        return x, z, self._everywhere if all_finite(x) else np.isfinite(x).all(axis=1)

    def _point(self, A, b):
        """:meth:`solve` where the hard rows are as many as the dofs, no soft row and no dof
        held: they alone fix x = A⁻¹b (one LU; nothing is left to minimise, and z is not
        computed: None), checked as every answer is."""
        x, solved = lu_solve(A, b, self.x)
        met = self._fits(A, b, EQUALITY_TOLERANCE)
        if met is not self._everywhere and not met.all():
            met = self._within_rounding(A, b, met)
        return x, None, solved if met is solved else both(solved, met)

    def _refined(self, R, rhs, met, solved) -> np.ndarray:
        """Up to ``REFINEMENTS`` steps of iterative refinement of x and z while some world's
        residual is above ``REFINE_TOLERANCE``, with the solve's factor of K (``solved``
        where it was accepted); whether each world's residual is then within
        ``EQUALITY_TOLERANCE``, or within what a float x can meet (:meth:`_within_rounding`)."""
        for _ in range(REFINEMENTS):
            if met is not nowhere(len(met)) and met.all():
                return self._everywhere
            correction = cholesky_substitute(self._factor, self._fit, solved)  # K δz = −residual
            if len(met) > 1:  # only where the residual asks: each world's answer its own (one world's is not met)
                correction[met] = 0.0
            self.z -= correction
            self.x -= vecmat(correction, self.scaled, self._Rz)
            met = self._fits(R, rhs, REFINE_TOLERANCE)
        if met.all():
            return met
        met = self._fits(R, rhs, EQUALITY_TOLERANCE)
        return met if met.all() else self._within_rounding(R, rhs, met)

    def _within_rounding(self, R, rhs, met) -> np.ndarray:
        """``met``, or where the miss (in ``_fit``) is what a float x can meet: each soft
        row's within ``EQUALITY_TOLERANCE`` (1 + |r_i|) plus its rounding, nv·ε (|R_i||x| +
        |z_i|) (a large x cancelling to a small target: any-robot case 8850), a non-finite
        term failing; the hard rows' within ``EQUALITY_TOLERANCE`` (1 + |b_i|) each, or
        together within the promise a solver's answer is held to (its rule,
        :func:`~qpik.solvers.base.misses_met`, at ``EXACT_EQUALITY_TOLERANCE``)."""
        m = self.soft_rows
        terms = matvec(np.abs(R[:, :m]), np.abs(self.x), np.empty((len(R), m))) + np.abs(self.z[:, :m])
        allowed = EQUALITY_TOLERANCE * (1.0 + np.abs(rhs[:, :m])) + R.shape[2] * EPSILON * terms
        soft = (np.abs(self._fit[:, :m]) <= allowed).all(axis=1) & np.isfinite(terms).all(axis=1)
        miss, b = self._fit[:, m:], rhs[:, m:]
        each = (np.abs(miss) <= EQUALITY_TOLERANCE * (1.0 + np.abs(b))).all(axis=1)
        together = misses_met(miss, R[:, m:], self.x, b, EXACT_EQUALITY_TOLERANCE)
        return met | (soft & (each | together))

    def _fits(self, R, rhs, tolerance: float) -> np.ndarray:
        """(N,) whether R x + [z₁; 0] meets rhs to ``tolerance`` row by row (the system's
        residual, :func:`rows_met`), leaving the miss in ``_fit``."""
        fit = matvec(R, self.x, self._fit)
        if self.soft_rows:
            self._soft_fit += self._soft_z
        return rows_met(fit, rhs, tolerance)

    def gradient(self, damping, R, c) -> np.ndarray:
        """Dx + c − Rᵀz of the last solve (D = ``damping``, c None for zero): zero on the
        free dofs; on a held dof, the bound's multiplier (>= 0 at a lower bound, <= 0 at an
        upper one at the minimiser)."""
        g = np.multiply(damping, self.x, self._gradient)
        if c is not None:
            g += c
        g -= vecmat(self.z, R, self._Rz)
        return g

    def objective(self, x, damping, R, rhs, c) -> np.ndarray:
        r""":math:`\tfrac12 \|R_1 x - r_1\|^2 + \tfrac12 x^T D x + c^T x` of x (N, nv) in
        every world (N,)."""
        m = self.soft_rows
        residual = np.einsum("nij,nj->ni", R[:, :m], x) - rhs[:, :m]
        value = 0.5 * np.einsum("ni,ni->n", residual, residual) + 0.5 * np.einsum("ni,ni,ni->n", x, damping, x)
        return value if c is None else value + np.einsum("ni,ni->n", c, x)

    def admits(self, box: np.ndarray, G: np.ndarray | None, h: np.ndarray | None) -> np.ndarray:
        """(N,) whether the last x is in the box and under the rows (:func:`inside`)."""
        return inside(self.x, box, G, h, self._gap, self._x_row, self._sides)


def active_bounds(x: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The bounds x is on, to ``ACTIVE_TOLERANCE`` relative: (at lower, at upper). An absent
    bound (±inf) is never reached (|x − inf| <= inf would say it is)."""
    at_lower = np.isfinite(lower) & (np.abs(x - lower) <= ACTIVE_TOLERANCE * (1.0 + np.abs(lower)))
    at_upper = np.isfinite(upper) & ~at_lower & (np.abs(x - upper) <= ACTIVE_TOLERANCE * (1.0 + np.abs(upper)))
    return at_lower, at_upper


def rows_met(Ax: np.ndarray, b: np.ndarray, tolerance: float) -> np.ndarray:
    """(N,) whether every row's miss |A_i x − b_i| <= tolerance (1 + |b_i|) in each world
    (NaN fails), from A x (N, m) (overwritten with the residual). Row by row: a far row (a
    soft target 1e9 away) must not excuse a near row's miss, which a norm-wise test lets
    hide the digits a closed form loses (refinement would not start)."""
    np.subtract(Ax, b, Ax)
    miss = norm(Ax)
    if miss <= tolerance:  # every row's miss is below the least bound
        return everywhere(len(b))
    # One world's rows all within their bounds miss by at most tolerance |1 + |b|| <=
    # tolerance (√m + |b|): past that, one row is out (a refinement's usual first check).
    if len(b) == 1 and miss > tolerance * (math.sqrt(b.size) + norm(b)):
        return nowhere(1)
    return (np.abs(Ax) <= tolerance * (1.0 + np.abs(b))).all(axis=1)


_SIDES = np.array([1.0, -1.0])[None, :, None]  # x − lower >= 0, upper − x >= 0


def inside(x: np.ndarray, box: np.ndarray, G: np.ndarray | None = None, h: np.ndarray | None = None,
           gap: np.ndarray | None = None, x_row: np.ndarray | None = None, sides: np.ndarray = _SIDES) -> np.ndarray:
    """(N,) whether x is finite, in the box (N, 2, nv) and under the rows (exact
    comparisons: a point on a bound is inside; NaN and ±inf are not). One comparison
    decides the usual step where every world is inside; one world's, in floats."""
    if len(x) == 1 and G is None:
        values = x[0].tolist()
        for value, low, high in zip(values, *box[0].tolist()):
            if not low <= value <= high:  # NaN fails too
                return nowhere(1)
        finite = math.isfinite(sum(values)) or all(map(math.isfinite, values))  # (the sum may overflow)
        return everywhere(1) if finite else nowhere(1)
    if not all_finite(x):  # decided on the finite worlds alone (inf − inf would be NaN)
        finite = np.isfinite(x).all(axis=1)
        if not finite.all():
            if finite.any():
                finite[finite] = inside(x[finite], box[finite], None if G is None else G[finite],
                                        None if h is None else h[finite])
            return finite
    gap = np.subtract(x[:, None, :] if x_row is None else x_row, box, gap)
    np.multiply(gap, sides, gap)
    ok = everywhere(len(x)) if gap.min(initial=np.inf) >= 0.0 else gap.reshape(len(x), -1).min(axis=1) >= 0.0
    if G is None or not G.shape[1]:
        return ok
    if ok is everywhere(len(x)):
        return (np.matmul(G, x[:, :, None])[:, :, 0] <= h).all(axis=1)
    worlds = np.flatnonzero(ok)  # the rows of the worlds in the box only
    ok[worlds] = (np.matmul(G[worlds], x[worlds, :, None])[:, :, 0] <= h[worlds]).all(axis=1)
    return ok


class HeldBounds:
    """The bounds held at each world's last answer, and the closed form that holds them
    (see the module's description), for a cost of ``soft_rows`` rows and ``rows`` hard
    rows. ``hold`` False: the plain closed form only (a tolerance-based solver's answers
    stay its own)."""

    def __init__(self, n: int, nv: int, soft_rows: int, rows: int, hold: bool = True):
        self.hold, self.shape = hold, (nv, soft_rows, rows)
        self._forms: dict[int, DampedLeastSquares] = {}
        self.lower = np.zeros((n, nv), dtype=bool)  # dofs held at their lower bound
        self.upper = np.zeros((n, nv), dtype=bool)
        self.holding = False  # whether any world holds a bound

    def remember(self, worlds: np.ndarray, x: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> None:
        """The bounds active at answers x (len(worlds), nv) of some worlds, held next step."""
        if not self.hold:
            return
        self.lower[worlds], self.upper[worlds] = active_bounds(x, lower, upper)
        self.holding = bool(self.lower.any() or self.upper.any())

    def solve(self, cost, box, G=None, h=None, worlds=None):
        """The QP's minimiser by closed forms with bounds held, in ``worlds`` (an index
        array, None: all), for the :class:`~qpik.problem.Cost` ``cost`` (its rows, D and c).

        Returns:
            ``(x (len, nv), solved (len,))``: ``solved`` where x is the checked minimiser.
        """
        data = (cost.dinv, cost.damping, cost.R, cost.rhs, cost.linear, box, G, h)
        if worlds is not None:
            data = tuple(None if a is None else a[worlds] for a in data)
        if not self.holding:  # the plain closed form first: most steps end here
            form = self._form(len(box) if worlds is None else len(worlds))
            x, _, ok = form.solve(data[0], data[2], data[3], data[4])
            inside_box = form.admits(data[5], data[6], data[7])
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
            crossed = data[5][start]
            self.lower[ids[start]], self.upper[ids[start]] = x[start] < crossed[:, 0], x[start] > crossed[:, 1]
        else:
            ids = np.arange(len(box)) if worlds is None else worlds
            x, solved, start = np.zeros((len(ids), self.shape[0])), np.zeros(len(ids), dtype=bool), np.arange(len(ids))
        self._held(data, ids, start, x, solved)
        self.holding = bool(self.lower.any() or self.upper.any())
        return x, solved

    def polish(self, cost, box, G, h, w: int, x: np.ndarray) -> np.ndarray:
        """A solver's answer x (nv,) of world ``w`` replaced by the minimiser the held-bounds
        iteration finds from the bounds x is on, where it costs no more (to rounding:
        ``COST_ROUNDING``); x where a general row is on its bound. Solvers meet loosely a
        cost that only ε makes definite in some directions (a hierarchy's level; ProxQP held
        wrong bounds at 2% more cost: any-robot case 9190)."""
        if G is not None and G.shape[1] and not (G[w] @ x < h[w]).all():
            return x
        held = self.lower[w].copy(), self.upper[w].copy()
        self.lower[w], self.upper[w] = active_bounds(x, *box[w])
        data = tuple(None if a is None else a[w:w + 1]
                     for a in (cost.dinv, cost.damping, cost.R, cost.rhs, cost.linear, box, G, h))
        answer, solved = np.zeros((1, len(x))), np.zeros(1, dtype=bool)
        self._held(data, np.array([w]), np.arange(1), answer, solved)
        self.lower[w], self.upper[w] = held
        if not solved[0]:
            return x
        form, (damping, R, rhs, c) = self._form(1), data[1:5]
        before = form.objective(x[None], damping, R, rhs, c)[0]
        kept = form.objective(answer, damping, R, rhs, c)[0] <= before + COST_ROUNDING * abs(before)
        return answer[0] if kept else x

    def _form(self, count: int) -> DampedLeastSquares:
        """The closed form's buffers for ``count`` worlds."""
        if count not in self._forms:
            self._forms[count] = DampedLeastSquares(count, *self.shape)
        return self._forms[count]

    def _held(self, data, ids, todo, x, solved) -> None:
        """Closed forms with bounds held in the worlds ``todo`` (positions in ``ids``),
        until their answer is the minimiser, the held set stops changing or the tries run out."""
        for _ in range(HELD_TRIES):
            if not len(todo):
                return
            every = len(todo) == len(x)  # todo is every position: the data as it is
            worlds = ids if every else ids[todo]
            part = data if every else tuple(None if a is None else a[todo] for a in data)
            attempt, kept, (held_lower, held_upper, changed) = _attempt(self._form(len(todo)), part,
                                                                        self.lower[worlds], self.upper[worlds])
            if every and kept.all():
                x[...], solved[...] = attempt, True
            else:
                x[todo[kept]], solved[todo[kept]] = attempt[kept], True
            self.lower[worlds], self.upper[worlds] = held_lower, held_upper
            todo = todo[~kept & changed]  # the worlds whose held set changed: try again


def _attempt(form: DampedLeastSquares, data, held_lower, held_upper):
    """One closed form with the given bounds held: (x, kept (count,), (held lower, held
    upper, changed (count,)))."""
    dinv, damping, R, rhs, c, box, G, h = data
    lower, upper = box[:, 0], box[:, 1]
    fixed = held_lower | held_upper
    values = np.zeros_like(dinv)
    np.copyto(values, lower, where=held_lower)
    np.copyto(values, upper, where=held_upper)
    x, _, ok = form.solve(dinv, R, rhs, c, fixed, values)
    gradient = form.gradient(damping, R, c)
    wrong = (held_lower & (gradient < 0.0)) | (held_upper & (gradient > 0.0))
    kept = ok & ~wrong.any(axis=1) & form.admits(box, G, h)
    if kept.all():
        return x, kept, (held_lower, held_upper, ~kept)
    below, above = ~fixed & (x < lower), ~fixed & (x > upper)
    changed = ok & ~kept & (wrong | below | above).any(axis=1)
    return x, kept, ((held_lower & ~wrong) | below, (held_upper & ~wrong) | above, changed)
