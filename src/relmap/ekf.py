"""EKF localization with a known map (lecture Eqs. 13-28), batched over independent filters.

The state is the robot's pose AT in the world: mean ``(x, y, θ)``, covariance in relmap's chart.
Everything takes leading batch axes, so a thousand filters of one scenario (e.g. Monte Carlo
runs) step together with no Python loop per filter.

- :func:`predict` (Eq. 13): ``x⁻ = g(x, u)``, ``Σ⁻ = Gx Σ Gxᵀ + Gu Σu Guᵀ`` — the pose compounded
  with the step's AT in the robot frame (:mod:`relmap.robot`), the same thing.
- :func:`correct_pose` (Eqs. 14-19): a full-pose sensor (GPS + compass), reading z with
  covariance Σz — exactly the paper's merge (§4) of the prediction with the reading, after a
  gate on the innovation (the paper's merge is this special case of the EKF).
- :func:`correct_landmarks` (Eqs. 20-28): range-bearing readings of point landmarks of a known
  map: association (signatures, Mahalanobis Eq. 23 or Euclidean Eq. 22 nearest neighbour, one
  reading to one landmark by default or the lecture's Eq. 21 variant), gating with a χ² quantile
  (Eq. 25), then one stacked update (Eqs. 26-28). Each step reports which reading matched which
  landmark, and why the others were rejected.

Covariance updates use the Joseph form ``(I - KH) Σ⁻ (I - KH)ᵀ + K R Kᵀ`` rather than Eq. 28's
``Σ⁻ - K S Kᵀ``: it is a sum of congruences, so it stays symmetric positive semi-definite under
rounding, even after many updates or with a nearly exact prior.
"""

from __future__ import annotations

from typing import Literal, NamedTuple

import numpy as np

from relmap import gaussian
from relmap.at import AT, compound, merge
from relmap.errors import ParameterError, ShapeError
from relmap.lie import se2
from relmap.robot.motion import DiffDrive, Integration, Noise, _pairs, _step_ats
from relmap.sensors.polar import RangeBearingSensor
from relmap.typing import ArrayLike, FloatArray, IntArray

__all__ = [
    "ABSENT",
    "GATED",
    "INVALID",
    "LOST",
    "UNKNOWN",
    "USED",
    "LandmarkUpdate",
    "PoseUpdate",
    "correct_landmarks",
    "correct_pose",
    "predict",
]

Association = Literal["signatures", "mahalanobis", "euclidean"]
Pairing = Literal["one_to_one", "per_landmark"]

#: Status of a reading after :func:`correct_landmarks`.
USED, GATED, UNKNOWN, INVALID, ABSENT, LOST = 0, 1, 2, 3, 4, 5
STATUS = {
    USED: "used",
    GATED: "outside the gate",
    UNKNOWN: "no landmark of the map matches it",
    INVALID: "not a finite reading",
    ABSENT: "no reading (padding)",
    LOST: "its landmark went to a closer reading",
}


def predict(
    state: AT,
    motion: ArrayLike,
    noise: Noise,
    *,
    integration: Integration = "midpoint",
    drive: DiffDrive | None = None,
) -> AT:
    """The prediction step (Eq. 13) for a step ``(Δs, Δθ)`` — or wheel increments with ``drive``."""
    m = _pairs(motion, "motion")
    if drive is not None:
        m = drive.motion(m)
    return compound(state, _step_ats(m, noise, integration, drive))


class PoseUpdate(NamedTuple):
    """The corrected state and the gate's verdict on a full-pose reading."""

    state: AT
    mahalanobis2: FloatArray  #: (...) d² of the innovation under Σ⁻ + Σz
    accepted: np.ndarray  #: (...) whether the reading was used


def correct_pose(state: AT, reading: AT, *, gate: float | None = 0.999) -> PoseUpdate:
    """Correct with a full-pose reading (GPS + compass; Eqs. 14-19): the merge of §4.

    The innovation (heading wrapped) is gated at the χ²₃ quantile ``gate`` (None: no gate);
    a gated-out reading leaves the state as it was.
    """
    v = se2.minus(reading.mean, state.mean)
    S = state.cov + reading.cov
    d2 = gaussian.mahalanobis2(v, np.zeros(3), S)
    ok = np.ones(np.shape(d2), bool) if gate is None else d2 <= gaussian.confidence_k2(gate, 3)
    merged = merge(state, reading)
    mean = np.where(ok[..., None], merged.mean, state.mean)
    cov = np.where(ok[..., None, None], merged.cov, state.cov)
    return PoseUpdate(AT._trusted(mean, cov), d2, ok)


class LandmarkUpdate(NamedTuple):
    """The corrected state and what happened to every reading (arrays shaped like the readings'
    leading axes ``(..., m)``)."""

    state: AT
    landmark: IntArray  #: row of the map each reading was paired with (-1: none)
    mahalanobis2: FloatArray  #: d² to the paired (or nearest) landmark, inf if none
    status: IntArray  #: USED, GATED, UNKNOWN, INVALID, ABSENT or LOST

    def report(self) -> dict[str, int]:
        """How many readings ended in each status."""
        return {STATUS[k]: int((self.status == k).sum()) for k in STATUS}


def correct_landmarks(
    state: AT,
    readings: ArrayLike,
    sensor: RangeBearingSensor,
    landmarks: ArrayLike,
    *,
    associate: Association = "mahalanobis",
    pairing: Pairing = "one_to_one",
    signatures: ArrayLike | None = None,
    landmark_signatures: ArrayLike | None = None,
    gate: float = 0.99,
    valid: ArrayLike | None = None,
) -> LandmarkUpdate:
    """Correct with range-bearing readings ``(r, φ)`` (..., m, 2) of landmarks ``(L, 2)``.

    Association: ``"signatures"`` pairs a reading with the landmark of equal signature (e.g. a
    barcode; ``signatures`` (..., m) and ``landmark_signatures`` (L,)), ``"mahalanobis"`` (Eq. 23)
    or ``"euclidean"`` (Eq. 22, metres and radians mixed as in the lecture) with the nearest
    landmark. Signatures, when given, must agree under every method. ``pairing="one_to_one"``
    gives each landmark at most one reading (the nearest; the others are LOST);
    ``"per_landmark"`` is the lecture's Eq. 21 (each landmark takes its nearest reading, which may
    serve two landmarks). Pairs whose ``d² > χ²₂(gate)`` are GATED (Eq. 25). ``valid`` (..., m)
    marks padding; NaN readings are INVALID. The used pairs form one stacked update (Eqs. 26-28).
    """
    z = np.asarray(readings, dtype=np.float64)
    lm = np.asarray(landmarks, dtype=np.float64)
    if z.ndim < 2 or z.shape[-1] != 2:
        raise ShapeError(f"readings must have shape (..., m, 2); got {z.shape}")
    if lm.ndim != 2 or lm.shape[-1] != 2 or len(lm) == 0:
        raise ShapeError(f"landmarks must be a non-empty (L, 2) array; got {lm.shape}")
    gaussian.check_finite(lm, "landmarks")
    gaussian.check_probability(gate, "gate")
    if associate not in ("signatures", "mahalanobis", "euclidean"):
        raise ParameterError(
            f"associate must be signatures, mahalanobis or euclidean; got {associate!r}"
        )
    if pairing not in ("one_to_one", "per_landmark"):
        raise ParameterError(f"pairing must be one_to_one or per_landmark; got {pairing!r}")
    batch = np.broadcast_shapes(state.batch_shape, z.shape[:-2])
    m, L = z.shape[-2], len(lm)
    z = np.broadcast_to(z, (*batch, m, 2))
    present = (
        np.ones((*batch, m), bool)
        if valid is None
        else np.broadcast_to(np.asarray(valid, bool), (*batch, m))
    )
    finite = np.isfinite(z).all(axis=-1)
    usable = present & finite & (z[..., 0] > 0)
    z = np.where(usable[..., None], z, np.array([1.0, 0.0]))  # placeholders, never used

    # predicted readings of every landmark, and their innovation covariances S (…, L, 2, 2)
    mean, cov = state.mean, state.cov
    h, H, _ = sensor.predict(mean[..., None, :], lm, jacobians=True)
    h = np.broadcast_to(h, (*batch, L, 2))
    H = np.broadcast_to(H, (*batch, L, 2, 3))
    R = sensor.noise(h[..., 0])
    S = H @ cov[..., None, :, :] @ np.swapaxes(H, -1, -2) + R
    Sinv = np.linalg.inv(S)
    v = z[..., :, None, :] - h[..., None, :, :]  # (…, m, L, 2)
    v[..., 1] = se2.wrap_angle(v[..., 1])
    d2 = np.einsum("...mla,...lab,...mlb->...ml", v, Sinv, v)
    cost = d2 if associate != "euclidean" else np.einsum("...a,...a->...", v, v)
    allowed = np.broadcast_to(usable[..., None], cost.shape).copy()
    if signatures is not None or associate == "signatures":
        if signatures is None or landmark_signatures is None:
            raise ParameterError("signature association needs signatures and landmark_signatures")
        sig = np.broadcast_to(np.asarray(signatures), (*batch, m))
        lsig = np.asarray(landmark_signatures)
        if lsig.shape != (L,):
            raise ShapeError(f"landmark_signatures must have shape ({L},); got {lsig.shape}")
        allowed &= sig[..., :, None] == lsig
    cost = np.where(allowed, cost, np.inf)

    status = np.where(~present, ABSENT, np.where(~usable, INVALID, UNKNOWN)).astype(np.int64)
    candidate = np.isfinite(cost).any(axis=-1) & usable  # some landmark of the map could match
    gate2 = float(gaussian.confidence_k2(gate, 2))
    if pairing == "per_landmark":
        # Eq. 21: each landmark takes its nearest reading; a reading may serve several landmarks
        best = np.argmin(cost, axis=-2)  # (…, L)
        best_cost = np.take_along_axis(cost, best[..., None, :], axis=-2)[..., 0, :]
        best_d2 = np.take_along_axis(d2, best[..., None, :], axis=-2)[..., 0, :]
        use_l = np.isfinite(best_cost) & (best_d2 <= gate2)
        gated_l = np.isfinite(best_cost) & ~use_l
        chosen = best[..., None, :] == np.arange(m)[:, None]  # (…, m, L)
        served, refused = chosen & use_l[..., None, :], chosen & gated_l[..., None, :]
        used_r, gated_r = served.any(axis=-1), refused.any(axis=-1) & ~served.any(axis=-1)
        landmark = np.where(used_r, served.argmax(-1), np.where(gated_r, refused.argmax(-1), -1))
        status = np.where(used_r, USED, np.where(gated_r, GATED, np.where(candidate, LOST, status)))
        zr = np.take_along_axis(z, best[..., None], axis=-2)  # (…, L, 2)
        new = _joseph(state, zr, h, H, R, use_l)
        pair_d2 = np.where(
            landmark >= 0,
            np.take_along_axis(d2, np.maximum(landmark, 0)[..., None], -1)[..., 0],
            np.inf,
        )
        return LandmarkUpdate(new, landmark, pair_d2, status)

    # one to one: the cheapest remaining pair first (a loop over readings, vectorized over filters)
    landmark = np.full((*batch, m), -1, dtype=np.int64)
    c = cost.copy()
    for _ in range(min(m, L)):
        flat = c.reshape(*batch, m * L)
        k = np.argmin(flat, axis=-1)
        found = np.isfinite(np.take_along_axis(flat, k[..., None], axis=-1)[..., 0])
        if not found.any():
            break
        ri, li = k // L, k % L
        hit = found[..., None] & (np.arange(m) == ri[..., None])  # (…, m)
        landmark = np.where(hit, li[..., None], landmark)
        taken = (
            hit[..., :, None] | (found[..., None] & (np.arange(L) == li[..., None]))[..., None, :]
        )
        c = np.where(taken, np.inf, c)
    paired = landmark >= 0
    pair_d2 = np.take_along_axis(d2, np.maximum(landmark, 0)[..., None], axis=-1)[..., 0]
    used = paired & (pair_d2 <= gate2)
    gated = paired & ~used
    status = np.where(used, USED, np.where(gated, GATED, np.where(candidate, LOST, status)))
    nearest = np.where(np.isfinite(cost), d2, np.inf).min(axis=-1)
    out_d2 = np.where(paired, pair_d2, nearest)
    lk = np.maximum(landmark, 0)
    hr = np.take_along_axis(h, lk[..., None], axis=-2)
    Hr = np.take_along_axis(H, lk[..., None, None], axis=-3)
    Rr = np.take_along_axis(R, lk[..., None, None], axis=-3)
    new = _joseph(state, z, hr, Hr, Rr, used)
    return LandmarkUpdate(new, np.where(paired, landmark, -1), out_d2, status)


def _joseph(
    state: AT, z: FloatArray, h: FloatArray, H: FloatArray, R: FloatArray, use: np.ndarray
) -> AT:
    """One stacked EKF update over k pairs (…, k): unused pairs get H = 0, v = 0 (no effect)."""
    k = z.shape[-2]
    if k == 0 or not np.any(use):
        return state
    v = z - h
    v[..., 1] = se2.wrap_angle(v[..., 1])
    v = np.where(use[..., None], v, 0.0)
    Hm = np.where(use[..., None, None], H, 0.0)
    Rm = np.where(use[..., None, None], R, np.eye(2))
    batch = v.shape[:-2]
    Hs = Hm.reshape(*batch, 2 * k, 3)
    Rs = np.zeros((*batch, 2 * k, 2 * k))
    for i in range(k):
        Rs[..., 2 * i : 2 * i + 2, 2 * i : 2 * i + 2] = Rm[..., i, :, :]
    P = np.broadcast_to(state.cov, (*batch, 3, 3))
    PHt = P @ np.swapaxes(Hs, -1, -2)
    S = Hs @ PHt + Rs  # Eq. 27's H Σ⁻ Hᵀ + R
    K = np.swapaxes(np.linalg.solve(S, np.swapaxes(PHt, -1, -2)), -1, -2)  # Σ⁻ Hᵀ S⁻¹
    mean = se2.plus(
        np.broadcast_to(state.mean, (*batch, 3)),
        np.einsum("...ij,...j->...i", K, v.reshape(*batch, 2 * k)),
    )
    I_KH = np.eye(3) - K @ Hs
    cov = I_KH @ P @ np.swapaxes(I_KH, -1, -2) + K @ Rs @ np.swapaxes(K, -1, -2)
    return AT._trusted(mean, 0.5 * (cov + np.swapaxes(cov, -1, -2)))
