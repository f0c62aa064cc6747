"""One any-robot fuzz case: built from its seed, rolled out, every returned step checked.

A case draws a model (:mod:`.models`), a start inside, on or outside the joint
ranges, 1–4 tasks of every kind (soft or hard, gains up to K·Δt just below 2, reachable,
far, huge or malformed targets), the limits, and a controller (QPController with each
solver (the closed form always tried first), HierarchicalController with 2–3 levels,
SNSController, PseudoinverseController). One case in six injects one invalid parameter,
which must be refused with a typed error. :func:`run_case` returns the case's failure
classes (:data:`CLASSES`) with the details that reproduce it.
"""

from __future__ import annotations

import hashlib
import time
import traceback
import warnings
from pathlib import Path

import mujoco
import numpy as np

from qpik.errors import GainWarning, InvalidInput, QpikError, SolverError

from .checks import box_and_rows, crossing, hard_residual, lp_feasible, velocity_excess
from .models import _log_uniform, random_mjcf, short_name, third_party_models
from .recipe import Recipe

DT = 0.002
STEPS = 25
# A step that takes more CPU time than this is a hang. CPU time (the process's, BLAS
# threads included), not wall time: a step that waits for a busy machine's cores is not
# slow, one that computes for 100 ms is, however idle the machine.
SLOW_STEP_S = 0.100
TOLERANCE = 1e-9
# A hard row's promise per solver (docs/controllers.md, "answers checked"): 1e-9 for the
# closed form and the active-set solvers; the tolerance-based OSQP and ProxQP promise
# their documented 1e-6 (relative to 1 + |v|). Their residuals are reported apart.
ITERATIVE_SOLVERS = ("osqp", "proxqp")
ITERATIVE_HARD_TOLERANCE = 1e-6
ALL_SOLVERS = ("daqp", "osqp", "proxqp", "quadprog")

# (key, description, a defect?)
CLASSES = (
    ("ok", "every returned step kept every promise", False),
    ("typed", "stopped with a typed error the LP confirms (infeasible, or a law without limits)", False),
    ("rejected", "an invalid parameter refused with a typed error", False),
    ("untyped", "untyped exception (not a QpikError)", True),
    ("nonfinite", "non-finite answer", True),
    ("crossing", "limit crossed by more than 1e-9 (position or speed)", True),
    ("hard_missed", "hard task missed on a returned step (by > 1e-9 relative; OSQP, ProxQP: > 1e-6)", True),
    ("invalid_accepted", "invalid parameter accepted", True),
    ("typed_on_feasible", "typed error on a step an LP finds feasible with a margin", True),
    ("misleading", "misleading diagnosis (limits blamed though feasible, or infeasibility as SolverError)", True),
    ("nondeterministic", "another process gave a different q trajectory", True),
    ("stray_warning", "a warning other than GainWarning", True),
    ("hang", "a step over 100 ms of CPU time or a case past its time budget", True),
    ("batch_same", "on N = 4 worlds (other states and targets), every world got its own one-world run's answer "
                   "(q̇ to 1e-10; 10·nv·ε·κ on a step of condition number κ; OSQP, ProxQP: 1e-6) or the same typed "
                   "error at the same step", False),
    ("batch_same_minimum", "on N = 4 worlds, OSQP's or ProxQP's answers apart by more than 1e-6 but each the same "
                           "minimum (each level's cost to 1e-6, a lower level's past what the level above moves it; "
                           "hard rows, limits)", False),
    ("batch_differs", "on N = 4 worlds, a world's q̇ or error differed from its own one-world run's", True),
)
DEFECTS = tuple(key for key, _, bad in CLASSES if bad)
INVALID = ("posture_gain", "task_gain", "task_weight", "influence", "damper_rate", "limit_gain", "margin",
           "velocity_values", "target", "posture_target", "gain_over_2_per_dt", "dt", "solver", "model_range")
BAD_VALUES = (None, "fast", [[1.0, 2.0]], float("nan"), float("inf"), -50.0)  # [[..]]: no task has 2-D gains


def solvers() -> list[str]:
    from qpik.solvers import available_solvers

    return [s for s in ALL_SOLVERS if s in available_solvers()]


class Case:
    """The objects of one case, drawn from ``seed`` by :meth:`build`."""

    def __init__(self, seed: int, folder: Path):
        self.seed, self.folder = seed, folder
        self.rng = np.random.default_rng(seed)
        self.params: dict = {"seed": seed}
        rng = self.rng
        self.invalid = str(rng.choice(INVALID)) if rng.random() < 1 / 6 else None
        self.injected = False  # whether the invalid value was given (its place may not exist)
        self.refusal_wrong = ""  # how a start outside the ranges was not refused as it must be
        self.kind = str(rng.choice(["qp", "hqp", "sns", "pinv"], p=[0.45, 0.25, 0.15, 0.15]))
        self.params.update(invalid=self.invalid, controller=self.kind)
        self.levels = None  # the QP's cost levels (one for QPController), once built
        self.recipe: Recipe | None = None  # how the tasks, limits and controller were built (from the start)

    def bad(self, where: str, value):
        """``value``, or an invalid one when this case injects one at ``where``."""
        if self.invalid != where:
            return value
        # A task's gain None is valid: the dead-beat default K = 1/Δt.
        values = [v for v in BAD_VALUES if not (where == "task_gain" and v is None)]
        bad = values[int(self.rng.integers(len(values)))]
        self.params["invalid_value"] = repr(bad)
        self.injected = True
        return bad

    def new(self, cls, *args, **kwargs):
        """``cls(*args, **kwargs)``, recorded in the case's recipe."""
        return self.recipe.new(cls, *args, **kwargs)

    # Building ---------------------------------------------------------------------------

    def build(self) -> None:
        from qpik.robot import Robot

        rng, params = self.rng, self.params
        models = third_party_models()
        if models and rng.random() < 0.3:
            path = str(rng.choice(models))
            params["model"] = short_name(path)
        else:
            path = str(self.folder / f"fuzz_{self.seed}.xml")
            Path(path).write_text(random_mjcf(rng, params))
            params["model"] = "generated"
        self.robot = robot = Robot.load(path)
        if self.invalid == "model_range":
            robot = self.robot = self._inverted_range(robot)
        self._start(robot)
        self.recipe = Recipe(robot)  # every object from here on is built through it (.batched replays it)
        self.tasks = self._tasks(robot)
        self.limits = self._limits(robot)
        self.controller = self._controller(robot)

    def _inverted_range(self, robot):
        """The same model with one limited joint's range reversed after compilation."""
        from qpik.robot import Robot

        model = robot.model
        limited = [j for j in range(model.njnt) if model.jnt_limited[j] and model.jnt_type[j] >= 2]
        j = int(self.rng.choice(limited)) if limited else 0
        model.jnt_limited[j] = 1
        model.jnt_range[j] = [1.0, -1.0]
        self.params["invalid_value"] = f"joint {j} range [1, -1]"
        self.injected = True
        return Robot(model)

    def _start(self, robot) -> None:
        rng = self.rng
        model = robot.model
        q = robot.q.copy()
        for j in range(model.njnt):
            adr, kind = int(model.jnt_qposadr[j]), int(model.jnt_type[j])
            if kind in (0, 1):  # free, ball: a random orientation
                quat = rng.normal(size=4)
                q[adr + (3 if kind == 0 else 0): adr + (7 if kind == 0 else 4)] = quat / np.linalg.norm(quat)
            elif model.jnt_limited[j]:
                low, high = model.jnt_range[j]
                where = rng.choice(["inside", "lower", "upper", "outside"], p=[0.6, 0.15, 0.15, 0.1])
                width = min(high - low, 10.0)
                q[adr] = {"inside": rng.uniform(max(low, -5), min(high, 5)), "lower": low, "upper": high,
                          "outside": (low - rng.uniform(0, 0.1) * width) if rng.random() < 0.5
                          else (high + rng.uniform(0, 0.1) * width)}[str(where)]
                self.params.setdefault("start", []).append(str(where))
            else:
                q[adr] = rng.uniform(-np.pi, np.pi)
        if self._refused_outside(robot, q):
            robot.allow_outside_limits = True  # the opt-in: the limits bring the joints back
            self.params["allow_outside_limits"] = True
        robot.set_q(q)
        robot.update_kinematics()

    def _refused_outside(self, robot, q: np.ndarray) -> bool:
        """Whether ``q`` lies outside the ranges; if so, ``set_q`` without the opt-in must
        refuse it naming exactly the joints outside, and by how much (else a defect)."""
        from qpik.errors import OutsideJointLimits
        from qpik.robot import KEYFRAME_TOLERANCE

        limits = robot.joint_limits
        values = q[limits.qpos_index]
        excess = np.maximum(limits.lower - values, values - limits.upper)
        expected = {limits.names[i]: float(excess[i]) for i in np.flatnonzero(excess > KEYFRAME_TOLERANCE)}
        if not expected:
            return False
        try:
            robot.set_q(q)
        except OutsideJointLimits as exc:
            named = exc.excess
            if set(named) != set(expected) or any(abs(named[k] - v) > 1e-12 * max(1.0, v) for k, v in expected.items()):
                self.refusal_wrong = f"named {named}, expected {expected}"
        else:
            self.refusal_wrong = "a start outside the ranges accepted without allow_outside_limits"
        return True

    def _frames(self, robot) -> list[tuple[str, str]]:
        model = robot.model
        frames = [(model.site(i).name, "site") for i in range(model.nsite) if model.site(i).name]
        frames += [(model.body(i).name, "body") for i in range(1, model.nbody)
                   if model.body(i).name and model.body_weldid[i] != 0]
        return frames

    def _gain(self, kind_dt_max: float = 1.999) -> float:
        kdt = _log_uniform(self.rng, -3, np.log10(kind_dt_max))
        if self.invalid == "gain_over_2_per_dt" and self.kind != "pinv":  # pinv: no period
            kdt = float(self.rng.uniform(2.01, 100.0))
            self.params["invalid_value"] = f"K·dt = {kdt:.3g}"
            self.injected = True
        return self.bad("task_gain", kdt / DT)

    def _tasks(self, robot) -> list:
        from qpik import DampingTask, PostureTask

        rng = self.rng
        count = int(rng.integers(1, 5))
        kinds = ["frame", "position", "orientation", "relative", "com", "posture", "damping", "equality",
                 "manipulability"]
        tasks = []
        for _ in range(count):
            kind = str(rng.choice(kinds))
            injected = self.injected
            task = self._task(robot, kind)
            if task is None and self.injected and not injected:  # drawn for a task not built
                self.injected = False
                self.params.pop("invalid_value", None)
            if task is not None:
                tasks.append(task)
                self.params.setdefault("tasks", []).append(kind + (" hard" if task.hard else ""))
        if not tasks or all(t.hard for t in tasks):
            tasks.append(self.new(DampingTask, robot, weight=_log_uniform(rng, -8, -2)) if rng.random() < 0.5
                         else self.new(PostureTask, robot, gain=self.bad("posture_gain", _log_uniform(rng, -2, 2)),
                                       weight=_log_uniform(rng, -6, 0)))
            self.params.setdefault("tasks", []).append(type(tasks[-1]).__name__)
        return tasks

    def _task(self, robot, kind: str):
        from qpik import (ComTask, DampingTask, EqualityTask, FrameTask, ManipulabilityTask, OrientationTask,
                          PositionTask, PostureTask, RelativeFrameTask, Yoshikawa)

        rng = self.rng
        frames = self._frames(robot)
        hard = bool(rng.random() < 0.4)
        weight = self.bad("task_weight", _log_uniform(rng, -3, 2))
        if kind in ("frame", "position", "orientation", "relative", "manipulability") and not frames:
            return None
        if kind in ("frame", "position", "orientation", "relative"):
            name, frame_type = frames[int(rng.integers(len(frames)))]
            axes = "".join(sorted(set(rng.choice(list("xyz"), int(rng.integers(1, 4))))))
            self.params.setdefault("axes", []).append(axes)
            if kind == "frame":
                task = self.new(FrameTask, robot, name, frame_type, position_gain=self._gain(),
                                orientation_gain=self._gain(), weight=weight, hard=hard)
            elif kind == "position":
                task = self.new(PositionTask, robot, name, frame_type, axes=axes, gain=self._gain(), weight=weight,
                                hard=hard)
            elif kind == "orientation":
                task = self.new(OrientationTask, robot, name, frame_type, axes=axes, gain=self._gain(), weight=weight,
                                hard=hard)
            else:
                root, root_type = frames[int(rng.integers(len(frames)))]
                if root == name:
                    return None
                task = self.new(RelativeFrameTask, robot, name, root, frame_type, root_type,
                                position_gain=self._gain(), orientation_gain=self._gain(), weight=weight, hard=hard)
            self._target(robot, task, kind)
            return task
        if kind == "com":
            task = self.new(ComTask, robot, gain=self._gain(), weight=weight, hard=hard)
            self.recipe.call(task, "set_target", self.bad("target", self._point(robot.data.subtree_com[0])))
            return task
        if kind == "posture":
            task = self.new(PostureTask, robot,
                            gain=self.bad("posture_gain", _log_uniform(rng, -2, np.log10(1.999 / DT))), weight=weight)
            self.recipe.call(task, "set_target", self.bad("posture_target", self._posture_target(robot)))
            return task
        if kind == "damping":
            return self.new(DampingTask, robot, weight=weight)
        if kind == "equality":
            if not any(robot.data.eq_active):
                return None
            gain = None if rng.random() < 0.5 else self._gain()
            return self.new(EqualityTask, robot, gain=gain, hard=hard, weight=weight)
        name, frame_type = frames[int(rng.integers(len(frames)))]
        return self.new(ManipulabilityTask, robot, self.new(Yoshikawa, robot, name, frame_type),
                        gain=_log_uniform(rng, -2, 1), weight=weight)

    def _point(self, current: np.ndarray) -> np.ndarray:
        """A target point: near, far (up to 1e8 m) or a finite 1e308."""
        rng = self.rng
        kind = str(rng.choice(["near", "far", "huge"], p=[0.6, 0.3, 0.1]))
        self.params.setdefault("targets", []).append(kind)
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        distance = {"near": rng.uniform(0, 0.5), "far": _log_uniform(rng, 1, 8), "huge": 1e308}[kind]
        return current + distance * direction if kind != "huge" else distance * direction

    def _target(self, robot, task, kind: str) -> None:
        rng = self.rng
        quat = rng.normal(size=4)
        rotation = np.empty(9)
        mujoco.mju_quat2Mat(rotation, quat / np.linalg.norm(quat))
        rotation = self.bad("target", rotation.reshape(3, 3)) if kind == "orientation" else rotation.reshape(3, 3)
        if kind == "orientation":
            self.recipe.call(task, "set_target", rotation)
            return
        position = self._point(np.zeros(3) if kind == "relative" else task.frame.position)
        if kind == "position":
            position = position[[("xyz").index(a) for a in self.params["axes"][-1]]]
        position = self.bad("target", position)
        self.recipe.call(task, "set_target", *((position, rotation) if kind in ("frame", "relative") else (position,)))

    def _posture_target(self, robot) -> np.ndarray:
        rng = self.rng
        target = robot.q.copy()
        kind = str(rng.choice(["near", "far", "huge"], p=[0.7, 0.2, 0.1]))
        self.params.setdefault("targets", []).append("posture " + kind)
        model = robot.model
        scalar = [int(model.jnt_qposadr[j]) for j in range(model.njnt) if int(model.jnt_type[j]) in (2, 3)]
        for adr in scalar:
            target[adr] += {"near": rng.normal(0, 0.5), "far": rng.normal(0, 1e4), "huge": 0.0}[kind]
        if kind == "huge" and scalar:  # one joint: a sum of several would overflow, refused as such
            target[scalar[int(rng.integers(len(scalar)))]] = 1e308
        return target

    def _limits(self, robot) -> list:
        from qpik import CollisionAvoidanceLimit, JointPositionLimit, JointVelocityLimit

        rng, limits = self.rng, []
        if len(robot.joint_limits.names) and rng.random() < 0.8:
            influence = 0.0 if rng.random() < 0.5 else float(rng.uniform(0.01, 0.5))
            limits.append(self.new(JointPositionLimit, robot, gain=self.bad("limit_gain", float(rng.uniform(0.1, 1.0))),
                                   influence=self.bad("influence", influence),
                                   damper_rate=self.bad("damper_rate", _log_uniform(rng, -1, 2)),
                                   margin=self.bad("margin", 1e-10)))
        if rng.random() < 0.6:
            values = np.array([_log_uniform(rng, -1, 2) for _ in range(robot.nv)])
            limits.append(self.new(JointVelocityLimit, robot, self.bad("velocity_values", values)))
        pairs = _collision_pairs(robot.model)
        if pairs and rng.random() < 0.25:
            a, b = pairs[int(rng.integers(len(pairs)))]
            limits.append(self.new(CollisionAvoidanceLimit, robot, [([a], [b])]))
        self.params["limits"] = [type(lim).__name__ for lim in limits]
        return limits

    def _controller(self, robot):
        from qpik import HierarchicalController, PseudoinverseController, QPController, SNSController

        rng, params = self.rng, self.params
        kind = self.kind
        dt = self.bad("dt", DT) if kind != "pinv" else DT
        if kind == "qp":
            solver = self.bad("solver", str(rng.choice(solvers())))
            rng.random()  # drew the removed fast_path option: kept, so that a seed draws the case it drew before
            params.update(solver=solver)
            self.levels = [self.tasks]
            return self.new(QPController, robot, self.tasks, self.limits, solver=solver, dt=dt)
        if kind == "pinv":
            primary = [t for t in self.tasks if not t.joint_space]
            secondary = next((t for t in self.tasks if t.joint_space), None)
            for task in primary:
                if task.needs_period:
                    self.recipe.set(task, "gain", 0.5 / DT)  # the law has no period of its own
            if not primary:
                primary, secondary = [secondary], None
            self.levels = [primary] + ([[secondary]] if secondary is not None else [])  # (what .batched compares)
            damping = 0.0 if rng.random() < 0.5 else _log_uniform(rng, -4, -1)
            params.update(damping=damping)
            self.limits = []
            return self.new(PseudoinverseController, robot, primary, secondary, damping=damping)
        levels = self._levels()  # (kept as self.levels: the costs the ProxQP repeat compares)
        if kind == "sns":
            self.limits = [lim for lim in self.limits if not lim.inequality_rows]  # SNS: boxes only
            return self.new(SNSController, robot, limits=self.limits, dt=dt, levels=levels)
        solver = self.bad("solver", str(rng.choice(solvers())))
        params.update(solver=solver)
        return self.new(HierarchicalController, robot, limits=self.limits, solver=solver, dt=dt, levels=levels)

    def _levels(self) -> list[list]:
        """2–3 levels; hard tasks only at level 0 (then no lower level may be infeasible)."""
        from qpik import DampingTask

        rng = self.rng
        tasks = sorted(self.tasks, key=lambda t: not t.hard)
        count = min(int(rng.integers(2, 4)), len(tasks))
        if count < 2:
            tasks.append(self.new(DampingTask, self.robot, weight=1e-3))
            count = 2
        cuts = sorted(rng.choice(np.arange(1, len(tasks)), count - 1, replace=False)) if len(tasks) > 2 else [1]
        levels = [tasks[a:b] for a, b in zip([0, *cuts], [*cuts, len(tasks)])]
        for level in levels[1:]:
            for task in level:
                self.recipe.set(task, "hard", False)
        self.params["levels"] = [len(level) for level in levels]
        self.levels = levels
        return levels


def _collision_pairs(model) -> list[tuple[str, str]]:
    """Named geoms of two bodies that are neither the same, welded, nor parent and child."""
    geoms = [i for i in range(model.ngeom) if model.geom(i).name and model.geom_bodyid[i] != 0]
    pairs = []
    for a in geoms:
        for b in geoms:
            body_a, body_b = int(model.geom_bodyid[a]), int(model.geom_bodyid[b])
            collide = model.geom_contype[a] & model.geom_conaffinity[b] or model.geom_contype[b] & model.geom_conaffinity[a]
            if a < b and collide and model.body_weldid[body_a] != model.body_weldid[body_b] \
                    and body_b not in (model.body_parentid[body_a], body_a) and model.body_parentid[body_b] != body_a:
                pairs.append((model.geom(a).name, model.geom(b).name))
    return pairs[:200]


# Running and checking -------------------------------------------------------------------

def _warning_line(record: warnings.WarningMessage) -> str:
    return f"{record.category.__name__} at {Path(record.filename).name}:{record.lineno}: {str(record.message)[:150]}"


def _stray(records) -> list[str]:
    return [_warning_line(r) for r in records if not issubclass(r.category, GainWarning)]


def run_case(seed: int, folder: Path, steps: int = STEPS, replay: list | None = None, batched: bool = False) -> dict:
    """Build and roll out case ``seed``; its classes, parameters, details and q hash.
    ``batched``: then also its problem on N worlds against each world's own run
    (:mod:`.batched`).

    A ProxQP case also records the configuration before each step (``q_steps``) and the
    cost of each level of its QP at each answer (``step_costs``); ``replay`` (another
    run's ``q_steps``) sets the robot to those configurations instead of integrating its
    own answers, so that two processes answer the same problems (see
    :func:`.sweep.same_run`)."""
    result = {"case": seed, "classes": [], "details": {}}
    with warnings.catch_warnings(record=True) as records:
        warnings.simplefilter("always")
        case = Case(seed, folder)
        result["params"] = case.params
        try:
            case.build()
        except QpikError as exc:
            result["classes"].append("rejected" if case.injected else "typed")
            result["details"]["error"] = f"{type(exc).__name__}: {str(exc)[:300]}"
            result["details"]["at"] = "build"
        except Exception as exc:  # noqa: BLE001 - the class the fuzz looks for
            _untyped(result, exc, "build")
        else:
            if case.refusal_wrong:
                result["classes"].append("invalid_accepted")
                result["details"]["outside_start"] = case.refusal_wrong[:300]
            _roll_out(case, result, steps, replay)
        if batched:
            from .batched import check_batched

            check_batched(case, result, steps, DT)
        stray = _stray(records)
    if stray:
        result["classes"].append("stray_warning")
        result["details"]["warnings"] = sorted(set(stray))[:5]
    if not any(c in DEFECTS or c in ("typed", "rejected") for c in result["classes"]):
        result["classes"].insert(0, "ok")
    return result


def _untyped(result: dict, exc: Exception, where: str) -> None:
    frame = traceback.extract_tb(exc.__traceback__)[-1]
    result["classes"].append("untyped")
    result["details"].update(error=f"{type(exc).__name__}: {str(exc)[:300]}", at=where,
                             site=f"{Path(frame.filename).name}:{frame.lineno}")


def _roll_out(case: Case, result: dict, steps: int, replay: list | None = None) -> None:
    robot, controller, details = case.robot, case.controller, result["details"]
    digest = hashlib.sha256()
    slowest = 0.0
    record = case.params.get("solver") == "proxqp"
    if replay is not None:
        robot.allow_outside_limits = True  # the first run's configurations, wherever they were
        steps = min(steps, len(replay))
    for step in range(steps):
        if replay is not None:
            robot.set_q(np.array(replay[step], dtype=float))
            robot.update_kinematics()
        q_before = robot.q.copy()
        if record:
            result.setdefault("q_steps", []).append(q_before.tolist())
        started = time.process_time()
        try:
            qdot = np.array(controller.compute_velocity(), dtype=float)
        except QpikError as exc:
            _typed_step(case, result, exc, step)
            break
        except Exception as exc:  # noqa: BLE001
            _untyped(result, exc, f"step {step}")
            break
        finally:
            slowest = max(slowest, time.process_time() - started)
        if case.injected:  # the invalid parameter went through a step
            result["classes"].append("invalid_accepted")
            break
        if not np.all(np.isfinite(qdot)):
            result["classes"].append("nonfinite")
            details["nonfinite_step"] = step
            break
        _check_step(case, result, qdot, q_before)
        if record:
            result.setdefault("step_costs", []).append(level_costs(case.levels, qdot))
        robot.integrate(qdot, DT)
        try:
            robot.update_kinematics()
        except InvalidInput as exc:  # the step took q past MuJoCo's range: the next has no answer
            details.update(error=f"{type(exc).__name__}: {str(exc)[:300]}", at=f"step {step + 1}")
            result["classes"].append("typed")
            break
        digest.update(robot.q.tobytes())
    else:
        if case.injected:
            result["classes"].append("invalid_accepted")
    details["max_step_cpu_ms"] = slowest * 1e3
    if slowest > SLOW_STEP_S:
        result["classes"].append("hang")
    result["q_hash"] = digest.hexdigest()
    result["classes"] = sorted(set(result["classes"]), key=result["classes"].index)


def level_costs(levels: list[list], qdot: np.ndarray, hard: bool = False) -> list[float]:
    """Each level's soft cost ½ Σ w (J q̇ − v)² at ``qdot`` (the tasks as last updated;
    ``hard``: the hard tasks' rows counted too, as the pseudoinverse law counts them)."""
    costs = []
    for level in levels:
        cost = 0.0
        for task in level:
            if hard or not task.hard:
                residual = task.jacobian @ qdot - task.target_velocity
                cost += 0.5 * float(np.dot(task.weight * residual, residual))
        costs.append(cost)
    return costs


def _check_step(case: Case, result: dict, qdot: np.ndarray, q_before: np.ndarray) -> None:
    details, robot = result["details"], case.robot
    if case.params["controller"] in ("qp", "hqp"):
        miss = max((hard_residual(t, qdot) for t in case.tasks if t.hard), default=0.0)
        details["hard_residual"] = max(details.get("hard_residual", 0.0), miss)
        iterative = case.params.get("solver") in ITERATIVE_SOLVERS
        if miss > (ITERATIVE_HARD_TOLERANCE if iterative else TOLERANCE):
            result["classes"].append("hard_missed")
    excess = max(crossing(robot, case.limits, q_before, qdot, DT), velocity_excess(case.limits, qdot))
    details["limit_excess"] = max(details.get("limit_excess", 0.0), excess)
    if excess > TOLERANCE:
        result["classes"].append("crossing")


def _typed_step(case: Case, result: dict, exc: QpikError, step: int) -> None:
    """A typed error on a step: confirmed by an LP, or a failure on a feasible step."""
    details = result["details"]
    details.update(error=f"{type(exc).__name__}: {str(exc)[:300]}", at=f"step {step}")
    if case.injected:
        result["classes"].append("rejected")
        return
    kind = case.params["controller"]
    if kind == "pinv":
        result["classes"].append("typed")
        return
    hard = [t for t in case.tasks if t.hard] if kind in ("qp", "hqp") else []
    A, b, lb, ub, G, h = box_and_rows(case.robot, hard, case.limits, DT)
    feasible = lp_feasible(A, b, lb, ub, G, h, margin=True)
    details["lp_feasible_with_margin"] = feasible
    if feasible:
        result["classes"].append("typed_on_feasible")
    if "limits alone" in str(exc) and lp_feasible(A[:0], b[:0], lb, ub, G, h, margin=False):
        result["classes"].append("misleading")
    elif isinstance(exc, SolverError) and np.all(np.isfinite(b)) and not feasible \
            and not lp_feasible(A, b, lb, ub, G, h, margin=False):
        result["classes"].append("misleading")  # an infeasible step reported as a solver failure
    if not feasible:
        result["classes"].append("typed")
