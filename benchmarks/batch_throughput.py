r"""Throughput of qpik.batch: robot-steps per second for N = 1 … 16,384 worlds, against
qpik's serial loop and mink-warp's CPU solvers, each with its distance from the exact answer.

Problems (one control step = set the moving targets, solve, integrate; dt = 2 ms):

- ``arm``: the bundled planar arm, a hard x-y position task (gain 500) on a 5 cm circle
  with its feed-forward, the σ manipulability task (k0 = 5), joint position and speed limits;
- ``hexapod``: the bundled 6-PUS platform, a hard pose task (gain 500) on a 1 cm circle,
  the six loop closures hard (connect equalities), damping, stroke and speed limits —
  skipped, with a message, while ``qpik.batch`` has no ``EqualityTask`` (the engine's
  loop closures);
- ``pusher``: a third-party 7-DoF arm — gymnasium's pusher arm (PR2's right arm, puck and
  goal removed, :func:`qpik.models.pusher_arm`) — a soft pose task on ``tips_arm``
  (gains 500, weight 1) along a 5 cm circle, a posture task (weight 1e-2), joint position
  limits and 2 rad/s speed limits.

Contestants, per N, block-interleaved in one process (benchmarks/timing.py: blocks of a
few steps, the order rotated, ``--repeats`` fresh runs):

- ``qpik.batch``: one batched step of all N worlds (the engine's classes on a
  ``batch.Robot``: ``mujoco.batch`` for the kinematics, its default
  thread count: one per 2048 worlds, at most the CPUs); beside it, from N = 1024 on,
  ``qpik.batch (1 thread)`` where the default uses more and ``qpik.batch (2 threads)``
  where it uses one (the machine has more): whether a second thread pays depends on
  the load, and these columns are what the default is chosen from;
- ``qpik serial (N robots)``: the serial loop that qpik.batch replaces — N robots, each
  with its own ``QPController``, stepped one after the other (N up to 1,024: each robot
  holds about 1 MB once stepped); per robot-step. At N = 1,024 its robots' data outgrow
  the caches, as they would in a user's loop;
- ``qpik serial (32 robots)``: the same loop over min(N, 32) robots, whose data stay in
  the caches between their own steps (less so as the batched blocks between its blocks
  grow); ``qpik serial (1 robot)``: one robot stepped again and again, its data always in
  the caches — the serial loop's best case, the most conservative baseline;
- ``mink-warp dls`` / ``mink-warp constrained`` (pusher only): mink-warp 0.1 on Warp's
  CPU device, pose + posture (mink's costs), its ``ConstrainedSolver`` with mink's
  ``ConfigurationLimit`` and ``VelocityLimit``. mink-warp runs in a throwaway virtual
  environment the script makes under a temporary folder (``pip install mink-warp``);
  the measurement then runs there, with this environment's packages added after its own.
  mink-warp 0.1 with mujoco 4.0 silently drops every joint range: its limits test
  ``model.jnt_type[j] not in (mjJNT_HINGE, mjJNT_SLIDE)``, and a NumPy integer is not
  found among mujoco 4.0's enum members, so no joint counts as limited (and
  ``VelocityLimit`` refuses hinges). The script patches the two modules' joint-type
  tuples to plain integers before building the limits, and checks that the pusher's
  seven ranges are then enforced.

Distance from the exact answer: qpik.batch's worlds against qpik's serial controller on
the same states (max |q̇_batch − q̇_serial| over a 1 s rollout, and |q_batch − q_serial|
after it); mink-warp's step against mink's own exact QP (mink 1.3, solver daqp) on the
same states and targets, relative (median, p90), and its configuration drift from mink
after 1 s.

    python benchmarks/batch_throughput.py [--sizes 1 16 256 1024 4096 16384] [--repeats 3]
                                          [--robots arm hexapod pusher] [--no-mink-warp]

writes benchmarks/results/batch_throughput.{json,md,png}.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results"
sys.path.insert(0, str(HERE))

DT = 0.002
SIZES = (1, 16, 256, 1024, 4096, 16384)
SERIAL_ROBOTS = 32
# The loop over all N robots up to this N: each robot's MuJoCo data and controller take
# about 1 MB once stepped, and two repeats' robots are alive while the next one is built.
SERIAL_ALL_MAX = 1024
PUSHER_START = np.array([0.2, 0.3, -0.2, -1.0, 0.3, -0.5, 0.2])
PUSHER_SPEED = 2.0
RADIUS = {"arm": 0.05, "hexapod": 0.01, "pusher": 0.05}
PERIOD = 2.0
TITLES = {"arm": "planar RRR+P arm (bundled)", "hexapod": "6-PUS hexapod, loops closed (bundled)",
          "pusher": "7-DoF arm (gymnasium pusher's PR2 arm)"}
ROBOT_STEPS_PER_RUN = 60_000  # steps of a batched run: about this many robot-steps, 8 to 200


# -- the problems ------------------------------------------------------------------------
def circle(n: int, steps: int, radius: float, axes=(0, 1), seed: int = 0):
    """Offsets (steps, n, 3) and their velocities along circles of random phase."""
    phase = np.random.default_rng(seed).uniform(0, 2 * np.pi, n)
    t = np.arange(steps)[:, None] * DT
    w = 2 * np.pi / PERIOD
    offset, velocity = np.zeros((steps, n, 3)), np.zeros((steps, n, 3))
    angle = w * t + phase
    offset[:, :, axes[0]] = radius * (np.cos(angle) - np.cos(phase))
    offset[:, :, axes[1]] = radius * (np.sin(angle) - np.sin(phase))
    velocity[:, :, axes[0]] = -radius * w * np.sin(angle)
    velocity[:, :, axes[1]] = radius * w * np.cos(angle)
    return offset, velocity


def build(lib, name: str, n: int, **options):
    """(robots, tasks, limits, mover) of a problem in ``lib`` (qpik.batch, or qpik with n=1:
    then ``robots`` is a serial Robot). ``mover(offset, velocity)`` sets the moving targets;
    ``options`` go to the batched robots' back-end (``nthread``)."""
    from qpik.models import pusher_arm

    serial = lib.__name__ == "qpik"
    make = (lambda model, **kw: lib.Robot.load(model, **kw)) if serial else \
        (lambda model, **kw: lib.Robot.load(model, n, **kw, **options))
    if name == "arm":
        robots = make("arm")
        robots.set_q(np.array([np.pi / 2, -0.4, 0.6, 0.5]))
        robots.ensure_kinematics()
        task = lib.PositionTask(robots, "end_effector", axes="xy", gain=500.0, hard=True)
        home = np.array(task.target, copy=True)
        sigma = lib.SigmaProxy(robots, ["theta2", "theta3"])
        tasks = [task, lib.ManipulabilityTask(robots, sigma, gain=5.0)]
        limits = [lib.JointPositionLimit(robots), lib.JointVelocityLimit(robots)]
        return robots, tasks, limits, lambda off, vel: task.set_target(home + off[..., :2], vel[..., :2])
    if name == "hexapod":
        robots = make("hexapod")
        robots.ensure_kinematics()
        pose = lib.FrameTask(robots, "platform_center", position_gain=500.0, orientation_gain=500.0, hard=True)
        home, rotation = np.array(pose.target_position, copy=True), np.array(pose.target_rotation, copy=True)
        names = robots.template.joint_names if not serial else robots.joint_names
        tasks = [pose, lib.EqualityTask(robots, gain=500.0), lib.DampingTask(robots, weight=1e-6, joints=names)]
        limits = [lib.JointPositionLimit(robots), lib.JointVelocityLimit(robots)]
        return robots, tasks, limits, lambda off, vel: pose.set_target(home + off, rotation, vel)
    model = pusher_arm()
    robots = lib.Robot(model, name="pusher_arm") if serial else lib.Robot(model, n, name="pusher_arm", **options)
    robots.set_q(PUSHER_START)
    robots.ensure_kinematics()
    hand = lib.FrameTask(robots, "tips_arm", "body", position_gain=500.0, orientation_gain=500.0)
    home, rotation = np.array(hand.target_position, copy=True), np.array(hand.target_rotation, copy=True)
    tasks = [hand, lib.PostureTask(robots, gain=1.0, weight=1e-2)]
    limits = [lib.JointPositionLimit(robots), lib.JointVelocityLimit(robots, np.full(7, PUSHER_SPEED))]
    return robots, tasks, limits, lambda off, vel: hand.set_target(home + off, rotation, vel)


def unbatched(robot: str) -> str | None:
    """Why this checkout's ``qpik.batch`` cannot run ``robot``'s problem (None: it can)."""
    from qpik import batch

    if robot == "hexapod" and "EqualityTask" not in batch.__all__:
        return "hexapod skipped: qpik.batch has no EqualityTask (the loop closures) until the engine has one"
    return None


def run_steps(n: int) -> int:
    return int(np.clip(ROBOT_STEPS_PER_RUN // n, 8, 200))


class BatchRun:
    failures = ()

    def __init__(self, name: str, n: int, steps: int, nthread: int | None = None):
        from qpik import batch

        options = {} if nthread is None else {"nthread": nthread}
        self.robots, tasks, limits, self.mover = build(batch, name, n, **options)
        self.controller = batch.QPController(self.robots, tasks, limits, dt=DT)
        self.offset, self.velocity = circle(n, steps, RADIUS[name], axes=(0, 2) if name == "pusher" else (0, 1))
        self.steps = steps

    def step(self, k: int) -> None:
        self.mover(self.offset[k], self.velocity[k])
        self.robots.integrate(self.controller.compute_velocity(), DT)

    def after(self, k: int) -> None:
        pass


class SerialRun:
    """qpik's serial loop over ``count`` robots: one timed step is every robot's step."""

    failures = ()

    def __init__(self, name: str, n: int, steps: int, count: int | None = None, inner: int = 1):
        import qpik

        self.count = min(n, SERIAL_ROBOTS) if count is None else count
        self.inner = inner  # control steps of each robot per timed step
        self.items = []
        offset, velocity = circle(self.count, steps * inner, RADIUS[name], axes=(0, 2) if name == "pusher" else (0, 1))
        for i in range(self.count):
            robot, tasks, limits, mover = build(qpik, name, 1)
            self.items.append((robot, qpik.QPController(robot, tasks, limits, dt=DT), mover))
        self.offset, self.velocity, self.steps = offset, velocity, steps

    def step(self, k: int) -> None:
        for j in range(k * self.inner, (k + 1) * self.inner):
            for i, (robot, controller, mover) in enumerate(self.items):
                mover(self.offset[j, i], self.velocity[j, i])
                robot.integrate(controller.compute_velocity(), DT)

    def after(self, k: int) -> None:
        pass


# -- mink-warp ---------------------------------------------------------------------------
def patch_mink_warp() -> None:
    """mink-warp 0.1's joint-type tests compare NumPy integers with mujoco 4.0's enum
    members, which never match: every joint range is dropped. Plain integers match."""
    import mujoco
    import mink_warp.limits.configuration_limit as configuration_limit
    import mink_warp.limits.velocity_limit as velocity_limit

    scalar = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
    configuration_limit._SCALAR_JOINTS = scalar
    velocity_limit._SCALAR_JOINTS = scalar


def mink_warp_limits(model):
    import mink_warp as mw

    limits = [mw.ConfigurationLimit(model), mw.VelocityLimit(model, {model.joint(j).name: PUSHER_SPEED
                                                                     for j in range(model.njnt)})]
    if limits[0].n_limited != model.njnt:
        raise RuntimeError(f"mink-warp enforces {limits[0].n_limited} of {model.njnt} joint ranges")
    return limits


class MinkWarpRun:
    failures = ()

    def __init__(self, solver: str, n: int, steps: int):
        import mink_warp as mw
        import warp as wp
        from qpik.models import pusher_arm
        from mink_warp.lie import SE3  # noqa: F401 (mink-warp's own types)

        self.wp, self.mw = wp, mw
        model = pusher_arm()
        self.configuration = mw.Configuration(model, q=np.tile(PUSHER_START, (n, 1)), nworld=n, device="cpu")
        self.hand = mw.FrameTask("tips_arm", "body", position_cost=1.0, orientation_cost=1.0)
        self.hand.set_target_from_configuration(self.configuration)
        self.posture = mw.PostureTask(model, cost=1e-2)
        self.posture.set_target(PUSHER_START)
        self.home = self._home_pose(model)
        self.offset, _ = circle(n, steps, RADIUS["pusher"], axes=(0, 2))
        self.solver = (mw.ConstrainedSolver(self.configuration, limits=mink_warp_limits(model)) if solver == "constrained"
                       else mw.DLSSolver(self.configuration))
        self.steps = steps
        self.targets = np.empty((n, 7), dtype=np.float32)

    def _home_pose(self, model):
        import mujoco

        data = mujoco.MjData(model)
        data.qpos[:] = PUSHER_START
        mujoco.mj_kinematics(model, data)
        body = model.body("tips_arm").id
        quat = np.empty(4)
        mujoco.mju_mat2Quat(quat, data.xmat[body])
        return np.concatenate([quat, data.xpos[body]])

    def step(self, k: int) -> None:
        self.targets[:] = self.home
        self.targets[:, 4:] += self.offset[k]
        self.hand.set_target(self.wp.array(self.targets, dtype=float, device="cpu"))
        self.solver.solve_and_integrate([self.hand, self.posture], DT)
        self.configuration.update()
        self.wp.synchronize()

    def after(self, k: int) -> None:
        pass


def mink_warp_accuracy(steps: int = 500, n: int = 64) -> dict:
    """mink-warp's constrained step against mink's exact QP (daqp) at the same states, and
    both rollouts' configurations after ``steps`` steps."""
    import mink
    from qpik.models import pusher_arm

    run = MinkWarpRun("constrained", n, steps)
    model = pusher_arm()
    configuration = mink.Configuration(model)
    hand = mink.FrameTask("tips_arm", "body", position_cost=1.0, orientation_cost=1.0)
    posture = mink.PostureTask(model, cost=1e-2)
    posture.set_target(PUSHER_START)
    limits = [mink.ConfigurationLimit(model), mink.VelocityLimit(model, {model.joint(j).name: PUSHER_SPEED
                                                                        for j in range(model.njnt)})]
    references = [mink.Configuration(model) for _ in range(n)]
    for ref in references:
        ref.update(PUSHER_START.copy())
    relative, drift = [], 0.0
    for k in range(steps):
        q = run.configuration.q.numpy().astype(float)
        run.step(k)
        v = run.solver.v.numpy().astype(float)
        for i in range(n):
            target = mink.SE3(np.concatenate([run.home[:4], run.home[4:] + run.offset[k, i]]))
            hand.set_target(target)
            configuration.update(q[i])
            exact = mink.solve_ik(configuration, [hand, posture], DT, "daqp", limits=limits)
            if np.linalg.norm(exact) > 1e-9:
                relative.append(float(np.linalg.norm(v[i] - exact) / np.linalg.norm(exact)))
            references[i].update(references[i].q)
            hand.set_target(target)
            references[i].integrate_inplace(mink.solve_ik(references[i], [hand, posture], DT, "daqp", limits=limits), DT)
    final = run.configuration.q.numpy().astype(float)
    drift = max(float(np.abs(final[i] - references[i].q).max()) for i in range(n))
    return {"worlds": n, "steps": steps, "step_relative_error_median": float(np.median(relative)),
            "step_relative_error_p90": float(np.percentile(relative, 90)), "q_drift_after_1s_rad": drift}


# -- accuracy of qpik.batch ---------------------------------------------------------------
def batch_accuracy(name: str, n: int = 32, steps: int = 500) -> dict:
    """A 1 s batched rollout beside qpik's serial controllers on the same worlds."""
    import qpik
    from qpik import batch

    run = BatchRun(name, n, steps)
    serial = SerialRun(name, n, steps)
    worst_qdot = 0.0
    for k in range(steps):
        run.mover(run.offset[k], run.velocity[k])
        qdot = run.controller.compute_velocity()
        run.robots.integrate(qdot, DT)
        for i, (robot, controller, mover) in enumerate(serial.items):
            mover(run.offset[k, i], run.velocity[k, i])
            reference = controller.compute_velocity()
            worst_qdot = max(worst_qdot, float(np.abs(reference - qdot[i]).max()))
            robot.integrate(reference, DT)
    worst_q = max(float(np.abs(run.robots.q[i] - robot.q).max()) for i, (robot, _, _) in enumerate(serial.items))
    solver = run.controller.solver_calls
    stats = {"closed_form": n * steps - solver, "solver": solver}  # world-steps settled by each stage
    del qpik, batch
    return {"worlds": serial.count, "steps": steps, "max_qdot_difference": worst_qdot, "max_q_difference": worst_q,
            "qp_stats": stats}


# -- the measurement ------------------------------------------------------------------------
def other_threads(n: int, steps: int, robot: str) -> list:
    """From N = 1024 on, qpik.batch on another thread count than its default: one thread
    where the default uses more, two where it uses one and the machine has two CPUs."""
    from timing import Contestant

    from qpik.batch.backends.cpu import default_threads

    if n < 1024:
        return []
    if default_threads(n) > 1:
        return [Contestant("qpik.batch (1 thread)", lambda: BatchRun(robot, n, steps, nthread=1))]
    if (os.cpu_count() or 1) > 1:
        return [Contestant("qpik.batch (2 threads)", lambda: BatchRun(robot, n, steps, nthread=2))]
    return []


def measure(robot: str, sizes, repeats: int, mink_warp: bool) -> dict:
    from timing import Contestant, interleave

    rows = []
    for n in sizes:
        steps = run_steps(n)
        block = max(1, steps // 8)
        contestants = [Contestant("qpik.batch", lambda n=n, s=steps: BatchRun(robot, n, s)), *other_threads(n, steps, robot),
                       Contestant("qpik serial (32 robots)", lambda n=n, s=steps: SerialRun(robot, n, s)),
                       Contestant("qpik serial (1 robot)", lambda n=n, s=steps: SerialRun(robot, n, s, count=1, inner=SERIAL_ROBOTS))]
        if SERIAL_ROBOTS < n <= SERIAL_ALL_MAX:
            contestants.append(Contestant("qpik serial (N robots)", lambda n=n, s=steps: SerialRun(robot, n, s, count=n)))
        if mink_warp:
            contestants += [Contestant("mink-warp dls", lambda n=n, s=steps: MinkWarpRun("dls", n, s)),
                            Contestant("mink-warp constrained", lambda n=n, s=steps: MinkWarpRun("constrained", n, s))]
        timing = interleave(contestants, repeats=repeats, block=block)
        per_step = {c.label: c.repeat_medians_us for c in timing.contestants.values()}
        del timing  # its last runs (up to N serial robots) before the next N's are built
        robots_per_step = {"qpik.batch": n, "qpik.batch (1 thread)": n, "qpik.batch (2 threads)": n,
                           "qpik serial (32 robots)": min(n, SERIAL_ROBOTS), "qpik serial (1 robot)": SERIAL_ROBOTS,
                           "qpik serial (N robots)": n,
                           "mink-warp dls": n, "mink-warp constrained": n}
        row = {"n": n, "steps": steps}
        for label, medians in per_step.items():
            row[label] = {"robot_steps_per_s": float(np.median(robots_per_step[label] / medians * 1e6)),
                          "step_us_per_repeat": [float(m) for m in medians]}
        batch_rate = per_step["qpik.batch"] / n
        for label in per_step:
            if not label.startswith("qpik.batch"):
                other = per_step[label] / robots_per_step[label]
                ratios = other / batch_rate
                row[f"speedup vs {label}"] = {"median": float(np.median(ratios)), "min": float(ratios.min()),
                                              "max": float(ratios.max())}
        rows.append(row)
        print(f"{robot} N={n}: " + ", ".join(f"{label} {row[label]['robot_steps_per_s']:.3g}/s" for label in per_step),
              file=sys.stderr, flush=True)
    return {"rows": rows}


def profile_shares(robot: str, n: int = 1024, steps: int = 40) -> dict:
    """Where a batched step's time goes: kinematics (mujoco.batch forward), the QP (the
    engine's closed form with its held bounds, then the solver world by world), the rest
    (the tasks' rows, the limits, the cost)."""
    run = BatchRun(robot, n, steps)
    backend, controller = run.robots.backend, run.controller  # the benchmark looks inside
    spent = {"kinematics": 0.0, "qp": 0.0}
    forward, solve, finish = backend.forward, controller.held.solve, controller._finish

    def timed(key, fn):
        def wrapper(*args, **kwargs):
            start = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                spent[key] += time.perf_counter() - start
        return wrapper

    backend.forward, controller.held.solve = timed("kinematics", forward), timed("qp", solve)
    controller._finish = timed("qp", finish)
    start = time.perf_counter()
    for k in range(steps):
        run.step(k)
    total = time.perf_counter() - start
    return {"n": n, "step_us_per_world": total / steps / n * 1e6,
            "kinematics_share": spent["kinematics"] / total, "qp_share": spent["qp"] / total,
            "tasks_limits_and_rest_share": 1.0 - (spent["kinematics"] + spent["qp"]) / total}


def mujoco_floor(robot: str, n: int = 1024, number: int = 20) -> dict:
    """What one thread of ``mujoco.batch`` costs per world on the back-end's kinematic
    model, whatever runs around it (best of 3 rounds of ``number`` calls on a fixed state):
    a call that computes nothing (each world's state row loaded and saved, the bound
    outputs copied), the back-end's call (the position stage, ``mj_fwdPosition``, with
    MuJoCo's profiling timers off as the back-end runs it) and the same call with the
    Python bindings' timer on, and ``Batch.jac`` (``mj_kinematics`` + ``mj_comPos`` + one
    ``mj_jac``, nothing copied out: the kinematics alone, which no call of the batch
    offers with its outputs)."""
    import mujoco
    from timing import call_cost_us

    from qpik.batch.backends.cpu import profiling_timers_off

    run = BatchRun(robot, n, 8, nthread=1)
    batch = run.robots.backend._batch  # the benchmark looks inside: not an interface
    stage = mujoco.mjtStage

    def quiet(call):
        def run_quietly():
            with profiling_timers_off():
                call()
        return run_quietly

    costs = {"nothing": quiet(lambda: batch.forward(stage=int(stage.mjSTAGE_NONE))),
             "position_stage": run.robots.backend.forward,
             "position_stage_with_timers": lambda: batch.forward(stage=int(stage.mjSTAGE_POS)),
             "kinematics_jac": quiet(lambda: batch.jac(0, np.zeros(3)))}
    return {"n": n, **{f"{key}_us_per_world": call_cost_us(call, number=number) / n for key, call in costs.items()}}


def figure(results: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    robots = list(results["throughput"])
    fig, axes = plt.subplots(1, len(robots), figsize=(5 * len(robots), 4.8), squeeze=False)
    for ax, robot in zip(axes[0], robots):
        rows = results["throughput"][robot]["rows"]
        for label, style in (("qpik.batch", "o-"), ("qpik.batch (1 thread)", "o:"), ("qpik.batch (2 threads)", "d:"),
                             ("qpik serial (N robots)", "s-"), ("qpik serial (32 robots)", "s--"),
                             ("qpik serial (1 robot)", "x--"),
                             ("mink-warp dls", "^:"),
                             ("mink-warp constrained", "v-.")):
            points = [(r["n"], r[label]["robot_steps_per_s"]) for r in rows if label in r]
            if points:
                ax.plot(*zip(*points), style, label=label)
        ax.set_xscale("log", base=2)
        ax.set_yscale("log")
        ax.set_xlabel("worlds N")
        ax.set_ylabel("robot-steps / s")
        ax.set_title(TITLES[robot])
        ax.grid(True, which="both", alpha=0.3)
    handles = {}
    for ax in axes[0]:  # one legend for all panels, below them: none hides a curve
        curves, labels = ax.get_legend_handles_labels()
        handles.update(zip(labels, curves))
    fig.legend(handles.values(), handles.keys(), loc="lower center", ncol=4, fontsize=9)
    fig.suptitle(f"qpik.batch throughput, robot-steps/s ({results['machine']['cpus']} CPUs; load average "
                 f"{results['machine']['load_before']} before, {results['machine']['load_after']} after)")
    fig.tight_layout(rect=(0, 0.14, 1, 1))
    from qpik.rollout.io import save_figure

    save_figure(fig, path, dpi=110)
    plt.close(fig)


def markdown(results: dict) -> str:
    lines = ["# qpik.batch throughput", "",
             f"`{results['command']}` — {results['machine']['cpus']} CPUs, load average before "
             f"{results['machine']['load_before']}, after {results['machine']['load_after']}.", ""]
    for robot, data in results["throughput"].items():
        rows = data["rows"]
        labels = list(dict.fromkeys(k for r in rows for k in r if k not in ("n", "steps") and not k.startswith("speedup")))
        speedups = list(dict.fromkeys(k for r in rows for k in r if k.startswith("speedup")))
        lines += [f"## {robot}", "", "| N | " + " | ".join(f"{k} (robot-steps/s)" for k in labels) + " | "
                  + " | ".join(f"{k} (median, range)" for k in speedups) + " |",
                  "|" + "---|" * (1 + len(labels) + len(speedups))]
        for r in rows:
            cells = [f"{r[k]['robot_steps_per_s']:.3g}" if k in r else "" for k in labels]
            cells += [f"{r[k]['median']:.2f} ({r[k]['min']:.2f}–{r[k]['max']:.2f})" if k in r else "" for k in speedups]
            lines.append(f"| {r['n']} | " + " | ".join(cells) + " |")
        acc = results["accuracy"].get(robot)
        if acc:
            lines += ["", f"Exactness: {acc['worlds']} worlds, {acc['steps']} steps beside qpik's serial controller: "
                          f"max |q̇_batch − q̇_serial| = {acc['max_qdot_difference']:.2g}, max |q_batch − q_serial| after "
                          f"1 s = {acc['max_q_difference']:.2g} rad; QP stages {acc['qp_stats']}."]
        prof = results["profile"].get(robot)
        if prof:
            lines += ["", f"Profile at N = {prof['n']}: {prof['step_us_per_world']:.2f} µs per robot-step; kinematics "
                          f"{prof['kinematics_share']:.0%}, QP {prof['qp_share']:.0%}, tasks, limits and the rest "
                          f"{prof['tasks_limits_and_rest_share']:.0%}."]
        floor = results.get("mujoco_floor", {}).get(robot)
        if floor:
            lines += ["", f"mujoco.batch on one thread, N = {floor['n']}, per world: a call computing nothing "
                          f"{floor['nothing_us_per_world']:.2f} µs, the position stage (the back-end's call) "
                          f"{floor['position_stage_us_per_world']:.2f} µs ("
                          f"{floor['position_stage_with_timers_us_per_world']:.2f} µs with the Python bindings' "
                          f"profiling timer on), Batch.jac (kinematics + comPos + one Jacobian, no output) "
                          f"{floor['kinematics_jac_us_per_world']:.2f} µs."]
        lines.append("")
    if results.get("mink_warp_accuracy"):
        a = results["mink_warp_accuracy"]
        lines += ["## mink-warp's distance from the exact QP", "",
                  f"mink-warp {results.get('mink_warp_version', '')} constrained solver (Warp CPU device, float32, "
                  f"30 ADMM iterations), pusher arm, {a['worlds']} worlds, {a['steps']} steps, against mink's exact QP "
                  f"(daqp) at the same states: step off by {a['step_relative_error_median']:.1%} (median, relative), "
                  f"{a['step_relative_error_p90']:.1%} (p90); q drifts {a['q_drift_after_1s_rad']:.2g} rad from mink's "
                  "own rollout within 1 s. Its joint ranges were dropped by mink-warp under mujoco 4.0 (a NumPy integer "
                  "compared with enum members); the script patches that, see the script's docstring.", ""]
    if results.get("mink_warp_skipped"):
        lines += [f"mink-warp not measured: {results['mink_warp_skipped']}", ""]
    lines += [f"{why}." for why in results.get("skipped", {}).values()]
    return "\n".join(lines)


def load() -> str:
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def main_inside(args) -> None:
    mink_warp, skipped, version = not args.no_mink_warp, "", ""
    if mink_warp:
        try:
            import importlib.metadata

            patch_mink_warp()
            version = importlib.metadata.version("mink-warp")
        except ImportError as exc:
            mink_warp, skipped = False, f"mink-warp does not import here ({exc})"
    results = {"command": "python benchmarks/batch_throughput.py " + " ".join(sys.argv[1:]).replace("--inside", "").strip(),
               "machine": {"cpus": os.cpu_count(), "python": platform.python_version(), "load_before": load()},
               "throughput": {}, "accuracy": {}, "profile": {}, "mujoco_floor": {}, "mink_warp_version": version,
               "mink_warp_skipped": skipped}
    for robot in args.robots:
        skipped = unbatched(robot)
        if skipped:
            print(skipped, file=sys.stderr, flush=True)
            results.setdefault("skipped", {})[robot] = skipped
            continue
        results["throughput"][robot] = measure(robot, args.sizes, args.repeats, mink_warp and robot == "pusher")
        results["accuracy"][robot] = batch_accuracy(robot)
        results["profile"][robot] = profile_shares(robot)
        results["mujoco_floor"][robot] = mujoco_floor(robot)
    if mink_warp and "pusher" in args.robots:
        results["mink_warp_accuracy"] = mink_warp_accuracy()
    results["machine"]["load_after"] = load()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    from qpik.rollout.io import write_text

    write_text(out / "batch_throughput.json", json.dumps(results, indent=1))
    write_text(out / "batch_throughput.md", markdown(results))
    figure(results, out / "batch_throughput.png")
    print(markdown(results))
    sys.path.insert(0, str(HERE.parent))  # the repository: tools (the results page)
    from tools.results import refresh

    refresh(out)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=list(SIZES))
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--robots", nargs="+", default=["arm", "hexapod", "pusher"], choices=["arm", "hexapod", "pusher"])
    parser.add_argument("--no-mink-warp", action="store_true", help="skip mink-warp (no throwaway environment)")
    parser.add_argument("--out", default=str(RESULTS))
    parser.add_argument("--inside", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.inside or args.no_mink_warp:
        main_inside(args)
        return
    rerun_beside_mink_warp(__file__)


def rerun_beside_mink_warp(script: str) -> None:
    """Run ``script --inside`` (with this process's arguments) in a throwaway environment
    that has mink-warp 0.1 (pinned by constraints.txt) and sees this environment's packages."""
    with tempfile.TemporaryDirectory(prefix="qpik-mink-warp-") as folder:
        venv = Path(folder) / "venv"
        subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
        python = venv / "bin" / "python"
        print("installing mink-warp into a throwaway environment ...", file=sys.stderr, flush=True)
        subprocess.run([str(python), "-m", "pip", "install", "-q", "-c", str(HERE.parent / "constraints.txt"),
                        "mink-warp==0.1.0"], check=True)
        import site

        ours = [p for p in site.getsitepackages() if p.endswith("site-packages")]
        code = ("import site, runpy, sys; [site.addsitedir(p) for p in %r]; sys.argv = %r; "
                "runpy.run_path(%r, run_name='__main__')") % (ours, [script, "--inside", *sys.argv[1:]], script)
        subprocess.run([str(python), "-c", code], check=True)

if __name__ == "__main__":
    main()
