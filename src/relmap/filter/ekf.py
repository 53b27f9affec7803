"""The extended Kalman filter in the textbook's letters (lecture Eqs. 13-28): predict and update.

The belief is a mean ``x`` ``(..., n)`` and a covariance ``P`` ``(..., n, n)`` in the chart of the
state — a pose :class:`relmap.AT` (relmap's chart: ``(x, y, θ)``, heading wrapped) or a
:class:`Belief` of any size with its chart. Leading axes are a batch of filters: one filter and a
thousand go through the same lines.

- :func:`predict` (Eq. 13): ``x⁻ = f(x, u)``, ``P⁻ = F P Fᵀ + G Q Gᵀ`` with any
  :class:`relmap.models.Motion` (``F = ∂f/∂x``, ``G = ∂f/∂w`` for its noise ``w ~ N(0, Q)``).
- :func:`update` (Eqs. 26-28): m independent readings' innovations ``y`` ``(..., m, d)`` with
  ``H`` ``(..., m, d, n)`` and noises ``R`` ``(..., m, d, d)`` in one stacked update:
  ``S = H P Hᵀ + R``, ``K = P Hᵀ S⁻¹``, ``x = x ⊞ K y``, ``P = (I - KH) P (I - KH)ᵀ + K R Kᵀ``.
- :func:`correct`: a reading ``z`` of any :class:`relmap.models.Measurement` (of the state, or
  of a known landmark): ``y = z ⊖ h(x)``, then :func:`update`; :func:`correct_pose`: a
  full-pose reading, the paper's merge, behind a χ² gate.

The association of readings with landmarks, gating and the runs over whole logs build on these
(:mod:`relmap.filter.landmarks`, :mod:`relmap.filter.logs`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from relmap.errors import ParameterError, ShapeError
from relmap.models.base import Measurement, Motion
from relmap.models.pose import FullPose
from relmap.typing import ArrayLike, FloatArray
from relmap.uncertain.at import AT
from relmap.uncertain.gaussian import confidence_k2, inverse_pd
from relmap.uncertain.propagate import EUCLIDEAN, SE2, Chart

__all__ = [
    "Belief",
    "Correction",
    "PoseUpdate",
    "State",
    "correct",
    "correct_pose",
    "innovations_given",
    "predict",
    "update",
]


class Belief(NamedTuple):
    """A Gaussian belief of any size: mean ``x`` (..., n), covariance ``P`` (..., n, n), in
    ``chart`` (how a correction moves x: ``chart.plus(x, δ)``)."""

    x: FloatArray
    P: FloatArray
    chart: Chart = EUCLIDEAN


State = AT | Belief


def _arrays(state: State) -> tuple[FloatArray, FloatArray, Chart]:
    if isinstance(state, AT):
        return state.mean, state.cov, SE2
    x, P = np.asarray(state.x, dtype=np.float64), np.asarray(state.P, dtype=np.float64)
    if x.ndim < 1 or P.shape[-2:] != (x.shape[-1], x.shape[-1]):
        raise ShapeError(f"a belief needs x (..., n) and P (..., n, n); got {x.shape}, {P.shape}")
    return x, P, state.chart


def _like(state: State, x: FloatArray, P: FloatArray) -> State:
    return AT._trusted(x, P) if isinstance(state, AT) else Belief(x, P, state.chart)


def _T(a: FloatArray) -> FloatArray:
    return np.swapaxes(a, -1, -2)


def predict(state: State, u: ArrayLike, motion: Motion) -> State:
    """The prediction (lecture Eq. 13) of ``state`` by the input ``u`` (..., k) of ``motion``."""
    x, P, _ = _arrays(state)
    u = np.asarray(u, dtype=np.float64)
    F, G = motion.jacobians(x, u)
    Q = G @ motion.input_noise(u) @ _T(G)
    P = F @ P @ _T(F) + Q
    return _like(state, motion.f(x, u), 0.5 * (P + _T(P)))


def update(
    P: FloatArray, y: FloatArray, H: FloatArray, R: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """The stacked update (Eqs. 26-28) of m independent readings: ``(δ, P⁺, nis, logdet)``.

    ``P`` (..., n, n); ``y`` (..., m, d), ``H`` (..., m, d, n), ``R`` (..., m, d, d) positive
    definite. Returns the correction ``δ = K y`` (..., n) of the mean (the caller moves x by it in
    the state's chart), the covariance ``P⁺`` (..., n, n), and the stacked innovation's
    ``yᵀ S⁻¹ y`` and ``log det S`` (...), for ``S = H P Hᵀ + R`` and ``K = P Hᵀ S⁻¹``.
    """
    n = P.shape[-1]
    I = np.eye(n)
    Ri = inverse_pd(R)
    HtRi = _T(H) @ Ri  # (..., m, n, d)
    A = (HtRi @ H).sum(axis=-3)  # Hᵀ R⁻¹ H, the readings' information about the state
    b = (HtRi @ y[..., None]).sum(axis=-3)  # Hᵀ R⁻¹ y, (..., n, 1)
    # The readings are independent (R block diagonal), so the gain is taken through the
    # push-through identity Hᵀ S⁻¹ = (I + Hᵀ R⁻¹ H P)⁻¹ Hᵀ R⁻¹: K = P Hᵀ S⁻¹ = P⁺ Hᵀ R⁻¹ with
    # P⁺ = P (I + A P)⁻¹, inverting R's d×d blocks and one n×n matrix, never the (md)×(md) S
    # (nor P: a singular P is fine).
    Pp = _T(np.linalg.solve(_T(I + A @ P), P))
    delta = Pp @ b
    # Joseph form P = (I - KH) P (I - KH)ᵀ + K R Kᵀ (here KH = P⁺ A and K R Kᵀ = P⁺ A P⁺) rather
    # than Eq. 28's P - K S Kᵀ: a sum of two congruences, so P stays symmetric positive
    # semi-definite under rounding, even after a reading far more precise than the prior.
    I_KH = I - Pp @ A
    P_new = I_KH @ P @ _T(I_KH) + Pp @ A @ _T(Pp)
    # yᵀ S⁻¹ y = yᵀ R⁻¹ y - bᵀ P⁺ b (Woodbury) and det S = det R det(I + A P) (Sylvester)
    nis = (y[..., None, :] @ Ri @ y[..., :, None]).sum(axis=(-3, -2, -1)) - (_T(b) @ delta)[
        ..., 0, 0
    ]
    logdet = np.linalg.slogdet(R)[1].sum(axis=-1) + np.linalg.slogdet(I + A @ P)[1]
    return delta[..., 0], 0.5 * (P_new + _T(P_new)), nis, logdet


def innovations_given(
    P: FloatArray, y: FloatArray, H: FloatArray, R: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Each reading's innovation and its covariance given the readings before it in the
    stacked update: ``(y_given, S_given, δ, P⁺)``, shapes (..., m, d), (..., m, d, d), and the
    correction and covariance given all m (:func:`update`'s, with these R).

    Reading i, given the readings j < i: ``y_i - H_i δ_(i)`` and ``H_i P_(i) H_iᵀ + R_i`` where
    ``P_(i) = P (I + A_(i) P)⁻¹`` and ``δ_(i) = P_(i) b_(i)`` are the update with the information
    ``A_(i) = Σ_{j<i} H_jᵀ R_j⁻¹ H_j``, ``b_(i) = Σ_{j<i} H_jᵀ R_j⁻¹ y_j`` of those before it: the
    prediction-error decomposition (Schweppe 1965), whose Gaussian densities multiply to the
    stacked innovation's (Σ of their NIS and log det is the stacked yᵀS⁻¹y and log det S).
    """
    n, m = P.shape[-1], y.shape[-2]
    HtRi = _T(H) @ inverse_pd(R)
    lead = HtRi.shape[:-3]
    info = np.concatenate([np.zeros((*lead, 1, n, n)), HtRi @ H], axis=-3)
    vec = np.concatenate([np.zeros((*lead, 1, n, 1)), HtRi @ y[..., None]], axis=-3)
    A, b = np.cumsum(info, axis=-3), np.cumsum(vec, axis=-3)  # (..., m + 1, ...): before each
    P_b = P[..., None, :, :]
    P_i = _T(np.linalg.solve(_T(np.eye(n) + A @ P_b), P_b))
    delta = P_i @ b
    y_given = y - (H @ delta[..., :m, :, :])[..., 0]
    S_given = H @ P_i[..., :m, :, :] @ _T(H) + R
    return y_given, 0.5 * (S_given + _T(S_given)), delta[..., m, :, 0], P_i[..., m, :, :]


class Correction(NamedTuple):
    """The corrected state and the reading's innovation statistics (leading axes: the batch)."""

    state: State
    y: FloatArray  #: (..., d) the innovation z ⊖ h(x⁻)
    S: FloatArray  #: (..., d, d) its covariance H P⁻ Hᵀ + R
    nis: FloatArray  #: (...) yᵀ S⁻¹ y


def correct(
    state: State,
    z: ArrayLike,
    model: Measurement,
    landmark: ArrayLike | None = None,
    *,
    R: ArrayLike | None = None,
) -> Correction:
    """The correction (Eqs. 26-28, Joseph form) with a reading ``z`` (..., d) of ``model``, of
    the state or of a known ``landmark`` (..., p); ``R`` the reading's noise (default: the
    model's at the predicted reading)."""
    x, P, chart = _arrays(state)
    zz = np.asarray(z, dtype=np.float64)
    if zz.shape[-1:] != (model.dim,):
        raise ShapeError(f"the reading must have shape (..., {model.dim}); got {zz.shape}")
    h, H, _ = model.linearize(x, None if landmark is None else np.asarray(landmark, float))
    y = model.innovation(zz, h)
    R = model.noise(h) if R is None else np.asarray(R, dtype=np.float64)
    if not (np.isfinite(y).all() and np.isfinite(H).all() and np.isfinite(R).all()):
        raise ParameterError("the innovation, H and R must be finite (a landmark at the sensor?)")
    S = H @ P @ _T(H) + R
    delta, P_new, nis, _ = update(P, y[..., None, :], H[..., None, :, :], R[..., None, :, :])
    return Correction(_like(state, chart.plus(x, delta), P_new), y, S, nis)


class PoseUpdate(NamedTuple):
    """The corrected state and the gate's verdict on a full-pose reading."""

    state: AT
    mahalanobis2: FloatArray  #: (...) d² of the innovation under P⁻ + R
    accepted: np.ndarray  #: (...) whether the reading was used


def correct_pose(state: AT, reading: AT, *, gate: float | None = 0.999) -> PoseUpdate:
    """Correct with a full-pose reading (GPS + compass; lecture Eqs. 14-19): ``h(x) = x``,
    ``H = I``, ``R`` the reading's covariance — the paper's merge of §4 as a correction
    (:class:`relmap.models.FullPose`). The innovation (heading wrapped) is gated at the χ²₃
    quantile ``gate`` (None: no gate); a gated-out reading leaves the state as it was."""
    c = correct(state, reading.mean, FullPose(reading.cov))
    ok = np.ones(c.nis.shape, bool) if gate is None else c.nis <= confidence_k2(gate, 3)
    mean = np.where(ok[..., None], c.state.mean, state.mean)
    cov = np.where(ok[..., None, None], c.state.cov, state.cov)
    return PoseUpdate(AT._trusted(mean, cov), c.nis, ok)
