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
    "predict",
    "update",
    "Update",
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


class Update(NamedTuple):
    """What :func:`update` gives (leading axes: the batch)."""

    delta: FloatArray  #: (..., n) the mean's correction ``K y``
    P: FloatArray  #: (..., n, n) the corrected covariance (Joseph form)
    nis: FloatArray  #: (...) the stacked innovation's ``yᵀ S⁻¹ y``
    logdet: FloatArray  #: (...) its ``log det S``
    #: (..., m, d), (..., m, d, d): each reading's innovation and its covariance given the
    #: readings before it (``given=True``; else empty)
    y_given: FloatArray
    S_given: FloatArray


def update(
    P: FloatArray,
    y: FloatArray,
    H: FloatArray,
    R: FloatArray,
    used: np.ndarray | None = None,
    *,
    given: bool = False,
) -> Update:
    """The stacked update (Eqs. 26-28) of m independent readings.

    ``P`` (..., n, n); innovations ``y`` (..., m, d), ``H`` (..., m, d, n), noises ``R``
    (..., m, d, d) positive definite; ``used`` (..., m): the readings in the update (default
    all; the others carry no information). ``S = H P Hᵀ + R`` and ``K = P Hᵀ S⁻¹``; the caller
    moves the mean by ``delta`` in the state's chart. ``given``: also each reading's innovation
    and covariance given the used ones before it, ``y_i - H_i δ_(i)`` and ``H_i P_(i) H_iᵀ + R_i``
    with ``δ_(i)``, ``P_(i)`` the update by those (the prediction-error decomposition, Schweppe
    1965: their Gaussian densities multiply to the stacked innovation's).
    """
    n, m = P.shape[-1], y.shape[-2]
    I = np.eye(n)
    if used is not None:  # (an unused reading's numbers may be anything, NaN too)
        y, H = np.where(used[..., None], y, 0.0), np.where(used[..., None, None], H, 0.0)
        R = np.where(used[..., None, None], R, I[:1, :1] if R.shape[-1] == 1 else np.eye(R.shape[-1]))
    Ri = inverse_pd(R)
    if used is not None:
        Ri = np.where(used[..., None, None], Ri, 0.0)
    HtRi = _T(H) @ Ri  # (..., m, n, d)
    info, vec = HtRi @ H, HtRi @ y[..., None]  # each reading's Hᵀ R⁻¹ H and Hᵀ R⁻¹ y
    A, b = info.sum(axis=-3), vec.sum(axis=-3)  # the readings' information about the state
    # The readings are independent (R block diagonal), so the gain is taken through the
    # push-through identity Hᵀ S⁻¹ = (I + Hᵀ R⁻¹ H P)⁻¹ Hᵀ R⁻¹: K = P Hᵀ S⁻¹ = P⁺ Hᵀ R⁻¹ with
    # P⁺ = P (I + A P)⁻¹ (A = Hᵀ R⁻¹ H), inverting R's d×d blocks and one n×n matrix, never the
    # (md)×(md) S (nor P: a singular P is fine).
    I_AP = I + A @ P
    Pp = _T(np.linalg.solve(_T(I_AP), P))
    delta = Pp @ b
    # Joseph form P = (I - KH) P (I - KH)ᵀ + K R Kᵀ (here KH = P⁺ A and K R Kᵀ = P⁺ A P⁺) rather
    # than Eq. 28's P - K S Kᵀ: a sum of two congruences, so P stays symmetric positive
    # semi-definite under rounding, even after a reading far more precise than the prior.
    I_KH = I - Pp @ A
    P_new = I_KH @ P @ _T(I_KH) + Pp @ A @ _T(Pp)
    # yᵀ S⁻¹ y = yᵀ R⁻¹ y - bᵀ P⁺ b (Woodbury) and det S = det R det(I + A P) (Sylvester)
    nis = (y[..., None, :] @ Ri @ y[..., :, None]).sum(axis=(-3, -2, -1)) - (_T(b) @ delta)[..., 0, 0]
    logdet = np.linalg.slogdet(R)[1].sum(axis=-1) + np.linalg.slogdet(I_AP)[1]
    y_given = S_given = np.empty(0)
    if given:  # each reading given those before it: the update by their information A_(i)
        P_b = P[..., None, :, :]
        if m > 1:
            zero = np.zeros((*info.shape[:-3], 1, n, n))
            A_i = np.concatenate([zero, np.cumsum(info[..., :-1, :, :], axis=-3)], axis=-3)
            b_i = np.concatenate([zero[..., :1], np.cumsum(vec[..., :-1, :, :], axis=-3)], axis=-3)
            P_b = _T(np.linalg.solve(_T(I + A_i @ P_b), P_b))
            y = y - (H @ (P_b @ b_i))[..., 0]
        S_given = H @ P_b @ _T(H) + R
        y_given, S_given = y, 0.5 * (S_given + _T(S_given))
    return Update(delta[..., 0], 0.5 * (P_new + _T(P_new)), nis, logdet, y_given, S_given)


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
    up = update(P, y[..., None, :], H[..., None, :, :], R[..., None, :, :])
    return Correction(_like(state, chart.plus(x, up.delta), up.P), y, S, up.nis)


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
