"""Decisions made ahead of time from an uncertain relative pose (§6.1-6.2 and Appendix A).

Smith & Cheeseman decide "is the object in the camera's field of view?" and "will the robot get
through the door?" by checking whether the P-confidence ellipse of the estimated relation lies
wholly inside the region where the task succeeds. Each decision here is available both ways:

- the **paper's test**: the P-ellipse (or, for the door, a stated P-box) inside the region;
- the **actual probability**: the Gaussian integrated over the region, to a stated accuracy.

The paper's test is a *sufficient* condition: an ellipse holding P that lies inside the region
proves the region holds at least P (checked on thousands of random cases in the tests). It is
conservative: it can answer "no" while the region holds far more than P, because it wants the
whole ellipse inside even where a single boundary is near and the region extends far beyond the
ellipse everywhere else: with one straight edge at Mahalanobis distance d the probability is
Φ(d), 0.97 for d = 1.9, while the 90% ellipse needs d ≥ k = 2.146. (The door's box test is only
conservative to first order: with large heading errors it can pass while the probability is
below P; see :func:`through_door`.)

Conventions: metres and radians; an AT's mean is ``(x, y, θ)`` with the covariance on
``(x, y, θ)`` in the parent frame (:class:`relmap.AT`); leading batch axes are supported and
every returned array has the AT's batch shape (numpy scalars for a single AT). A batch is
processed at once: no Python loop over its elements or over quadrature nodes.

**Field of view** (:func:`in_view`). The AT is the object seen from the sensor frame (x forward).
The view is the closed circular sector ``|bearing| ≤ fov/2``, ``min_range ≤ r ≤ max_range``.
The probability uses the 2-D position marginal. In polar coordinates around the sensor the
radial integral ``∫ r·N(r·u) dr`` along each bearing u has a closed form (complete the square:
Gaussian and error-function terms), so what remains is an analytic 1-D integral over the bearing
on the sector's angular range (its ends are the sector's edges, so no kinks), done by vectorized
adaptive Gauss-Legendre quadrature (:func:`relmap.uncertain.quadrature.adaptive`). Narrow features
of the integrand are located beforehand and made panel ends (:func:`_view_cuts`): the bearing
peak, rays parallel to the ellipse's major axis, and the bearings where the ray's density peak
crosses a range limit.
The bearing is measured from the mean's bearing, so a tiny uncertainty far away (angular sigma
1e-13 rad) keeps full precision.

**Accuracy.** On every panel the 10-point Gauss-Legendre rule is compared with the same rule on
the panel's two halves; the difference (an estimate of the *coarser* rule's error) is accepted
when it is at most ``tol/2`` times the panel's share of the interval, and an element is finished
as soon as its accepted and pending error estimates add up to at most ``tol``; unfinished panels
are bisected (a vectorized loop over refinement levels). The returned value is the sum of the
finer estimates, so its error is usually far below the reported ``error`` (≤ tol); measured
against independent nested ``scipy.integrate.quad`` references the error is ≈ 1e-14 for
``tol = 1e-10``. ``tol`` must lie in [1e-14, 0.1]. An error estimate can be fooled only by a
feature no node sees; that is what the pre-located panel ends prevent.

**Degenerate covariances.** A position covariance whose smaller eigenvalue is below ``1e-13``
times the larger is treated as singular (the entries of a 2×2 matrix do not resolve a smaller
eigenvalue much better than that in double precision). Rank 1: the position lies on a line; the
line is cut exactly at the region's boundary (circles, edges' lines), each piece is in or out,
and the probability is a sum of normal-CDF differences (continuous with the nearly singular
case: σ_minor = 1e-6·σ_major agrees to ~1e-9). Rank 0 (exactly known position): the probability
is 1 if the mean is in the closed region, boundary included (up to a 1e-12 allowance for
rounding), and 0 otherwise. The limit of a vanishing Gaussian centred on a straight edge would
be 1/2: the probability is discontinuous there, and the exact case follows the closed region.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from relmap.errors import NumericalError, ParameterError
from relmap.typing import FloatArray, IntArray
from relmap.uncertain import gaussian
from relmap.uncertain.at import AT
from relmap.uncertain.quadrature import adaptive, panels, split_panels

__all__ = ["DoorDecision", "ViewDecision", "in_view", "through_door"]

#: Eigenvalue ratio below which a 2×2 position covariance counts as singular.
_RANK_RTOL = 1e-13
#: Grid points per heading window on which the door's switching headings are bracketed.
_ROOT_GRID = 129
#: Bisection steps refining each bracketed switching heading (2⁻⁵⁰ of a grid cell).
_BISECTIONS = 50
#: Standard deviations of the heading covered by the door quadrature (tail mass 2Q(9) ≈ 2e-19).
_HEADING_SPAN = 9.0
#: Relative (radius) and absolute (bearing, rad) allowance of the closed sector's membership test.
_BOUNDARY_RTOL = 1e-12
_TWO_PI = 2.0 * math.pi
_SQRT_2PI = math.sqrt(_TWO_PI)


class ViewDecision(NamedTuple):
    """Is the object in the sensor's field of view? (:func:`in_view`).

    - ``probability``: Gaussian position marginal integrated over the view sector.
    - ``error``: estimated absolute error bound of ``probability`` (≤ ``tol``; 0 when exact).
    - ``ellipse_inside``: the paper's test, the P-ellipse of the position wholly inside the
      sector (equivalently ``margin >= k``). If True, ``probability >= P``.
    - ``margin``: signed Mahalanobis distance from the mean position to the region: the largest
      k' whose ellipse lies inside if the mean is inside, minus the smallest k' whose ellipse
      touches the region otherwise (±inf for an exactly known position; −inf when a
      singular distribution's support misses the region).
    - ``mean_inside``: the mean position lies in the (closed) sector.
    - ``k``: Mahalanobis radius of the P-ellipse (``k² = −2 ln(1 − P)``).
    - ``probability_level``: P.
    """

    probability: FloatArray
    error: FloatArray
    ellipse_inside: np.bool_ | np.ndarray
    margin: FloatArray
    mean_inside: np.bool_ | np.ndarray
    k: float
    probability_level: float


class DoorDecision(NamedTuple):
    """Will the robot drive through the door? (:func:`through_door`).

    - ``probability``: probability of passing under the model of :func:`through_door`.
    - ``error``: estimated absolute error bound of ``probability`` (≤ ``tol``; 0 when exact).
    - ``paper_test``: the P-box test of :func:`through_door` (True iff ``slack >= 0``).
    - ``crossing``: nominal lateral position ``ŷ_c = ŷ − x̂·tan θ̂`` where the line of travel
      meets the door line (m).
    - ``crossing_sigma``: first-order standard deviation of ``y_c`` (m).
    - ``clearance``: nominal clearance ``W/2 − w/(2 cos θ̂) − |ŷ_c|`` (m); −inf if the mean
      heading does not point through the door (``cos θ̂ ≤ 0``).
    - ``slack``: the paper test's clearance ``W/2 − w/(2 cos θ_worst) − |ŷ_c| − k·σ_c`` (m), −inf
      when the heading P-interval reaches ±π/2.
    - ``k``: Mahalanobis radius of the P-ellipse of ``(y_c, θ)`` (2 degrees of freedom).
    - ``probability_level``: P.
    """

    probability: FloatArray
    error: FloatArray
    paper_test: np.bool_ | np.ndarray
    crossing: FloatArray
    crossing_sigma: FloatArray
    clearance: FloatArray
    slack: FloatArray
    k: float
    probability_level: float


# ------------------------------------------------------------------------------ helpers
def _scalar(value: float, name: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ParameterError(f"{name} must be a real number; got {value!r}") from None
    if not math.isfinite(v):
        raise ParameterError(f"{name} must be finite; got {v}")
    return v


def _check_at(at: object) -> AT:
    if not isinstance(at, AT):
        raise TypeError(f"expected an AT; got {type(at).__name__}")
    return at


def _check_tol(tol: float) -> float:
    t = _scalar(tol, "tol")
    if not 1e-14 <= t <= 0.1:
        raise ParameterError(
            f"tol must lie in [1e-14, 0.1] (below 1e-14 rounding dominates); got {t:g}"
        )
    return t


def _ndtr() -> Callable[[FloatArray], FloatArray]:
    from scipy.special import ndtr  # lazy: keeps `import relmap` light

    return ndtr  # type: ignore[no-any-return]


def _phi_diff(ndtr: Callable[[FloatArray], FloatArray], a: FloatArray, b: FloatArray) -> FloatArray:
    """``Φ(b) − Φ(a)`` for ``a ≤ b``, as ``Φ(−a) − Φ(−b)`` when both are positive (no 1 − 1)."""
    upper = a > 0.0
    return ndtr(np.where(upper, -a, b)) - ndtr(np.where(upper, -b, a))


def _finish(arr: FloatArray | np.ndarray, batch: tuple[int, ...]) -> FloatArray:
    return np.asarray(arr).reshape(batch)[()]


def _quartic_angles(
    c4: np.ndarray, c3: np.ndarray, c2: np.ndarray, c1: np.ndarray, c0: np.ndarray
) -> tuple[FloatArray, FloatArray]:
    """Arguments and moduli of the roots of ``c4 z⁴ + c3 z³ + c2 z² + c1 z + c0`` (batched (B,)).

    Used for trigonometric polynomials of degree 2 in t (``z = e^{it}``): their zeros are the
    roots on the unit circle; the other roots give extra angles, which callers must tolerate.
    A vanishing leading coefficient is replaced by a tiny one (two roots then go to 0 or ∞).
    """
    scale = np.maximum.reduce([np.abs(c) for c in (c4, c3, c2, c1, c0)])
    scale = np.where(scale > 0.0, scale, 1.0)
    c4 = np.where(np.abs(c4) > 1e-13 * scale, c4, 1e-13 * scale)
    comp = np.zeros((c4.size, 4, 4), dtype=complex)
    comp[:, 1:, :3] = np.eye(3)
    for j, c in enumerate((c3, c2, c1, c0)):
        comp[:, 0, j] = -c / c4
    roots = np.linalg.eigvals(comp)
    roots = np.where(np.isfinite(roots), roots, 1.0)
    return np.angle(roots), np.abs(roots)


# -------------------------------------------------------------------------- field of view
class _Sector(NamedTuple):
    half: float  # half the field of view (rad)
    rmin: float
    rmax: float
    full: bool  # fov == 2π: an annulus (or a disc), no straight edges

    def contains(self, px: FloatArray, py: FloatArray) -> np.ndarray:
        """Membership of the closed sector; a point off it by rounding only (1e-12) is in."""
        r = np.hypot(px, py)
        ok = (r >= self.rmin * (1.0 - _BOUNDARY_RTOL)) & (r <= self.rmax * (1.0 + _BOUNDARY_RTOL))
        if not self.full:
            ok &= np.abs(np.arctan2(py, px)) <= self.half + _BOUNDARY_RTOL
        return ok

    def edges(self) -> list[tuple[float, float]]:
        """Unit directions of the straight edges (none for a full circle)."""
        if self.full:
            return []
        c, s = math.cos(self.half), math.sin(self.half)
        return [(c, s), (c, -s)]


def _eig2(S: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Eigenvalues ``λ1 ≥ λ2 ≥ 0`` and major-axis angle of 2×2 covariances ``(B, 2, 2)``."""
    a, b, c = S[:, 0, 0], S[:, 0, 1], S[:, 1, 1]
    half_sum = 0.5 * (a + c)
    radius = np.hypot(0.5 * (a - c), b)
    lam1 = np.maximum(half_sum + radius, 0.0)
    lam2 = np.clip(half_sum - radius, 0.0, lam1)
    return lam1, lam2, 0.5 * np.arctan2(2.0 * b, a - c)


def _view_probability_full_rank(
    m: FloatArray, lam1: FloatArray, lam2: FloatArray, alpha: FloatArray, sec: _Sector, tol: float
) -> tuple[FloatArray, FloatArray]:
    """Probability of the sector for full-rank 2-D Gaussians (B elements): polar quadrature.

    Along the ray at bearing φ (unit u, normal w), with D = det S and ``ww = wᵀSw``:
    ``∫ r N(r u) dr = e^{-g/2}/(2π) [√D/ww (e^{-z0²/2} − e^{-z1²/2})
    + μ √(2π/ww) (Φ(z1) − Φ(z0))]``, where ``g = (m·w)²/ww`` (Mahalanobis distance² from the
    mean to the ray's line), ``μ`` the density's peak along the ray, ``s = √(D/ww)`` its
    conditional sigma and ``z = (r − μ)/s``. The variable is Δ = φ − (mean's bearing).
    """
    ndtr = _ndtr()
    rho = np.hypot(m[:, 0], m[:, 1])
    beta0 = np.arctan2(m[:, 1], m[:, 0])
    theta0 = beta0 - alpha  # the mean's bearing relative to the major axis
    sqrt_det = np.sqrt(lam1 * lam2)

    # Per element: ρ·λ2·cos θ0 and ρ·λ1·sin θ0 (the numerator of μ).
    mu_c, mu_s = rho * lam2 * np.cos(theta0), rho * lam1 * np.sin(theta0)

    def integrand(delta: FloatArray, e: IntArray) -> FloatArray:
        r0, t0 = rho[e][:, None], theta0[e][:, None]
        l1, l2, sd = lam1[e][:, None], lam2[e][:, None], sqrt_det[e][:, None]
        psi = t0 + delta
        cp, sp = np.cos(psi), np.sin(psi)
        ww = l1 * sp * sp + l2 * cp * cp
        g = (r0 * np.sin(delta)) ** 2 / ww
        mu = (mu_c[e][:, None] * cp + mu_s[e][:, None] * sp) / ww
        s = sd / np.sqrt(ww)
        z0, z1 = (sec.rmin - mu) / s, (sec.rmax - mu) / s
        gauss = np.exp(-0.5 * (g + z0 * z0)) - np.exp(-0.5 * (g + z1 * z1))
        cdf = mu * np.sqrt(_TWO_PI / ww) * np.exp(-0.5 * g) * _phi_diff(ndtr, z0, z1)
        return (sd / ww * gauss + cdf) / _TWO_PI

    cuts = _view_cuts(rho, theta0, lam1, lam2, sec)
    lo, hi, elem = split_panels(-sec.half - beta0, sec.half - beta0, cuts)
    return adaptive(integrand, lo, hi, elem, rho.size, tol, "in_view")


def _view_cuts(
    rho: FloatArray, theta0: FloatArray, lam1: FloatArray, lam2: FloatArray, sec: _Sector
) -> FloatArray:
    """Where the polar integrand (in Δ = bearing − mean's bearing) has its features: (B, K).

    A narrow feature that no Gauss-Legendre node sees would go unnoticed by the error
    estimate, so every feature gets panel ends at its centre ± 1, 4, 16 times its width:

    - the bearing peak at Δ = 0 and, through the sensor, its antipode Δ = π (the ray's line is
      the same): widths the linearized bearing sigma and ``√λ1/|m|``;
    - rays parallel to the major axis (``wᵀSw`` is smallest there), width ``√(λ2/λ1)``;
    - the range limits: Φ(z1) − Φ(z0) switches where the ray's peak μ(Δ) crosses a radius R
      (steeply for thin ellipses), width ``s/|μ'(Δ)|``. ``μ = R ⇔ (R u − m)ᵀ G u = 0`` is a
      trigonometric polynomial of degree 2 in Δ (a quartic in e^{iΔ}); μ = 0 (the sensor, when
      ``min_range`` is 0) is ``u ⊥ G m``.

    Each centre is repeated 2π either way, as the Δ range may extend on either side of 0.
    """
    B = rho.size
    mult = np.array([0.0, 1.0, 4.0, 16.0])
    mult = np.concatenate([mult, -mult[1:]])
    with np.errstate(divide="ignore", invalid="ignore"):
        sig_b = np.sqrt(lam1 * np.sin(theta0) ** 2 + lam2 * np.cos(theta0) ** 2) / rho
        sig_w = np.sqrt(lam1) / rho
        g1, g2 = 1.0 / lam1, 1.0 / lam2
    sig_p = np.sqrt(lam2 / lam1)
    half_turns = np.arange(-2, 3)[None, :] * math.pi  # Δ = kπ, k = -2..2
    axis = (-theta0 + 0.5 * math.pi) % math.pi - 0.5 * math.pi  # the major axis' direction
    centres = [half_turns, half_turns, axis[:, None] + half_turns]
    widths = [sig_b, sig_w, sig_p]
    # Range limits, in a frame turned to the mean's bearing (the major axis at angle −θ0).
    ca, sa = np.cos(theta0), -np.sin(theta0)
    A, C, Bc = g1 * ca * ca + g2 * sa * sa, g1 * sa * sa + g2 * ca * ca, (g1 - g2) * ca * sa
    q1, q2 = A * rho, Bc * rho
    roots = []
    for R in (sec.rmin, sec.rmax):
        if R > 0.0:
            angle, modulus = _quartic_angles(
                R * (0.25 * (A - C) - 0.5j * Bc),
                -0.5 * (q1 - 1j * q2),
                0.5 * R * (A + C) + 0j,
                -0.5 * (q1 + 1j * q2),
                R * (0.25 * (A - C) + 0.5j * Bc),
            )
            # Only roots on the unit circle are crossings (loosely: a double root splits).
            roots.append(np.where(np.abs(modulus - 1.0) < 1e-3, angle, np.nan))
        else:
            perp = np.arctan2(q2, q1)[:, None] + 0.5 * math.pi
            roots.append(np.concatenate([perp, perp - math.pi], axis=1))
    t = np.concatenate(roots, axis=1)
    psi = theta0[:, None] + t
    cp, sp = np.cos(psi), np.sin(psi)
    l1, l2, r0, t0 = lam1[:, None], lam2[:, None], rho[:, None], theta0[:, None]
    ww = l1 * sp * sp + l2 * cp * cp
    num = r0 * (l2 * cp * np.cos(t0) + l1 * sp * np.sin(t0))
    dnum = r0 * (-l2 * sp * np.cos(t0) + l1 * cp * np.sin(t0))
    dmu = (dnum * ww - num * 2.0 * (l1 - l2) * sp * cp) / (ww * ww)
    with np.errstate(divide="ignore"):
        sig_t = np.sqrt(l1 * l2 / ww) / np.abs(dmu)
    shifts = np.array([-_TWO_PI, 0.0, _TWO_PI])
    out = [
        (t[:, :, None] + shifts).reshape(B, -1, 1) + (np.repeat(sig_t, 3, axis=1)[..., None] * mult)
    ]
    for c, wd in zip(centres, widths, strict=True):
        wd = np.minimum(np.nan_to_num(wd, nan=_TWO_PI, posinf=_TWO_PI), _TWO_PI)
        out.append(np.broadcast_to(c, (B, c.shape[-1]))[:, :, None] + wd[:, None, None] * mult)
    return np.concatenate([o.reshape(B, -1) for o in out], axis=1)


def _mahalanobis2_eig(
    vx: FloatArray, vy: FloatArray, lam1: FloatArray, lam2: FloatArray, alpha: FloatArray
) -> FloatArray:
    ca, sa = np.cos(alpha), np.sin(alpha)
    v1 = vx * ca + vy * sa
    v2 = -vx * sa + vy * ca
    return v1 * v1 / lam1 + v2 * v2 / lam2


def _view_distance2_full_rank(
    m: FloatArray, lam1: FloatArray, lam2: FloatArray, alpha: FloatArray, sec: _Sector
) -> FloatArray:
    """Smallest Mahalanobis distance² from the mean to the sector's boundary (full-rank S).

    Edges are segments ``s·d``, ``rmin ≤ s ≤ rmax`` (a closed-form minimum). On an arc
    ``p(t) = R(cos t, sin t)`` the distance² is a trigonometric polynomial of degree 2 in t;
    its critical points are the roots of a quartic in ``z = e^{it}`` (companion matrix), polished
    by Newton steps; the arc's end points are candidates too. Every candidate is a point of the
    boundary, so the minimum over them is exact up to rounding.
    """
    mx, my = m[:, 0], m[:, 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        ca, sa = np.cos(alpha), np.sin(alpha)
        g1, g2 = 1.0 / lam1, 1.0 / lam2
    A = g1 * ca * ca + g2 * sa * sa
    C = g1 * sa * sa + g2 * ca * ca
    Bc = (g1 - g2) * ca * sa

    def d2(px: FloatArray, py: FloatArray) -> FloatArray:
        return _mahalanobis2_eig(
            px - mx[..., None], py - my[..., None], *(v[..., None] for v in (lam1, lam2, alpha))
        )

    best = np.full(m.shape[0], np.inf)
    for dx, dy in sec.edges():
        dGd = A * dx * dx + 2.0 * Bc * dx * dy + C * dy * dy
        dGm = (A * dx + Bc * dy) * mx + (Bc * dx + C * dy) * my
        s = np.clip(dGm / dGd, sec.rmin, sec.rmax)[:, None]
        best = np.minimum(best, d2(s * dx, s * dy)[:, 0])

    q1, q2 = A * mx + Bc * my, Bc * mx + C * my
    for R in (sec.rmax, sec.rmin):
        if R <= 0.0:
            continue
        # f'(t)·z²/R = c4 z⁴ + c3 z³ + c1 z + c0 (see the docstring).
        zero = np.zeros_like(q1, dtype=complex)
        t = _quartic_angles(
            R * (Bc + 0.5j * (A - C)), -q2 - 1j * q1, zero, -q2 + 1j * q1, R * (Bc - 0.5j * (A - C))
        )[0]
        cand = [t]
        for _ in range(3):  # Newton on f'(t) = 0
            c, s = np.cos(t), np.sin(t)
            c2, s2 = np.cos(2 * t), np.sin(2 * t)
            AmC, B_, Q1, Q2 = (v[:, None] for v in (A - C, Bc, q1, q2))
            f1 = R * R * (-AmC * s2 + 2 * B_ * c2) + 2 * R * (Q1 * s - Q2 * c)
            f2 = R * R * (-2 * AmC * c2 - 4 * B_ * s2) + 2 * R * (Q1 * c + Q2 * s)
            with np.errstate(divide="ignore", invalid="ignore"):
                step = np.where(f2 > 0.0, f1 / f2, 0.0)
            t = t - np.where(np.isfinite(step), step, 0.0)
            cand.append(t)
        t = np.concatenate(cand, axis=1)
        t = (t + math.pi) % _TWO_PI - math.pi
        if not sec.full:
            t = np.clip(t, -sec.half, sec.half)  # a point off the arc becomes an end point
            t = np.concatenate([t, np.full((t.shape[0], 2), [-sec.half, sec.half])], axis=1)
        best = np.minimum(best, d2(R * np.cos(t), R * np.sin(t)).min(axis=1))
    return best


def _view_line(
    m: FloatArray, lam1: FloatArray, alpha: FloatArray, sec: _Sector
) -> tuple[FloatArray, FloatArray]:
    """Probability and margin when the position lies on a line (rank-1 covariance, B elements).

    The line ``m + t·e1``, ``t ~ N(0, λ1)``, is cut at every crossing with the region's boundary
    (the circles, the edges' lines); each piece is in or out of the sector (tested at its
    midpoint), and the probability is a sum of Φ differences.
    """
    ndtr = _ndtr()
    a = np.sqrt(lam1)
    ex, ey = np.cos(alpha), np.sin(alpha)
    mx, my = m[:, 0], m[:, 1]
    along = mx * ex + my * ey  # m·e
    offset = mx * ey - my * ex  # signed distance of the line from the sensor
    disc = sec.rmax**2 - offset**2
    hit = disc >= 0.0
    root = np.sqrt(np.maximum(disc, 0.0))
    ta = np.where(hit, -along - root, 0.0)
    tb = np.where(hit, -along + root, 0.0)
    pts = []
    if sec.rmin > 0.0:
        dmin = sec.rmin**2 - offset**2
        rmin_root = np.sqrt(np.maximum(dmin, 0.0))
        pts += [
            np.where(dmin >= 0, -along - rmin_root, tb),
            np.where(dmin >= 0, -along + rmin_root, tb),
        ]
    for dx, dy in sec.edges():
        den = dx * ey - dy * ex
        cross_m = dx * my - dy * mx
        with np.errstate(divide="ignore", invalid="ignore"):
            pts.append(np.where(den != 0.0, -cross_m / den, tb))
    inner = (
        np.clip(np.stack(pts, axis=1), ta[:, None], tb[:, None])
        if pts
        else np.zeros((m.shape[0], 0))
    )
    T = np.sort(np.concatenate([ta[:, None], inner, tb[:, None]], axis=1), axis=1)
    lo, hi = T[:, :-1], T[:, 1:]
    mid = 0.5 * (lo + hi)
    ins = (
        sec.contains(mx[:, None] + mid * ex[:, None], my[:, None] + mid * ey[:, None])
        & hit[:, None]
    )
    prob = (ins * _phi_diff(ndtr, lo / a[:, None], hi / a[:, None])).sum(axis=1)

    inside_m = sec.contains(mx, my)
    out = ~ins
    inf = np.inf
    exit_plus = np.minimum(tb, np.where(out & (lo >= 0.0), lo, inf).min(axis=1))
    exit_minus = np.minimum(-ta, np.where(out & (hi <= 0.0), -hi, inf).min(axis=1))
    reach = np.where(ins, np.where(lo > 0.0, lo, np.where(hi < 0.0, -hi, 0.0)), inf).min(axis=1)
    margin = np.where(inside_m, np.minimum(exit_plus, exit_minus), -reach) / a
    return prob, margin


def in_view(
    at: AT,
    fov: float,
    max_range: float,
    *,
    min_range: float = 0.0,
    probability: float = 0.9,
    tol: float = 1e-9,
) -> ViewDecision:
    """Decide ahead of time whether an object is in a sensor's field of view (Appendix A).

    Parameters
    ----------
    at:
        The object's AT seen from the sensor frame (x forward, y left), any batch shape. Only the
        position marginal ``(x, y)`` matters.
    fov:
        Full angular width of the view (rad), in (0, 2π]; the view is ``|bearing| ≤ fov/2``
        (2π: a disc or an annulus).
    max_range, min_range:
        Radial limits (m), ``0 ≤ min_range < max_range``. The region is closed.
    probability:
        P of the paper's test (the P-ellipse of the position inside the sector), in (0, 1).
    tol:
        Absolute accuracy of ``probability`` (see the module docstring), in [1e-14, 0.1].

    Returns a :class:`ViewDecision`. The batch is processed at once (no Python loop over it).
    """
    at = _check_at(at)
    fov = _scalar(fov, "fov")
    if not 0.0 < fov <= _TWO_PI:
        raise ParameterError(f"fov must lie in (0, 2π] radians; got {fov:g}")
    max_range = _scalar(max_range, "max_range")
    min_range = _scalar(min_range, "min_range")
    if min_range < 0.0:
        raise ParameterError(f"min_range must be non-negative; got {min_range:g}")
    if max_range <= 0.0:
        raise ParameterError(f"max_range must be positive; got {max_range:g}")
    if max_range <= min_range:
        raise ParameterError(
            f"max_range ({max_range:g}) must be greater than min_range ({min_range:g})"
        )
    p = float(gaussian.check_probability(_scalar(probability, "probability")))
    tol = _check_tol(tol)
    k = math.sqrt(float(gaussian.confidence_k2(p, 2)))
    sec = _Sector(0.5 * fov, min_range, max_range, fov >= _TWO_PI)

    batch = at.batch_shape
    m = np.ascontiguousarray(at.mean[..., :2]).reshape(-1, 2)
    S = np.ascontiguousarray(at.cov[..., :2, :2]).reshape(-1, 2, 2)
    lam1, lam2, alpha = _eig2(S)
    n = m.shape[0]
    mean_inside = sec.contains(m[:, 0], m[:, 1])
    prob = mean_inside.astype(np.float64)  # rank 0: exactly known position
    margin = np.where(mean_inside, np.inf, -np.inf)
    error = np.zeros(n)

    line = (lam1 > 0.0) & (lam2 <= _RANK_RTOL * lam1)
    if line.any():
        prob[line], margin[line] = _view_line(m[line], lam1[line], alpha[line], sec)
    full = (lam1 > 0.0) & ~line
    if full.any():
        args = (m[full], lam1[full], lam2[full], alpha[full], sec)
        try:
            p_full, error[full] = _view_probability_full_rank(*args, tol)
            dist = np.sqrt(_view_distance2_full_rank(*args))
        except np.linalg.LinAlgError:  # inf or NaN met inside: inputs near the float range
            p_full = dist = np.full(int(full.sum()), np.nan)
        prob[full] = np.clip(p_full, 0.0, 1.0)
        margin[full] = np.where(mean_inside[full], dist, -dist)
    _overflowed("in_view", at, prob, error, margin)
    return ViewDecision(
        probability=_finish(prob, batch),
        error=_finish(error, batch),
        ellipse_inside=_finish(margin >= k, batch),
        margin=_finish(margin, batch),
        mean_inside=_finish(mean_inside, batch),
        k=k,
        probability_level=p,
    )


def _overflowed(what: str, at: AT, *results: FloatArray) -> None:
    """Raise :class:`NumericalError` where a decision's arithmetic met inf or NaN (variances or
    positions near the floating-point range, e.g. a covariance of 1e300)."""
    for r in results:
        bad = np.isnan(r)
        if bad.any():
            raise NumericalError(
                f"{what}: the computation overflowed the floating-point range (largest "
                f"variance {float(np.max(at.cov)):.3g}, largest |mean| "
                f"{float(np.max(np.abs(at.mean))):.3g}): no probability can be given"
            )


#: Most heading windows ``2πj ± θmax`` :func:`through_door` integrates over per AT.
_MAX_WINDOWS = 1e4


# -------------------------------------------------------------------------------- doorway
def through_door(
    at: AT,
    door_width: float,
    robot_width: float,
    *,
    probability: float = 0.9,
    tol: float = 1e-9,
) -> DoorDecision:
    """Decide ahead of time whether a robot will drive through a doorway (§6).

    Door frame: origin at the centre of the doorway, x axis through the door (the direction of
    passage), y along the door line; the opening is ``x = 0, |y| ≤ door_width/2``. ``at`` is the
    robot's pose in the door frame, any batch shape.

    Model: the robot (a body of width ``robot_width``, centred on its reference point) drives
    straight along its heading θ. Its line of travel meets the door line at
    ``y_c = y − x·tan θ``, where its swept strip is ``robot_width/|cos θ|`` wide. It passes iff
    ``cos θ > 0`` (it heads through the door, |θ| < π/2 modulo 2π) and
    ``|y_c| + robot_width/(2 cos θ) ≤ door_width/2``. A heading pointing away from the door
    fails; the sign of x is not examined (a pose beyond the door line is judged by the same
    line of travel). The robot's length, the jambs' thickness and any steering are ignored.

    **Probability.** For a fixed heading, ``(x, y)`` is Gaussian (conditioned on θ), so ``y_c``
    is Gaussian and ``P(pass | θ) = Φ((h − ν)/τ) − Φ((−h − ν)/τ)``, ``h = door_width/2 −
    robot_width/(2 cos θ)``. This is integrated over θ's Gaussian marginal (unwrapped, on
    ``θ̂ ± 9σθ``: the neglected tail is 2e-19) by the adaptive Gauss-Legendre quadrature of
    :func:`in_view`, to ``tol`` absolute (measured against independent ``scipy.integrate.quad``
    references: ≈ 1e-15). The integrand vanishes outside the heading windows
    ``|θ − 2πj| ≤ arccos(robot_width/door_width)`` (a kink at their ends, made panel ends);
    inside, panels are cut at θ̂ + (0, ±1, ±2, ±3, ±4, ±5, ±7)σθ and at the headings where the
    conditional mean of y_c meets an edge of the gap (ν = ±h, bracketed on a 129-point grid per
    window and bisected), ± 1, 4, 16 times the width τ/|d(h ∓ ν)/dθ| of that switch; there
    P(pass | θ) jumps when the position given the heading is exact, and is steep when nearly so.
    An exactly known heading needs no quadrature; an exactly known position gives the indicator
    of the closed condition. Equal widths pass only when exactly aligned and centred.

    **Paper-style test** (``paper_test``). Linearize ``y_c`` at the mean (first-order σ_c from the
    3×3 covariance) and take the bounding box ``[ŷ_c ± kσ_c] × [θ̂ ± kσθ]`` of the P-ellipse of
    ``(y_c, θ)`` (k for two degrees of freedom). The test passes iff the whole box lies in the
    pass region: ``|θ̂| + kσθ < π/2`` and ``|ŷ_c| + kσ_c ≤ door_width/2 − robot_width/(2 cos
    θ_worst)`` with ``θ_worst = |θ̂| + kσθ`` (the region is convex, so the box's corners decide).
    To first order this is conservative (box ⊇ ellipse ⊂ region ⇒ probability ≥ P); with large
    heading errors the linearization itself may fail.

    Raises :class:`ParameterError` for widths ≤ 0, a robot wider than the door, a probability
    outside (0, 1) or a bad tol.
    """
    at = _check_at(at)
    W = _scalar(door_width, "door_width")
    w = _scalar(robot_width, "robot_width")
    if W <= 0.0:
        raise ParameterError(f"door_width must be positive; got {W:g}")
    if w <= 0.0:
        raise ParameterError(f"robot_width must be positive; got {w:g}")
    if w > W:
        raise ParameterError(
            f"the robot ({w:g} m wide) is wider than the door ({W:g} m): it can never pass"
        )
    p = float(gaussian.check_probability(_scalar(probability, "probability")))
    tol = _check_tol(tol)
    k = math.sqrt(float(gaussian.confidence_k2(p, 2)))
    ndtr = _ndtr()
    theta_max = math.acos(w / W)  # in [0, π/2): the headings at which the robot fits at all

    batch = at.batch_shape
    mean = np.ascontiguousarray(at.mean).reshape(-1, 3)
    cov = np.ascontiguousarray(at.cov).reshape(-1, 3, 3)
    n = mean.shape[0]
    x0, y0, th0 = mean[:, 0], mean[:, 1], mean[:, 2]
    var_th = cov[:, 2, 2]
    sig_th = np.sqrt(var_th)
    uncertain = var_th > 0.0
    # Regression of (x, y) on θ and the conditional covariance of (x, y) given θ.
    beta = np.where(
        uncertain[:, None], cov[:, :2, 2] / np.where(uncertain, var_th, 1.0)[:, None], 0.0
    )
    cond = cov[:, :2, :2] - beta[:, :, None] * beta[:, None, :] * var_th[:, None, None]

    def terms(theta: FloatArray, dth: FloatArray, e: IntArray) -> tuple[FloatArray, ...]:
        """Half-width h, conditional mean ν and sigma τ of y_c, for θ = θ̂ + dth.

        ``theta``/``dth`` are (P, n) or (P,), ``e`` the elements (P,).
        """
        exp = (slice(None),) + (None,) * (theta.ndim - 1)
        b = beta[e]
        cth = np.cos(theta)
        tan = np.tan(theta)
        nu = (y0[e][exp] + b[:, 1][exp] * dth) - tan * (x0[e][exp] + b[:, 0][exp] * dth)
        c = cond[e]
        tau2 = c[:, 1, 1][exp] - 2.0 * tan * c[:, 0, 1][exp] + tan * tan * c[:, 0, 0][exp]
        with np.errstate(divide="ignore"):
            h = np.where(cth > 0.0, 0.5 * W - 0.5 * w / cth, -np.inf)
        return h, nu, np.sqrt(np.maximum(tau2, 0.0))

    def pass_given(theta: FloatArray, dth: FloatArray, e: IntArray) -> FloatArray:
        """P(pass | θ) for headings θ = θ̂ + dth (closed condition when τ = 0)."""
        h, nu, tau = terms(theta, dth, e)
        hi, lo = h - nu, -h - nu
        pos = tau > 0.0
        safe = np.where(pos, tau, 1.0)
        with np.errstate(invalid="ignore"):
            z_hi = np.where(pos, hi / safe, np.where(hi >= 0.0, np.inf, -np.inf))
            z_lo = np.where(pos, lo / safe, np.where(lo > 0.0, np.inf, -np.inf))
        ok = (h >= 0.0) & (z_hi >= z_lo)
        return np.where(ok, _phi_diff(ndtr, np.minimum(z_lo, z_hi), z_hi), 0.0)

    prob = np.zeros(n)
    error = np.zeros(n)
    exact = ~uncertain
    if exact.any():
        idx = np.flatnonzero(exact)
        prob[idx] = pass_given(th0[idx], np.zeros(idx.size), idx)
    if uncertain.any():
        idx = np.flatnonzero(uncertain)
        sg, tc = sig_th[idx], th0[idx]
        span = _HEADING_SPAN * sg
        # Heading windows 2πj ± θmax met by θ̂ ± span, in the deviation δ = θ − θ̂.
        j_lo = np.ceil((tc - span - theta_max) / _TWO_PI)
        j_hi = np.floor((tc + span + theta_max) / _TWO_PI)
        windows = np.maximum(j_hi - j_lo + 1, 0)
        if not (windows <= _MAX_WINDOWS).all():  # σθ beyond ~10⁵ rad (or inf): meaningless
            k = int(np.flatnonzero(~(windows <= _MAX_WINDOWS))[0])
            raise NumericalError(
                f"through_door: the heading's standard deviation {sg[k]:.3g} rad is too large "
                f"to integrate over its {windows[k]:.3g} heading windows (at most {_MAX_WINDOWS:g})"
            )
        count = windows.astype(np.int64)
        owner = np.repeat(np.arange(idx.size), count)
        first = np.repeat(np.cumsum(count) - count, count)
        j = j_lo[owner] + (np.arange(owner.size) - first)
        win_lo = np.maximum(_TWO_PI * j - theta_max - tc[owner], -span[owner])
        win_hi = np.minimum(_TWO_PI * j + theta_max - tc[owner], span[owner])
        steps = np.array([0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 7.0])
        steps = np.concatenate([steps, -steps[1:]])
        cut_win = [np.repeat(np.arange(owner.size), steps.size)]
        cut_val = [(sg[owner][:, None] * steps).ravel()]
        # P(pass | θ) switches where the conditional mean of y_c meets an edge of the gap,
        # ν = ±h (a jump when the position given the heading is exact, a steep step when nearly
        # so): find those headings (sign changes on a grid, then bisection) and cut there.
        grid = np.linspace(0.0, 1.0, _ROOT_GRID)
        dth = win_lo[:, None] + (win_hi - win_lo)[:, None] * grid
        gidx = idx[owner]

        def edge_gap(d: FloatArray, rows: IntArray, sign: float | FloatArray) -> FloatArray:
            """h ∓ ν at deviations d ((rows, M) grid or (rows,)) of windows ``rows``."""
            t = tc[owner[rows]]
            h, nu, _ = terms(t[:, None] + d if d.ndim > 1 else t + d, d, gidx[rows])
            return h - sign * nu

        g = np.concatenate([edge_gap(dth, np.arange(owner.size), s) for s in (1.0, -1.0)])
        which, cols = np.nonzero(np.sign(g[:, :-1]) * np.sign(g[:, 1:]) <= 0.0)
        rows = which % owner.size
        sign = np.where(which < owner.size, 1.0, -1.0)
        a, b = dth[rows, cols], dth[rows, cols + 1]
        ga = g[which, cols]
        for _ in range(_BISECTIONS):
            mid = 0.5 * (a + b)
            gm = edge_gap(mid, rows, sign)
            left = np.sign(gm) * np.sign(ga) <= 0.0
            b = np.where(left, mid, b)
            a, ga = np.where(left, a, mid), np.where(left, ga, gm)
        root = 0.5 * (a + b)
        # Width of the switch: τ / |d(h ∓ ν)/dθ| at the root; cut at ±1, 4, 16 widths too.
        e = gidx[rows]
        theta = tc[owner[rows]] + root
        cth, tan = np.cos(theta), np.tan(theta)
        dh = -0.5 * w * np.sin(theta) / (cth * cth)
        dnu = beta[e, 1] - (x0[e] + beta[e, 0] * root) / (cth * cth) - tan * beta[e, 0]
        tau = terms(theta, root, e)[2]
        with np.errstate(divide="ignore", invalid="ignore"):
            width = tau / np.abs(dh - sign * dnu)
        mult = np.array([0.0, 1.0, 4.0, 16.0, -1.0, -4.0, -16.0])
        cut_win.append(np.repeat(rows, mult.size))
        cut_val.append((root[:, None] + width[:, None] * mult).ravel())
        lo, hi, win = panels(win_lo, win_hi, np.concatenate(cut_win), np.concatenate(cut_val))
        elem = owner[win]

        def integrand(dth: FloatArray, e: IntArray) -> FloatArray:
            s = sg[e][:, None]
            weight = np.exp(-0.5 * (dth / s) ** 2) / (_SQRT_2PI * s)
            return weight * pass_given(tc[e][:, None] + dth, dth, idx[e])

        p_unc, e_unc = adaptive(integrand, lo, hi, elem, idx.size, tol, "through_door")
        prob[idx] = np.clip(p_unc, 0.0, 1.0)
        error[idx] = e_unc

    # Paper-style test: the box around the linearized P-ellipse of (y_c, θ).
    cth = np.cos(th0)
    tan = np.tan(th0)
    crossing = y0 - x0 * tan
    J = np.stack([-tan, np.ones(n), -x0 / (cth * cth)], axis=1)
    sig_c = np.sqrt(np.maximum(np.einsum("bi,bij,bj->b", J, cov, J), 0.0))
    with np.errstate(divide="ignore"):
        clearance = np.where(cth > 0.0, 0.5 * W - 0.5 * w / cth - np.abs(crossing), -np.inf)
        worst = np.abs(th0) + k * sig_th
        slack = np.where(
            worst < 0.5 * math.pi,
            0.5 * W
            - 0.5 * w / np.cos(np.minimum(worst, 0.5 * math.pi))
            - np.abs(crossing)
            - k * sig_c,
            -np.inf,
        )
    _overflowed("through_door", at, prob, error, slack)
    return DoorDecision(
        probability=_finish(prob, batch),
        error=_finish(error, batch),
        paper_test=_finish(slack >= 0.0, batch),
        crossing=_finish(crossing, batch),
        crossing_sigma=_finish(sig_c, batch),
        clearance=_finish(clearance, batch),
        slack=_finish(slack, batch),
        k=k,
        probability_level=p,
    )
