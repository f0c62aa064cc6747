"""The any-robot fuzz's batched path: a case's problem on N = 4 worlds, each world against
its own one-world run.

A case's recipe (:mod:`.recipe`: how its tasks, limits and controller were built, from its
start) is replayed on a :class:`qpik.batch.Robot` of N = 4 worlds of its model, and on one
:class:`qpik.Robot` per world (``tests/engine/tasks_support.py``'s ``one_robot``). World 0
is the case itself; worlds 1–3 are moved from it by a random tangent step of 1e-6, 1e-2 or
0.3 (``displaced``, MuJoCo's ``mj_integratePos``), and so are their targets, by the same
scale: a position scaled and shifted, a rotation turned, a posture moved on the manifold
(an invalid target, the case's injected parameter, is the same in every world). Both roll
out the case's steps with the same controller and solver. At every step each world must
get what its own run gets:

- the same q̇, norm-wise: ‖q̇_N − q̇_1‖ ≤ 1e-10 (1 + ‖q̇_1‖) (``WORLDS``, the engine tests'
  figure for a world against its own run). Why it holds: the engine computes every world
  with the same formulas; N worlds go through its N > 1 primitives (NumPy across the
  world axis, the CPU back-end's Jacobians formed from ``cdof``), one world through its
  N = 1 ones (MuJoCo's routines on 2-D views, ``mj_jac`` in C) — the same arithmetic up to the order
  of sums, ~1e-16 relative per operation. A solve carries such a rounding of its data into
  q̇ multiplied by its condition number κ: up to about nv·ε·κ, below 1e-10 while κ stays
  under ~1e5/nv. The fuzz's steps go far past that (a cost only the 1e-12 regulariser
  makes definite, an undamped pseudoinverse near a singularity: κ of 1e11 to 1e17, seen
  with bit-identical J and v in both runs and q̇ 1e-9 to 1e-5 apart), so a step whose κ
  (:meth:`Judge.condition`: of the tasks' normal matrix, and of the system a QP with
  equality rows solves on its active set, ``_active_condition``) makes 10·nv·ε·κ the
  larger is held to that (the pseudoinverse's at the size of the terms its law sums:
  :meth:`Judge.magnification`), up to 1e-2
  (``conditioned_steps``, ``max_condition`` in the details say how often and how far).
  Past 1e-2 the step's data does not determine q̇ (a rounding moves it farther along the
  cost's flat directions), and what it does determine is judged: the same minimum, as an
  iterative solver's below, with the hard rows to the exact solvers' 1e-9
  (``undetermined_steps``);
- an iterative solver's (OSQP, ProxQP: ``ITERATIVE_SOLVERS``) the same q̇ to 1e-6, its
  promise, or the same minimum where its q̇ is not determined that well (flat directions):
  each level's cost at the batch's answer equal to that at the world's own to 1e-6
  relative (``PROXQP_COST_TOLERANCE``, as its repeat in another process is judged:
  :func:`.sweep.same_run`; a hierarchy's lower level past what the level above's two
  answers move its minimum, :func:`_moved_minimum`: the level above is itself pinned
  only to the solver's tolerance), the batch's answer on the world's hard rows to 1e-6 and
  inside its limits to 1e-9 ("batch_same_minimum"). It stops where its residuals pass its
  tolerance, so a rounding can end it an iteration earlier or later (each world has its
  own workspace, ``WorldSolver``, warm-started from that world's last answer, as its own
  run's is);
- or the same typed error: a world that fails is named by a
  :class:`~qpik.errors.WorldsFailed` whose reason is the type its own run raises (the
  other worlds still compared), and an error of the whole batch is its every world's
  (an :class:`~qpik.errors.InvalidWorlds` raised by the worlds it names, as an
  :class:`~qpik.errors.InvalidInput`, and by no other: a world it does not name was not
  solved, so its own run may still fail in the solve, with any other error).

After each step the batch's q is checked against MuJoCo's integration of its own q̇
(``mj_integratePos``, to 1e-10), then the one-world robot is put at the batch's q: each
step compares the same problem, and no rounding is carried by the loop. A world is
compared until it fails (in both runs) or its q̇ is not finite. The same holds of a build:
a step of the recipe that raises in the batch raises there in every world's replay (an
InvalidWorlds: in the worlds it names). Warnings count as the case's others do (a stray
one is a defect).
"""

from __future__ import annotations

import copy
import importlib.util
from pathlib import Path

import mujoco
import numpy as np
from scipy.optimize import lsq_linear

from qpik.errors import InvalidInput, InvalidWorlds, WorldsFailed

from qpik.problem import active_bounds

from .cases import ITERATIVE_HARD_TOLERANCE, ITERATIVE_SOLVERS, TOLERANCE as LIMIT_TOLERANCE, level_costs
from .checks import box_and_rows, crossing, hard_residual, velocity_excess
from .sweep import PROXQP_COST_TOLERANCE, cost_gap

# A step's rounding carried into q̇ by its solve (see the module): 10·nv·ε·κ relative (κ its
# condition number, ε the unit roundoff) where that exceeds 1e-10, and at most 1e-2 (κ near
# or past 1/ε: the step's answer is not determined; a world apart is still caught).
EPSILON = np.finfo(float).eps
CONDITIONED = 10.0  # a few roundings per entry of the solve's data
CONDITIONED_CAP = 1e-2
REGULARIZATION = 1e-12  # QPController's ε, the smallest of the controllers'

N = 4
# The worlds' tangent steps from the case's start (world 0: none), drawn per world.
SCALES = (1e-6, 1e-2, 0.3)
STREAM = 0xBA7C4  # the batched draws' own stream: the case's draws are not disturbed

_spec = importlib.util.spec_from_file_location(
    "tasks_support", Path(__file__).resolve().parents[2] / "tests" / "engine" / "tasks_support.py")
support = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(support)
TOLERANCE = support.WORLDS  # 1e-10


def gap(a: np.ndarray, b: np.ndarray) -> float:
    """‖a − b‖ / (1 + ‖b‖); 0 where both are the same (non-finite entries included), inf
    where their non-finite entries differ. Computed on a and b scaled by their largest
    |entry| (at least 1), so that entries near the float range give no overflow (and no
    RuntimeWarning of the harness's own, which the case would count as a stray one)."""
    if np.array_equal(a, b, equal_nan=True):
        return 0.0
    finite = np.isfinite(a)
    if not (np.array_equal(finite, np.isfinite(b)) and np.array_equal(a[~finite], b[~finite], equal_nan=True)):
        return np.inf
    a, b = a[finite], b[finite]
    scale = max(1.0, float(np.max(np.abs(a), initial=0.0)), float(np.max(np.abs(b), initial=0.0)))
    return float(np.linalg.norm(a / scale - b / scale) / (1.0 / scale + np.linalg.norm(b / scale)))


def check_batched(case, result: dict, steps: int, dt: float) -> None:
    """Case ``case`` (built, rolled out) on N worlds against each world's own run; adds
    "batch_same", "batch_same_minimum" or "batch_differs" to ``result``'s classes, and
    ``details["batched"]``."""
    recipe = case.recipe
    if recipe is None:  # stopped before its objects: the model or the start refused
        return
    rng = np.random.default_rng([case.seed, STREAM])
    scales = [0.0] + [float(rng.choice(SCALES)) for _ in range(N - 1)]
    starts = [recipe.q] + [support.displaced(recipe.model, recipe.q, int(rng.integers(2**31)), s)
                           for s in scales[1:]]
    targets = _world_targets(recipe, scales, rng)
    robots = _batch_robot(recipe.model, starts)
    singles = [support.one_robot(copy.copy(recipe.model), q) for q in starts]
    batch = recipe.replay(robots, _values(targets, None))
    alone = [recipe.replay(robot, _values(targets, w)) for w, robot in enumerate(singles)]
    record = {"worlds": N, "scales": scales, "steps": 0, "max_gap": 0.0, "max_cost_gap": 0.0, "minimum_steps": 0,
              "failed": {}}
    result["details"]["batched"] = record
    difference = _build_difference(batch, alone)
    controller = getattr(case, "controller", None)
    if difference is None and batch.failed is None and controller is not None:
        runs = [(robot, made.get(controller), Judge(case, made, dt, record, made.get(controller)))
                for robot, made in zip(singles, alone)]
        difference = _roll_out(batch.get(controller), robots, runs, steps, dt, record)
    if difference is not None:
        record["difference"] = difference
    result["classes"].append("batch_differs" if difference else "batch_same_minimum" if record["minimum_steps"]
                             else "batch_same")


def _batch_robot(model, starts):
    from qpik import batch

    robots = batch.Robot(copy.copy(model), n=len(starts), allow_outside_limits=True)
    robots.set_q(np.array(starts))
    robots.update_kinematics()
    return robots


# Each world's targets ---------------------------------------------------------------------

def _world_targets(recipe, scales: list[float], rng: np.random.Generator) -> dict[int, list[tuple]]:
    """id(step) → each world's arguments, for every set_target step of the recipe."""
    targets = {}
    for step in recipe.steps:
        if step.kind == "call" and step.name == "set_target":
            targets[id(step)] = [tuple(_moved(value, step.target, recipe.model, s, rng) for value in step.args)
                                 for s in scales]
    return targets


def _moved(value, task, model, scale: float, rng: np.random.Generator):
    """A target moved by ``scale``: a posture on the manifold, a rotation turned, a vector
    scaled and shifted; the same value where it is not a finite float array (an invalid
    one) or ``scale`` is 0."""
    from qpik import PostureTask

    if not (scale and isinstance(value, np.ndarray) and value.dtype.kind == "f" and value.ndim
            and np.all(np.isfinite(value))):
        return value
    if isinstance(task, PostureTask) and value.shape == (model.nq,):
        moved = value.copy()
        mujoco.mj_integratePos(model, moved, rng.uniform(-scale, scale, model.nv), 1.0)
        return moved
    if value.shape == (3, 3) and np.allclose(value.T @ value, np.eye(3), atol=1e-9):
        axis, turn, quat = rng.normal(size=3), np.empty(9), np.empty(4)
        mujoco.mju_axisAngle2Quat(quat, axis / np.linalg.norm(axis), scale * rng.uniform(-1, 1))
        mujoco.mju_quat2Mat(turn, quat)
        return turn.reshape(3, 3) @ value
    return value * (1.0 + scale * rng.uniform(-1, 1, value.shape)) + scale * rng.uniform(-1, 1, value.shape)


def _values(targets: dict, world: int | None):
    """The replay's arguments: world ``world``'s targets, or (None) the batch's, stacked
    along a leading world axis where every world's is an array of one shape."""
    def values(step, args, kwargs):
        if id(step) not in targets:
            return args, kwargs
        worlds = targets[id(step)]
        if world is not None:
            return worlds[world], kwargs
        stacked = []
        for i, first in enumerate(worlds[0]):
            each = [w[i] for w in worlds]
            same_shape = all(isinstance(v, np.ndarray) and v.shape == np.shape(first) for v in each)
            stacked.append(np.stack(each) if same_shape else first)
        return tuple(stacked), kwargs
    return values


# Comparing ----------------------------------------------------------------------------------

def _same_error(batch_error: Exception, alone: Exception | None, world: int) -> bool:
    """Whether world ``world``'s own run raised what the batch's error says of it. An
    InvalidWorlds stops the batch before it solves: a world it does not name must pass
    the checks (no InvalidInput), and its own run's later failure is one the batch never
    reached (any-robot case 8480: world 3's own run fails DivergenceError where the batch
    stops on world 0's configuration at 1.1e10)."""
    if isinstance(batch_error, InvalidWorlds):
        named = world in batch_error.worlds.tolist()
        return isinstance(alone, InvalidInput) == named
    return alone is not None and type(alone) is type(batch_error)


def _name(exc: Exception | None) -> str | None:
    return None if exc is None else f"{type(exc).__name__}: {str(exc)[:200]}"


def _build_difference(batch, alone) -> dict | None:
    """Where the replays disagree: the batch's step failed and a world's did not fail
    there with that error, or the batch built and a world did not."""
    where, error = batch.failed if batch.failed is not None else (None, None)
    for w, made in enumerate(alone):
        at, own = made.failed if made.failed is not None else (None, None)
        if where is None:
            same = at is None
        else:
            same = _same_error(error, own if at == where else None, w) and (at is None or at >= where)
        if not same:
            return {"at": "build", "world": w, "what": "error", "batch": _name(error), "batch_step": where,
                    "alone": _name(own), "alone_step": at}
    return None


def _step(controller):
    """(q̇ or None, the exception or None)."""
    try:
        return np.array(controller.compute_velocity(), dtype=float), None
    except Exception as exc:  # noqa: BLE001 - compared, whatever it is
        return None, exc


def _roll_out(controller, robots, singles: list, steps: int, dt: float, record: dict) -> dict | None:
    """Step the batch and each world's own run; the first difference, or None."""
    alive = list(range(len(singles)))
    for step in range(steps):
        qdots, error = _step(controller)
        if isinstance(error, WorldsFailed):
            qdots = np.array(error.qdot, dtype=float)
        elif error is not None:
            return _whole_error(error, singles, alive, step, record)
        failed = {} if error is None else {int(w): why for w, why in error.reasons.items()}
        answers = {}
        for w in alive:
            robot, alone, judge = singles[w]
            q_before = robot.q.copy()
            qdot, own = _step(alone)
            verdict = _world_verdict(qdots[w], failed.get(w), qdot, own, lambda a, b: judge(robot, a, b, q_before))
            if isinstance(verdict, dict):  # with the world's largest |q| (past MuJoCo's mjMAXVAL, 1e10,
                # the batch's forward resets a world to qpos0, the one-world robot does not)
                return {"at": f"step {step}", "world": w, **verdict, "largest_q": float(np.max(np.abs(q_before)))}
            if own is not None:
                record["failed"][str(w)] = f"{type(own).__name__} at step {step}"
            elif np.all(np.isfinite(qdot)):
                answers[w] = qdot
        record["steps"] = step + 1
        alive = list(answers)
        if not alive:
            return None
        qdots[~np.isfinite(qdots).all(axis=1)] = 0.0
        robots.integrate(qdots, dt)
        for w in answers:
            robot = singles[w][0]
            expected = robot.q.copy()  # (the batch's q before the step)
            mujoco.mj_integratePos(robot.model, expected, qdots[w], dt)
            moved = gap(robots.q[w], expected)
            if moved > TOLERANCE:
                return {"at": f"step {step} (integration)", "world": w, "what": "q", "gap": moved}
            robot.q[:] = robots.q[w]  # the next step compares the same problem (its update refuses a q past range)
    return None


def _world_verdict(batch_qdot, batch_reason: str | None, qdot, own: Exception | None, judge):
    """World w's batch answer (q̇, or the reason WorldsFailed gives) against its own run's
    (q̇, or its error): "same", "minimum" (``judge``'s verdict on two answers), or how they
    differ (a dict)."""
    if batch_reason is None and own is None:
        return judge(batch_qdot, qdot)
    if batch_reason is not None and own is not None and batch_reason.split(":", 1)[0] == type(own).__name__:
        return "same"
    return {"what": "error", "batch": batch_reason[:200] if batch_reason else "solved",
            "alone": _name(own) or "solved"}


class Judge:
    """Two answers of world w's step, the batch's and its own run's, judged on the world's
    own tasks and limits (``made``: its replay; see the module): "same" where q̇ agree to
    ``TOLERANCE``, or to nv·ε·κ where the step's condition number κ (:meth:`condition`)
    makes that larger; for an iterative solver, else "minimum" where both are minimisers
    of the step (each level's cost equal to ``PROXQP_COST_TOLERANCE``, a lower level's past
    what the level above moves it, the batch's answer on the hard rows to 1e-6 and inside
    the limits to 1e-9); else how they differ."""

    def __init__(self, case, made, dt: float, record: dict, controller=None):
        self.controller = controller  # the world's own (its last step's QP data, read by condition)
        self.iterative = case.params.get("solver") in ITERATIVE_SOLVERS
        self.kind = case.params["controller"]
        self.levels = [[made.get(task) for task in level] for level in case.levels or []]
        self.hard = [made.get(task) for task in case.tasks if task.hard] if self.kind in ("qp", "hqp") else []
        self.limits = [made.get(limit) for limit in case.limits]
        self.damping = case.params.get("damping", 0.0)
        self.dt, self.record = dt, record

    def __call__(self, robot, batch_qdot, qdot, q_before):
        record = self.record
        difference = gap(batch_qdot, qdot)
        record["max_gap"] = max(record["max_gap"], difference)
        if difference <= TOLERANCE:
            return "same"
        if not self.iterative:
            kappa = self.condition(len(qdot), qdot)
            record["max_condition"] = max(record.get("max_condition", 0.0), kappa)
            spread = CONDITIONED * len(qdot) * EPSILON * kappa * self.magnification(qdot)
            if difference <= min(CONDITIONED_CAP, spread):
                record["conditioned_steps"] = record.get("conditioned_steps", 0) + 1
                return "same"
            if spread <= CONDITIONED_CAP:  # q̇ is determined to the spread: they differ
                return {"what": "qdot", "gap": difference, "condition": kappa, "batch": batch_qdot.tolist(),
                        "alone": qdot.tolist()}
            record["undetermined_steps"] = record.get("undetermined_steps", 0) + 1
        elif difference <= ITERATIVE_HARD_TOLERANCE:
            return "same"
        verdict = self._promises(robot, batch_qdot, qdot, q_before)
        if verdict is None:
            record["minimum_steps"] += 1
            return "minimum"
        return {"what": "qdot", "gap": difference, **verdict}

    def condition(self, nv: int, qdot: np.ndarray | None = None) -> float:
        """κ of the matrix the step's solve factors, on the world's own tasks as last
        updated — the factor by which the solve can carry a rounding into q̇. The
        pseudoinverse law: J Jᵀ + λ² I of its primary tasks. The QP controllers: Σ w JᵀJ
        plus the smallest of their regularisations, 1e-12, on the dofs some task's rows
        reach (a dof no row reaches is a block of its own, ε q̇ = 0, solved exactly), the
        largest over the levels a hierarchy or SNS solves one after the other (a level
        restricted to the null space of those above keeps its eigenvalues within its
        own: Cauchy's interlacing); and, where a QP has equality rows (hard rows; a
        hierarchy level's rows above it), κ of the system its answer solves on its
        active set (:func:`_active_condition`), the largest over the levels."""
        if self.kind == "pinv":
            jacobian = self._primary_jacobian(nv)
            with np.errstate(over="ignore", invalid="ignore"):
                return _condition(jacobian @ jacobian.T + self.damping**2 * np.eye(len(jacobian)))
        groups = self.levels if self.kind in ("hqp", "sns") else [[task for level in self.levels for task in level]]
        kappa = max((_condition(_normal(tasks, nv)) for tasks in groups), default=1.0)
        return max([kappa, *self._active_conditions(qdot)])

    def _primary_jacobian(self, nv: int) -> np.ndarray:
        """The pseudoinverse law's primary tasks' J, stacked (as last updated)."""
        return np.vstack([np.asarray(t.jacobian, dtype=float).reshape(-1, nv) for t in self.levels[0]])

    def _active_conditions(self, qdot: np.ndarray | None) -> list[float]:
        """κ of each equality-constrained QP the step solved (:func:`_active_condition`),
        from the world's own controller's last step: the QP controller's hard rows, H and
        box at its answer; each hierarchy level's rows (those above it, then its hard
        rows), Hessian (its regularisation included) and box at that level's answer."""
        controller = self.controller
        if controller is None or qdot is None:
            return []
        if self.kind == "qp":
            return [_active_condition(controller.H, controller.A, qdot, controller.lb, controller.ub)]
        if self.kind != "hqp":
            return []
        return [_active_condition(level.cost.world_hessian(0), level.A[0], answer, controller.lb, controller.ub)
                for level, answer in zip(controller.levels, np.atleast_2d(controller.level_velocities))]

    def magnification(self, qdot: np.ndarray) -> float:
        """How much larger than q̇ the terms are that the step's solve sums into it:
        (1 + that size) / (1 + ‖q̇‖), at least 1. The rounding a solve leaves is ε·κ of
        the size of what it computes, not of the answer that remains once those terms
        cancel. The pseudoinverse law q̇ = Jᵀz + q̇₀ − Jᵀz₀, z = (J Jᵀ + λ² I)⁻¹ v and
        z₀ = (J Jᵀ + λ² I)⁻¹ J q̇₀, sums terms of sizes ‖J‖‖z‖, ‖q̇₀‖, ‖J‖‖z₀‖: case 7270,
        a posture 1e6 rad away, q̇₀ 9.5e6 projected to a q̇ of 15 (the worlds 1.9e-9 apart,
        ε·‖q̇₀‖); case 2110, a singular J damped by λ = 8e-4, z 1.1e9 for a q̇ of 0.9 (the
        worlds one ulp of 1e9, 1.2e-7, apart). The QP controllers' answers are judged at
        their own size (1)."""
        if self.kind != "pinv":
            return 1.0
        nv = len(qdot)
        jacobian = self._primary_jacobian(nv)
        v = np.concatenate([np.asarray(t.target_velocity, dtype=float).ravel() for t in self.levels[0]])
        secondary = np.zeros(nv)  # q̇₀ = I[dofs]ᵀ v of the joint-space secondary task
        if len(self.levels) > 1:
            task = self.levels[1][0]
            secondary[np.asarray(task.dofs)] = np.asarray(task.target_velocity, dtype=float)
        with np.errstate(all="ignore"):
            system = jacobian @ jacobian.T + self.damping**2 * np.eye(len(jacobian))
            try:
                z = np.linalg.solve(system, np.stack([v, jacobian @ secondary], axis=1))
            except np.linalg.LinAlgError:
                return 1.0  # singular: κ is inf, the cap decides
            size = np.linalg.norm(jacobian, 2) * np.linalg.norm(z, axis=0).sum() + np.linalg.norm(secondary)
        return max(1.0, (1.0 + size) / (1.0 + float(np.linalg.norm(qdot)))) if np.isfinite(size) else 1.0

    def _promises(self, robot, batch_qdot, qdot, q_before) -> dict | None:
        """None where the batch's answer is a minimiser of the world's step as its own is:
        each level's cost equal to ``PROXQP_COST_TOLERANCE`` (a hierarchy's lower level:
        past what the level above's two answers move its minimum, :func:`_moved_minimum`),
        the hard rows met to the solver's promise (1e-6 iterative, 1e-9 exact), inside the
        limits to 1e-9."""
        hard = self.kind == "pinv"  # the law weighs its hard rows as its soft ones
        gaps, moved = [], []
        box = None
        for k, (a, b) in enumerate(zip(level_costs(self.levels, batch_qdot, hard),
                                       level_costs(self.levels, qdot, hard))):
            gaps.append(cost_gap(a, b))
            if gaps[-1] > PROXQP_COST_TOLERANCE and k and self.kind == "hqp" and np.isfinite(a - b):
                box = box_and_rows(robot, [], self.limits, self.dt)[2:] if box is None else box
                low, high = _moved_minimum(self.levels, k, batch_qdot, qdot, *box) or (0.0, 0.0)
                gaps[-1] = max(low - (a - b), (a - b) - high, 0.0) / (1.0 + abs(a))
                moved.append(gaps[-1] <= PROXQP_COST_TOLERANCE)
        costs = max(gaps, default=0.0)
        self.record["max_cost_gap"] = max(self.record["max_cost_gap"], costs)
        missed = max((hard_residual(task, batch_qdot) for task in self.hard), default=0.0)
        excess = max(crossing(robot, self.limits, q_before, batch_qdot, self.dt),
                     velocity_excess(self.limits, batch_qdot))
        hard_tolerance = ITERATIVE_HARD_TOLERANCE if self.iterative else LIMIT_TOLERANCE
        if costs <= PROXQP_COST_TOLERANCE and missed <= hard_tolerance and excess <= LIMIT_TOLERANCE:
            if any(moved):
                self.record["moved_minimum_steps"] = self.record.get("moved_minimum_steps", 0) + 1
            return None
        return {"cost_gap": costs, "hard_residual": missed, "limit_excess": excess}


def _moved_minimum(levels, k: int, batch_qdot, qdot, lower, upper, G, h) -> tuple[float, float] | None:
    """How far level ``k``'s minimum f_k moves between the two runs (batch minus own),
    from below and above, because the level above answered each run differently; None
    where an answer is not a minimiser of the level to 1e-6 (:func:`_multipliers`).

    Level k minimises f_k (its soft tasks' cost) under C q̇ = d, d = J_above q̇*_{k-1}
    (the levels above's rows at their answer), its hard rows and the limits. Its minimum
    W(d) is convex in d (a convex QP's value as a function of the right side of its
    equalities), and −λ, λ any multipliers of those rows at a minimiser, is a subgradient
    of W at d. So with Δd = d_b − d_a: −λ_a·Δd ≤ W(d_b) − W(d_a) ≤ −λ_b·Δd, exactly, not
    to first order. Each run's final q̇ keeps the rows above (Δd = J_above (q̇_b − q̇_a))
    and level k's rows (f_k and ∇f_k there are the level's own), and the multipliers pair
    with every minimiser; the level's own solve (its tolerance, the ε that breaks its ties)
    adds its ``PROXQP_COST_TOLERANCE``. An
    OSQP level's answer is pinned only to its tolerance at the level's scale: any-robot
    case 9430, step 5, level 1 (a frame task 1e6 m away, c 2.3e10) answered 0.036 apart
    (costs 1.1e-8 apart), so level 2's d differs by 0.042 and its cost by −1.9e-3 of
    1.8e3 (1.06e-6), inside [−2.2e-3, −1.6e-3]."""
    nv = len(qdot)
    above = np.vstack([np.asarray(t.jacobian, dtype=float).reshape(-1, nv) for level in levels[:k] for t in level])
    rows = np.vstack([above, *(np.asarray(t.jacobian, dtype=float).reshape(-1, nv) for t in levels[k] if t.hard)])
    soft = [t for t in levels[k] if not t.hard]
    ends = []
    with np.errstate(all="ignore"):
        moved = above @ (batch_qdot - qdot)
        for x in (qdot, batch_qdot):
            multipliers = _multipliers(_gradient(soft, x, nv), rows, x, lower, upper, G, h)
            if multipliers is None:
                return None
            ends.append(-float(multipliers[: len(above)] @ moved))
    return (min(ends), max(ends)) if np.all(np.isfinite(ends)) else None


def _gradient(tasks, qdot: np.ndarray, nv: int) -> np.ndarray:
    """∇ of ½ Σ w (J q̇ − v)² over ``tasks`` at ``qdot``."""
    gradient = np.zeros(nv)
    for task in tasks:
        jacobian = np.asarray(task.jacobian, dtype=float).reshape(-1, nv)
        residual = jacobian @ qdot - np.asarray(task.target_velocity, dtype=float).ravel()
        gradient += jacobian.T @ (np.broadcast_to(np.asarray(task.weight, dtype=float), len(residual)) * residual)
    return gradient


def _multipliers(gradient, rows, x, lower, upper, G, h) -> np.ndarray | None:
    """Multipliers λ of the equality rows at ``x`` of min f, rows q̇ = d, lb ≤ q̇ ≤ ub,
    G q̇ ≤ h (f's ``gradient`` at x): the least-squares fit of ∇f + rowsᵀλ − ν_lb + ν_ub
    + Gᵀμ = 0 with ν, μ ≥ 0 on the bounds and rows x is on to 1e-6 (an iterative solver
    leaves its answer that far inside a bound it holds; case 9430: 1.5e-8). None where the
    data is not finite or the fit leaves more than 1e-6 of ∇f (x is then no minimiser, and
    its fitted λ bounds nothing; case 9430's fits leave 1e-10 to 3e-9)."""
    near = ITERATIVE_HARD_TOLERANCE
    at_lower = np.isfinite(lower) & (x - lower <= near * (1.0 + np.abs(lower)))
    at_upper = np.isfinite(upper) & (upper - x <= near * (1.0 + np.abs(upper)))
    at_row = np.isfinite(h) & (h - G @ x <= near * (1.0 + np.abs(h)))
    identity = np.eye(len(x))
    columns = np.hstack([rows.T, -identity[:, at_lower], identity[:, at_upper], G[at_row].T])
    if not (np.all(np.isfinite(columns)) and np.all(np.isfinite(gradient))):
        return None
    scale = np.linalg.norm(columns, axis=0)
    scale[scale == 0.0] = 1.0  # (a zero row: its multiplier stays 0)
    columns /= scale
    free = np.zeros(columns.shape[1])
    free[: len(rows)] = -np.inf
    fit = lsq_linear(columns, -gradient, bounds=(free, np.inf), method="bvls")
    if not np.linalg.norm(columns @ fit.x + gradient) <= near * (1.0 + np.linalg.norm(gradient)):
        return None
    return fit.x[: len(rows)] / scale[: len(rows)]


def _normal(tasks, nv: int) -> np.ndarray:
    """Σ w JᵀJ + 1e-12 I over ``tasks``, on the dofs their rows reach."""
    normal = np.zeros((nv, nv))
    with np.errstate(over="ignore", invalid="ignore"):  # (entries past 1e154 overflow: κ is then inf)
        for task in tasks:
            jacobian = np.asarray(task.jacobian, dtype=float).reshape(-1, nv)
            weight = np.broadcast_to(np.abs(np.asarray(task.weight, dtype=float)), len(jacobian))
            normal += jacobian.T @ (weight[:, None] * jacobian)
    reached = np.flatnonzero(normal.diagonal() != 0.0)
    return normal[np.ix_(reached, reached)] + REGULARIZATION * np.eye(len(reached))


def _condition(matrix: np.ndarray) -> float:
    """κ of a symmetric positive semi-definite ``matrix`` (inf where singular or not finite)."""
    if not len(matrix):
        return 1.0
    if not np.all(np.isfinite(matrix)):
        return np.inf
    eigenvalues = np.linalg.eigvalsh(matrix)
    smallest, largest = float(eigenvalues[0]), float(eigenvalues[-1])
    return largest / smallest if smallest > 0.0 and largest < smallest * 1e300 else np.inf


def _active_condition(hessian: np.ndarray, rows: np.ndarray, answer: np.ndarray, lower: np.ndarray,
                      upper: np.ndarray) -> float:
    """κ of the system a QP min ½ xᵀHx + cᵀx, C x = d, lb ≤ x ≤ ub solves at ``answer``:
    with the bounds it holds fixed (F the dofs it does not hold), x_F is the solution of
    the KKT system [[H_F, C_Fᵀ], [C_F, 0]], and what the solvers factor for it is H_F
    (quadprog's Cholesky) and its Schur complement M = C_F H_F⁻¹ C_Fᵀ (the dual active-set
    solvers, DAQP and quadprog, factor M over their active rows, bounds among them:
    ``qpik.solvers.nullspace``; the closed form's K = R D⁻¹ Rᵀ is M for the hard rows). A
    rounding of d is carried into the multipliers by κ(M) and into x through H_F⁻¹ C_Fᵀ:
    κ = max(κ(H_F), κ(M)), κ(M) = κ(C_F H_F^(-1/2))². Where C_F's rows depend on each other
    (more rows than free dofs, or the free part of a row in the span of the others, as
    when the answer of the level above holds a bound of a dof they reach) M is singular:
    the rows fix a point only while d is exactly consistent, the worlds' rounding of d
    (J_above q̇*_{k-1}, each world's own) makes it inconsistent by ε‖d‖, and where the
    answer lands is the solver's handling of that (the dependent row DAQP drops; quadprog
    failing, then the guard's retry with 1e-9 of damping, which it keeps for its next 8
    steps): κ is inf (or past 1/ε, M's smallest singular value a rounding). Any-robot case 110 (level 1: 6 rows above on the 5 free dofs they
    reach, d 3e-14 apart, q̇ 1.7e-9) and case 3730 (level 1: 3 rows on 3 dofs, one held at
    its bound; quadprog failed at step 0 in one run and not the other, whose guard then
    damped steps 1–4: q̇ 3e-9 apart on a dof of curvature 0.23, 1e-9/0.23 of its velocity).
    1 where there are no rows or no free dof."""
    rows = np.asarray(rows, dtype=float)
    if not rows.size:
        return 1.0
    at_lower, at_upper = active_bounds(answer, lower, upper)
    free = ~(at_lower | at_upper)
    if not free.any():
        return 1.0
    with np.errstate(over="ignore", invalid="ignore"):
        hessian = np.asarray(hessian, dtype=float)[np.ix_(free, free)]
        if not (np.all(np.isfinite(hessian)) and np.all(np.isfinite(rows))):
            return np.inf
        curvatures, basis = np.linalg.eigh(hessian)
        if not curvatures[0] > 0.0:
            return np.inf
        scaled = (rows[:, free] @ basis) / np.sqrt(curvatures)  # C_F H_F^(-1/2), in H_F's eigenbasis
        if len(scaled) > scaled.shape[1]:
            return np.inf  # more rows than free dofs: dependent
        singular = np.linalg.svd(scaled, compute_uv=False)
        kappa_h = float(curvatures[-1] / curvatures[0])
    if not singular[-1] > 0.0 or not singular[0] < singular[-1] * 1e150:
        return np.inf
    return max(kappa_h, float(singular[0] / singular[-1]) ** 2)


def _whole_error(error: Exception, singles: list, alive: list[int], step: int, record: dict) -> dict | None:
    """An error of the whole batch (not WorldsFailed): each world still compared must
    raise it alone (an InvalidWorlds: the worlds it names, and those only)."""
    record["whole"] = f"{_name(error)} at step {step}"
    if isinstance(error, InvalidWorlds) and not set(error.worlds.tolist()) & set(alive):
        return None  # it names worlds that already failed, whose own runs stopped there
    for w in alive:
        own = _step(singles[w][1])[1]
        if not _same_error(error, own, w):
            return {"at": f"step {step}", "world": w, "what": "error", "batch": _name(error),
                    "alone": _name(own) or "solved"}
    return None
