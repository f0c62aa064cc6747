"""Scenarios: a named, reproducible run setup, and the registry the robots fill.

A scenario builds, for one run, a fresh robot with its tasks, limits, reference
trajectory and gains (a :class:`Setup`); every controller of a comparison gets an
identical copy. The bundled robots register their scenarios when their
``scenarios`` module is imported; :func:`scenarios` imports them on first use, so
nothing here imports a robot (no import cycle).
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from typing import Callable

import mujoco

from .controllers.hierarchy import HierarchicalController
from .controllers.qp import QPController
from .controllers.sns import SNSController
from .errors import UnknownName
from .robot import JointLimits, Robot, scene_path
from .robots import BUNDLED
from .rollout import Rollout
from .solvers import available_solvers
from .tasks import Task

DT = 0.002


@dataclass(frozen=True)
class JointPlotSpec:
    """Which joints figures show: names, qpos/qvel columns, limits (inf: none), units."""

    names: tuple[str, ...]
    qpos_index: tuple[int, ...]
    dof_index: tuple[int, ...]
    lower: tuple[float, ...]
    upper: tuple[float, ...]
    units: tuple[str, ...]

    @classmethod
    def from_limits(cls, robot: Robot, limits: JointLimits, names=None) -> JointPlotSpec:
        names = tuple(limits.names if names is None else names)
        idx = [limits.names.index(n) for n in names]
        slide = int(mujoco.mjtJoint.mjJNT_SLIDE)
        units = tuple("m" if int(robot.model.jnt_type[robot.joint_id(n)]) == slide else "rad" for n in names)
        return cls(names, tuple(int(limits.qpos_index[i]) for i in idx), tuple(int(limits.dof_index[i]) for i in idx),
                   tuple(float(limits.lower[i]) for i in idx), tuple(float(limits.upper[i]) for i in idx), units)


@dataclass
class Setup:
    """Everything one run of a scenario needs; ``controller()`` builds a controller on it.

    ``hierarchy`` lists the tasks (each with its ``priority``) that the strict hierarchy
    (``hqp``) and SNS (``sns``) order into levels; ``level_errors`` measures each level's
    error for every controller; ``variants`` are further controllers built with a solver
    name (e.g. ``qp-hard``); ``classical`` those without one.
    """

    scenario: str
    robot_name: str
    robot: Robot
    duration: float
    reference: object
    qp_tasks: list[Task]
    limits: list
    joint_limits: JointLimits
    manipulability: Callable[[Robot], float]
    manipulability_measure: str
    classical: dict[str, Callable[[], object]]
    plot_joints: JointPlotSpec
    params: dict = field(default_factory=dict)
    dt: float = DT
    closure: Callable[[Robot], None] | None = None  # closes the loops of a closed chain
    hierarchy: list[Task] | None = None
    level_errors: object | None = None  # a qpik.rollout.levels.LevelErrors
    variants: dict[str, Callable[[str], object]] = field(default_factory=dict)

    rolled_out: bool = False  # set by qpik.app.runs.run, which refuses a setup twice

    def controller_kinds(self) -> list[str]:
        """Every controller this setup builds (the peers aside)."""
        return ["qp", *self.variants, *(["hqp", "sns"] if self.hierarchy else []), *self.classical]

    def controller(self, kind: str = "qp", solver: str = "daqp", **options):
        if kind == "qp":
            return QPController(self.robot, self.qp_tasks, self.limits, solver=solver, dt=self.dt, **options)
        if kind in self.variants:
            return self.variants[kind](solver, **options)
        if kind == "hqp" and self.hierarchy:
            return HierarchicalController(self.robot, self.hierarchy, self.limits, solver=solver, dt=self.dt, **options)
        if kind == "sns" and self.hierarchy:
            return SNSController(self.robot, self.hierarchy, self.limits, dt=self.dt, **options)
        if kind in self.classical:
            return self.classical[kind]()
        raise UnknownName(f"unknown controller {kind!r} for {self.scenario}; choose from {self.controller_kinds()}")

    def rollout(self, controller, *, mode: str = "kinematic", on_failure: str = "raise", progress=None,
                duration: float | None = None, scenario: str | None = None) -> Rollout:
        """``controller`` (built on this setup's robot) rolled out along the setup's
        reference, measured as the scenario says (its manipulability, joint limits,
        joints, levels), for ``duration`` (default the scenario's) seconds; ``scenario``
        relabels the run. See :class:`qpik.rollout.Rollout` for the other arguments."""
        return Rollout(controller, self.reference, self.duration if duration is None else duration, dt=self.dt,
                       mode=mode, manipulability=self.manipulability,
                       manipulability_measure=self.manipulability_measure, joint_limits=self.joint_limits,
                       scenario=scenario or self.scenario, robot_name=self.robot_name, on_failure=on_failure,
                       closure=self.closure, speed_dofs=self.plot_joints.dof_index, progress=progress,
                       levels=self.level_errors)


@dataclass(frozen=True)
class ScenarioInfo:
    name: str
    robot: str
    description: str
    build: Callable[..., Setup]


_SCENARIOS: dict[str, ScenarioInfo] = {}


def register(name: str, robot: str, description: str):
    def decorator(build: Callable[..., Setup]) -> Callable[..., Setup]:
        _SCENARIOS[name] = ScenarioInfo(name, robot, description, build)
        return build

    return decorator


def scenarios() -> dict[str, ScenarioInfo]:
    """Every registered scenario by name (the bundled robots' first, in their order)."""
    for module in (entry[1] for entry in BUNDLED.values()):
        importlib.import_module(module)
    return dict(_SCENARIOS)


def build_scenario(name: str, robot: str | None = None, **options) -> Setup:
    """A fresh setup of scenario ``name``.

    ``robot`` is checked against the scenario's robot (``"arm"``, ``"hexapod"``); an
    MJCF path instead replaces the bundled scene (it must define the same names).
    """
    known = scenarios()
    if name not in known:
        raise UnknownName(f"unknown scenario {name!r}; known: {', '.join(known)}")
    info = known[name]
    if robot is not None and robot not in BUNDLED:
        scene_path(robot)  # raises a clear error for an unknown name or a missing file
        options.setdefault("scene", robot)
    elif robot is not None and robot != info.robot:
        raise UnknownName(f"scenario {name!r} is for robot {info.robot!r}, not {robot!r}")
    return info.build(**options)


def check_solver(solver: str) -> str:
    if solver not in available_solvers():
        raise UnknownName(f"unknown or uninstalled QP solver {solver!r}; available: {', '.join(available_solvers())}")
    return solver
