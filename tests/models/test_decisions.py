"""relmap.models.decisions (public name relmap.models.decisions): field-of-view and doorway
decisions,
the paper's test and the probability.

Every probability is checked against Monte Carlo (samples drawn with ``AT.sample``, agreement
within 4 sampling standard errors ``√(p(1−p)/n)``), against closed forms where they exist, and
the quadrature's accuracy against an independent nested ``scipy.integrate.quad`` reference.
"""

from __future__ import annotations

import itertools
import math
import subprocess
import sys

import numpy as np
import pytest
from scipy import integrate, optimize
from scipy.special import ndtr

import relmap as rm
from relmap.errors import ParameterError
from relmap.models.decisions import in_view, through_door

N_MC = 1_000_000


# ------------------------------------------------------------------------------ helpers
def in_sector(px, py, fov, max_range, min_range=0.0):
    r = np.hypot(px, py)
    return (r >= min_range) & (r <= max_range) & (np.abs(np.arctan2(py, px)) <= fov / 2)


def mc_view(at, fov, max_range, min_range=0.0, n=N_MC, seed=0):
    s = at.sample(n, seed)
    return in_sector(s[..., 0], s[..., 1], fov, max_range, min_range).mean(axis=0)


def passes(x, y, th, door_width, robot_width):
    c = np.cos(th)
    with np.errstate(divide="ignore", invalid="ignore"):
        clear = door_width / 2 - robot_width / (2 * c) - np.abs(y - x * np.tan(th))
    return (c > 0) & (clear >= 0)


def mc_door(at, door_width, robot_width, n=N_MC, seed=0):
    s = at.sample(n, seed)
    return passes(s[..., 0], s[..., 1], s[..., 2], door_width, robot_width).mean(axis=0)


def assert_mc_agrees(p, p_mc, n=N_MC):
    se = math.sqrt(p * (1 - p) / n)
    assert abs(p - p_mc) <= 4 * se + 1e-12, f"probability {p:.6f} vs Monte Carlo {p_mc:.6f}"


def cov_xy(sxx, sxy, syy, stt=0.01):
    return np.array([[sxx, sxy, 0.0], [sxy, syy, 0.0], [0.0, 0.0, stt]])


def reference_view(at, fov, max_range, min_range=0.0):
    """Independent reference: nested adaptive quadrature of the density in polar coordinates."""
    m, S = at.mean[:2], at.cov[:2, :2]
    G = np.linalg.inv(S)
    c = 1.0 / (2 * math.pi * math.sqrt(np.linalg.det(S)))
    b0 = math.atan2(m[1], m[0])

    def along(phi):
        u = np.array([math.cos(phi), math.sin(phi)])
        peak = (u @ G @ m) / (u @ G @ u)
        pts = [peak] if min_range < peak < max_range else None
        return integrate.quad(
            lambda r: r * c * math.exp(-0.5 * (r * u - m) @ G @ (r * u - m)),
            min_range,
            max_range,
            points=pts,
            epsabs=1e-14,
            epsrel=1e-13,
            limit=200,
        )[0]

    sig = math.sqrt(np.linalg.eigvalsh(S)[-1]) / max(np.hypot(*m), 1e-300)
    brk = sorted({min(max(b0 + d * sig, -fov / 2), fov / 2) for d in (-3, 0, 3)})
    brk = [b for b in brk if -fov / 2 < b < fov / 2] or None
    return integrate.quad(
        along, -fov / 2, fov / 2, points=brk, epsabs=1e-13, epsrel=1e-13, limit=400
    )[0]


def random_view_batch(rng, n):
    mean = np.column_stack([rng.uniform(-3, 6, n), rng.uniform(-3, 3, n), np.zeros(n)])
    L = rng.normal(size=(n, 2, 2)) * rng.uniform(0.05, 1.0, (n, 1, 1))
    cov = np.zeros((n, 3, 3))
    cov[:, :2, :2] = L @ np.swapaxes(L, -1, -2) + 1e-4 * np.eye(2)
    cov[:, 2, 2] = 0.01
    return rm.AT(mean, cov)


# ------------------------------------------------------------------------- field of view
VIEW_CASES = {
    # name: (mean, covariance, fov, max_range, min_range)
    "well_inside": ([5.0, 0.3, 0.0], cov_xy(0.25, 0.0, 0.16), 1.0, 10.0, 0.0),
    "near_fov_edge": ([5.0, 2.5, 0.0], cov_xy(0.25, 0.05, 0.16), 1.0, 10.0, 0.0),
    "near_max_range": ([9.5, 0.0, 0.0], cov_xy(0.25, -0.05, 0.16), 1.0, 10.0, 0.0),
    "straddling_sensor": ([0.1, 0.3, 0.0], cov_xy(0.25, 0.1, 0.16), 2 * math.pi / 3, 3.0, 0.0),
    "beside_sensor_edge": ([0.2, 2.0, 0.0], cov_xy(0.3, 0.0, 0.1), math.pi, 4.0, 0.5),
    "full_circle_disc": ([1.5, -1.0, 0.0], cov_xy(0.5, 0.2, 0.3), 2 * math.pi, 2.5, 0.0),
    "full_circle_behind": ([-2.0, 0.01, 0.0], cov_xy(0.25, 0.0, 0.25), 2 * math.pi, 3.0, 0.3),
    "narrow_fov": ([5.0, 0.1, 0.0], cov_xy(0.09, 0.0, 0.0025), 0.05, 10.0, 1.0),
    "reflex_fov": ([-1.0, 0.5, 0.0], cov_xy(1.0, 0.3, 0.5), 4.5, 3.0, 0.5),
    "thin_ellipse": ([4.0, 0.2, 0.0], None, 1.0, 4.5, 0.0),
}


def view_case(name):
    mean, cov, fov, rmax, rmin = VIEW_CASES[name]
    if cov is None:
        return rm.AT.from_ellipse(mean, 1.0, 1e-5, 0.5), fov, rmax, rmin
    return rm.AT(mean, cov), fov, rmax, rmin


@pytest.mark.parametrize("name", list(VIEW_CASES))
def test_view_probability_matches_monte_carlo(name):
    at, fov, rmax, rmin = view_case(name)
    d = in_view(at, fov, rmax, min_range=rmin)
    p_mc = mc_view(at, fov, rmax, rmin, seed=sum(map(ord, name)))
    assert_mc_agrees(float(d.probability), p_mc)
    assert 0 <= d.error <= 1e-9
    assert d.ellipse_inside == (d.margin >= d.k)
    assert d.mean_inside == bool(in_sector(*at.mean[:2], fov, rmax, rmin))


@pytest.mark.parametrize(
    "name", ["near_fov_edge", "straddling_sensor", "reflex_fov", "narrow_fov", "full_circle_behind"]
)
def test_view_accuracy_against_independent_reference(name):
    """tol=1e-10 vs nested adaptive quad (no closed form, no shared code) agrees to 1e-9."""
    at, fov, rmax, rmin = view_case(name)
    d = in_view(at, fov, rmax, min_range=rmin, tol=1e-10)
    assert d.error <= 1e-10
    assert float(d.probability) == pytest.approx(reference_view(at, fov, rmax, rmin), abs=1e-9)


@pytest.mark.parametrize("tol", [1e-3, 1e-6, 1e-8, 1e-12])
def test_view_tolerance_is_honoured(tol):
    at = random_view_batch(np.random.default_rng(8), 200)
    fine = in_view(at, 2.0, 4.0, min_range=0.3, tol=1e-14).probability
    d = in_view(at, 2.0, 4.0, min_range=0.3, tol=tol)
    assert np.all(d.error <= tol)
    assert np.abs(d.probability - fine).max() <= tol


@pytest.mark.slow
def test_margin_is_the_mahalanobis_distance_to_the_boundary():
    """margin equals the minimum over a dense sampling of the boundary (which bounds it above)."""
    rng = np.random.default_rng(5)
    at = random_view_batch(rng, 60)
    t = np.linspace(0, 1, 20001)
    for fov, rmin, rmax in [(1.2, 0.0, 5.0), (2 * math.pi, 0.5, 3.0), (4.5, 1.0, 6.0)]:
        d = in_view(at, fov, rmax, min_range=rmin)
        pts = [rmax * np.column_stack([np.cos(fov * (t - 0.5)), np.sin(fov * (t - 0.5))])]
        if rmin > 0:
            pts.append(pts[0] * rmin / rmax)
        if fov < 2 * math.pi:
            s = rmin + (rmax - rmin) * t
            for a in (fov / 2, -fov / 2):
                pts.append(np.column_stack([s * math.cos(a), s * math.sin(a)]))
        P = np.concatenate(pts)
        for i in range(at.batch_shape[0]):
            v = P - at.mean[i, :2]
            dense = np.sqrt(np.einsum("ni,ij,nj->n", v, np.linalg.inv(at.cov[i, :2, :2]), v).min())
            assert abs(float(d.margin[i])) <= dense * (1 + 1e-9) + 1e-12
            assert abs(float(d.margin[i])) == pytest.approx(dense, rel=1e-3, abs=1e-3)
            assert (d.margin[i] >= 0) == d.mean_inside[i]


@pytest.mark.slow
def test_paper_test_is_the_ellipse_inside_the_sector():
    """ellipse_inside ⇔ margin ≥ k ⇔ every point of the filled P-ellipse is in the sector."""
    rng = np.random.default_rng(6)
    at = random_view_batch(rng, 300)
    r, a = np.meshgrid(np.linspace(0, 1, 40), np.linspace(0, 2 * math.pi, 181))
    disc = np.column_stack([(r * np.cos(a)).ravel(), (r * np.sin(a)).ravel()])
    for fov, rmin, rmax in [(1.5, 0.0, 5.0), (2 * math.pi, 0.8, 4.0), (5.0, 0.5, 6.0)]:
        d = in_view(at, fov, rmax, min_range=rmin, probability=0.9)
        assert np.array_equal(d.ellipse_inside, d.margin >= d.k)
        L = np.linalg.cholesky(at.cov[:, :2, :2])
        pts = at.mean[:, None, :2] + d.k * np.einsum("bij,nj->bni", L, disc)
        all_in = in_sector(pts[..., 0], pts[..., 1], fov, rmax, rmin).all(axis=1)
        assert np.all(all_in[d.ellipse_inside])
        # Ellipses clearly not inside (margin < 0.98 k) have a sampled point outside.
        clearly_out = d.margin < 0.98 * d.k
        assert not np.any(all_in[clearly_out])
        assert d.ellipse_inside.any() and clearly_out.any()


@pytest.mark.slow
def test_ellipse_test_is_conservative():
    """Ellipse inside ⇒ probability ≥ P (a subset holds P); the converse fails often."""
    at = random_view_batch(np.random.default_rng(2), 2000)
    for fov, rmin, rmax in [(1.0, 0.0, 5.0), (2 * math.pi, 0.5, 4.0), (4.5, 1.0, 6.0)]:
        d = in_view(at, fov, rmax, min_range=rmin)
        for p in (0.5, 0.9, 0.99):
            inside = d.margin >= math.sqrt(-2 * math.log(1 - p))  # ellipse_inside at level p
            assert np.all(d.probability[inside] >= p)
            assert np.any(~inside & (d.probability >= p))


def test_ellipse_not_inside_yet_probability_above_P():
    """Near max range only one boundary is close: the ellipse pokes out but P(view) > 0.9.

    The ellipse test is conservative because it asks the whole P-ellipse to fit, while the
    region extends far beyond the ellipse everywhere except at the near boundary: with the
    range limit 2σ away the 90% ellipse (k = 2.146) crosses it, yet the probability is about
    Φ(2) ≈ 0.977.
    """
    at = rm.AT([4.0, 0.0, 0.0], cov_xy(0.25, 0.0, 0.25))
    d = in_view(at, 2 * math.pi, 5.0, probability=0.9)
    assert d.margin == pytest.approx(2.0, abs=1e-12)
    assert not d.ellipse_inside
    assert d.probability > 0.97
    assert_mc_agrees(float(d.probability), mc_view(at, 2 * math.pi, 5.0, seed=3))


def test_exactly_known_position():
    """Rank 0: probability 1 inside the closed sector (boundary included), else 0."""
    fov, rmax, rmin = 1.0, 5.0, 0.5
    means = [
        [3.0, 0.0, 0.0],  # inside
        [4 * math.cos(0.5), 4 * math.sin(0.5), 0.0],  # on an edge
        [5 * math.cos(0.2), 5 * math.sin(0.2), 0.0],  # on the max-range arc
        [0.5, 0.0, 0.0],  # on the min-range arc
        [6.0, 0.0, 0.0],  # beyond range
        [3.0, 3.0, 0.0],  # off to the side
        [0.0, 0.0, 0.0],  # at the sensor, inside the min range
    ]
    d = in_view(rm.AT(means), fov, rmax, min_range=rmin)
    expect = np.array([1, 1, 1, 1, 0, 0, 0], dtype=bool)
    np.testing.assert_array_equal(d.probability, expect.astype(float))
    np.testing.assert_array_equal(d.ellipse_inside, expect)
    np.testing.assert_array_equal(d.margin, np.where(expect, np.inf, -np.inf))
    np.testing.assert_array_equal(d.error, 0.0)


def test_position_on_a_line():
    """Rank 1: exact Φ differences, and continuity with a nearly singular covariance."""
    # The line y = 0.2 (σx = 1): inside from the edge / min-range crossing to max range.
    at = rm.AT([4.0, 0.2, 0.0], np.diag([1.0, 0.0, 0.01]))
    d = in_view(at, 1.0, 4.5, min_range=0.5)
    x_in = max(0.2 / math.tan(0.5), math.sqrt(0.25 - 0.04))
    x_out = math.sqrt(4.5**2 - 0.04)
    assert float(d.probability) == pytest.approx(ndtr(x_out - 4.0) - ndtr(x_in - 4.0), abs=1e-14)
    assert float(d.margin) == pytest.approx(x_out - 4.0, abs=1e-12)
    # An oblique line, against Monte Carlo and against the nearly singular full-rank path.
    for angle in (0.5, 2.0):
        line = rm.AT.from_ellipse([4.0, 0.2, 0.0], 1.0, 0.0, angle)
        thin = rm.AT.from_ellipse([4.0, 0.2, 0.0], 1.0, 1e-6, angle)
        d0, d1 = in_view(line, 1.0, 4.5), in_view(thin, 1.0, 4.5, tol=1e-11)
        assert float(d0.probability) == pytest.approx(float(d1.probability), abs=1e-9)
        assert float(d0.margin) == pytest.approx(float(d1.margin), rel=1e-6)
        assert_mc_agrees(float(d0.probability), mc_view(line, 1.0, 4.5, seed=4))
    # A line that misses the sector: never seen, margin -inf.
    miss = in_view(rm.AT([4.0, 3.0, 0.0], np.diag([1.0, 0.0, 0.0])), 1.0, 4.5)
    assert miss.probability == 0.0 and miss.margin == -np.inf


def test_thin_ellipse_through_the_sensor_corner():
    """A thin ellipse whose line passes 1 cm from the sensor (the sector's apex).

    Its bearing density has steep switches far from the mean's bearing; they are cut at, so
    the quadrature agrees with the exact line result (and a brute-force sum along the line).
    """
    m, a, ang = [4.62066747, 0.1915594, 0.0], 1.7610914341512574, 0.04398690380097081
    line = in_view(rm.AT.from_ellipse(m, a, 0.0, ang), 1.0, 5.0)
    thin = in_view(rm.AT.from_ellipse(m, a, a * 1e-6, ang), 1.0, 5.0, tol=1e-12)
    assert float(thin.probability) == pytest.approx(float(line.probability), abs=1e-11)
    t = np.linspace(-12 * a, 12 * a, 2_000_001)  # spacing 2e-5: the sum is good to ~1e-5
    px, py = m[0] + t * math.cos(ang), m[1] + t * math.sin(ang)
    w = np.exp(-0.5 * (t / a) ** 2) / (a * math.sqrt(2 * math.pi)) * (t[1] - t[0])
    brute = (w * in_sector(px, py, 1.0, 5.0)).sum()
    assert float(line.probability) == pytest.approx(brute, abs=1e-5)


@pytest.mark.parametrize("sigma", [1e-6, 1e-9, 1e-13])
def test_tiny_uncertainty_on_an_edge(sigma):
    """A tiny Gaussian centred on a straight edge is half in view (the bearing keeps precision)."""
    at = rm.AT.from_sigmas([8 * math.cos(0.5), 8 * math.sin(0.5), 0.0], [sigma, sigma, 0.0])
    d = in_view(at, 1.0, 10.0, tol=1e-10)
    assert float(d.probability) == pytest.approx(0.5, abs=1e-10)
    assert abs(float(d.margin)) < 1e-3


def test_view_batched_equals_per_element():
    rng = np.random.default_rng(9)
    mean = np.column_stack([rng.uniform(-1, 5, 6), rng.uniform(-2, 2, 6), np.zeros(6)])
    L = rng.normal(scale=0.5, size=(6, 3, 3))
    cov = L @ np.swapaxes(L, -1, -2)
    cov[1] = 0.0  # exactly known
    cov[4] = np.diag([0.3, 0.0, 0.01])  # on a line
    at = rm.AT(mean.reshape(2, 3, 3), cov.reshape(2, 3, 3, 3))
    d = in_view(at, 2.0, 4.0, min_range=0.2)
    assert d.probability.shape == (2, 3) and d.ellipse_inside.shape == (2, 3)
    for i in range(2):
        for j in range(3):
            one = in_view(at[i, j], 2.0, 4.0, min_range=0.2)
            for field in ("probability", "margin", "ellipse_inside", "mean_inside"):
                assert getattr(one, field) == pytest.approx(getattr(d, field)[i, j], abs=1e-15)


def test_view_bad_parameters():
    at = rm.AT.from_sigmas([3.0, 0.0, 0.0], [0.1, 0.1, 0.1])
    bad = [
        ({"fov": 0.0}, "fov"),
        ({"fov": -1.0}, "fov"),
        ({"fov": 2 * math.pi + 0.1}, "fov"),
        ({"fov": float("nan")}, "fov"),
        ({"max_range": 0.0}, "max_range"),
        ({"max_range": 1.0, "min_range": 1.0}, "greater than min_range"),
        ({"min_range": -0.5}, "min_range"),
        ({"probability": 0.0}, "probability"),
        ({"probability": 1.0}, "probability"),
        ({"probability": 1.5}, "probability"),
        ({"tol": 0.0}, "tol"),
    ]
    for change, message in bad:
        kwargs = {"fov": 1.0, "max_range": 5.0, **change}
        with pytest.raises(ParameterError, match=message):
            in_view(at, **kwargs)
    with pytest.raises(TypeError):
        in_view(np.zeros(3), 1.0, 5.0)  # type: ignore[arg-type]


# -------------------------------------------------------------------------------- doorway
DOOR_CASES = {
    # name: (mean, sigmas or covariance, door width, robot width)
    "centred_aligned": ([-2.0, 0.0, 0.0], [0.05, 0.05, 0.02], 1.0, 0.6),
    "offset": ([-2.0, 0.12, 0.0], [0.05, 0.08, 0.03], 1.0, 0.6),
    "angled": ([-2.0, 0.0, 0.15], [0.05, 0.05, 0.05], 1.0, 0.6),
    "correlated": (
        [-2.0, 0.05, 0.1],
        [[0.04, 0.01, 0.005], [0.01, 0.02, -0.01], [0.005, -0.01, 0.04]],
        1.0,
        0.6,
    ),
    "large_heading_uncertainty": ([-1.0, 0.0, 0.1], [0.05, 0.05, 0.6], 1.2, 0.5),
    "heading_wraps": ([-1.0, 0.0, 0.0], [0.05, 0.05, 2.5], 1.2, 0.5),
    "heading_behind": ([-2.0, 0.0, 2.0], [0.05, 0.05, 0.5], 1.0, 0.6),
    "exact_position": ([-2.0, 0.1, 0.0], [0.0, 0.0, 0.1], 1.0, 0.6),
}


def door_case(name):
    mean, spread, W, w = DOOR_CASES[name]
    spread = np.asarray(spread, dtype=float)
    at = rm.AT.from_sigmas(mean, spread) if spread.ndim == 1 else rm.AT(mean, spread)
    return at, W, w


@pytest.mark.parametrize("name", list(DOOR_CASES))
def test_door_probability_matches_monte_carlo(name):
    at, W, w = door_case(name)
    d = through_door(at, W, w)
    assert_mc_agrees(float(d.probability), mc_door(at, W, w, seed=sum(map(ord, name))))
    assert 0 <= d.error <= 1e-9
    assert d.paper_test == (d.slack >= 0)


def test_door_centred_and_aligned():
    at, W, w = door_case("centred_aligned")
    d = through_door(at, W, w)
    assert d.probability > 0.99
    assert d.paper_test
    assert d.clearance == pytest.approx((W - w) / 2)
    assert d.crossing == 0.0
    # σ_c² = σy² + x̂²σθ² at θ̂ = 0; the box's worst heading is k·σθ.
    sc = math.hypot(0.05, 2.0 * 0.02)
    assert d.crossing_sigma == pytest.approx(sc)
    assert d.slack == pytest.approx(W / 2 - w / (2 * math.cos(d.k * 0.02)) - d.k * sc)


def test_door_paper_test_counts_the_heading_interval():
    """Exact position 1 cm before the door, uncertain heading: the box's worst heading decides."""
    k = math.sqrt(-2 * math.log(0.1))
    # k·σθ = 0.64 rad fits; 1.07 rad makes the robot too wide; 1.72 rad turns it past ±π/2.
    for sig, expect in [(0.3, True), (0.5, False), (0.8, False)]:
        d = through_door(rm.AT([-0.01, 0.0, 0.0], np.diag([0.0, 0.0, sig**2])), 1.0, 0.6)
        worst = k * sig
        slack = 0.5 - 0.3 / math.cos(worst) - k * 0.01 * sig if worst < math.pi / 2 else -math.inf
        assert d.slack == pytest.approx(slack, abs=1e-12)
        assert d.paper_test == expect


def test_door_offset_and_angled_fail_the_paper_test():
    for name in ("offset", "angled"):
        at, W, w = door_case(name)
        d = through_door(at, W, w)
        assert not d.paper_test and d.slack < 0
    d = through_door(*door_case("angled"))
    assert d.crossing == pytest.approx(2.0 * math.tan(0.15))
    assert d.clearance < 0 and d.probability < 0.5


def test_door_heading_behind():
    """A robot facing away from the door does not pass; clearance and slack are -inf."""
    at = rm.AT.from_sigmas([-2.0, 0.0, math.pi], [0.05, 0.05, 0.1])
    d = through_door(at, 1.0, 0.6)
    assert d.probability < 1e-15 and not d.paper_test
    assert d.clearance == -np.inf and d.slack == -np.inf
    exact = through_door(rm.AT([-2.0, 0.0, math.pi]), 1.0, 0.6)
    assert exact.probability == 0.0 and exact.error == 0.0


def test_door_exact_heading_closed_form():
    at = rm.AT([-2.0, 0.05, 0.1], np.diag([0.01, 0.02, 0.0]))
    d = through_door(at, 1.0, 0.6)
    t = math.tan(0.1)
    nu, tau = 0.05 + 2.0 * t, math.sqrt(0.02 + t * t * 0.01)
    h = 0.5 - 0.3 / math.cos(0.1)
    assert float(d.probability) == pytest.approx(ndtr((h - nu) / tau) - ndtr((-h - nu) / tau))
    assert d.error == 0.0


def heading_limit(x, door_width, robot_width):
    """θ* > 0 with |x|·tan θ* + robot_width/(2 cos θ*) = door_width/2 (centred robot)."""

    def f(th):
        return abs(x) * math.tan(th) + robot_width / (2 * math.cos(th)) - door_width / 2

    return optimize.brentq(f, 0.0, math.acos(robot_width / door_width), xtol=1e-15)


def centred_pass_probability(sig, limit):
    """P(|θ − 2πj| ≤ θ* for some j), θ ~ N(0, σ²): the heading windows repeat every 2π."""
    return sum(
        ndtr((2 * math.pi * j + limit) / sig) - ndtr((2 * math.pi * j - limit) / sig)
        for j in range(-3, 4)
    )


def test_door_exact_position_closed_form():
    """Known position, uncertain heading: P = Σ_j P(|θ − 2πj| ≤ θ*) (jumps in the integrand)."""
    limit = heading_limit(-4.0, 12.0, 0.5)
    for sig in (0.05, 0.2, 0.45, 1.0):
        at = rm.AT([-4.0, 0.0, 0.0], np.diag([0.0, 0.0, sig * sig]))
        d = through_door(at, 12.0, 0.5, tol=1e-10)
        assert float(d.probability) == pytest.approx(centred_pass_probability(sig, limit), abs=1e-9)
        assert d.error <= 1e-10
    # With σθ = 1 the windows at ±2π add 9.5e-8: the heading is integrated unwrapped.
    assert centred_pass_probability(1.0, limit) - (2 * ndtr(limit) - 1) > 9e-8


def test_door_paper_test_is_not_conservative_for_large_heading_errors():
    """Linearizing y_c = y − x tan θ fails for large heading errors (the paper's §6.3 caveat).

    Here the P-box of (y_c, θ) fits in the pass region, but tan θ grows faster than θ, so the
    true probability (closed form, Monte Carlo) is 0.978 < P = 0.99.
    """
    # Linearized, y_c = 4θ: the box fits while 4kσ + 0.25/cos(kσ) ≤ 6, i.e. kσ ≤ 1.281 rad;
    # exactly, |4 tan θ| + 0.25/cos θ ≤ 6 holds only for |θ| ≤ 0.947 rad.
    linear_limit = optimize.brentq(lambda t: 4 * t + 0.25 / math.cos(t) - 6, 0.0, 1.5)
    sig = 0.98 * linear_limit / math.sqrt(-2 * math.log(0.01))  # the box reaches 98% of it
    at = rm.AT([-4.0, 0.0, 0.0], np.diag([0.0, 0.0, sig * sig]))
    d = through_door(at, 12.0, 0.5, probability=0.99)
    assert d.paper_test
    exact = centred_pass_probability(sig, heading_limit(-4.0, 12.0, 0.5))
    assert float(d.probability) == pytest.approx(exact, abs=1e-9)
    assert d.probability < 0.98
    assert_mc_agrees(float(d.probability), mc_door(at, 12.0, 0.5, seed=12))


@pytest.mark.parametrize("position_sigma", [None, 1e-3])
def test_door_accuracy_against_reference(position_sigma):
    """tol=1e-10 vs scipy quad of P(pass | θ) (written out independently here) agrees to 1e-9.

    With a nearly exact position (σ = 1 mm) P(pass | θ) switches within 1e-4 rad; quad is
    given those headings (found here with brentq) as break points.
    """
    mean = np.array([-2.0, 0.05, 0.1])
    C = np.array([[0.04, 0.01, 0.005], [0.01, 0.02, -0.01], [0.005, -0.01, 0.04]])
    W, w = 1.0, 0.6
    if position_sigma is not None:
        mean = np.array([-4.0, 0.3, 0.1])
        C = np.diag([position_sigma**2, position_sigma**2, 0.09])
        W, w = 12.0, 0.5
    d = through_door(rm.AT(mean, C), W, w, tol=1e-10)
    st = math.sqrt(C[2, 2])
    b = C[:2, 2] / C[2, 2]
    Cc = C[:2, :2] - np.outer(b, b) * C[2, 2]

    def parts(dth):
        th = mean[2] + dth
        v = np.array([-math.tan(th), 1.0])
        return W / 2 - w / (2 * math.cos(th)), v @ (mean[:2] + b * dth), math.sqrt(v @ Cc @ v)

    def f(dth):
        h, nu, tau = parts(dth)
        pdf = math.exp(-0.5 * (dth / st) ** 2) / (math.sqrt(2 * math.pi) * st)
        return pdf * (ndtr((h - nu) / tau) - ndtr((-h - nu) / tau)) if h > 0 else 0.0

    lim = math.acos(w / W)
    lo, hi = -lim - mean[2], lim - mean[2]
    grid = np.linspace(lo, hi, 2001)
    points = []
    for sign in (1, -1):

        def gap(x, sign=sign):
            h, nu, _ = parts(x)
            return h - sign * nu

        v = np.array([gap(x) for x in grid])
        for i in np.flatnonzero(v[:-1] * v[1:] < 0):
            r = optimize.brentq(gap, grid[i], grid[i + 1], xtol=1e-15)
            width = parts(r)[2] / abs((gap(r + 1e-7) - gap(r - 1e-7)) / 2e-7)
            points += [r + k * width for k in (0, -1, 1, -4, 4, -16, 16)]  # resolve the switch
    edges = [lo, *sorted(points), hi]
    ref = sum(
        integrate.quad(f, x0, x1, epsabs=1e-14, epsrel=1e-13, limit=200)[0]
        for x0, x1 in itertools.pairwise(edges)
    )
    assert d.error <= 1e-10
    assert float(d.probability) == pytest.approx(ref, abs=1e-9)


def test_door_batched_equals_per_element():
    rng = np.random.default_rng(10)
    mean = np.column_stack(
        [rng.uniform(-3, -1, 6), rng.uniform(-0.2, 0.2, 6), rng.normal(0, 0.2, 6)]
    )
    L = rng.normal(scale=0.1, size=(6, 3, 3))
    cov = L @ np.swapaxes(L, -1, -2)
    cov[2] = 0.0
    cov[3] = np.diag([0.01, 0.01, 0.0])
    at = rm.AT(mean.reshape(3, 2, 3), cov.reshape(3, 2, 3, 3))
    d = through_door(at, 1.0, 0.5)
    assert d.probability.shape == (3, 2)
    for i in range(3):
        for j in range(2):
            one = through_door(at[i, j], 1.0, 0.5)
            for field in ("probability", "paper_test", "crossing", "clearance", "slack"):
                assert getattr(one, field) == pytest.approx(getattr(d, field)[i, j], abs=1e-15)


def test_door_bad_parameters():
    at = rm.AT.from_sigmas([-2.0, 0.0, 0.0], [0.05, 0.05, 0.02])
    for W, w, message in [
        (0.0, 0.5, "door_width"),
        (-1.0, 0.5, "door_width"),
        (1.0, 0.0, "robot_width"),
        (1.0, -0.1, "robot_width"),
        (1.0, 1.2, "wider than the door"),
        (float("inf"), 0.5, "door_width"),
    ]:
        with pytest.raises(ParameterError, match=message):
            through_door(at, W, w)
    for p in (0.0, 1.0, -0.2):
        with pytest.raises(ParameterError, match="probability"):
            through_door(at, 1.0, 0.5, probability=p)


def test_import_stays_light():
    code = (
        "import sys, relmap.models.decisions; "
        "bad = [m for m in ('scipy.special', 'scipy.stats', 'scipy.sparse') if m in sys.modules]; "
        "assert not bad, bad"
    )
    subprocess.run([sys.executable, "-c", code], check=True)
