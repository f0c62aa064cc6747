"""Cost of single tasks, each side by side with the computation it replaced, in one run.

Block-interleaved (A, B, A, B, ...) with the garbage collector off (:mod:`timing`), the
median over every call:

- Yoshikawa's gradient: the analytic one (one Jacobian, O(nv) work) against central
  differences over every dof (2 nv kinematics updates on a scratch MjData, the former
  implementation), on the arm and on dm_control's CMU humanoid (free joint + 56 hinges);
- the hexapod's loop-closure rows: EqualityTask (``mj_makeConstraint`` with the other
  constraint types disabled) against two ``mj_jacSite`` per ``connect`` (the former
  LoopClosureTask);
- with ``--against REV``: the QP step of bundled scenarios, this checkout against the
  package at git revision REV, both imported in this process (:func:`timing.import_revision`)
  and block-interleaved.

    python benchmarks/task_costs.py [--against main]
writes benchmarks/results/task_costs.json and .md.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import platform
import sys
import tempfile
from pathlib import Path

import mujoco
import numpy as np

from qpik import EqualityTask, Robot, Yoshikawa
from qpik.rollout.io import write_json, write_text
from timing import Contestant, ControllerRun, import_revision, interleave

RESULTS = Path(__file__).resolve().parent / "results"
ROOT = Path(__file__).resolve().parents[1]


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


def step_rows(revision: str, scenarios: list[str], repeats: int) -> list[dict]:
    """The QP step of each scenario (the timing harness's: set_target, compute_velocity,
    integrate), this checkout against the package at git ``revision``, both in this
    process, block-interleaved."""
    import qpik.scenario

    def qp_run(scenario_module, name: str) -> ControllerRun:
        setup = scenario_module.build_scenario(name)
        return ControllerRun(setup.controller("qp", "daqp"), setup)

    rows = []
    with tempfile.TemporaryDirectory() as folder:
        other = importlib.import_module(import_revision(ROOT, revision, Path(folder)) + ".scenario")
        for name in scenarios:
            timing = interleave([Contestant("new", lambda: qp_run(qpik.scenario, name)),
                                 Contestant("old", lambda: qp_run(other, name))], repeats=repeats)
            median = {row["label"]: row["median_us"] for row in timing.rows()}
            rows.append({"measure": f"QP step, {name} (set_target, compute_velocity, integrate)",
                         "new": "this checkout", "new_us": median["new"], "old": revision, "old_us": median["old"]})
    return rows


def to_markdown(rows: list[dict]) -> str:
    lines = ["| what | new | µs | former | µs | ratio former/new |", "|---|---|---:|---|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['measure']} | {r['new']} | {r['new_us']:.1f} | {r['old']} | {r['old_us']:.1f} | "
                     f"{r['old_us'] / r['new_us']:.2f} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--blocks", type=int, default=15)
    parser.add_argument("--against", metavar="REV", help="a git revision whose QP steps to compare with")
    parser.add_argument("--scenarios", nargs="+", default=["seed-redundant", "joint-limits", "hexapod-circle",
                                                            "hexapod-position-only"])
    args = parser.parse_args(argv)
    rows = yoshikawa_rows(args.blocks) + [loop_rows(args.blocks)]
    if args.against is not None:
        rows += step_rows(args.against, args.scenarios, max(3, args.blocks // 3))
    RESULTS.mkdir(exist_ok=True)
    write_json(RESULTS / "task_costs.json", {"machine": platform.processor() or platform.machine(),
                                             "python": sys.version.split()[0], "rows": rows})
    text = to_markdown(rows)
    write_text(RESULTS / "task_costs.md", text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
