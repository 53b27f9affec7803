"""§6.2: glitch tests, covariance forecasts, and the sensing procedure on a relational map."""

from __future__ import annotations

import numpy as np
import pytest

import relmap as rm
from relmap.errors import ParameterError
from relmap.lie import se2
from relmap.network.sensing import covariance_after, glitch_test


def fig1_map() -> rm.RelationalMap:
    from relmap.app.demo import fig1

    g = rm.RelationalMap()
    for r in fig1().inputs:
        if r.name != "S":
            g.add(r.src, r.dst, r.at, name=r.name)
    return g


def test_glitch_test_accepts_consistent_and_rejects_far_readings():
    predicted = rm.AT([1.0, 2.0, 0.3], np.diag([0.04, 0.04, 0.01]))
    good = rm.AT([1.1, 1.9, 0.35], np.diag([0.01, 0.01, 0.001]))
    far = rm.AT([2.5, 2.0, 0.3], np.diag([0.01, 0.01, 0.001]))
    t = glitch_test(predicted, good)
    assert t.accepted and t.dof == 3 and 0 < t.p_value < 1
    v = np.array([0.1, -0.1, 0.05])
    S = predicted.cov + good.cov
    assert t.mahalanobis2 == pytest.approx(v @ np.linalg.solve(S, v))
    assert not glitch_test(predicted, far).accepted


def test_glitch_test_heading_wraps_and_exact_components():
    predicted = rm.AT([1.0, 0.0, 3.1], np.diag([0.01, 0.01, 0.01]))
    across = rm.AT([1.0, 0.0, -3.1], np.diag([0.01, 0.01, 0.01]))
    assert glitch_test(predicted, across).accepted  # 0.08 rad apart, not 6.2
    exact = rm.AT([1.0, 0.0, 0.3], np.diag([0.01, 0.01, 0.0]))
    off = rm.AT([1.0, 0.0, 0.31], np.diag([0.01, 0.01, 0.0]))
    t = glitch_test(exact, off)
    assert t.dof == 2 and t.mahalanobis2 == np.inf and not t.accepted and t.p_value == 0


def test_glitch_test_false_alarm_rate():
    """Readings drawn from the predicted distribution are rejected at the stated rate."""
    predicted = rm.AT(
        [1.0, 2.0, 0.3], np.array([[0.04, 0.01, 0.0], [0.01, 0.03, 0.002], [0.0, 0.002, 0.01]])
    )
    sensor = np.diag([0.01, 0.02, 0.001])
    n = 3000
    draws = rm.AT(predicted.mean, predicted.cov + sensor).sample(n, seed=1)
    rejected = sum(not glitch_test(predicted, rm.AT(d, sensor), 0.95).accepted for d in draws)
    assert abs(rejected / n - 0.05) < 4 * np.sqrt(0.05 * 0.95 / n)
    with pytest.raises(ParameterError):
        glitch_test(predicted, predicted, 1.5)


def test_covariance_after_needs_no_reading():
    prior = rm.AT([1.0, 2.0, 0.3], np.diag([0.04, 0.09, 0.01]))
    sensor = np.diag([0.01, 0.01, 0.02])
    expected = rm.merge(prior, rm.AT([5.0, -3.0, 1.0], sensor)).cov  # any reading: same cov
    np.testing.assert_allclose(covariance_after(prior, sensor), expected, rtol=1e-12)


def test_forecast_sensing_elsewhere_in_the_map():
    """Fig. 1: would sensing W from L4 help know L2? Forecast, then really do it."""
    g = fig1_map()
    sensor = np.diag([0.03**2, 0.03**2, np.radians(1) ** 2])
    frames_before = len(g)
    f = g.forecast_sensing(("L4", "W"), sensor, ("W", "L2"))
    assert len(g) == frames_before  # the map is untouched
    assert f.before.method == "reduce" and f.after.method == "optimal"
    assert 0 < f.position_shrink < 1 and 0 < f.heading_shrink < 1
    predicted = g.query("L4", "W").at
    g.add("L4", "W", rm.AT(predicted.mean, sensor), name="S")
    real = g.query("W", "L2")
    np.testing.assert_allclose(real.at.cov, f.after.at.cov, rtol=1e-9)


def test_sense_adds_consistent_readings_and_reports_glitches():
    g = fig1_map()
    predicted = g.query("L4", "W").at
    sensor = np.diag([0.03**2, 0.03**2, np.radians(1) ** 2])
    near = rm.AT(se2.plus(predicted.mean, [0.05, -0.05, 0.01]), sensor)
    decision = g.sense("L4", "W", near, name="S")
    assert decision.added and decision.name == "S" and "S" in g
    assert decision.glitch.accepted and "added" in decision.reason
    wild = rm.AT(se2.plus(predicted.mean, [3.0, 0.0, 0.0]), sensor)
    size = len(g)
    bad = g.sense("L4", "W", wild, name="S2")
    assert not bad.added and "glitch" in bad.reason and len(g) == size and "S2" not in g
    lone = g.sense("Mars", "Moon", rm.AT([1.0, 0.0, 0.0], sensor))
    assert lone.added and lone.predicted is None


def test_sense_declines_what_cannot_be_seen():
    g = fig1_map()
    sensor = np.diag([0.03**2, 0.03**2, np.radians(1) ** 2])
    predicted = g.query("L4", "W").at  # W is behind-left of the robot at L4
    bearing = np.arctan2(predicted.mean[1], predicted.mean[0])
    reading = rm.AT(predicted.mean, sensor)
    narrow = g.sense("L4", "W", reading, fov=np.radians(20), max_range=10.0)
    if abs(bearing) > np.radians(30):
        assert not narrow.added and "view" in narrow.reason and narrow.visible_probability < 0.9
    wide = g.sense("L4", "W", reading, fov=2 * np.pi, max_range=10.0)
    assert wide.added and wide.visible_probability > 0.99
