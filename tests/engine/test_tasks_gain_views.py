"""A task's ``gain`` (and a frame task's ``position_gain``/``orientation_gain``) is the gain
the step uses, as it was in the serial tasks: written in place or set whole, it is the
next step's; a dead-beat default reads 1/Δt once a controller gave its period; on a batch
it is every world's (N, dim) view."""

from __future__ import annotations

import numpy as np
import pytest

from qpik import FrameTask, InvalidInput, PositionTask, QPController, RelativeFrameTask, Robot, Task, batch

DT = 0.01


def _moved(task) -> None:
    """A target 2 cm and 0.1 rad away: every row has an error, so every gain shows."""
    rotation = np.array([[np.cos(0.1), -np.sin(0.1), 0.0], [np.sin(0.1), np.cos(0.1), 0.0], [0.0, 0.0, 1.0]])
    task.set_target(task.target_position + [0.02, -0.01, 0.0], rotation @ task.target_rotation)


def _step(robot, task) -> np.ndarray:
    return QPController(robot, [task], dt=DT).compute_velocity().copy()


def test_a_dead_beat_default_reads_one_over_dt_through_its_views():
    robot = Robot.load("arm")
    task = FrameTask(robot, "end_effector", position_axes="xy", orientation_axes="z")
    QPController(robot, [task], dt=DT)
    np.testing.assert_array_equal(task.position_gain, [1.0 / DT] * 2)
    np.testing.assert_array_equal(task.orientation_gain, [1.0 / DT])
    np.testing.assert_array_equal(task.gain, task.feedback_gains())
    relative = RelativeFrameTask(robot, "end_effector", "link1", root_type="body")
    QPController(robot, [relative], dt=DT)
    np.testing.assert_array_equal(relative.position_gain, [1.0 / DT] * 3)


def test_a_gain_written_in_place_is_the_next_steps():
    """The step after ``position_gain[:] = ...`` is the step of a task built with those gains
    (the same arithmetic: equal to the last bit)."""
    robot = Robot.load("arm")
    written = FrameTask(robot, "end_effector", position_gain=50.0, orientation_gain=50.0)
    _moved(written)
    written.position_gain[:] = [20.0, 30.0, 40.0]
    written.orientation_gain[:] = 10.0
    built = FrameTask(robot, "end_effector", position_gain=[20.0, 30.0, 40.0], orientation_gain=10.0)
    _moved(built)
    np.testing.assert_array_equal(written.feedback_gains(), [20.0, 30.0, 40.0, 10.0, 10.0, 10.0])
    np.testing.assert_array_equal(_step(robot, written), _step(robot, built))


def test_a_gain_set_whole_is_checked_and_the_next_steps():
    robot = Robot.load("arm")
    set_whole, built = PositionTask(robot, "end_effector"), PositionTask(robot, "end_effector", gain=25.0)
    for task in (set_whole, built):
        task.set_target(task.target + [0.02, -0.01, 0.0])
    set_whole.gain = 25.0
    assert not set_whole.needs_period
    np.testing.assert_array_equal(_step(robot, set_whole), _step(robot, built))
    for bad in (np.nan, -1.0, [1.0, 2.0], "fast"):
        with pytest.raises(InvalidInput, match="position task gain"):
            set_whole.gain = bad
    np.testing.assert_array_equal(set_whole.gain, [25.0] * 3)


def test_a_batchs_gain_is_every_worlds():
    robots = batch.Robot.load("arm", n=3)
    task = batch.FrameTask(robots, "end_effector", position_gain=50.0)
    assert task.gain.shape == (3, 6) and task.position_gain.shape == (3, 3)
    task.position_gain[:] = 20.0
    np.testing.assert_array_equal(task.gains[:, :3], 20.0)


def test_a_task_without_feedback_keeps_a_gain_of_its_own():
    """A subclass that measures its own rows and follows a gradient (no K e) may keep its k0
    as ``gain``, as qpik's hexapod manipulability task does."""

    class Gradient(Task):
        dim = 1

        def __init__(self, robot):
            super().__init__(robot)
            self.gain = 3.0

        def measure_rows(self) -> None:
            self.jacobians[:, 0, 0] = 1.0

    task = Gradient(Robot.load("arm"))
    assert task.gains is None and task.gain == 3.0
