"""Polar (range-bearing) sensing: the observation model, its noise, and Appendix B's mappings.

**Range-bearing sensor** (lecture Eq. 20). A sensor mounted at pose ``mount = (x, y, θ)`` on the
robot observes a point landmark ``l = (lx, ly)`` (world frame) from robot pose ``p``:
``z = (r, φ)`` with r the distance from the sensor and φ the bearing from the sensor's x axis
(radians in [-π, π)). Its noise is ``R = diag(σr², σφ²)`` where σr and σφ are constant, grow
∝ r, or ∝ r² (``noise_model``). It sees the landmark when ``min_range ≤ r ≤ max_range`` and
``|φ| ≤ fov/2``.

**Appendix B.** A polar AT ``(r, φ, θ)`` — the position of a frame at range r and bearing φ,
its orientation θ — and its Cartesian AT ``(r cos φ, r sin φ, θ)``: the mean and covariance map
either way to first order (``C_xyθ = R C_rφθ Rᵀ`` with Appendix B's Jacobian R) or by the
unscented transform. Several polar sensings of one object are merged in the sensor's own
coordinates first and mapped once (§6.2 step 3) — :func:`merge_polar` — rather than mapped each
and merged in Cartesian coordinates.
"""

from __future__ import annotations

from typing import Literal, overload

import numpy as np

from relmap.errors import ParameterError, ShapeError
from relmap.lie import se2
from relmap.typing import ArrayLike, FloatArray
from relmap.uncertain import gaussian
from relmap.uncertain.at import AT
from relmap.uncertain.pose import check_result
from relmap.uncertain.propagate import SE2, Chart, propagate, unscented

__all__ = [
    "POLAR",
    "RangeBearingSensor",
    "cartesian_to_polar",
    "merge_polar",
    "polar_to_cartesian",
]

NoiseModel = Literal["constant", "proportional", "quadratic"]
Method = Literal["linear", "unscented"]


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


class RangeBearingSensor:
    """A range-bearing sensor on a robot (lecture Eq. 20); see the module docstring.

    ``sigma_range`` (m) and ``sigma_bearing`` (rad) are the noise at range 1 m for the
    proportional and quadratic models (σ = σ₁·r or σ₁·r²), and everywhere for the constant one.
    """

    __slots__ = (
        "fov",
        "max_range",
        "min_range",
        "mount",
        "noise_model",
        "sigma_bearing",
        "sigma_range",
    )

    def __init__(
        self,
        sigma_range: float,
        sigma_bearing: float,
        *,
        mount: ArrayLike = (0.0, 0.0, 0.0),
        fov: float = 2 * np.pi,
        max_range: float = np.inf,
        min_range: float = 0.0,
        noise_model: NoiseModel = "constant",
    ) -> None:
        for name, v in (("sigma_range", sigma_range), ("sigma_bearing", sigma_bearing)):
            if not np.isfinite(v) or v < 0:
                raise ParameterError(f"{name} must be non-negative; got {v}")
        if not 0 < fov <= 2 * np.pi:
            raise ParameterError(f"field of view must be in (0, 2π]; got {fov}")
        if not max_range > 0:
            raise ParameterError(f"max_range must be positive; got {max_range}")
        if not 0 <= min_range < max_range:
            raise ParameterError(f"min_range must be in [0, max_range); got {min_range}")
        if noise_model not in ("constant", "proportional", "quadratic"):
            raise ParameterError(
                f"noise_model must be constant, proportional or quadratic; got {noise_model!r}"
            )
        m = np.asarray(mount, dtype=np.float64)
        if m.shape != (3,):
            raise ShapeError(f"mount must be a pose (x, y, θ); got shape {m.shape}")
        values = {
            "sigma_range": float(sigma_range),
            "sigma_bearing": float(sigma_bearing),
            "mount": m,
            "fov": float(fov),
            "max_range": float(max_range),
            "min_range": float(min_range),
            "noise_model": noise_model,
        }
        for name, v in values.items():
            object.__setattr__(self, name, v)

    def __setattr__(self, name: str, value: object) -> None:
        raise AttributeError("RangeBearingSensor is immutable")

    @overload
    def predict(
        self, robot: ArrayLike, landmark: ArrayLike, *, jacobians: Literal[False] = ...
    ) -> FloatArray: ...
    @overload
    def predict(
        self, robot: ArrayLike, landmark: ArrayLike, *, jacobians: Literal[True]
    ) -> tuple[FloatArray, FloatArray, FloatArray]: ...
    def predict(
        self, robot: ArrayLike, landmark: ArrayLike, *, jacobians: bool = False
    ) -> FloatArray | tuple[FloatArray, FloatArray, FloatArray]:
        """The reading ``z = (r, φ)`` (..., 2) of ``landmark`` (..., 2) from robot pose (..., 3).

        With ``jacobians=True`` also ``H_robot = ∂z/∂p`` (..., 2, 3) — in relmap's chart of the
        robot pose — and ``H_landmark = ∂z/∂l`` (..., 2, 2) (lecture Eq. 24's H).
        """
        p = np.asarray(robot, dtype=np.float64)
        lm = np.asarray(landmark, dtype=np.float64)
        if lm.shape[-1:] != (2,):
            raise ShapeError(f"landmark must have shape (..., 2); got {lm.shape}")
        sensor, J_s_p, _ = se2.compose(p, self.mount, jacobians=True)
        dx, dy = lm[..., 0] - sensor[..., 0], lm[..., 1] - sensor[..., 1]
        q = dx * dx + dy * dy
        r = np.sqrt(q)
        z = np.stack(
            np.broadcast_arrays(r, se2.angle_difference(np.arctan2(dy, dx), sensor[..., 2])),
            axis=-1,
        )
        if not jacobians:
            return z
        if np.any(r == 0):
            raise ParameterError("a landmark at the sensor's own position has no bearing")
        # ∂z/∂(sensor pose) and ∂z/∂l, then the chain rule through the mount
        H_s = np.zeros((*z.shape[:-1], 2, 3))
        H_s[..., 0, 0], H_s[..., 0, 1] = -dx / r, -dy / r
        H_s[..., 1, 0], H_s[..., 1, 1], H_s[..., 1, 2] = dy / q, -dx / q, -1.0
        H_l = np.zeros((*z.shape[:-1], 2, 2))
        H_l[..., 0, 0], H_l[..., 0, 1] = dx / r, dy / r
        H_l[..., 1, 0], H_l[..., 1, 1] = -dy / q, dx / q
        return z, H_s @ J_s_p, H_l

    def noise(self, r: ArrayLike) -> FloatArray:
        """The reading's covariance ``R`` (..., 2, 2) at range r (m)."""
        r = np.asarray(r, dtype=np.float64)
        if (r <= 0).any():
            raise ParameterError(f"range must be positive; got {r.min()}")
        R = np.zeros((*r.shape, 2, 2))
        R[..., 0, 0], R[..., 1, 1] = self._variances(r)
        return R

    def _variances(self, r: FloatArray) -> tuple[FloatArray | float, FloatArray | float]:
        """``(σr², σφ²)``, the diagonal of :meth:`noise` at ranges r > 0 (unchecked): plain
        floats for the constant model, arrays shaped like r otherwise."""
        if self.noise_model == "constant":
            return self.sigma_range**2, self.sigma_bearing**2
        scale = r if self.noise_model == "proportional" else r * r
        return (self.sigma_range * scale) ** 2, (self.sigma_bearing * scale) ** 2

    def in_view(self, z: ArrayLike) -> np.ndarray:
        """Whether readings ``(r, φ)`` (..., 2) lie in the field of view and range."""
        z = np.asarray(z, dtype=np.float64)
        r, b = z[..., 0], se2.wrap_angle(z[..., 1])
        return (r >= self.min_range) & (r <= self.max_range) & (np.abs(b) <= self.fov / 2 + 1e-12)


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
    return m, gaussian.validate_covariance(cov, dim=3, name=f"{what} cov")


def polar_to_cartesian(mean: ArrayLike, cov: ArrayLike, method: Method = "linear") -> AT:
    """The Cartesian AT of a polar ``(r, φ, θ)`` mean and covariance (Appendix B).

    ``"linear"``: ``C = R C_polar Rᵀ`` with R the Jacobian at the mean (Appendix B);
    ``"unscented"``: the unscented transform (:func:`relmap.uncertain.propagate.unscented`).
    """
    m, C = _triples(mean, cov, "polar")
    if (m[..., 0] < 0).any():
        raise ParameterError("range must be non-negative")
    if method == "linear":
        out = propagate(
            _to_cartesian, m, C, jacobian=_to_cartesian_jacobian, chart_in=POLAR, chart_out=SE2
        )
    elif method == "unscented":
        out = unscented(_to_cartesian, m, C, chart_in=POLAR, chart_out=SE2)
    else:
        raise ParameterError(f"method must be 'linear' or 'unscented'; got {method!r}")
    check_result("polar_to_cartesian", out.mean, out.cov)
    return AT._trusted(out.mean, out.cov)


def cartesian_to_polar(at: AT, method: Method = "linear") -> tuple[FloatArray, FloatArray]:
    """The polar ``(r, φ, θ)`` mean and covariance of a Cartesian AT (inverse of the above)."""
    if (np.hypot(at.mean[..., 0], at.mean[..., 1]) == 0).any():
        raise ParameterError("the bearing of a frame at the origin is undefined")
    if method == "linear":
        out = propagate(_to_polar, at.mean, at.cov, chart_in=SE2, chart_out=POLAR)
    elif method == "unscented":
        out = unscented(_to_polar, at.mean, at.cov, chart_in=SE2, chart_out=POLAR)
    else:
        raise ParameterError(f"method must be 'linear' or 'unscented'; got {method!r}")
    return out.mean, out.cov


def merge_polar(
    means: ArrayLike, covs: ArrayLike, *, method: Method = "linear"
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
