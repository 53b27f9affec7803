"""Polar sensing of point landmarks — range-bearing, range only, bearing only — and Appendix B.

**Range-bearing** (lecture Eq. 20). A sensor mounted at pose ``mount = (x, y, θ)`` on the robot
reads a point landmark ``l = (lx, ly)`` (world frame) from robot pose ``p``: ``z = (r, φ)``, r the
distance from the sensor and φ the bearing from the sensor's x axis (radians in [-π, π)). Its
noise is ``R = diag(σr², σφ²)``, σr and σφ constant, ∝ r or ∝ r² (``noise_model``); it sees the
landmark when ``min_range ≤ r ≤ max_range`` and ``|φ| ≤ fov/2``. :class:`RangeOnly` reads the
first row (radio beacons), :class:`BearingOnly` the second (a camera without depth). The three
are :class:`relmap.models.base.Measurement` models of one geometry, with analytic Jacobians.

**Appendix B.** A polar AT ``(r, φ, θ)`` — the position of a frame at range r and bearing φ,
its orientation θ — and its Cartesian AT ``(r cos φ, r sin φ, θ)``: the mean and covariance map
either way to first order (``C_xyθ = R C_rφθ Rᵀ`` with Appendix B's Jacobian R) or by the
unscented transform. Several polar sensings of one object are merged in the sensor's own
coordinates first and mapped once (§6.2 step 3) — :func:`merge_polar` — rather than mapped each
and merged in Cartesian coordinates.
"""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import numpy as np

from relmap.errors import ParameterError, ShapeError
from relmap.lie import se2
from relmap.models.base import Measurement, positive
from relmap.typing import ArrayLike, FloatArray, Option
from relmap.uncertain import gaussian
from relmap.uncertain.at import AT
from relmap.uncertain.pose import check_result
from relmap.uncertain.propagate import SE2, Chart, propagate, unscented

__all__ = [
    "POLAR",
    "BearingOnly",
    "Method",
    "NoiseModel",
    "RangeBearingSensor",
    "RangeOnly",
    "cartesian_to_polar",
    "merge_polar",
    "polar_to_cartesian",
]


class NoiseModel(Option):
    """How a polar sensor's σ grows with the range r (σ₁: the σ at 1 m)."""

    CONSTANT = "constant"  #: σ
    PROPORTIONAL = "proportional"  #: σ₁ r
    QUADRATIC = "quadratic"  #: σ₁ r²


class Method(Option):
    """How Appendix B maps a mean and covariance between polar and Cartesian coordinates."""

    LINEAR = "linear"  #: first order, ``R C Rᵀ``
    UNSCENTED = "unscented"  #: the unscented transform


def _polar_plus(x: FloatArray, d: FloatArray) -> FloatArray:
    out = np.asarray(x, dtype=np.float64) + d
    out[..., 1:] = se2.wrap_angle(out[..., 1:])
    return out


def _polar_minus(a: FloatArray, b: FloatArray) -> FloatArray:
    out = np.asarray(a, dtype=np.float64) - b
    out[..., 1:] = se2.wrap_angle(out[..., 1:])
    return out


#: The chart of polar triples ``(r, φ, θ)``: both angles wrapped.
POLAR = Chart(_polar_plus, _polar_minus)


@dataclasses.dataclass(frozen=True, kw_only=True)
class _Polar(Measurement):
    """The geometry the three polar sensors share: the mount, the field of view, the noise's
    growth with range. ``rows`` picks the reading's components of ``(r, φ)``."""

    mount: ArrayLike = (0.0, 0.0, 0.0)
    fov: float = 2 * np.pi
    max_range: float = np.inf
    min_range: float = 0.0
    noise_model: NoiseModel | str = NoiseModel.CONSTANT
    landmark_dim: ClassVar[int] = 2
    rows: ClassVar[slice] = slice(0, 2)

    def __post_init__(self) -> None:
        if not 0 < self.fov <= 2 * np.pi:
            raise ParameterError(f"field of view must be in (0, 2π]; got {self.fov}")
        if not self.max_range > 0:
            raise ParameterError(f"max_range must be positive; got {self.max_range}")
        if not 0 <= self.min_range < self.max_range:
            raise ParameterError(f"min_range must be in [0, max_range); got {self.min_range}")
        m = np.array(self.mount, dtype=np.float64)
        if m.shape != (3,):
            raise ShapeError(f"mount must be a pose (x, y, θ); got shape {m.shape}")
        m.flags.writeable = False
        object.__setattr__(self, "mount", m)
        object.__setattr__(self, "noise_model", NoiseModel.parse(self.noise_model, "noise_model"))
        for name in self.noise_parameters:
            object.__setattr__(self, name, positive(getattr(self, name), name))

    def _geometry(self, x: FloatArray, landmark: ArrayLike) -> tuple[FloatArray, ...]:
        """``(dx, dy, q, z, ox, oy)``: the landmark relative to the sensor (world axes), its
        squared range, the reading ``(r, φ)`` and the mount's offset in world axes."""
        p = np.asarray(x, dtype=np.float64)
        lm = np.asarray(landmark, dtype=np.float64)
        if lm.shape[-1:] != (2,):
            raise ShapeError(f"landmark must have shape (..., 2); got {lm.shape}")
        c, s = np.cos(p[..., 2]), np.sin(p[..., 2])
        mx, my, mt = self.mount.tolist()
        ox, oy = c * mx - s * my, s * mx + c * my
        dx, dy = lm[..., 0] - (p[..., 0] + ox), lm[..., 1] - (p[..., 1] + oy)
        q = dx * dx + dy * dy
        z = np.empty((*q.shape, 2))
        z[..., 0] = np.sqrt(q)
        z[..., 1] = se2.angle_difference(np.arctan2(dy, dx), p[..., 2] + mt)
        return dx, dy, q, z, ox, oy

    def h(self, x: FloatArray, landmark: FloatArray | None = None) -> FloatArray:
        """The reading of ``landmark`` (..., 2) from robot pose ``x`` (..., 3)."""
        return self._geometry(x, landmark)[3][..., self.rows]

    def linearize(
        self, x: FloatArray, landmark: FloatArray | None = None
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """The reading, ``H = ∂z/∂x`` (..., d, 3) in relmap's chart of the robot pose (through
        the mount: the sensor sits at ``p ⊕ mount``) and ``∂z/∂l`` (..., d, 2) (lecture Eq. 24's
        H); a landmark at the sensor gives NaN (no bearing)."""
        dx, dy, q, z, ox, oy = self._geometry(x, landmark)
        H = np.empty((*q.shape, 2, 3))
        with np.errstate(divide="ignore", invalid="ignore"):
            u, w = dx / z[..., 0], dy / z[..., 0]  # the unit vector to the landmark
            H[..., 0, 0], H[..., 0, 1], H[..., 0, 2] = -u, -w, u * oy - w * ox
            u, w = dx / q, dy / q
            # ∂z/∂p = -∂z/∂l on the position; the heading turns the mount's offset (-oy, ox)
            # and, for the bearing, the sensor's axis
            H[..., 1, 0], H[..., 1, 1], H[..., 1, 2] = w, -u, -(w * oy + u * ox) - 1.0
        rows = self.rows
        return z[..., rows], H[..., rows, :], -H[..., rows, :2]

    def jacobians(
        self, x: FloatArray, landmark: FloatArray | None = None
    ) -> tuple[FloatArray, FloatArray | None]:
        return self.linearize(x, landmark)[1:]

    def _scale(self, r: FloatArray) -> FloatArray | float:
        if self.noise_model is NoiseModel.CONSTANT:
            return 1.0
        return r if self.noise_model is NoiseModel.PROPORTIONAL else r * r

    def usable(self, z: FloatArray) -> np.ndarray:
        """Finite readings, with a positive range where they have one."""
        ok = np.isfinite(z).all(axis=-1)
        if self.rows.start == 0:
            with np.errstate(invalid="ignore"):
                ok &= z[..., 0] > 0
        return ok

    def in_view(self, z: ArrayLike) -> np.ndarray:
        """Whether range-bearing readings ``(r, φ)`` (..., 2) lie in the field of view and
        range."""
        z = np.asarray(z, dtype=np.float64)
        r, b = z[..., 0], se2.wrap_angle(z[..., 1])
        return (r >= self.min_range) & (r <= self.max_range) & (np.abs(b) <= self.fov / 2 + 1e-12)


@dataclasses.dataclass(frozen=True)
class RangeBearingSensor(_Polar):
    """A range-bearing sensor on a robot (lecture Eq. 20; module docstring).

    ``sigma_range`` (m) and ``sigma_bearing`` (rad) are the noise at range 1 m for the
    proportional and quadratic models (σ = σ₁·r or σ₁·r²), and everywhere for the constant one.
    """

    sigma_range: float | FloatArray = 0.0
    sigma_bearing: float | FloatArray = 0.0
    noise_parameters: ClassVar[tuple[str, ...]] = ("sigma_range", "sigma_bearing")
    dim: ClassVar[int] = 2
    angles: ClassVar[tuple[int, ...]] = (1,)
    ranges: ClassVar[tuple[int, ...]] = (0,)

    def noise(self, z: FloatArray) -> FloatArray:
        """``R = diag(σr², σφ²)`` (..., 2, 2) at readings ``z`` (..., 2) (their ranges)."""
        z = np.asarray(z, dtype=np.float64)
        k = self._scale(z[..., 0])
        vr, vb = (self.sigma_range * k) ** 2, (self.sigma_bearing * k) ** 2
        R = np.zeros((*np.broadcast_shapes(np.shape(vr), np.shape(vb), z.shape[:-1]), 2, 2))
        R[..., 0, 0], R[..., 1, 1] = vr, vb
        return R


@dataclasses.dataclass(frozen=True)
class RangeOnly(_Polar):
    """A range sensor (radio beacons): Eq. 20's first row, ``z = (r,)``, σ ``sigma_range``."""

    sigma_range: float | FloatArray = 0.0
    noise_parameters: ClassVar[tuple[str, ...]] = ("sigma_range",)
    dim: ClassVar[int] = 1
    ranges: ClassVar[tuple[int, ...]] = (0,)
    rows: ClassVar[slice] = slice(0, 1)

    def noise(self, z: FloatArray) -> FloatArray:
        """``R = (σr²,)`` (..., 1, 1) at readings ``z`` (..., 1)."""
        k = self._scale(np.asarray(z, dtype=np.float64)[..., 0])
        return ((self.sigma_range * k) ** 2 + np.zeros(np.shape(z)[:-1]))[..., None, None]


@dataclasses.dataclass(frozen=True)
class BearingOnly(_Polar):
    """A bearing sensor (a camera without depth): Eq. 20's second row, ``z = (φ,)``, σ
    ``sigma_bearing`` (constant: a bearing-only sensor knows no range to scale it by)."""

    sigma_bearing: float | FloatArray = 0.0
    noise_parameters: ClassVar[tuple[str, ...]] = ("sigma_bearing",)
    dim: ClassVar[int] = 1
    angles: ClassVar[tuple[int, ...]] = (0,)
    rows: ClassVar[slice] = slice(1, 2)

    def noise(self, z: FloatArray) -> FloatArray:
        """``R = (σφ²,)`` (..., 1, 1)."""
        return (self.sigma_bearing**2 + np.zeros(np.shape(z)[:-1]))[..., None, None]


# ------------------------------------------------------------------- Appendix B
def _to_cartesian(x: FloatArray) -> FloatArray:
    r, phi, th = x[..., 0], x[..., 1], x[..., 2]
    return np.stack([r * np.cos(phi), r * np.sin(phi), se2.wrap_angle(th)], axis=-1)


def _to_cartesian_jacobian(x: FloatArray) -> FloatArray:
    """Appendix B's R: [[x/r, -y, 0], [y/r, x, 0], [0, 0, 1]] at the mean."""
    r, phi = x[..., 0], x[..., 1]
    c, s = np.cos(phi), np.sin(phi)
    J = np.zeros((*x.shape[:-1], 3, 3))
    J[..., 0, 0], J[..., 0, 1] = c, -r * s
    J[..., 1, 0], J[..., 1, 1] = s, r * c
    J[..., 2, 2] = 1.0
    return J


def _to_polar(x: FloatArray) -> FloatArray:
    return np.stack(
        [np.hypot(x[..., 0], x[..., 1]), np.arctan2(x[..., 1], x[..., 0]), x[..., 2]], axis=-1
    )


def _triples(mean: ArrayLike, cov: ArrayLike, what: str) -> tuple[FloatArray, FloatArray]:
    m = gaussian.real_array(mean, f"{what} mean")
    if m.ndim == 0 or m.shape[-1] != 3:
        raise ShapeError(f"{what} mean must have shape (..., 3); got {m.shape}")
    gaussian.check_finite(m, f"{what} mean")
    C = gaussian.validate_covariance(cov, dim=3, name=f"{what} cov")
    gaussian.broadcast(f"{what} mean and cov batch", m.shape[:-1], C.shape[:-2])
    return m, C


def polar_to_cartesian(mean: ArrayLike, cov: ArrayLike, method: Method | str = "linear") -> AT:
    """The Cartesian AT of a polar ``(r, φ, θ)`` mean and covariance (Appendix B).

    ``"linear"``: ``C = R C_polar Rᵀ`` with R the Jacobian at the mean (Appendix B);
    ``"unscented"``: the unscented transform (:func:`relmap.uncertain.propagate.unscented`).
    """
    m, C = _triples(mean, cov, "polar")
    if (m[..., 0] < 0).any():
        raise ParameterError("range must be non-negative")
    if Method.parse(method, "method") is Method.LINEAR:
        out = propagate(
            _to_cartesian, m, C, jacobian=_to_cartesian_jacobian, chart_in=POLAR, chart_out=SE2
        )
    else:
        out = unscented(_to_cartesian, m, C, chart_in=POLAR, chart_out=SE2)
    check_result("polar_to_cartesian", out.mean, out.cov)
    return AT._trusted(out.mean, out.cov)


def cartesian_to_polar(at: AT, method: Method | str = "linear") -> tuple[FloatArray, FloatArray]:
    """The polar ``(r, φ, θ)`` mean and covariance of a Cartesian AT (inverse of the above)."""
    if (np.hypot(at.mean[..., 0], at.mean[..., 1]) == 0).any():
        raise ParameterError("the bearing of a frame at the origin is undefined")
    if Method.parse(method, "method") is Method.LINEAR:
        out = propagate(_to_polar, at.mean, at.cov, chart_in=SE2, chart_out=POLAR)
    else:
        out = unscented(_to_polar, at.mean, at.cov, chart_in=SE2, chart_out=POLAR)
    return out.mean, out.cov


def merge_polar(
    means: ArrayLike, covs: ArrayLike, *, method: Method | str = "linear"
) -> tuple[AT, tuple[FloatArray, FloatArray]]:
    """Merge k polar sensings ``(r, φ, θ)`` (k, ..., 3) of one object in polar coordinates, then
    map the merged estimate to a Cartesian AT once (§6.2 step 3).

    Returns ``(cartesian AT, (polar mean, polar cov))``. In polar coordinates each sensing is
    linear in the object's polar state, so the merge there is the exact linear estimate; the
    nonlinearity enters only once, in the final mapping.
    """
    m = np.asarray(means, dtype=np.float64)
    C = np.asarray(covs, dtype=np.float64)
    if m.ndim < 2 or m.shape[-1] != 3 or C.shape[:-1] != m.shape:
        raise ShapeError(
            f"means must be (k, ..., 3) and covs (k, ..., 3, 3); got {m.shape}, {C.shape}"
        )
    mean, cov = m[0], gaussian.validate_covariance(C[0], dim=3, name="polar cov")
    for i in range(1, len(m)):
        mean, cov = gaussian.fuse(
            mean,
            cov,
            m[i],
            gaussian.validate_covariance(C[i], dim=3, name="polar cov"),
            minus=POLAR.minus,
            plus=POLAR.plus,
            what=f"polar sensing #{i} into the preceding ones",
            components="(r, φ, θ)",
        )
    return polar_to_cartesian(mean, cov, method), (mean, cov)
