"""Monte-Carlo sweep: random reachable targets, every controller rolled out on each.

Arm: a configuration drawn uniformly within the joint limits gives, by forward kinematics,
a target that the arm can reach; the reference runs a straight segment from the start
pose (0.5, 2) m to it under the quintic law in 1 s, then holds it 0.5 s (751 steps).
Both priorities of the position task, on the same targets:

- ``hard``: the position task as an equality and the σ task (k0 = 5) as the cost, as in
  ``seed-redundant``. A random segment may need more than the joints' speed limits allow
  (or run a joint into its range): the QP is then infeasible and the run stops — counted
  as a failure, as a user would see it.
- ``soft``: the position task as a weighted cost with Levenberg–Marquardt damping plus a
  small damping task, as in ``unreachable``: what a user picks when a target may be out
  of reach in time; the QP always has a solution and the arm catches up once it can.

A run succeeds when it completes with a final error ≤ 1e-3 m, no commanded joint beyond
its range and no commanded speed beyond its limit (both to within 1e-6). Per controller:
success rate, the reasons of failures, the largest limit and speed violations, max-error
percentiles over the runs, step time median / p99 over all steps.

    python benchmarks/monte_carlo.py [--n 1000] [--seed 0] [--priority hard,soft]
        [--controllers qp:daqp,qp:osqp,pinv,mink:daqp,mink:osqp,placo]

Hexapod: poses drawn as for the calibration (uniform in home ± (8, 6, 4) cm and ±10° in
roll, pitch, yaw; kept if every leg reaches within its stroke and the manipulability is
at least 0.02); the platform goes there from home along a straight segment while its
roll-pitch-yaw angles move linearly, both under the quintic law in 1 s, then holds
0.5 s. ``hard``: the 6-D pose task as an equality (as ``hexapod-circle``); ``soft``: as a
weighted cost with Levenberg–Marquardt damping (as ``hexapod-stroke-limits``). Success as
for the arm, the error being the platform position error.

writes benchmarks/results/monte_carlo_<robot>.{json,md,npz,png}.
"""

from __future__ import annotations

import argparse
import platform
import sys
from collections import Counter
from pathlib import Path

import numpy as np
from tqdm import tqdm

from qpik.app.progress import wanted

from qpik.robots.hexapod.calibration import sample_poses
from qpik.rollout.io import save_figure, write_json, write_npz, write_text
from qpik.robots.hexapod.kinematics import HexapodGeometry
from qpik.robots.hexapod.scenarios import hexapod_setup
from qpik.app.peers import PEERS, PLACO_SOLVER, peer_installed
from qpik.robot import Robot
from qpik.robots.arm.scenarios import SEED_PATH, arm_setup
from qpik.scenario import Setup
from qpik.trajectories import PoseTrajectory, Segment
from timing import timed_run

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository: tools (the results page)

from tools.results import refresh  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
MOVE, HOLD = 1.0, 0.5  # s: quintic segment, then the target held
SUCCESS_ERROR = 1e-3  # m
VIOLATION_TOL = 1e-6  # joint units (position) and joint units/s (speed)
DEFAULT_CONTROLLERS = "qp:daqp,qp:osqp,pinv,mink:daqp,mink:osqp,placo"


def parse_controllers(text: str) -> list[tuple[str, str]]:
    """``qp:daqp,pinv,placo`` → [("qp", "daqp"), ("pinv", "none"), ("placo", "eiquadprog")]."""
    out = []
    for item in filter(None, (s.strip() for s in text.split(","))):
        kind, _, solver = item.partition(":")
        out.append((kind, solver or (PLACO_SOLVER if kind == "placo" else "none")))
    return out


def arm_targets(n: int, seed: int) -> np.ndarray:
    """n reachable end-effector targets (x, y): FK of q uniform within the joint limits."""
    robot = Robot.load("arm")
    site = robot.site_id("end_effector")
    limits = robot.joint_limits
    rng = np.random.default_rng(seed)
    targets = np.empty((n, 2))
    for k in range(n):
        robot.q[limits.qpos_index] = rng.uniform(limits.lower, limits.upper)
        robot.update_kinematics()
        targets[k] = robot.site_position(site)[:2]
    return targets


def arm_trial(target: np.ndarray, hard: bool) -> Setup:
    segment = Segment(SEED_PATH[0], target, MOVE, time_law="quintic")
    return arm_setup(f"monte-carlo-{'hard' if hard else 'soft'}", segment, redundant=hard, hard=hard,
                     duration=MOVE + HOLD)


def hexapod_targets(n: int, seed: int) -> np.ndarray:
    """n reachable, well-conditioned platform poses [x, y, z (m), θx, θy, θz (deg)]."""
    return sample_poses(n, np.random.default_rng(seed), [HexapodGeometry.default()])[0]


def hexapod_trial(pose: np.ndarray, hard: bool) -> Setup:
    home = HexapodGeometry.default().home_position
    trajectory = PoseTrajectory(Segment(home, pose[:3], MOVE, time_law="quintic"),
                                Segment(np.zeros(3), pose[3:], MOVE, time_law="quintic"))
    return hexapod_setup(f"monte-carlo-{'hard' if hard else 'soft'}", trajectory, orientation=True, hard=hard,
                         duration=MOVE + HOLD)


ROBOTS = {"arm": (arm_targets, arm_trial), "hexapod": (hexapod_targets, hexapod_trial)}


def sweep(robot: str, targets: np.ndarray, hard: bool, controllers: list[tuple[str, str]]) -> dict:
    """Roll every controller out on every target; per-run metrics and step times."""
    n = len(targets)
    metrics = {c: {key: np.zeros(n) for key in ("completed", "max_error", "final_error", "limit", "speed")}
               for c in controllers}
    times = {c: [] for c in controllers}
    failures = {c: [] for c in controllers}
    label = "hard" if hard else "soft"
    trial = ROBOTS[robot][1]
    bar = tqdm(total=n * len(controllers), desc=f"{robot}, {label} task", unit="run", file=sys.stderr,
               disable=not wanted())
    for k, target in enumerate(targets):
        for controller, solver in controllers:
            setup = trial(target, hard)
            _, log = timed_run(robot, setup.scenario, controller, solver, on_failure="stop", setup=setup)
            m = metrics[(controller, solver)]
            m["completed"][k] = log.completed
            m["max_error"][k] = log.error.max()
            m["final_error"][k] = log.error[-1]
            m["limit"][k] = log.limit_violation.max()
            m["speed"][k] = max(0.0, float(np.max(np.abs(log.qdot) - setup.robot.velocity_limits)))
            times[(controller, solver)].append(log.step_time[1:].astype(np.float32))  # step 0 sets up solvers
            if not log.completed:
                failures[(controller, solver)].append(log.failure)
            bar.update()
    bar.close()
    return {"metrics": metrics, "times": times, "failures": failures}


def summarize(result: dict) -> list[dict]:
    rows = []
    for (controller, solver), m in result["metrics"].items():
        completed = m["completed"].astype(bool)
        error_ok = m["final_error"] <= SUCCESS_ERROR
        limit_ok = m["limit"] <= VIOLATION_TOL
        speed_ok = m["speed"] <= VIOLATION_TOL
        success = completed & error_ok & limit_ok & speed_ok
        t = np.concatenate(result["times"][(controller, solver)]) * 1e6
        p50, p95, p99 = np.percentile(m["max_error"], [50, 95, 99])
        rows.append({
            "controller": controller, "solver": solver, "runs": int(len(success)),
            "success_rate": float(success.mean()),
            "failures": {"stopped": int((~completed).sum()), "final_error": int((completed & ~error_ok).sum()),
                         "limit_violation": int((~limit_ok).sum()), "speed_violation": int((~speed_ok).sum())},
            "stop_reasons": dict(Counter(f.split(" at t")[0] for f in result["failures"][(controller, solver)])),
            "limit_violation_max": float(m["limit"].max()), "speed_violation_max": float(m["speed"].max()),
            "max_error_p50": float(p50), "max_error_p95": float(p95), "max_error_p99": float(p99),
            "max_error_max": float(m["max_error"].max()), "final_error_p99": float(np.percentile(m["final_error"], 99)),
            "step_median_us": float(np.median(t)), "step_p99_us": float(np.percentile(t, 99)),
        })
    return rows


def to_markdown(robot: str, n: int, seed: int, tables: dict[str, list[dict]]) -> str:
    lines = [f"Monte Carlo on the {robot}: {n} random reachable targets (seed {seed}), quintic segment "
             f"{MOVE:g} s + hold {HOLD:g} s. Success: completed, final error ≤ {SUCCESS_ERROR:g} m, no joint "
             f"beyond its range and no speed beyond its limit (to {VIOLATION_TOL:g}). Failures: stopped early / "
             "final error / range / speed (a run may count in several)."]
    for priority, rows in tables.items():
        lines += ["", f"**{priority} {'position' if robot == 'arm' else 'pose'} task**", "",
                  "| controller | solver | success | failures | max range viol. | max speed viol. | "
                  "max error p50 / p95 / p99 [m] | step median / p99 [µs] |",
                  "|---|---|---:|---|---:|---:|---|---|"]
        for r in rows:
            f = r["failures"]
            lines.append(
                f"| {r['controller']} | {r['solver']} | {100 * r['success_rate']:.1f} % | "
                f"{f['stopped']} / {f['final_error']} / {f['limit_violation']} / {f['speed_violation']} | "
                f"{r['limit_violation_max']:.1e} | {r['speed_violation_max']:.1e} | "
                f"{r['max_error_p50']:.1e} / {r['max_error_p95']:.1e} / {r['max_error_p99']:.1e} | "
                f"{r['step_median_us']:.1f} / {r['step_p99_us']:.1f} |")
        stops = [f"- {r['controller']} ({r['solver']}) stopped on: "
                 + ", ".join(f"{why} × {count}" for why, count in r["stop_reasons"].items())
                 for r in rows if r["stop_reasons"]]
        lines += [""] + stops if stops else []
    return "\n".join(lines) + "\n"


def plot(results: dict[str, dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(results), 2, figsize=(12, 4.2 * len(results)), squeeze=False)
    for row, (priority, result) in enumerate(results.items()):
        ax_cdf, ax_box = axes[row]
        labels, medians = [], []
        for i, ((controller, solver), m) in enumerate(result["metrics"].items()):
            label = controller if solver in ("none", PLACO_SOLVER) else f"{controller} ({solver})"
            # A run stopped early never reaches its target: inf, so its curve stays below 1.
            errors = np.sort(np.where(m["completed"] > 0, np.maximum(m["max_error"], 1e-12), np.inf))
            # Controllers solving the same problem overlap: thinner, dashed lines on top.
            ax_cdf.step(errors, np.arange(1, len(errors) + 1) / len(errors), where="post", label=label,
                        lw=3.0 - 0.4 * i, ls=("-", "--", "-.", ":")[i % 4])
            labels.append(label)
            medians.append([np.median(t) * 1e6 for t in result["times"][(controller, solver)]])
        ax_cdf.axvline(SUCCESS_ERROR, color="k", lw=0.8, ls=":")
        ax_cdf.set(xscale="log", xlabel="max tracking error of a run [m]", ylabel="fraction of runs",
                   title=f"{priority} task: error CDF (runs stopped early never reach 1)")
        ax_cdf.grid(alpha=0.3)
        ax_cdf.legend(fontsize=8)
        ax_box.boxplot(medians, showfliers=False)
        ax_box.set_xticks(range(1, len(labels) + 1), labels, rotation=30, ha="right", fontsize=8)
        ax_box.set(yscale="log", ylabel="median step time of a run [µs]", title=f"{priority} task: step time")
        ax_box.grid(alpha=0.3, axis="y")
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robot", default="arm,hexapod", help="arm, hexapod or both (comma-separated)")
    parser.add_argument("--n", type=int, default=1000, help="random targets per robot")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--priority", default="hard,soft", help="hard, soft or both (comma-separated)")
    parser.add_argument("--controllers", default=DEFAULT_CONTROLLERS, help="kind[:solver], comma-separated")
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    controllers = []
    for kind, solver in parse_controllers(args.controllers):
        if kind in PEERS and not peer_installed(kind):
            print(f"{kind} not installed: skipped")
            continue
        controllers.append((kind, solver))
    for robot in filter(None, args.robot.split(",")):
        if robot not in ROBOTS:
            parser.error(f"unknown robot {robot!r}; choose from {', '.join(ROBOTS)}")
        targets = ROBOTS[robot][0](args.n, args.seed)
        results = {p: sweep(robot, targets, p == "hard", controllers) for p in args.priority.split(",") if p}
        tables = {p: summarize(r) for p, r in results.items()}
        md = to_markdown(robot, args.n, args.seed, tables)
        print(md)
        stem = args.out / f"monte_carlo_{robot}"
        meta = {"python": sys.version.split()[0], "machine": platform.machine(), "processor": platform.processor()}
        write_json(stem.with_suffix(".json"), {"robot": robot, "n": args.n, "seed": args.seed, "meta": meta,
                                               "move_s": MOVE, "hold_s": HOLD, "results": tables})
        write_text(stem.with_suffix(".md"), md)
        write_npz(stem.with_suffix(".npz"), targets=targets, **{
            f"{p}/{c}:{s}/{key}": v for p, r in results.items() for (c, s), m in r["metrics"].items()
            for key, v in m.items()})
        plot(results, stem.with_suffix(".png"))
    return refresh(args.out)


if __name__ == "__main__":
    sys.exit(main())
