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
from relmap.uncertain.gaussian import confidence_k2, inverse_pd, not_positive_definite
from relmap.uncertain.propagate import EUCLIDEAN, SE2, Chart

__all__ = [
    "Belief",
    "Correction",
    "PoseUpdate",
    "State",
    "Update",
    "correct",
    "correct_pose",
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
    return a.swapaxes(-1, -2)


def predict(state: State, u: ArrayLike, motion: Motion) -> State:
    """The prediction (lecture Eq. 13) of ``state`` by the input ``u`` (..., k) of ``motion``."""
    x, P, _ = _arrays(state)
    x_new, F, G, Qu = motion.linearize(x, np.asarray(u, dtype=np.float64))
    P = F @ P @ _T(F) + G @ Qu @ _T(G)
    return _like(state, x_new, 0.5 * (P + _T(P)))


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
    all; the others carry no information). The caller moves the mean by ``delta`` in the
    state's chart. ``given``: also each reading's innovation and covariance given the used ones
    before it (the prediction-error decomposition, Schweppe 1965: their Gaussian densities
    multiply to the stacked innovation's).
    """
    n, (m, d) = P.shape[-1], y.shape[-2:]
    masked = used is not None and not used.all()
    if masked:  # an unused reading: y = 0, H = 0, R = I (its numbers may be NaN)
        y = np.where(used[..., None], y, 0.0)
        H = np.where(used[..., None, None], H, 0.0)
        R = np.where(used[..., None, None], R, np.eye(d))
    Ri = inverse_pd(R)
    # The readings are independent (R block diagonal), so the gain K = P Hᵀ S⁻¹ with
    # S = H P Hᵀ + R is taken as K = P⁺ Hᵀ R⁻¹, P⁺ = (I + P A)⁻¹ P, from the readings'
    # information A = Hᵀ R⁻¹ H: R inverted block by block and one n×n matrix solved, never
    # the (md)×(md) S (nor P: a singular P is fine). The readings as rows: (..., md, ·).
    Hs, ys = _rows(H), _rows(y[..., None])
    RiH, Riy = _rows(Ri @ H), _rows(Ri @ y[..., None])
    A, b = _T(Hs) @ RiH, _T(Hs) @ Riy  # Hᵀ R⁻¹ H and Hᵀ R⁻¹ y
    I_PA = np.eye(n) + P @ A
    Pp = np.linalg.solve(I_PA, P)
    delta = Pp @ b  # K y
    # Joseph form P = (I - KH) P (I - KH)ᵀ + K R Kᵀ (KH = P⁺ A, K R Kᵀ = P⁺ A P⁺) rather than
    # Eq. 28's P - K S Kᵀ: a sum of two congruences, so P stays symmetric positive
    # semi-definite under rounding, even after a reading far more precise than the prior.
    I_KH = np.eye(n) - Pp @ A
    P_new = I_KH @ P @ _T(I_KH) + Pp @ A @ Pp
    # yᵀ S⁻¹ y = yᵀ R⁻¹ (y - H K y) (Woodbury), det S = det R det(I + P A) (Sylvester)
    nis = (_T(ys) @ Riy - _T(b) @ delta)[..., 0, 0]
    logdet = np.linalg.slogdet(R)[1].sum(axis=-1) + np.linalg.slogdet(I_PA)[1]
    y_given = S_given = np.empty(0)
    if given:  # each reading given the ones before it: the update by their information
        P_i, y_given = P[..., None, :, :], y
        if m > 1:
            each = _T(H) @ Ri  # (..., m, n, d): Hᵢᵀ R⁻¹ᵢ
            zero = np.zeros((*A.shape[:-2], 1, n, n))
            A_i = np.concatenate([zero, np.cumsum((each @ H)[..., :-1, :, :], axis=-3)], -3)
            b_i = np.concatenate([zero[..., :1], np.cumsum((each @ y[..., None])[..., :-1, :, :],
                                                           axis=-3)], -3)  # fmt: skip
            P_i = np.linalg.solve(np.eye(n) + P_i @ A_i, P_i)
            y_given = y - (H @ (P_i @ b_i))[..., 0]
        S_given = H @ P_i @ _T(H) + R
        S_given = 0.5 * (S_given + _T(S_given))
    return Update(delta[..., 0], 0.5 * (P_new + _T(P_new)), nis, logdet, y_given, S_given)


def _rows(a: FloatArray) -> FloatArray:
    """The readings' blocks ``(..., m, d, k)`` stacked as rows ``(..., md, k)``."""
    return a.reshape(*a.shape[:-3], a.shape[-3] * a.shape[-2], a.shape[-1])


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
    if (bad := not_positive_definite(R)) is not None:  # update weighs by R⁻¹
        raise ParameterError(f"the reading's noise R{list(bad[0]) or ''} is not positive "
                             f"definite{bad[1]}")  # fmt: skip
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
