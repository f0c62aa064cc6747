"""What the examples share: a problem on a third-party model (a :class:`Demo`), its
command line, its headless run, and the interactive viewer with a draggable target.

Each example builds a :class:`Demo` (robot, tasks, limits, a reference that moves the
targets) and either rolls it out headless with :func:`qpik.simulate` and prints what it
achieved, or, with ``--viewer``, runs it in real time in MuJoCo's passive viewer: the
scripted motion plays, and once you drag the green target (double-click it, then
Ctrl + right-drag to move, Ctrl + left-drag to turn) the task follows the target instead.
The benchmarks (benchmarks/third_party.py) run the same problems beside mink.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import dataclass, field
from typing import Callable, Sequence

import mujoco
import numpy as np

from qpik import QPController, Robot, RolloutLog, simulate
from qpik.rollout import Reference
from qpik.solvers import available_solvers

MOCAP = "target"  # name of the draggable mocap body the viewer adds


@dataclass
class Demo:
    """A problem ready to run: the robot with its tasks, limits and moving targets.

    Attributes:
        name: the example's name (printed first).
        robot: the robot (its state is the run's: build a fresh demo per run).
        tasks: the controller's tasks.
        limits: the controller's limits.
        reference: moves the targets (``apply(t)``) and measures the robot.
        dt: control period (s).
        duration: how long a headless run lasts (s).
        follow: the task the viewer's draggable target drives (a FrameTask or a
            PositionTask), or None.
        regularization: the QP's ε (see :class:`qpik.QPController`).
        moving: the tasks whose targets ``reference.apply`` changes (the others keep
            the target they were built with); the mink comparison uses it.
    """

    name: str
    robot: Robot
    tasks: list
    limits: list
    reference: Reference
    dt: float
    duration: float
    follow: object | None = None
    regularization: float = 1e-12
    moving: Sequence = field(default_factory=tuple)

    def controller(self, solver: str = "daqp") -> QPController:
        return QPController(self.robot, self.tasks, self.limits, solver=solver, dt=self.dt,
                            regularization=self.regularization)

    def run(self, solver: str = "daqp") -> RolloutLog:
        """The scripted motion, headless: the log of :func:`qpik.simulate`."""
        return simulate(self.controller(solver), self.reference, self.duration, dt=self.dt,
                        robot_name=self.robot.name, scenario=self.name)


class _OneLineParser(argparse.ArgumentParser):
    """A usage error is one line on stderr and exit code 2, as with ``qpik``."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message}\n")


def parser(description: str, duration: float) -> argparse.ArgumentParser:
    """The examples' command line: --duration, --solver, --viewer."""
    out = _OneLineParser(description=description)
    out.add_argument("--duration", type=float, default=duration,
                     help=f"seconds to run (default {duration:g}, the whole scripted motion; a shorter run stops "
                          "part way, a longer one holds the end)")
    out.add_argument("--solver", default="daqp", help="QP solver (a qpsolvers name; default daqp)")
    out.add_argument("--viewer", action="store_true",
                     help="open MuJoCo's viewer and run in real time, with a draggable target (needs a display)")
    return out


def check_arguments(parser_: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """The values argparse cannot check alone: a positive duration, an installed solver."""
    if not (np.isfinite(args.duration) and args.duration > 0):
        parser_.error(f"--duration must be a positive number of seconds, got {args.duration}")
    if args.solver not in available_solvers():
        parser_.error(f"--solver {args.solver!r}: not an installed QP solver; use one of {', '.join(available_solvers())}")


def add_mocap_target(spec: mujoco.MjSpec, position, quaternion=(1.0, 0.0, 0.0, 0.0), pose: bool = True) -> None:
    """Add the draggable target to a model spec: a mocap body with a translucent,
    massless, collision-free geom (a flat box for a pose target, a ball for a point)."""
    body = spec.worldbody.add_body(name=MOCAP, mocap=True, pos=list(position), quat=list(quaternion))
    if pose:
        body.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.03, 0.02, 0.005], rgba=[0.2, 0.8, 0.2, 0.5],
                      contype=0, conaffinity=0, mass=0.0)
    else:
        body.add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[0.025, 0, 0], rgba=[0.2, 0.8, 0.2, 0.5],
                      contype=0, conaffinity=0, mass=0.0)


def report(name: str, headline: str, rows: list[tuple], notes: Sequence[str] = ()) -> None:
    """Print what a run achieved: ``label: value unit`` lines (the test reads them back).
    A row is (label, value, unit) or (label, value, unit, digits)."""
    print(f"{name}: {headline}")
    for label, value, unit, *digits in rows:
        print(f"{label}: {value:.{digits[0] if digits else 3}g} {unit}".rstrip())
    for note in notes:
        print(note)


def display_problem() -> str | None:
    """Why no window can open here, or None."""
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        return "no display (neither DISPLAY nor WAYLAND_DISPLAY is set)"
    return None


def view(demo: Demo, set_target_from_mocap: Callable[[np.ndarray, np.ndarray], None], solver: str = "daqp") -> int:
    """Run ``demo`` in real time in MuJoCo's passive viewer until the window closes.

    The scripted motion plays first, the mocap target shown where the reference puts
    the task's target; once the user moves the target, ``set_target_from_mocap(pos,
    quat)`` sets the task's target from it every step. Returns the exit status.
    """
    problem = display_problem()
    if problem is not None:
        print(f"{demo.name}: --viewer needs a window: {problem}; run without --viewer for the headless run",
              file=sys.stderr)
        return 2
    import mujoco.viewer

    robot = demo.robot
    model, data = robot.model, robot.data
    mocap = model.body(MOCAP).mocapid[0]
    controller = demo.controller(solver)
    run = demo.reference.start(robot, np.arange(round(demo.duration / demo.dt) + 1) * demo.dt)
    try:
        viewer = mujoco.viewer.launch_passive(model, data)
    except Exception as exc:  # GLFW and platform failures come as several types
        print(f"{demo.name}: the viewer did not open ({type(exc).__name__}: {exc}); run without --viewer for the "
              "headless run", file=sys.stderr)
        return 2
    written_pos, written_quat = data.mocap_pos[mocap].copy(), data.mocap_quat[mocap].copy()
    scripted, step = True, 0
    with viewer:
        while viewer.is_running():
            begin = time.perf_counter()
            with viewer.lock():
                moved = not (np.array_equal(data.mocap_pos[mocap], written_pos)
                             and np.array_equal(data.mocap_quat[mocap], written_quat))
                scripted = scripted and not moved and step < len(run.times)
                if scripted:
                    run.apply(step)
                    _target_to_mocap(demo.follow, data, mocap)
                    written_pos[:], written_quat[:] = data.mocap_pos[mocap], data.mocap_quat[mocap]
                    step += 1
                else:
                    set_target_from_mocap(data.mocap_pos[mocap].copy(), data.mocap_quat[mocap].copy())
                robot.integrate(controller.compute_velocity(), demo.dt)
                robot.update_kinematics()
            viewer.sync()
            time.sleep(max(0.0, demo.dt - (time.perf_counter() - begin)))
    return 0


def _target_to_mocap(task, data: mujoco.MjData, mocap: int) -> None:
    """Show the followed task's current target with the mocap body."""
    if hasattr(task, "target_rotation"):
        data.mocap_pos[mocap] = task.target_position
        mujoco.mju_mat2Quat(data.mocap_quat[mocap], task.target_rotation.reshape(9))
    else:
        data.mocap_pos[mocap] = task.target


def quaternion_to_matrix(quat: np.ndarray) -> np.ndarray:
    matrix = np.empty(9)
    mujoco.mju_quat2Mat(matrix, quat)
    return matrix.reshape(3, 3)


def rotation_angle(desired: np.ndarray, current: np.ndarray) -> float:
    """The angle (rad) of the rotation between two rotation matrices, from the quaternion of
    R_d R^T (atan2 form: accurate at small angles, unlike arccos of the trace)."""
    quat = np.empty(4)
    mujoco.mju_mat2Quat(quat, (desired @ current.T).reshape(9))
    return float(2.0 * np.arctan2(np.linalg.norm(quat[1:]), abs(quat[0])))


def speed_violation(log: RolloutLog, max_velocity: np.ndarray) -> float:
    """Largest joint speed beyond its bound over the run (0.0 when all are kept)."""
    excess = np.abs(log.qdot) - max_velocity
    return float(max(0.0, np.max(excess[:, np.isfinite(max_velocity)], initial=0.0)))
