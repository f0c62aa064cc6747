"""Closed-loop rollouts of one batched problem per robot, on any back-end, and quadprog
as an independent exact QP solver.

The problems: the arm's end effector (x, y), the hexapod's platform pose with its loop
closures hard, the 7-DoF pusher arm's tip position; a posture task; joint position and
velocity limits; far targets, so that the limits bind on many steps.
"""

from __future__ import annotations

import numpy as np

from qpik import batch

DT = 0.002
PUSHER_START = np.array([0.2, 0.3, -0.2, -1.0, 0.3, -0.5, 0.2])
PUSHER_SPEED = 1.5  # rad/s on every joint (the MJCF declares none)


def controller(name: str, n: int, pusher_model=None, backend: str = "cpu", **options):
    """(robots, controller) of ``name``'s problem over n worlds on ``backend``."""
    rng = np.random.default_rng(7)
    if name == "pusher":
        robots = batch.Robot(pusher_model, n, name="pusher_arm", backend=backend, **options)
        robots.set_q(PUSHER_START)
    else:
        robots = batch.Robot.load(name, n, backend=backend, **options)
    tasks = [_tracking_task(name, robots, rng), batch.PostureTask(robots, gain=1.0, weight=1e-3)]
    if name == "hexapod":
        tasks.append(batch.EqualityTask(robots))  # hard, dead-beat: the loops stay closed
    speeds = np.full(robots.nv, PUSHER_SPEED) if name == "pusher" else None
    limits = [batch.JointPositionLimit(robots), batch.JointVelocityLimit(robots, speeds)]
    return robots, batch.QPController(robots, tasks, limits, dt=DT)


def _tracking_task(name: str, robots, rng):
    n = robots.n
    if name == "arm":  # 0.5-1 m from the start, inside the reach: the speed limits bind
        task = batch.PositionTask(robots, "end_effector", "site", axes="xy", gain=50.0)
        radius, angle = rng.uniform(0.9, 1.6, n), rng.uniform(0.3, 2.8, n)
        task.set_target(np.column_stack([radius * np.cos(angle), radius * np.sin(angle)]))
    elif name == "hexapod":  # platform moves of up to 8 cm: the strokes reach their ends
        task = batch.FrameTask(robots, "platform_center", "site", position_gain=20.0, orientation_gain=20.0)
        robots.ensure_kinematics()
        home, rotation = task.frame.position.copy(), task.frame.rotation.copy()
        task.set_target(home + rng.uniform(-0.08, 0.08, (n, 3)), rotation)
    else:
        task = batch.PositionTask(robots, "tips_arm", "body", gain=20.0)
        task.set_target(np.column_stack([rng.uniform(0.2, 1.0, n), rng.uniform(-0.9, 0.3, n),
                                         rng.uniform(-0.6, 0.4, n)]))
    return task


def rollout(robots, ctrl, steps: int) -> dict:
    """q after every step, the commanded velocities, the boxes, and on how many steps
    some world had a bound active."""
    qs, qdots, boxes, bound_steps = [], [], [], 0
    for _ in range(steps):
        qdot = ctrl.compute_velocity()
        bound_steps += int(not ctrl.result.closed_form.all())
        qdots.append(qdot.copy())
        boxes.append((ctrl.lb.copy(), ctrl.ub.copy()))
        robots.integrate(qdot, DT)
        qs.append(robots.q.copy())
    return {"q": np.array(qs), "qdot": np.array(qdots), "boxes": boxes, "bound_steps": bound_steps}


def quadprog_solve(H, c, A, b, lb, ub) -> np.ndarray:
    """Every world by quadprog (Goldfarb–Idnani in double precision, exact at its end:
    no tolerance), one at a time. Raises ValueError for an infeasible world."""
    import quadprog

    x = np.zeros_like(c)
    nv = c.shape[1]
    for w in range(len(c)):
        finite_lb, finite_ub = np.isfinite(lb[w]), np.isfinite(ub[w])
        rows = np.vstack([A[w], np.eye(nv)[finite_lb], -np.eye(nv)[finite_ub]])
        values = np.concatenate([b[w], lb[w][finite_lb], -ub[w][finite_ub]])
        x[w] = quadprog.solve_qp(H[w], -c[w], rows.T, values, meq=A.shape[1])[0]
    return x
