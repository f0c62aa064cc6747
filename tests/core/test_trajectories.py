"""Trajectories against the reference task's closed forms (docs/arm.md) and finite differences."""

import numpy as np
import pytest

from qpik.errors import InvalidInput
from qpik.trajectories import Circle, CubicTimeLaw, Hold, QuinticTimeLaw, Segment

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
