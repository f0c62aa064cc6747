r"""qpik.batch's warp back-end beside mink-warp on one Warp device: throughput against N
(up to 65,536 worlds), the latency of one world, and the kernels' compile time.

The device is ``cuda:0`` when Warp finds a GPU, else Warp's CPU device (``--device``
chooses). Problems are those of benchmarks/batch_throughput.py: the arm, the hexapod
(loops closed, hard) and the 7-DoF pusher arm's pose task with hard joint position and
2 rad/s speed limits; mink-warp runs on the pusher only (its pose + posture tasks, its
damped least squares ``dls`` and its ``constrained`` solver with mink's configuration and
velocity limits, its joint-range bug under mujoco 4.0 patched as there).

Contestants, per N, block-interleaved in one process (benchmarks/timing.py):

- ``qpik warp``: ``batch.Robot.load(..., backend="warp", device=D)`` stepped by the
  engine's ``compute_velocity()`` and ``robots.integrate``: MuJoCo Warp's kinematics and
  Jacobians on the device (float32), the engine's step (the tasks' rows, the limits, the
  QP) on the host in NumPy — until the engine's primitives have device mirrors (the
  controller says so with a ``HostStepWarning``, silenced here);
- ``qpik cpu``: the same problem on the CPU back-end (this machine's CPUs), for scale;
- ``mink-warp dls`` / ``mink-warp constrained`` (pusher), on the same device.

The hexapod is skipped, with a message, while ``qpik.batch`` has no ``EqualityTask``.

Also: the latency at N = 1 (median step), and the compile time: a fresh process with an
empty Warp kernel cache builds each contestant and takes its first step.

Exactness beside speed: every qpik warp world's q̇ against the CPU back-end's exact step
at the same state (float64 kinematics), after the run.

mink-warp is installed into a throwaway virtual environment, with this repository's
constraints (so that MuJoCo Warp and Warp are the versions qpik uses); the measurement
runs there with this environment's packages added after its own.

    python benchmarks/batch_gpu.py [--device cuda:0|cpu] [--sizes 1 64 1024 4096 16384 65536]
                                   [--robots pusher arm hexapod] [--repeats 3] [--no-mink-warp]

writes benchmarks/results/batch_gpu.{json,md}.
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
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import batch_throughput as bt  # noqa: E402  (the problems, shared with the CPU benchmark)

GPU_SIZES = (1, 64, 1024, 4096, 16384, 65536)
CPU_SIZES = (1, 16, 64)
STEPS_PER_RUN = 40


class _BatchOn:
    """``qpik.batch`` with its robots made on one back-end (for bt.build)."""

    __name__ = "qpik.batch"

    def __init__(self, **backend):
        from qpik import batch

        self._batch, self._backend = batch, backend

        class Robot(batch.Robot):
            def __init__(inner, model, n, **kw):  # noqa: N805
                super().__init__(model, n, **kw, **backend)

        self.Robot = Robot

    def __getattr__(self, name):
        return getattr(self._batch, name)


class QpikRun:
    """One qpik problem on a back-end, stepped as a user's loop does."""

    failures = ()

    def __init__(self, name: str, n: int, steps: int, **backend):
        from qpik import batch

        self.robots, tasks, limits, self.mover = bt.build(_BatchOn(**backend), name, n)
        self.controller = batch.QPController(self.robots, tasks, limits, dt=bt.DT)
        self.offset, self.velocity = bt.circle(n, steps, bt.RADIUS[name], axes=(0, 2) if name == "pusher" else (0, 1))
        self.steps = steps

    def step(self, k: int) -> None:
        self.mover(self.offset[k], self.velocity[k])
        self.robots.integrate(self.controller.compute_velocity(), bt.DT)

    def last_qdot(self) -> np.ndarray:
        return self.controller.qdot

    def after(self, k: int) -> None:
        pass


class MinkWarpRun(bt.MinkWarpRun):
    """benchmarks/batch_throughput.py's mink-warp run, on ``device``."""

    def __init__(self, solver: str, n: int, steps: int, device: str):
        import mink_warp as mw
        import warp as wp
        from qpik.models import pusher_arm

        self.wp, self.mw, self.device = wp, mw, device
        model = pusher_arm()
        self.configuration = mw.Configuration(model, q=np.tile(bt.PUSHER_START, (n, 1)), nworld=n, device=device)
        self.hand = mw.FrameTask("tips_arm", "body", position_cost=1.0, orientation_cost=1.0)
        self.hand.set_target_from_configuration(self.configuration)
        self.posture = mw.PostureTask(model, cost=1e-2)
        self.posture.set_target(bt.PUSHER_START)
        self.home = self._home_pose(model)
        self.offset, _ = bt.circle(n, steps, bt.RADIUS["pusher"], axes=(0, 2))
        self.solver = (mw.ConstrainedSolver(self.configuration, limits=bt.mink_warp_limits(model))
                       if solver == "constrained" else mw.DLSSolver(self.configuration))
        self.steps = steps
        self.targets = np.empty((n, 7), dtype=np.float32)

    def step(self, k: int) -> None:
        self.targets[:] = self.home
        self.targets[:, 4:] += self.offset[k]
        self.hand.set_target(self.wp.array(self.targets, dtype=float, device=self.device))
        self.solver.solve_and_integrate([self.hand, self.posture], bt.DT)
        self.configuration.update()
        self.wp.synchronize()


def contestants(robot: str, n: int, steps: int, device: str, mink_warp: bool):
    from timing import Contestant

    out = [Contestant("qpik warp", lambda: QpikRun(robot, n, steps, backend="warp", device=device)),
           Contestant("qpik cpu", lambda: QpikRun(robot, n, steps))]
    if mink_warp and robot == "pusher":
        out += [Contestant("mink-warp dls", lambda: MinkWarpRun("dls", n, steps, device)),
                Contestant("mink-warp constrained", lambda: MinkWarpRun("constrained", n, steps, device))]
    return out


def throughput(robot: str, sizes, repeats: int, device: str, mink_warp: bool) -> list[dict]:
    from timing import interleave

    rows = []
    for n in sizes:
        timing = interleave(contestants(robot, n, STEPS_PER_RUN, device, mink_warp), repeats=repeats,
                            block=STEPS_PER_RUN // 4)
        row = {"n": n}
        for label, c in timing.contestants.items():
            medians = c.repeat_medians_us
            row[label] = {"robot_steps_per_s": float(np.median(n / medians * 1e6)), "step_median_us": float(np.median(medians)),
                          "step_us_per_repeat": [float(m) for m in medians]}
        rows.append(row)
        print(f"{robot} N={n}: " + ", ".join(f"{k} {v['robot_steps_per_s']:.3g}/s" for k, v in row.items() if k != "n"),
              file=sys.stderr, flush=True)
    return rows


def target_cost(robot: str, sizes, device: str, calls: int = 20) -> dict:
    """Microseconds per step that qpik's step spends in ``set_target`` on the host (the
    targets' checks), inside each timed step above: the share of a step the host's target
    API takes."""
    out = {}
    for n in sizes:
        run = QpikRun(robot, n, calls, backend="warp", device=device)
        start = time.perf_counter()
        for k in range(calls):
            run.mover(run.offset[k], run.velocity[k])
        out[str(n)] = (time.perf_counter() - start) / calls * 1e6
    return out


def exactness(robot: str, n: int, device: str, steps: int = 50) -> dict:
    """After ``steps`` warp steps: each world's q̇ of the next step against the CPU
    back-end's exact step at the same state and targets (float64 kinematics)."""
    run = QpikRun(robot, n, steps + 1, backend="warp", device=device)
    for k in range(steps):
        run.step(k)
    state = run.robots.q.copy()
    run.step(steps)
    qdot = run.last_qdot()
    reference = QpikRun(robot, n, steps + 1)
    reference.robots.set_q(state)
    reference.mover(run.offset[steps], run.velocity[steps])
    exact = reference.controller.compute_velocity()
    scale = max(1.0, float(np.abs(exact).max()))
    limits = run.robots.joint_limits
    q = run.robots.q[:, limits.qpos_index]
    return {"worlds": n, "steps": steps, "max_qdot_difference": float(np.abs(qdot - exact).max()),
            "relative": float(np.abs(qdot - exact).max() / scale),
            "max_beyond_range": float(max((limits.lower - q).max(), (q - limits.upper).max())), "step": "host"}


def latency(robot: str, device: str, mink_warp: bool, repeats: int) -> dict:
    from timing import interleave

    timing = interleave(contestants(robot, 1, 200, device, mink_warp), repeats=repeats, block=50)
    return {row["label"]: {"median_us": row["median_us"], "p99_us": row["p99_us"]} for row in timing.rows()}


FIRST_STEP = """
import site, sys, time
for folder in {sites!r}:
    site.addsitedir(folder)
sys.path.insert(0, {here!r})
start = time.perf_counter()
import batch_gpu as g
run = {make}
run.step(0)
print(time.perf_counter() - start)
"""


def compile_times(robot: str, device: str, mink_warp: bool) -> dict:
    """Seconds from import to the end of the first step, in a fresh process with an empty
    Warp kernel cache (everything compiled), then again with the cache filled."""
    makes = {"qpik warp": f"g.QpikRun({robot!r}, 1, 2, backend='warp', device={device!r})"}
    if mink_warp and robot == "pusher":
        makes["mink-warp constrained"] = f"g.bt.patch_mink_warp() or g.MinkWarpRun('constrained', 1, 2, {device!r})"
    out = {}
    for label, make in makes.items():
        with tempfile.TemporaryDirectory(prefix="qpik-warp-cache-") as cache:
            env = {**os.environ, "WARP_CACHE_PATH": cache}
            sites = [p for p in sys.path if p.endswith("site-packages")]
            code = FIRST_STEP.format(sites=sites, here=str(HERE), make=make)
            times = [_first_step_seconds(code, env) for _ in range(2)]
        out[label] = {"cold_s": times[0], "cached_s": times[1]}
        print(f"{robot} compile {label}: {times[0]:.1f} s cold, {times[1]:.1f} s cached", file=sys.stderr, flush=True)
    return out


def _first_step_seconds(code: str, env: dict) -> float:
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    if done.returncode:
        raise RuntimeError(f"the first-step process failed: {done.stderr[-2000:]}")
    return float(done.stdout.split()[-1])


def device_name(device: str) -> str:
    import warp as wp

    return wp.get_device(device).name


def markdown(results: dict) -> str:
    lines = [f"# qpik.batch on a Warp device: {results['device']} ({results['device_name']})", "",
             f"`{results['command']}` — {results['machine']['cpus']} CPUs, load {results['machine']['load_before']} "
             f"before, {results['machine']['load_after']} after.", ""]
    for robot, data in results["robots"].items():
        labels = [k for k in data["throughput"][0] if k != "n"]
        lines += [f"## {robot}", "", "| N | " + " | ".join(f"{k} (robot-steps/s)" for k in labels) + " |",
                  "|" + "---|" * (1 + len(labels))]
        for row in data["throughput"]:
            lines.append(f"| {row['n']} | " + " | ".join(f"{row[k]['robot_steps_per_s']:.3g}" for k in labels) + " |")
        lat = ", ".join(f"{k} {v['median_us']:.0f} µs" for k, v in data["latency"].items())
        comp = ", ".join(f"{k} {v['cold_s']:.1f} s (cached {v['cached_s']:.1f} s)" for k, v in data["compile"].items())
        ex = data["exactness"]
        cost = ", ".join(f"{us:.0f} µs at N = {n}" for n, us in data.get("set_target_us", {}).items())
        lines += ["", "qpik warp: kinematics on the device, the engine's step on the host.",
                  f"Of each qpik step, set_target on the host took {cost}.",
                  f"Latency at N = 1 (median step): {lat}.",
                  f"First step in a fresh process: {comp}.",
                  f"qpik warp against the CPU back-end's exact step at the same states ({ex['worlds']} worlds, after "
                  f"{ex['steps']} steps): max |Δq̇| = {ex['max_qdot_difference']:.2g} ({ex['relative']:.2g} relative: "
                  f"float32 kinematics); farthest beyond a joint range {ex['max_beyond_range']:.2g}.", ""]
    if results.get("mink_warp_skipped"):
        lines += [f"mink-warp not measured: {results['mink_warp_skipped']}", ""]
    lines += [f"{why}." for why in results.get("skipped", {}).values()]
    return "\n".join(lines)


def main_inside(args) -> None:
    import warp as wp
    from qpik import batch

    warnings.simplefilter("ignore", batch.HostStepWarning)  # the step on the host: said in the results

    device = args.device or ("cuda:0" if wp.get_cuda_device_count() else "cpu")
    sizes = args.sizes or (GPU_SIZES if device.startswith("cuda") else CPU_SIZES)
    mink_warp, skipped = not args.no_mink_warp, ""
    if mink_warp:
        try:
            bt.patch_mink_warp()
        except ImportError as exc:
            mink_warp, skipped = False, f"mink-warp does not import here ({exc})"
    results = {"command": "python benchmarks/batch_gpu.py " + " ".join(a for a in sys.argv[1:] if a != "--inside"),
               "device": device, "device_name": device_name(device),
               "machine": {"cpus": os.cpu_count(), "python": platform.python_version(), "load_before": bt.load()},
               "robots": {}, "mink_warp_skipped": skipped}
    for robot in args.robots:
        skipped = bt.unbatched(robot)
        if skipped:
            print(skipped, file=sys.stderr, flush=True)
            results.setdefault("skipped", {})[robot] = skipped
            continue
        results["robots"][robot] = {
            "compile": compile_times(robot, device, mink_warp),
            "throughput": throughput(robot, sizes, args.repeats, device, mink_warp),
            "set_target_us": target_cost(robot, sizes, device),
            "latency": latency(robot, device, mink_warp, args.repeats),
            "exactness": exactness(robot, min(64, max(sizes)), device),
        }
    results["machine"]["load_after"] = bt.load()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    from qpik.rollout.io import write_text

    write_text(out / "batch_gpu.json", json.dumps(results, indent=1))
    write_text(out / "batch_gpu.md", markdown(results))
    print(markdown(results))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--device", default=None, help="a Warp device: cuda:0 (default when there is a GPU) or cpu")
    parser.add_argument("--sizes", type=int, nargs="+", default=None)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--robots", nargs="+", default=["pusher", "arm", "hexapod"], choices=["arm", "hexapod", "pusher"])
    parser.add_argument("--no-mink-warp", action="store_true", help="skip mink-warp (no throwaway environment)")
    parser.add_argument("--out", default=str(bt.RESULTS))
    parser.add_argument("--inside", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.inside or args.no_mink_warp:
        main_inside(args)
        return
    bt.rerun_beside_mink_warp(__file__)

if __name__ == "__main__":
    main()
