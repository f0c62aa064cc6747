"""Cost of single tasks, each side by side with the computation it replaced, in one run.

Block-interleaved (A, B, A, B, ...) with the garbage collector off (:mod:`timing`), the
median over every call:

- Yoshikawa's gradient: the analytic one (one Jacobian, O(nv) work) against central
  differences over every dof (2 nv kinematics updates on a scratch MjData, the former
  implementation), on the arm and on dm_control's CMU humanoid (free joint + 56 hinges);
- the hexapod's loop-closure rows: EqualityTask (``mj_makeConstraint`` with the other
  constraint types disabled) against two ``mj_jacSite`` per ``connect`` (the former
  LoopClosureTask);
- with ``--baseline-src DIR`` (a ``src/`` of another checkout, e.g. from
  ``git archive <commit> src | tar -x -C /tmp/base``): the QP step of bundled scenarios,
  this checkout against that one, in alternating subprocesses.

    python benchmarks/task_costs.py [--baseline-src /tmp/base/src --baseline-label main]
writes benchmarks/results/task_costs.json and .md.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import platform
import subprocess
import sys
from pathlib import Path

import mujoco
import numpy as np

from qpik import EqualityTask, Robot, Yoshikawa
from qpik.io import write_json, write_text
from timing import Contestant, interleave

RESULTS = Path(__file__).resolve().parent / "results"
SRC = Path(__file__).resolve().parents[1] / "src"


def central_difference_gradient(measure: Yoshikawa, scratch: mujoco.MjData, jac: np.ndarray, out: np.ndarray,
                                step: float = 1e-6) -> None:
    """The former Yoshikawa gradient: central differences over each dof on a scratch MjData."""
    robot = measure.robot
    model, dq = robot.model, np.zeros(robot.nv)
    jacobian = mujoco.mj_jacSite if measure.frame.type == "site" else mujoco.mj_jacBody
    for k in range(robot.nv):
        values = []
        for sign in (1.0, -1.0):
            scratch.qpos[:] = robot.q
            dq[:] = 0.0
            dq[k] = sign * step
            mujoco.mj_integratePos(model, scratch.qpos, dq, 1.0)
            mujoco.mj_kinematics(model, scratch)
            mujoco.mj_comPos(model, scratch)
            jacobian(model, scratch, jac, None, measure.frame.id)
            rows = jac[measure.position_rows]
            values.append(float(np.sqrt(max(np.linalg.det(rows @ rows.T), 0.0))))
        out[k] = (values[0] - values[1]) / (2.0 * step)


def site_loop_rows(robot: Robot, equalities, jac1, jac2, jacobian, error):
    """The former LoopClosureTask: e = p1 − p2 and J = J(p1) − J(p2) per site connect."""
    model, data = robot.model, robot.data
    for k, eq in enumerate(equalities):
        s1, s2 = model.eq_obj1id[eq], model.eq_obj2id[eq]
        np.subtract(data.site_xpos[s1], data.site_xpos[s2], out=error[3 * k:3 * k + 3])
        mujoco.mj_jacSite(model, data, jac1[k], None, s1)
        mujoco.mj_jacSite(model, data, jac2[k], None, s2)
    np.subtract(jac1, jac2, out=jacobian.reshape(jac1.shape))


class _Calls:
    """A callable as a timing contestant: each step one call."""

    failures = ()

    def __init__(self, call, steps: int):
        self.call, self.steps = call, steps

    def step(self, k: int) -> None:
        self.call()

    def after(self, k: int) -> None:
        pass


def interleaved(calls: dict, number: int, blocks: int) -> dict:
    """Median µs per call of each callable, over ``blocks`` interleaved blocks of ``number``
    calls each (3 repeats)."""
    contestants = [Contestant(name, lambda call=call: _Calls(call, number * blocks + 1)) for name, call in calls.items()]
    timing = interleave(contestants, repeats=3, block=number)
    return {row["label"]: row["median_us"] for row in timing.rows()}


def yoshikawa_rows(blocks: int) -> list[dict]:
    rows = []
    cases = [("arm", Robot.load("arm"), "end_effector", "site", "xy")]
    spec = importlib.util.find_spec("dm_control")
    if spec is not None:
        path = Path(spec.origin).parent / "suite" / "humanoid_CMU.xml"
        cases.append(("humanoid_CMU", Robot.load(path), "lhand", "body", "xyz"))
    for name, robot, frame, frame_type, axes in cases:
        mujoco.mj_integratePos(robot.model, robot.q, np.random.default_rng(0).normal(scale=0.3, size=robot.nv), 1.0)
        robot.update_kinematics()
        measure = Yoshikawa(robot, frame, frame_type, axes=axes)
        scratch, analytic, numeric = mujoco.MjData(robot.model), np.zeros(robot.nv), np.zeros(robot.nv)
        jac = np.zeros((3, robot.nv))
        measure.gradient(analytic)
        central_difference_gradient(measure, scratch, jac, numeric)
        agreement = float(np.max(np.abs(analytic - numeric)) / np.max(np.abs(numeric)))
        fd_calls = max(2, 2000 // robot.nv)
        t = interleaved({"analytic": lambda: measure.gradient(analytic),
                         "central differences": lambda: central_difference_gradient(measure, scratch, jac, numeric)},
                        fd_calls, blocks)
        rows.append({"measure": f"Yoshikawa gradient, {name} ({frame}, nv={robot.nv})", "new": "analytic",
                     "new_us": t["analytic"], "old": "central differences", "old_us": t["central differences"],
                     "relative_agreement": agreement})
    return rows


def loop_rows(blocks: int) -> dict:
    robot = Robot.load("hexapod")
    task = EqualityTask(robot, [f"loop{i}" for i in range(1, 7)], gain=500.0)
    n = len(task.equalities)
    jac1, jac2 = np.zeros((n, 3, robot.nv)), np.zeros((n, 3, robot.nv))
    jacobian, error = np.zeros((3 * n, robot.nv)), np.zeros(3 * n)
    site_loop_rows(robot, task.equalities, jac1, jac2, jacobian, error)
    task.update()
    agreement = float(max(np.max(np.abs(jacobian - task.jacobian)), np.max(np.abs(error - task.error))))
    t = interleaved({"equality": task.update,
                     "sites": lambda: site_loop_rows(robot, task.equalities, jac1, jac2, jacobian, error)}, 200, blocks)
    return {"measure": "hexapod loop rows (6 connects, 18 x 24)", "new": "EqualityTask (mj_makeConstraint)",
            "new_us": t["equality"], "old": "2 mj_jacSite per loop", "old_us": t["sites"], "max_difference": agreement}


STEP_SCRIPT = """
import gc, json, sys, time
import numpy as np
from qpik.scenario import build_scenario
out = {}
for name in sys.argv[1:]:
    setup = build_scenario(name)
    controller = setup.controller("qp", "daqp")
    robot, dt = setup.robot, setup.dt
    times = []
    gc.disable()
    for k in range(int(setup.duration / dt)):
        setup.reference.apply(k * dt)
        start = time.perf_counter()
        robot.update_kinematics()
        qdot = controller.compute_velocity()
        times.append(time.perf_counter() - start)
        robot.integrate(qdot, dt)
    gc.enable()
    out[name] = float(np.median(times[1:]) * 1e6)
print(json.dumps(out))
"""


def step_rows(baseline_src: Path, label: str, scenarios: list[str], blocks: int) -> list[dict]:
    """Median QP step (kinematics + compute_velocity) over a scenario's kinematic rollout,
    this checkout vs another, in alternating subprocesses."""
    times = {("new", s): [] for s in scenarios} | {("old", s): [] for s in scenarios}
    for _ in range(blocks):
        for which, src in (("new", SRC), ("old", baseline_src)):
            env = dict(os.environ, PYTHONPATH=str(src))
            done = subprocess.run([sys.executable, "-c", STEP_SCRIPT, *scenarios], env=env, check=True,
                                  capture_output=True, text=True)
            for name, value in json.loads(done.stdout).items():
                times[(which, name)].append(value)
    return [{"measure": f"QP step, {s} (kinematics + compute_velocity)", "new": "this checkout",
             "new_us": float(np.median(times[("new", s)])), "old": label,
             "old_us": float(np.median(times[("old", s)]))} for s in scenarios]


def to_markdown(rows: list[dict]) -> str:
    lines = ["| what | new | µs | former | µs | ratio former/new |", "|---|---|---:|---|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['measure']} | {r['new']} | {r['new_us']:.1f} | {r['old']} | {r['old_us']:.1f} | "
                     f"{r['old_us'] / r['new_us']:.2f} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--blocks", type=int, default=15)
    parser.add_argument("--baseline-src", type=Path, help="src/ of another checkout to compare QP steps with")
    parser.add_argument("--baseline-label", help="what the baseline is (default: its path)")
    parser.add_argument("--scenarios", nargs="+", default=["seed-redundant", "joint-limits", "hexapod-circle",
                                                            "hexapod-position-only"])
    args = parser.parse_args(argv)
    rows = yoshikawa_rows(args.blocks) + [loop_rows(args.blocks)]
    if args.baseline_src is not None:
        label = args.baseline_label or str(args.baseline_src)
        rows += step_rows(args.baseline_src, label, args.scenarios, max(3, args.blocks // 3))
    RESULTS.mkdir(exist_ok=True)
    write_json(RESULTS / "task_costs.json", {"machine": platform.processor() or platform.machine(),
                                             "python": sys.version.split()[0], "rows": rows})
    text = to_markdown(rows)
    write_text(RESULTS / "task_costs.md", text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
