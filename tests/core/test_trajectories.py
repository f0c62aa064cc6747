"""Trajectories against the reference task's closed forms (docs/arm.md) and finite differences."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from qpik.errors import InvalidInput
from qpik.trajectories import (Circle, CircularTilt, CubicTimeLaw, Hold, PoseTrajectory, QuinticTimeLaw, Segment,
                               sample_many)

SQRT2 = np.sqrt(2.0)


def test_source_segment_matches_closed_forms():
    seg = Segment([0.5, 2.0], [1.5, 1.0], 5.0, time_law="cubic")
    for t in np.linspace(0.0, 5.0, 101):
        p, v = seg.sample(t)
        poly = (-2 * t**3 + 15 * t**2) / 125
        np.testing.assert_allclose(p, [0.5 + poly, 2.0 - poly], atol=1e-14)
        vx = -(6 / 125) * t**2 + (6 / 25) * t
        np.testing.assert_allclose(v, [vx, -vx], atol=1e-14)
        # Arc length s(t) = -(2√2/125) t³ + (3√2/25) t²
        s = -(2 * SQRT2 / 125) * t**3 + (3 * SQRT2 / 25) * t**2
        assert np.linalg.norm(p - [0.5, 2.0]) == pytest.approx(s, abs=1e-14)


@pytest.mark.parametrize("law", [CubicTimeLaw(2.0), QuinticTimeLaw(2.0)])
def test_time_law_rate_is_the_derivative(law):
    for t in np.linspace(0.05, 1.95, 20):
        s_plus, _ = law(t + 1e-6)
        s_minus, _ = law(t - 1e-6)
        assert law(t)[1] == pytest.approx((s_plus - s_minus) / 2e-6, rel=1e-6, abs=1e-9)
    assert law(0.0) == (0.0, 0.0) and law(2.0) == (1.0, 0.0)
    assert law(-1.0) == (0.0, 0.0) and law(5.0) == (1.0, 0.0)


def test_quintic_has_zero_end_accelerations():
    law = QuinticTimeLaw(1.0)
    h = 1e-5
    for t in (h, 1.0 - h):
        acc = (law(t + h)[1] - law(t - h)[1]) / (2 * h)
        assert abs(acc) < 1e-3
    assert law(0.5)[0] == pytest.approx(0.5)


def test_circle_position_velocity_and_closure():
    c = Circle([0.1, 0.2, 0.3], 0.05, 4.0, start_angle=0.3)
    p0, v0 = c.sample(0.0)
    p1, v1 = c.sample(4.0)
    np.testing.assert_allclose(p0, p1, atol=1e-14)
    np.testing.assert_allclose(v0, 0.0, atol=1e-14)
    for t in np.linspace(0.1, 3.9, 15):
        p, v = c.sample(t)
        assert np.linalg.norm(p - c.center) == pytest.approx(0.05, abs=1e-14)
        fd = (c.sample(t + 1e-6)[0] - c.sample(t - 1e-6)[0]) / 2e-6
        np.testing.assert_allclose(v, fd, atol=1e-8)


def test_hold_and_bad_arguments():
    p, v = Hold([1.0, 2.0], 1.0).sample(0.5)
    np.testing.assert_allclose(p, [1, 2])
    np.testing.assert_allclose(v, 0)
    with pytest.raises(InvalidInput):
        Segment([0, 0], [np.nan, 1], 1.0)
    with pytest.raises(InvalidInput):
        Segment([0, 0], [1, 1, 1], 1.0)
    with pytest.raises(InvalidInput):
        Segment([0, 0], [1, 1], 0.0)
    with pytest.raises(InvalidInput):
        Segment([0, 0], [1, 1], 1.0, time_law="septic")
    with pytest.raises(InvalidInput):
        Circle([0, 0, 0], 0.1, 1.0, u=(1, 0, 0), w=(1, 0, 0))
    with pytest.raises(InvalidInput):
        Segment([0, 0], [1, 1], 1.0).sample(np.inf)


# Vectorised sampling: a rollout samples its whole reference up front with sample_many;
# it must give the bits one sample(t) per step gives (the baseline rollouts depend on it).
finite = st.floats(-3.0, 3.0, allow_nan=False)
vectors3 = st.lists(finite, min_size=3, max_size=3)
laws = st.sampled_from(["cubic", "quintic"])


def _same_bits(many, single):
    many, single = np.asarray(many), np.asarray(single)
    return np.array_equal(many, single) and np.array_equal(np.signbit(many), np.signbit(single))


def _times(duration, step=0.002):
    return np.concatenate([np.arange(int(duration / step) + 50) * step, [-1.0, 0.0, duration, 1e6]])


@settings(max_examples=25, deadline=None)
@given(vectors3, vectors3, vectors3, vectors3, st.floats(0.1, 4.0), laws)
def test_pose_paths_sampled_many_at_once_equal_one_sample_per_time(a, b, c, d, duration, law):
    segment = PoseTrajectory(Segment(a, b, duration, law), Segment(np.array(c) * 10, np.array(d) * 10, duration, law))
    circle = Circle(a, 0.1 + abs(b[0]), duration, start_angle=c[0], turns=1.0 + abs(d[0]), time_law=law)
    tilted = PoseTrajectory(circle, CircularTilt(circle, 3.0 * c[1]))
    times = _times(duration, step=0.0123)
    for trajectory in (segment, tilted, PoseTrajectory(circle)):
        batch = trajectory.sample_pose_many(times)
        for i, t in enumerate(times):
            assert all(_same_bits(m[i], s) for m, s in zip(batch, trajectory.sample_pose(t)))


def test_every_bundled_trajectory_samples_many_as_one_by_one():
    circle = Circle([0.05, 0.02, 0.11], 0.03, 4.0, time_law="quintic")
    trajectories = [Segment([0.5, 2.0], [1.5, 1.0], 5.0), Hold([1.0, 2.0], 2.0), circle, CircularTilt(circle, 3.0),
                    Circle([0.5, 1.0], 0.7, 3.3, u=(0.6, 0.8), w=(-0.8, 0.6), start_angle=0.4, turns=1.7)]
    times = _times(5.0)
    for trajectory in trajectories:
        positions, velocities = sample_many(trajectory, times)
        for i, t in enumerate(times):
            p, v = trajectory.sample(t)
            assert _same_bits(positions[i], p) and _same_bits(velocities[i], v)


def test_sample_many_of_a_user_trajectory_and_its_errors():
    class Wobble:
        dim, duration = 2, 1.0

        def sample(self, t):
            return np.array([t, 1.0 / (1.0 - t)]), np.array([1.0, 0.0])

    positions, _ = sample_many(Wobble(), [0.0, 0.5])
    np.testing.assert_array_equal(positions, [[0.0, 1.0], [0.5, 2.0]])
    with pytest.raises(InvalidInput, match="NaN or inf"):
        sample_many(Wobble(), [0.5, float("inf")])
    with pytest.raises(InvalidInput, match="NaN or inf"):
        with np.errstate(divide="ignore"):
            sample_many(Wobble(), np.array([0.5, 1.0]))


def test_paths_keep_their_own_copy_of_the_points_they_are_given():
    """A path built from a live array (a task's target) does not move when that array does."""
    start, centre, point = np.array([0.0, 0.0, 1.0]), np.zeros(3), np.ones(3)
    segment = Segment(start, start + 1.0, 1.0)
    circle = Circle(centre, 0.5, 1.0)
    hold = Hold(point, 1.0)
    before = [path.sample(0.3)[0].copy() for path in (segment, circle, hold)]
    start += 5.0
    centre += 5.0
    point += 5.0
    for path, position in zip((segment, circle, hold), before):
        np.testing.assert_array_equal(path.sample(0.3)[0], position)
