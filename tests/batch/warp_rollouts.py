"""Closed-loop rollouts that compare batched back-ends, world by world.

One problem per robot (a frame or position task, a posture task, the hexapod's loop
closures as hard rows, joint position and velocity limits), assembled from any
:class:`~qpik.batch.backends.base.KinematicsBackend` and solved by any
:class:`~qpik.batch.backends.base.BatchQP` or by DAQP world by world. The same problem is
built with the serial controller (``qpik.QPController``) as the anchor: the assembly here
must equal it to 1e-9 before it can tell two back-ends apart.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import mujoco
import numpy as np

import qpik
from qpik.tasks.task import rotation_error, scalar_dofs

DT = 0.002
REGULARIZATION = 1e-12
POSTURE_WEIGHT = 1e-3
MARGIN = 1e-10  # JointPositionLimit's default


@dataclass
class Problem:
    """What a robot's rollout tracks: a frame's position (``axes``) and, when
    ``orientation``, its rotation; targets per world."""

    scene: str
    frame: str
    frame_type: str
    axes: str
    orientation: bool
    gain: float
    velocity_limits: dict | None
    equality: bool
    targets: np.ndarray = field(default=None)  # (N, 3)

    def serial_robot(self) -> qpik.Robot:
        return qpik.Robot.load(self.scene)


def problems(n: int, pusher_path: str) -> dict[str, Problem]:
    """The arm, the hexapod (loops closed) and the 7-DoF pusher arm, far targets that
    drive joints into their position and velocity limits."""
    rng = np.random.default_rng(7)
    arm = Problem("arm", "end_effector", "site", "xy", False, 50.0, None, False)
    # Inside the reach, away from the stretched singularity, 0.5-1 m from the start: the
    # speed limits bind on the way.
    radius, angle = rng.uniform(0.9, 1.6, n), rng.uniform(0.3, 2.8, n)
    arm.targets = np.column_stack([radius * np.cos(angle), radius * np.sin(angle), np.zeros(n)])
    hexapod = Problem("hexapod", "platform_center", "site", "xyz", True, 20.0, None, True)
    home = qpik.Robot.load("hexapod").frame("platform_center", "site").position
    hexapod.targets = home + rng.uniform(-0.08, 0.08, (n, 3))
    pusher = Problem(pusher_path, "tips_arm", "body", "xyz", False, 20.0,
                     {f"r_{j}_joint": 1.5 for j in ("shoulder_pan", "shoulder_lift", "upper_arm_roll", "elbow_flex",
                                                    "forearm_roll", "wrist_flex", "wrist_roll")}, False)
    pusher.targets = np.column_stack([rng.uniform(0.2, 1.0, n), rng.uniform(-0.9, 0.3, n), rng.uniform(-0.6, 0.4, n)])
    return {"arm": arm, "hexapod": hexapod, "pusher": pusher}


class Assembly:
    """H, c, A, b, lb, ub of every world from a kinematics back-end, as the serial
    controller builds them for :func:`serial_controller`'s tasks and limits."""

    def __init__(self, problem: Problem, backend, template: qpik.Robot):
        self.problem, self.backend, self.model = problem, backend, backend.model
        m = self.model
        self.frame = template.frame(problem.frame, problem.frame_type)
        self.body = int(m.site_bodyid[self.frame.id]) if problem.frame_type == "site" else self.frame.id
        self.position, self.rotation = backend.frame_pose(problem.frame_type, self.frame.id)
        self.target_rotation = self.frame.rotation.copy()
        self.rows = ["xyz".index(a) for a in problem.axes]
        self.posture_dofs = scalar_dofs(template)
        self.posture_target = template.q.copy()
        limits = template.joint_limits
        self.limit_q, self.limit_dofs = limits.qpos_index, limits.dof_index
        self.lower, self.upper = limits.lower + MARGIN, limits.upper - MARGIN
        vmax = qpik.JointVelocityLimit(template, problem.velocity_limits).max_velocity
        self.vmax = vmax
        self.equalities = np.arange(m.neq) if problem.equality else None

    def build(self) -> tuple:
        """The step's QP in every world (the back-end's kinematics must be current)."""
        be, p, m = self.backend, self.problem, self.model
        n, nv = be.nworld, m.nv
        jacp, jacr = be.jacobian(self.body, self.position)
        rows = [jacp[:, self.rows]]
        errors = [(p.targets - self.position)[:, self.rows]]
        if p.orientation:
            rows.append(jacr)
            errors.append(np.array([rotation_error(self.target_rotation, r) for r in self.rotation]))
        J, v = np.concatenate(rows, axis=1), p.gain * np.concatenate(errors, axis=1)
        H = np.einsum("nki,nkj->nij", J, J) + REGULARIZATION * np.eye(nv)
        c = -np.einsum("nki,nk->ni", J, v)
        posture = np.zeros((n, nv))
        for w in range(n):
            mujoco.mj_differentiatePos(m, posture[w], 1.0, be.qpos[w], self.posture_target)
        dofs = self.posture_dofs
        H[:, dofs, dofs] += POSTURE_WEIGHT
        c[:, dofs] -= POSTURE_WEIGHT * posture[:, dofs]  # the posture gain is 1
        if self.equalities is not None:
            residual, A = be.equality_rows(self.equalities)
            b = -residual / DT
        else:
            A, b = np.zeros((n, 0, nv)), np.zeros((n, 0))
        return H, c, A, b, *self.box()

    def box(self) -> tuple[np.ndarray, np.ndarray]:
        """The velocity box, then JointPositionLimit's (gain 1, no damper)."""
        n = self.backend.nworld
        lb, ub = np.tile(-self.vmax, (n, 1)), np.tile(self.vmax, (n, 1))
        q = self.backend.qpos[:, self.limit_q]
        low, high = (self.lower - q) / DT, (self.upper - q) / DT
        vel_lo, vel_hi = lb[:, self.limit_dofs], ub[:, self.limit_dofs]
        low, high = np.minimum(low, vel_hi), np.maximum(high, vel_lo)
        lb[:, self.limit_dofs] = np.maximum(vel_lo, low)
        ub[:, self.limit_dofs] = np.minimum(vel_hi, high)
        return lb, ub


def quadprog_solve(H, c, A, b, lb, ub) -> np.ndarray:
    """Every world by quadprog (Goldfarb–Idnani in double precision, exact at its end:
    no tolerance), one at a time: the reference for an exact QP."""
    import quadprog

    x = np.zeros_like(c)
    nv = c.shape[1]
    for w in range(len(c)):
        finite_lb, finite_ub = np.isfinite(lb[w]), np.isfinite(ub[w])
        rows = np.vstack([A[w], np.eye(nv)[finite_lb], -np.eye(nv)[finite_ub]])
        values = np.concatenate([b[w], lb[w][finite_lb], -ub[w][finite_ub]])
        x[w] = quadprog.solve_qp(H[w], -c[w], rows.T, values, meq=A.shape[1])[0]
    return x


def rollout(problem: Problem, backend, solve, template: qpik.Robot, steps: int) -> dict:
    """``steps`` control steps from the template's configuration; the trajectory of q,
    the commanded velocities and the box of every step."""
    backend.qpos[:] = template.q
    assembly = Assembly(problem, backend, template)
    qs, qdots, bounds, bound_steps = [], [], [], 0
    for _ in range(steps):
        backend.forward()
        H, c, A, b, lb, ub = assembly.build()
        qdot, active = solve(H, c, A, b, lb, ub)
        bound_steps += int(active)
        qdots.append(qdot.copy())
        bounds.append((lb, ub))
        backend.integrate(qdot, DT)
        qs.append(backend.qpos.copy())
    return {"q": np.array(qs), "qdot": np.array(qdots), "bounds": bounds, "bound_steps": bound_steps,
            "assembly": assembly}


def serial_rollout(problem: Problem, world: int, steps: int) -> np.ndarray:
    """World ``world``'s trajectory of q under the serial qpik.QPController (DAQP)."""
    robot = problem.serial_robot()
    frame_task = qpik.FrameTask if problem.orientation else qpik.PositionTask
    if problem.orientation:
        task = frame_task(robot, problem.frame, frame_type=problem.frame_type, position_gain=problem.gain,
                          orientation_gain=problem.gain)
        task.set_target(problem.targets[world], task.target_rotation.copy())
    else:
        task = frame_task(robot, problem.frame, frame_type=problem.frame_type, axes=problem.axes, gain=problem.gain)
        task.set_target(problem.targets[world][task.rows] if hasattr(task, "rows") else problem.targets[world])
    tasks = [task, qpik.PostureTask(robot, gain=1.0, weight=POSTURE_WEIGHT)]
    if problem.equality:
        tasks.append(qpik.EqualityTask(robot))
    limits = [qpik.JointPositionLimit(robot), qpik.JointVelocityLimit(robot, problem.velocity_limits)]
    controller = qpik.QPController(robot, tasks, limits, dt=DT, regularization=REGULARIZATION)
    out = []
    for _ in range(steps):
        robot.integrate(controller.compute_velocity(), DT)
        out.append(robot.q.copy())
    return np.array(out)
