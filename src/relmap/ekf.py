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

How :func:`correct_landmarks` computes (the results are those of the textbook procedure — all
m×L innovations, greedy one-to-one pairing over them, a 2k×2k stacked update — to rounding;
``tests/test_ekf_reference.py`` holds that procedure and compares):

- Layout: readings are ``(m, B)`` arrays and landmarks ``(C, B)``, the B filters innermost and
  contiguous; plane points are complex numbers (one product rotates and scales); 2×2 and 3×3
  algebra is written out entry by entry. One filter keeps its state in Python floats, so a
  single filter pays for few numpy calls.
- Innovation covariances in closed form: with ``u`` the unit vector from the sensor to the
  landmark (``u⊥`` turned by -90°), V the covariance of the sensor's position and g its
  covariance with the heading (both from Σ⁻ and the sensor's offset on the robot),
  ``S = [[uᵀVu, gᵀu - uᵀVu⊥/ρ], [·, u⊥ᵀVu⊥/ρ² - 2gᵀu⊥/ρ + Σ⁻θθ]] + R``.
- Candidates: for many filters, only landmarks that may fall inside the gate of some reading
  enter the reading×landmark matrix. A landmark is dropped when no reading's range and bearing
  can come that close: ``d² ≥ v_r²/S_rr`` and ``d² ≥ v_φ²/S_φφ`` (Cauchy-Schwarz), with
  ``S_rr``, ``S_φφ`` bounded through the largest eigenvalue of V and the readings' ranges and
  bearings through their hull. With signatures, only landmarks whose signature was read; with
  unique signatures and no signature read twice, each reading has its one landmark (no matrix;
  integer signatures of a small span are looked up in a table, not by binary search). The
  kept landmarks of each filter are gathered from the bits of one word per filter (L ≤ 64).
- Grid: bearing innovations are differences of bearings measured from the centre of the
  filter's readings; when every candidate's bearing bound leaves them within π, no entry
  inside the gate needs wrapping and those outside stay outside (see _gate_candidates), so the
  grid skips the wrap. A batch's bearing innovations of known pairs are differences of
  bearings (atan2 of the predicted direction) too: no complex exponential of the readings.
- Pairing (one to one, Mahalanobis): the greedy "cheapest pair first" run takes its pairs in
  increasing d²; those inside the gate are exactly the greedy pairing of the pairs inside the
  gate, so that runs first. When no two readings of a filter share their nearest landmark, it
  is each reading's nearest; filters with a conflict run the greedy by rounds of pairs that are
  the cheapest of their row and their column (which the greedy run takes too). Readings left
  over (gated out, lost, unknown) are then paired among themselves with the landmarks left,
  against all L landmarks, as the greedy run would have gone on.
- Update: with R block diagonal, ``Hᵀ(HΣ⁻Hᵀ + R)⁻¹ = (I + AΣ⁻)⁻¹HᵀR⁻¹`` with now
  ``A = HᵀR⁻¹H``, a 3×3 sum over the pairs, and ``b = HᵀR⁻¹v``: ``K v = Σ⁻ y`` with
  ``(I + AΣ⁻) y = b`` (solved by the adjugate, refined once), ``K H = G A`` with
  ``G = Σ⁻(I + AΣ⁻)⁻¹``, and the Joseph form ``(I - GA) Σ⁻ (I - GA)ᵀ + G A Gᵀ`` — the exact
  Joseph form of the gain computed, so rounding in G enters only to second order. For a batch
  the 3×3 matrices are stacked as (3, 3, B) arrays (a few numpy calls per product). When
  ``tr(AΣ⁻) > 10⁵`` (a reading far more precise than the prior: A then holds too few digits
  of the prior's information) and for a sensor without noise (no R⁻¹), the 2k×2k solve.

Which path runs:

- With numba (``relmap._numba.enabled()``: numba importable, ``RELMAP_NUMBA`` not ``0``, and
  not inside ``relmap._numba.one_shot()``, where a few steps would not repay numba's start-up),
  :func:`correct_landmarks` with one-to-one pairing by signatures or Mahalanobis distance is
  one call of a compiled kernel (``relmap._ekf_kernels``), for one filter or for a whole batch
  (the loop over filters is inside the kernel), and the batch's :func:`predict` is one too.
  The kernels compute the single-filter path's formulas (below) reading by reading: candidate
  landmarks from the signature table or the reading's disc, pairs inside the gate taken
  greedily, the leftover readings against the landmarks left, the 3×3 update.
- Otherwise, and for what the kernels do not take (Euclidean distance, the lecture's Eq. 21,
  a sensor without noise, non-integer signatures) or leave to numpy (an ill-conditioned update,
  a landmark at the sensor): a single filter takes the path on Python floats described at
  ``_correct_one``, a batch the numpy algebra above. All paths give the same pairings and
  statuses and the same states to rounding (``tests/test_ekf_reference.py`` runs on both).
"""

from __future__ import annotations

import bisect
import cmath
import functools
import math
from typing import Any, Literal, NamedTuple

import numpy as np

from relmap import _numba, gaussian
from relmap.at import AT, _compound_arrays, compound, merge
from relmap.errors import ParameterError, ShapeError
from relmap.lie import se2
from relmap.robot.motion import DiffDrive, Integration, Noise, _pairs, _step_ats, _step_single
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

_TWO_PI = 2.0 * np.pi
# Reading×landmark matrices of more entries than this (over all filters) are restricted to
# candidate landmarks first; below it the bookkeeping costs more than it saves.
_CANDIDATES_ABOVE = 4096
# Relative slack of the candidate bounds, far above rounding: a kept landmark costs little.
_SLACK = 1.0 + 1e-6
# Reading×landmark grids are computed in blocks of filters of about this many entries.
_GRID_BLOCK = 40_000
# Above this tr(A Σ⁻) the 3×3 update loses digits; the stacked 2n×2n solve takes over.
_ILL_CONDITIONED = 1e5


def predict(
    state: AT,
    motion: ArrayLike,
    noise: Noise,
    *,
    integration: Integration = "midpoint",
    drive: DiffDrive | None = None,
) -> AT:
    """The prediction step (Eq. 13) for a step ``(Δs, Δθ)`` — or wheel increments with ``drive``.

    One step for a batch of filters is one numba kernel call when numba is enabled (see the
    module notes)."""
    if type(state) is AT:  # one step (Python floats) for one filter or a batch
        step = _step_single(motion, noise, integration, drive)
        if step is not None:
            if state.mean.ndim == 1:
                return _compound_one(state, *step)
            return _compound_batch(state, *step)
    m = _pairs(motion, "motion")
    if drive is not None:
        m = drive.motion(m)
    return compound(state, _step_ats(m, noise, integration, drive))


def _compound_one(state: AT, delta: tuple[float, float, float], step: tuple[float, ...]) -> AT:
    """``state ⊕ step`` (Eqs. 1-4) for one pose and one step given in Python floats, built
    straight into the result's arrays. relmap.at's ``_shear`` and ``_rotate`` written out
    (bitwise the same): calling them costs 2.6 µs of this function's 10 µs, on the path of every
    single-filter prediction."""
    xa, ya, ta = state.mean.tolist()
    (p00, p01, p02), (_, p11, p12), (_, _, p22) = state.cov.tolist()
    xb, yb, tb = delta
    q00, q01, q02, q11, q12, q22 = step
    c, s = math.cos(ta), math.sin(ta)
    dx, dy = c * xb - s * yb, s * xb + c * yb
    r0 = p02 - dy * p22  # H C_a Hᵀ, H = [[1, 0, -dy], [0, 1, dx], [0, 0, 1]]
    r1 = p12 + dx * p22
    cc, ss, cs = c * c, s * s, c * s  # K C_b Kᵀ, K = blkdiag(R(θa), 1)
    cs_q01 = 2.0 * cs * q01
    return AT._single([
        xa + dx, ya + dy, _wrap_scalar(ta + tb),
        p00 - dy * (p02 + r0) + (cc * q00 - cs_q01 + ss * q11),
        p01 - dy * p12 + dx * r0 + (cs * (q00 - q11) + (cc - ss) * q01),
        r0 + (c * q02 - s * q12),
        p11 + dx * (p12 + r1) + (ss * q00 + cs_q01 + cc * q11),
        r1 + (s * q02 + c * q12),
        p22 + q22,
    ])  # fmt: skip


def _compound_batch(state: AT, delta: tuple[float, float, float], step: tuple[float, ...]) -> AT:
    """:func:`_compound_one` for a batch of poses and one step: one numba kernel call with
    numba, else relmap.at's array path."""
    if _numba.enabled():
        B = math.prod(state.batch_shape)
        mean, cov = np.empty((3, B)), np.empty((3, 3, B))
        _kernels().compound_batch(
            state.mean.reshape(B, 3), state.cov.reshape(B, 3, 3), np.array([*delta, *step]),
            mean, cov,
        )  # fmt: skip
        shape = state.batch_shape
        return AT._trusted(mean.T.reshape(*shape, 3), np.moveaxis(cov, 2, 0).reshape(*shape, 3, 3))
    q00, q01, q02, q11, q12, q22 = step
    cov_b = np.array([[q00, q01, q02], [q01, q11, q12], [q02, q12, q22]])
    return AT._trusted(*_compound_arrays(state.mean, state.cov, np.array(delta), cov_b))


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

    With numba, one-to-one association by signatures or Mahalanobis distance runs as one
    compiled kernel call (one filter or the whole batch); the rest, and everything without
    numba, on the numpy / Python-float paths — same results to rounding (see the module notes).
    """
    if _FAST_SINGLE and pairing == "one_to_one" and type(state) is AT and state.mean.ndim == 1:
        fast = None
        if _numba.enabled():
            fast = _compiled_one(
                state, readings, sensor, landmarks, associate, signatures, landmark_signatures,
                gate, valid,
            )  # fmt: skip
        if fast is None:
            fast = _correct_one(
                state, readings, sensor, landmarks, associate, signatures, landmark_signatures,
                gate, valid,
            )  # fmt: skip
        if fast is not None:
            return fast
    z = np.asarray(readings, dtype=np.float64)
    lm = np.asarray(landmarks, dtype=np.float64)
    if z.ndim < 2 or z.shape[-1] != 2:
        raise ShapeError(f"readings must have shape (..., m, 2); got {z.shape}")
    if lm.ndim != 2 or lm.shape[-1] != 2 or len(lm) == 0:
        raise ShapeError(f"landmarks must be a non-empty (L, 2) array; got {lm.shape}")
    if not np.isfinite(lm).all():
        gaussian.check_finite(lm, "landmarks")
    if not (isinstance(gate, float) and 0.0 < gate < 1.0):
        gaussian.check_probability(gate, "gate")
    if associate not in ("signatures", "mahalanobis", "euclidean"):
        raise ParameterError(
            f"associate must be signatures, mahalanobis or euclidean; got {associate!r}"
        )
    if pairing not in ("one_to_one", "per_landmark"):
        raise ParameterError(f"pairing must be one_to_one or per_landmark; got {pairing!r}")
    lsig = None
    if signatures is not None or associate == "signatures":
        if signatures is None or landmark_signatures is None:
            raise ParameterError("signature association needs signatures and landmark_signatures")
        lsig = np.asarray(landmark_signatures)
        if lsig.shape != (len(lm),):
            raise ShapeError(f"landmark_signatures must have shape ({len(lm)},); got {lsig.shape}")
    batch = state.batch_shape
    if z.shape[:-2] != batch:
        batch = np.broadcast_shapes(batch, z.shape[:-2])
    m = z.shape[-2]
    if m == 0 or 0 in batch:
        empty = np.zeros((*batch, m))
        return LandmarkUpdate(
            state, empty.astype(np.int64) - 1, empty + np.inf, empty.astype(np.int64) + ABSENT
        )

    if batch and pairing == "one_to_one" and associate != "euclidean" and _numba.enabled():
        compiled = _compiled_batch(state, z, batch, valid, signatures, lsig, sensor, lm, gate)
        if compiled is not None:
            return compiled
    job = _Job(state, z, batch, valid, signatures, lsig, sensor, lm, _gate2(float(gate)))
    if associate == "euclidean" or pairing == "per_landmark":
        out = job.general(associate, pairing)
    else:
        out = (job.known() if lsig is not None else None) or job.nearest()
    return job.finish(*out)


# --------------------------------------------------------------------------- implementation
# One filter (a single state AT, readings (m, 2)) takes _correct_one unless this is False.
_FAST_SINGLE = True


@functools.lru_cache(maxsize=64)
def _gate2(gate: float) -> float:
    return float(gaussian.confidence_k2(gate, 2))


def _wrap_near(a: FloatArray) -> FloatArray:
    """Wrap angles in [-3π, 3π) to [-π, π), in place (a difference of two wrapped angles)."""
    np.subtract(a, _TWO_PI, out=a, where=a >= np.pi)
    np.add(a, _TWO_PI, out=a, where=a < -np.pi)
    return a


def _wrap_scalar(a: float) -> float:
    return a if -np.pi <= a < np.pi else float(se2.wrap_angle(a))


Value = Any  # a per-filter quantity: a float for one filter, an array (B,) or (C, B) for B


class _Frame(NamedTuple):
    """Per-filter quantities: Python numbers for one filter, (B,) arrays for B filters.

    Points of the plane are complex numbers ``x + iy`` here: one complex product rotates and
    scales, which halves the numpy calls of the geometry.
    """

    x: Value
    y: Value
    t: Value
    p: tuple[Value, ...]  # Σ⁻ as (p00, p01, p02, p11, p12, p22)
    ax: Value  # the sensor's offset on the robot, in world axes
    ay: Value
    sc: Value  # the sensor's position (complex) and heading
    st: Value
    # V = Eᵀ Σ⁻ E, the covariance of the sensor's position (a pose change δ moves the sensor
    # by Eᵀδ, E = [[1, 0], [0, 1], [-ay, ax]]), and g = Eᵀ Σ⁻[:, 2], its covariance with θ:
    h: Value  # tr(V)/2
    cbar: Value  # (V00 - V11)/2 - i V01: uᵀVu = h + Re(c̄u²), uᵀVu⊥ = Im(c̄u²)
    gbar: Value  # g0 - i g1: gᵀu = Re(ḡu), gᵀu⊥ = Im(ḡu)

    @classmethod
    def build(cls, mean: FloatArray, cov: FloatArray, mount: FloatArray, single: bool) -> _Frame:
        x: Value
        y: Value
        t: Value
        c: Value
        s: Value
        P: Value
        if single:
            x, y, t = mean.tolist()
            P = cov.tolist()
            c, s = math.cos(t), math.sin(t)
        else:
            x, y, t = mean[:, 0], mean[:, 1], mean[:, 2]
            P = [[cov[:, i, j] for j in range(3)] for i in range(3)]
            c, s = np.cos(t), np.sin(t)
        p = (P[0][0], P[0][1], P[0][2], P[1][1], P[1][2], P[2][2])
        p00, p01, p02, p11, p12, p22 = p
        mx, my, mt = mount.tolist()
        ax, ay = c * mx - s * my, s * mx + c * my
        st = _wrap_scalar(t + mt) if single else se2.wrap_angle(t + mt)
        v00 = p00 - 2 * ay * p02 + ay * ay * p22
        v01 = p01 + ax * p02 - ay * p12 - ax * ay * p22
        v11 = p11 + 2 * ax * p12 + ax * ax * p22
        g0, g1 = p02 - ay * p22, p12 + ax * p22
        sx, sy = x + ax, y + ay
        return cls(
            x, y, t, p, ax, ay, sx + 1j * sy, st, 0.5 * (v00 + v11),
            0.5 * (v00 - v11) - 1j * v01, g0 - 1j * g1,
        )  # fmt: skip

    def take(self, idx: IntArray) -> _Frame:
        """The filters ``idx`` of a batch."""
        return _Frame(*(tuple(v[idx] for v in f) if i == 3 else f[idx] for i, f in enumerate(self)))


class _Pred(NamedTuple):
    """Predicted readings of landmarks, and what association and update need of them."""

    r: Value  # predicted range ρ
    ir: Value  # 1/ρ
    u: Value  # unit vector from the sensor to the landmark (complex, world axes)
    var_r: Value  # R = diag(var_r, var_b)
    var_b: Value
    k1: Value  # S⁻¹ factored: d² = ((v_r - k1 v_φ) c1)² + (v_φ c2)²
    c1: Value
    c2: Value

    def pick(self, k: IntArray, cols: IntArray | None) -> _Pred:
        """Entry ``k`` (n, …) along the landmark axis, per filter, of what the update uses."""
        var_r, var_b = (v if isinstance(v, float) else _pick(v, k, cols) for v in self[3:5])
        ir, u = _pick(self.ir, k, cols), _pick(self.u, k, cols)
        return _Pred(None, ir, u, var_r, var_b, None, None, None)

    def take(self, F: IntArray) -> _Pred:
        """The filters F of a batch."""
        return _Pred(*(v if v is None or isinstance(v, float) else v[:, F] for v in self))


def _pick(v: np.ndarray, k: IntArray, cols: IntArray | None) -> np.ndarray:
    """``v[k[j], j]`` per filter: v (C, …), k (n, …)."""
    return v[k] if cols is None else v[k, cols]


def _predict(f: _Frame, lc: FloatArray, sensor: RangeBearingSensor) -> _Pred:
    """Readings predicted for landmarks ``lc`` (complex, (C, …)) and their innovation
    covariances ``S = [[uᵀVu, gᵀu - uᵀVu⊥/ρ], [·, u⊥ᵀVu⊥/ρ² - 2gᵀu⊥/ρ + Σθθ]] + R``."""
    d = lc - f.sc
    r = np.abs(d)
    if not r.all():
        raise ParameterError("a landmark at the sensor's own position has no bearing")
    ir = 1.0 / r
    u = d * ir
    cw = f.cbar * (u * u)
    gu = f.gbar * u
    var_r, var_b = sensor._variances(r)
    uvu = f.h + cw.real  # uᵀVu; u⊥ᵀVu⊥ = tr V - uᵀVu
    s00 = uvu + var_r
    s01 = gu.real - cw.imag * ir
    s11 = ((2 * f.h - uvu) * ir - 2 * gu.imag) * ir + (f.p[5] + var_b)
    det = s00 * s11 - s01 * s01
    return _Pred(r, ir, u, var_r, var_b, s01 / s11, np.sqrt(s11 / det), np.sqrt(1.0 / s11))


def _innovations(p: _Pred, zr: FloatArray, ez: FloatArray) -> tuple[FloatArray, ...]:
    """``(d², v_r, v_φ)`` (m, C, …) of readings (m, …) against predictions (C, …); ``ez`` is
    ``exp(i(φ + θ_sensor))``, so that the bearing innovation ``angle(ez · ū)`` comes wrapped."""
    vr = zr[:, None] - p.r
    vb = np.angle(ez[:, None] * np.conj(p.u))
    return _mahalanobis2(p, vr, vb), vr, vb


def _grid_mahalanobis2(
    p: _Pred, bearing: FloatArray, zr: FloatArray, zb: FloatArray, wrap: bool = True
) -> FloatArray:
    """d² (m, C, B) of readings (m, B) (bearings wrapped) against predictions (C, B) with
    bearings ``bearing``, in blocks of filters small enough for their temporaries to stay in
    cache (a large grid is bound by memory traffic). ``wrap=False``: the bearing differences
    are not wrapped (see :meth:`_Job._gate_candidates` for when that is exact enough)."""
    m, C, B = len(zr), len(bearing), zr.shape[1]
    d2 = np.empty((m, C, B))
    step = max(1, _GRID_BLOCK // max(1, m * C))
    for s in range(0, B, step):
        b = slice(s, s + step)
        vb = zb[:, None, b] - bearing[:, b]
        if wrap:
            _wrap_near(vb)
        d = np.subtract(zr[:, None, b], p.r[:, b], out=d2[:, :, b])
        t = p.k1[:, b] * vb
        d -= t
        d *= p.c1[:, b]
        d *= d
        np.multiply(vb, p.c2[:, b], out=t)
        t *= t
        d += t
    return d2


def _mahalanobis2(p: _Pred, vr: FloatArray, vb: FloatArray) -> FloatArray:
    """``vᵀS⁻¹v`` from the factored S⁻¹ of the predictions."""
    d2 = vr - p.k1 * vb
    d2 *= p.c1
    d2 *= d2
    t = vb * p.c2
    t *= t
    d2 += t
    return d2


_POW2 = np.left_shift(np.uint64(1), np.arange(64, dtype=np.uint64))
_ZERO, _ONE = np.uint64(0), np.uint64(1)


def _sorted_lookup(keys: np.ndarray, values: np.ndarray) -> IntArray:
    """``min(searchsorted(keys, values), len(keys) - 1)`` for increasing ``keys``: for integer
    keys of a small span, through a table of that span (a binary search per value is slow)."""
    n = len(keys)
    if keys.dtype.kind in "iu" and values.dtype.kind in "iu" and n:
        lo, hi = int(keys[0]), int(keys[-1])
        if hi - lo <= 64 * n + 1024:
            table = np.searchsorted(keys, np.arange(lo, hi + 1, dtype=keys.dtype))
            np.minimum(table, n - 1, out=table)
            idx = values - lo if lo else values
            return table.take(idx, mode="clip")
    return np.minimum(np.searchsorted(keys, values), n - 1)


def _clashes(pair: IntArray, C: int) -> np.ndarray | np.bool_:
    """Per filter: do two rows of ``pair`` (n, …) hold the same column (≥ 0, < C)?"""
    if pair.ndim == 1:
        k = [c for c in pair.tolist() if c >= 0]
        return np.bool_(len(set(k)) < len(k))
    if C <= 64 and pair.dtype.kind == "i" and hasattr(np, "bitwise_count"):
        # a bit per column: no two rows alike iff the bits of the rows, OR-ed, number the rows
        # (no counts of C × B)
        taken = pair >= 0
        bits = np.left_shift(np.uint64(1), np.where(taken, pair, 0).astype(np.uint64))
        bits[~taken] = 0
        union = np.bitwise_or.reduce(bits, axis=0)
        return np.bitwise_count(union) != np.count_nonzero(taken, axis=0)
    j, b = np.nonzero(pair >= 0)
    count = np.bincount(b * C + pair[j, b], minlength=C * pair.shape[1])
    return (count.reshape(-1, C) > 1).any(axis=1)


def _greedy(cost: FloatArray) -> IntArray:
    """The greedy pairing — cheapest remaining pair first, ties to the lowest row then column —
    of a cost grid (n, C, F) (inf: no pair): column per row, -1 if none; vectorized over F.

    By rounds: a pair that is the cheapest of its row and of its column (same tie-break) is
    one the greedy run takes, and taking it leaves the greedy run of the other rows and columns;
    so each round takes all such pairs at once (the global cheapest is always one of them).
    """
    n, _, F = cost.shape
    c = cost.copy()
    pair = np.full((n, F), -1)
    rows, cols = np.arange(n)[:, None], np.arange(F)
    while True:
        k = c.argmin(axis=1)  # (n, F): each row's cheapest column
        take = np.isfinite(c[rows, k, cols]) & (c.argmin(axis=0)[k, cols] == rows)
        if not take.any():
            return pair
        j, f = np.nonzero(take)
        pair[j, f] = k[j, f]
        c[j, :, f] = np.inf
        c[:, k[j, f], f] = np.inf


def _one_to_one(cost: FloatArray, sub: np.ndarray | None = None) -> IntArray:
    """Greedy one-to-one pairing of a cost grid (n, C, …) (inf: no pair): column per row or -1.

    Each row's nearest column, unless two rows of a filter want the same one: only those
    filters run :func:`_greedy`. With ``sub`` (bool, like cost) only its entries count: for few
    per row (pairs inside the gate), counting them finds the nearest without an argmin over
    the whole grid, which is slow along a middle axis.
    """
    n, C = cost.shape[:2]
    if C == 0:
        return np.full((n, *cost.shape[2:]), -1)
    if sub is None:
        k = cost.argmin(axis=1)
        pair = np.where(np.isfinite(cost.min(axis=1)), k, -1)
    else:  # (n, C, B)
        t = np.matmul(np.array([np.ones(C), np.arange(C)], np.float32), sub)  # exact
        count, ksum = t[:, 0], t[:, 1]  # with one entry, ksum is its column
        pair = np.where(count == 1, ksum, -1).astype(np.intp)
        j, b = np.nonzero(count > 1)
        if len(j):  # several inside the gate: an argmin over those rows only
            pair[j, b] = np.where(sub[j, :, b], cost[j, :, b], np.inf).argmin(axis=1)
    clash = _clashes(pair, C)
    if clash.any():
        if pair.ndim == 1:  # one filter: as a batch of one
            return _greedy(cost[..., None])[:, 0]
        F = np.flatnonzero(clash)
        pair[:, F] = _greedy(
            cost[..., F] if sub is None else np.where(sub[..., F], cost[..., F], np.inf)
        )
    return pair


def _at(
    grid: np.ndarray, k: IntArray, cols: IntArray | None, rows: IntArray | None = None
) -> np.ndarray:
    """``grid[j, k[j], b]`` for every row j (and filter b)."""
    if rows is None:
        rows = np.arange(grid.shape[0])
    return grid[rows, k] if cols is None else grid[rows[:, None], k, cols]


class _Job:
    """One call of :func:`correct_landmarks`, laid out for the computation: the batch flattened
    to B filters (or a single one), readings as (m, B) arrays, landmarks as (C, B) arrays where
    C counts all landmarks or each filter's candidates."""

    batch: tuple[int, ...]
    single: bool
    B: int
    m: int
    L: int
    cols: IntArray | None  # arange(B), None for a single filter
    mean: FloatArray  # (B, 3) or (3,)
    cov: FloatArray
    f: _Frame
    zr: FloatArray  # ranges (m, B), placeholders where unusable
    zb: FloatArray  # φ (m, B), wrapped in a batch
    usable: np.ndarray  # (m, B)
    all_usable: bool
    base: IntArray | int  # status of readings not paired: UNKNOWN, INVALID or ABSENT
    sig: np.ndarray | None  # (m, B)
    lsig: np.ndarray | None  # (L,)
    lc: np.ndarray  # landmarks as complex numbers (L,)
    sensor: RangeBearingSensor
    gate2: float
    state: AT

    def __init__(
        self,
        state: AT,
        z: FloatArray,
        batch: tuple[int, ...],
        valid: ArrayLike | None,
        signatures: ArrayLike | None,
        lsig: np.ndarray | None,
        sensor: RangeBearingSensor,
        lm: FloatArray,
        gate2: float,
    ) -> None:
        m = z.shape[-2]
        single = batch == ()
        B = math.prod(batch)
        mean, cov = state.mean, state.cov
        if not single:
            mean = np.broadcast_to(mean, (*batch, 3)).reshape(B, 3)
            cov = np.broadcast_to(cov, (*batch, 3, 3)).reshape(B, 3, 3)
            z = np.ascontiguousarray(np.broadcast_to(z, (*batch, m, 2)).reshape(B, m, 2).T).T
        zr, zb = (z[:, 0], z[:, 1]) if single else (z[:, :, 0].T, z[:, :, 1].T)  # (m, B)

        def readings_shaped(a: ArrayLike) -> np.ndarray:
            a = np.asarray(a)
            if a.shape != (*batch, m):
                a = np.broadcast_to(a, (*batch, m))
            return a if single else a.reshape(B, m).T

        usable = np.isfinite(zb) & (zr > 0) & (zr < np.inf)
        present = None if valid is None else readings_shaped(np.asarray(valid, bool))
        if present is not None:
            usable &= present
        self.all_usable = all_usable = bool(usable.all())
        self.base: IntArray | int = UNKNOWN  # status of the readings not paired
        if not all_usable:  # placeholders, never used
            zr, zb = np.where(usable, zr, 1.0), np.where(usable, zb, 0.0)
            self.base = np.where(usable, UNKNOWN, INVALID)
            if present is not None:
                self.base[~present] = ABSENT
        self.f = _Frame.build(mean, cov, sensor.mount, single)
        if not single and not ((zb >= -np.pi) & (zb < np.pi)).all():
            zb = se2.wrap_angle(zb)
        self.zb = zb  # bearings of the readings (wrapped for a batch)
        self.batch, self.single, self.B, self.m, self.L = batch, single, B, m, len(lm)
        self.cols = None if single else np.arange(B)
        self.mean, self.cov, self.zr, self.usable = mean, cov, zr, usable
        self.sig = None if lsig is None else readings_shaped(signatures)  # type: ignore[arg-type]
        self.lsig, self.sensor, self.gate2, self.state = lsig, sensor, gate2, state
        self.lc = np.ascontiguousarray(lm).view(np.complex128)[:, 0]

    @functools.cached_property
    def ez(self) -> FloatArray:
        """``exp(i(φ + θ_sensor))`` (m, B): ``angle(ez · ū)`` is a bearing innovation, wrapped."""
        return np.exp(1j * (self.zb + self.f.st))

    # ---------------------------------------------------------------- candidates
    def _landmarks(self, cand: IntArray | None) -> FloatArray:
        """Complex positions of all landmarks (L,) / (L, 1), or of the candidates (K, B)."""
        if cand is not None:
            return self.lc[cand]
        return self.lc if self.single else self.lc[:, None]

    def _columns(self, cand: IntArray | None) -> IntArray:
        """The landmark of each column (C, B) — or (L,) for a single filter."""
        if cand is not None:
            return cand
        idx = np.arange(self.L)
        return idx if self.single else np.broadcast_to(idx[:, None], (self.L, self.B))

    def _restrict(self, sub: np.ndarray, cand: IntArray | None, ok: np.ndarray | None) -> None:
        """Keep (in place) the pairs (m, C, …) that may pair: usable readings, real
        candidates, equal signatures."""
        if not self.all_usable:
            sub &= self.usable[:, None]
        if ok is not None:
            sub &= ok
        if self.sig is not None:
            lsig: np.ndarray = self.lsig  # type: ignore[assignment]
            if cand is not None:
                lsig = lsig[cand]
            elif not self.single:
                lsig = lsig[:, None]
            sub &= self.sig[:, None] == lsig

    def _compact(self, mask: np.ndarray) -> tuple[IntArray, np.ndarray]:
        """Landmark mask (L, B) → the kept landmarks' rows (K, B), in order, padded with 0, and
        which are real."""
        if self.L <= 64 and hasattr(np, "bitwise_count"):
            # the kept rows as the bits of one word per filter, taken lowest first
            bits = np.bitwise_or.reduce(np.where(mask, _POW2[: self.L, None], _ZERO), axis=0)
            count = np.bitwise_count(bits)
            C = int(count.max())
            cand = np.empty((C, self.B), np.intp)
            low = np.empty_like(bits)
            for c in range(C):
                np.negative(bits, out=low)
                low &= bits  # the lowest bit set
                bits ^= low
                low -= _ONE  # its index: the bits below it (0 - 1 wraps: 64, padding)
                cand[c] = np.bitwise_count(low)
            ok = np.arange(C)[:, None] < count
            cand[~ok] = 0
            return cand, ok
        by_filter = np.ascontiguousarray(mask.T)
        count = by_filter.sum(axis=1)
        bi, li = np.nonzero(by_filter)
        at = (np.arange(len(bi)) - (np.cumsum(count) - count)[bi], bi)
        cand = np.zeros((int(count.max()), self.B), np.intp)
        ok = np.zeros(cand.shape, bool)
        cand[at] = li
        ok[at] = True
        return cand, ok

    def _signature_candidates(self) -> tuple[IntArray, np.ndarray] | None:
        """Landmarks whose signature some usable reading of the filter carries (None unless
        landmark signatures are unique)."""
        lsig, sig = self.lsig, self.sig
        assert lsig is not None and sig is not None
        order = np.argsort(lsig, kind="stable")
        ordered = lsig[order]
        if len(ordered) > 1 and not (ordered[1:] != ordered[:-1]).all():
            return None
        pos = np.minimum(np.searchsorted(ordered, sig), self.L - 1)
        found = (ordered[pos] == sig) & self.usable
        mask = np.zeros((self.L, self.B), bool)
        j, b = np.nonzero(found)
        mask[order[pos[j, b]], b] = True
        return self._compact(mask)

    def _gate_candidates(self) -> tuple[IntArray, np.ndarray, FloatArray | None]:
        """Landmarks that may lie inside the gate of some usable reading of the filter (see the
        module notes): range and bearing of the landmark against the readings' hull, with
        ``S_rr ≤ λ + σr²`` and ``S_φφ ≤ λ/ρ² + 2|g|/ρ + Σθθ + σφ²``, λ = h + |c̄| the top
        eigenvalue of V.
        """
        f, u = self.f, self.usable
        r_lo, r_hi = np.where(u, self.zr, np.inf).min(0), np.where(u, self.zr, -np.inf).max(0)
        b_lo, b_hi = np.where(u, self.zb, np.inf).min(0), np.where(u, self.zb, -np.inf).max(0)
        some = u.any(axis=0)
        if not some.all():  # filters without usable readings: no candidates
            r_lo, r_hi, b_lo, b_hi = (np.where(some, v, 0.0) for v in (r_lo, r_hi, b_lo, b_hi))
        d = self.lc[:, None] - f.sc
        r = np.abs(d)
        if not r.all():
            raise ParameterError("a landmark at the sensor's own position has no bearing")
        var_r, var_b = self.sensor._variances(r)
        k2 = self.gate2 * _SLACK
        lam = k2 * (f.h + np.abs(f.cbar))
        # distance of the range to [r_lo, r_hi], of the bearing to the arc [b_lo, b_hi]: to the
        # centre, less the half width (the bearing's from the centre direction, wrapped)
        gap = r - 0.5 * (r_lo + r_hi)
        np.abs(gap, out=gap)
        gap -= 0.5 * (r_hi - r_lo)
        np.maximum(gap, 0.0, out=gap)
        gap *= gap
        keep = gap <= lam + k2 * var_r
        d *= np.exp(-1j * (f.st + 0.5 * (b_lo + b_hi)))  # d turned to the centre direction
        gap = np.angle(d)
        np.abs(gap, out=gap)
        gap -= 0.5 * (b_hi - b_lo)
        np.maximum(gap, 0.0, out=gap)
        gap *= gap
        bound = np.divide(lam, r)
        bound += 2 * k2 * np.abs(f.gbar)
        bound /= r
        bound += k2 * (f.p[5] + var_b)
        keep &= gap <= bound
        keep &= some
        # Bearings measured from the hull's centre c: a reading's lies within ± half of it, a
        # candidate's within ± (half + δ), δ² = the largest bound; so a pair inside the gate
        # (|v_φ| ≤ δ) has |φ - c - (β - c)| < π unwrapped when half + δ < π, and a pair whose
        # unwrapped difference reaches π has d² ≥ π²/S_φφ > the gate either way: the grid's
        # entries inside the gate need no wrapping, and only those count (the grid is not
        # complete: leftovers are computed anew).
        centre = None
        top = np.max(bound, axis=0, where=keep, initial=0.0)
        if (0.5 * (b_hi - b_lo) + np.sqrt(top) < 0.99 * np.pi).all():
            centre = 0.5 * (b_lo + b_hi)
        return (*self._compact(keep), centre)

    # ---------------------------------------------------------------- association
    def known(self) -> tuple[IntArray, FloatArray, IntArray, AT] | None:
        """Signatures that name one landmark each, no two readings of a filter alike: each
        reading has one candidate, so no reading×landmark grid. None otherwise."""
        lsig, sig = self.lsig, self.sig
        assert lsig is not None and sig is not None
        if self.L == 1 or (lsig[1:] > lsig[:-1]).all():  # sorted already (e.g. the row numbers)
            lid = _sorted_lookup(lsig, sig)
            found = lsig[lid] == sig
        else:
            order = np.argsort(lsig, kind="stable")
            ordered = lsig[order]
            if not (ordered[1:] != ordered[:-1]).all():
                return None  # landmarks share signatures
            pos = np.minimum(np.searchsorted(ordered, sig), self.L - 1)
            found, lid = ordered[pos] == sig, order[pos]
        if not self.all_usable:
            found &= self.usable
        if self.single:
            ids = lid[found].tolist()
            if len(set(ids)) < len(ids):
                return None
        elif _clashes(np.where(found, lid, -1), self.L).any():
            return None
        p = _predict(self.f, self.lc[lid], self.sensor)
        vr = self.zr - p.r
        if self.single:
            vb = np.angle(self.ez * np.conj(p.u))
        else:  # bearings wrapped: as in the grid of nearest(), with no exp of the readings
            vb = _wrap_near(self.zb - _wrap_near(np.angle(p.u) - self.f.st))
        d2 = _mahalanobis2(p, vr, vb)
        used = found & (d2 <= self.gate2)
        landmark = np.where(found, lid, -1)
        out_d2 = np.where(found, d2, np.inf)
        status = np.where(used, USED, np.where(found, GATED, self.base))
        return landmark, out_d2, status, self._update(p, vr, vb, used)

    def nearest(self) -> tuple[IntArray, FloatArray, IntArray, AT]:
        """One to one by Mahalanobis distance (signatures optional): pairs inside the gate first,
        then the leftover readings (see the module notes)."""
        if self.single:
            return self._nearest_single()
        cand: IntArray | None = None
        ok: np.ndarray | None = None
        complete = True  # do the columns hold every landmark a usable reading may pair with?
        centre = None
        if self.m * self.L * self.B > _CANDIDATES_ABOVE:
            found = None if self.sig is None else self._signature_candidates()
            if found is None:
                *found, centre = self._gate_candidates()
                complete = False
            cand, ok = found
        p = _predict(self.f, self._landmarks(cand), self.sensor)
        bearing = _wrap_near(np.angle(p.u) - self.f.st)  # predicted bearings (C, B)
        if centre is None:
            d2 = _grid_mahalanobis2(p, bearing, self.zr, self.zb)
        else:  # bearings from the centre of the readings' (see _gate_candidates)
            d2 = _grid_mahalanobis2(
                p, _wrap_near(bearing - centre), self.zr, self.zb - centre, wrap=False
            )
        sub = d2 <= self.gate2
        self._restrict(sub, cand, ok)
        pair = _one_to_one(d2, sub)
        used = pair >= 0
        k = np.maximum(pair, 0)
        status = np.where(used, USED, self.base)
        if not used.any():  # perhaps no candidate at all
            landmark, out_d2, new = np.full(pair.shape, -1), np.full(pair.shape, np.inf), self.state
        else:
            # entry k[j, b] of (C, B) arrays, as flat indices (take is faster than a 2-D
            # fancy index)
            flat = k * self.B
            flat += self.cols

            def pick(v: np.ndarray) -> np.ndarray:
                return np.ravel(v).take(flat) if v.flags.c_contiguous else _pick(v, k, self.cols)

            columns = self._columns(cand)
            landmark = np.where(used, pick(columns), -1)
            at_d2 = np.arange(0, self.m * d2.shape[1], d2.shape[1])[:, None] * self.B + flat
            out_d2 = np.where(used, np.ravel(d2).take(at_d2), np.inf)
            # the used pairs' innovations, as in the grid
            vr = self.zr - pick(p.r)
            vb = _wrap_near(self.zb - pick(bearing))
            var_r, var_b = (v if isinstance(v, float) else pick(v) for v in (p.var_r, p.var_b))
            used_p = _Pred(None, pick(p.ir), pick(p.u), var_r, var_b, None, None, None)
            new = self._update(used_p, vr, vb, used)
        rejected = self.usable & ~used
        if rejected.any():
            self._leftovers(rejected, used, landmark, out_d2, status, d2, cand, ok, complete)
        return landmark, out_d2, status, new

    def _nearest_single(self) -> tuple[IntArray, FloatArray, IntArray, AT]:
        """:meth:`nearest` for one filter, in few numpy calls: a reading's nearest landmark is
        inside the gate if any is, so one argmin over the grid pairs the readings."""
        p = _predict(self.f, self.lc, self.sensor)
        d2, vr, vb = _innovations(p, self.zr, self.ez)
        cost = d2
        if not self.all_usable or self.sig is not None:
            allowed = np.ones(d2.shape, bool)
            self._restrict(allowed, None, None)
            cost = np.where(allowed, d2, np.inf)
        k = cost.argmin(axis=1)
        rows = np.arange(self.m)
        best = cost[rows, k]
        used = best <= self.gate2
        if _clashes(np.where(used, k, -1), self.L):
            pair = _one_to_one(np.where(cost <= self.gate2, cost, np.inf))
            used = pair >= 0
            k = np.maximum(pair, 0)
            best = cost[rows, k]
        landmark = np.where(used, k, -1)
        out_d2 = np.where(used, best, np.inf)
        status = np.where(used, USED, self.base)
        rejected = ~used if self.all_usable else self.usable & ~used
        if rejected.any():  # paired among themselves with the landmarks left, as in _leftovers
            j = np.flatnonzero(rejected)
            c = cost[j]
            nearest = c.min(axis=1)
            free = c.copy()
            free[:, k[used]] = np.inf
            pair = _one_to_one(free)
            paired = pair >= 0
            landmark[j] = pair
            out_d2[j] = np.where(paired, c[np.arange(len(j)), np.maximum(pair, 0)], nearest)
            status[j] = np.where(paired, GATED, np.where(np.isfinite(nearest), LOST, UNKNOWN))
        new = self._update(p.pick(k, None), vr[rows, k], vb[rows, k], used)
        return landmark, out_d2, status, new

    def _leftovers(
        self,
        rejected: np.ndarray,
        used: np.ndarray,
        landmark: IntArray,
        out_d2: FloatArray,
        status: IntArray,
        d2: FloatArray,
        cand: IntArray | None,
        ok: np.ndarray | None,
        complete: bool,
    ) -> None:
        """Readings of a batch not used: paired one to one, as the greedy run goes on, with the
        landmarks no used reading took (GATED), else LOST if some landmark could have matched,
        else UNKNOWN; d² to the paired or nearest landmark. Fills the outputs in place.

        The rejected readings form a flat list of columns (R), each against every landmark it
        may pair with; only filters where two of them want the same landmark run the loop.
        """
        B, L = self.B, self.L
        fb, j = np.nonzero(rejected.T)  # by filter, then reading
        R = len(j)
        F = np.flatnonzero(rejected.any(axis=0))
        taken = np.zeros((L, len(F)), bool)  # landmarks of used readings, in those filters
        uj, ub = np.nonzero(used[:, F])
        taken[landmark[uj, F[ub]], ub] = True
        pos = np.zeros(B, np.intp)
        pos[F] = np.arange(len(F))
        taken = taken[:, pos[fb]]  # (L, R)
        if complete:  # rows of the reading×candidate grid
            grid = d2[j, :, fb].T  # (C, R)
            columns = (
                np.broadcast_to(np.arange(L)[:, None], (L, R)) if cand is None else cand[:, fb]
            )
            allow = np.ones(grid.shape, bool) if ok is None else ok[:, fb]
        else:  # those readings against every landmark, computed now
            f = self.f.take(fb)
            p = _predict(f, self.lc[:, None], self.sensor)  # (L, R)
            vb = np.angle(np.exp(1j * (self.zb[j, fb] + f.st)) * np.conj(p.u))
            grid = _mahalanobis2(p, self.zr[j, fb] - p.r, vb)
            columns = np.broadcast_to(np.arange(L)[:, None], (L, R))
            allow = np.ones(grid.shape, bool)
        if self.sig is not None:
            allow &= self.sig[j, fb] == self.lsig[columns]  # type: ignore[index]
        cost = np.where(allow & ~taken[columns, np.arange(R)], grid, np.inf)
        k = cost.argmin(axis=0)
        rr = np.arange(R)
        pair = np.where(np.isfinite(cost[k, rr]), k, -1)
        # several of one filter wanting one landmark: those filters run the greedy loop
        lid = columns[k, rr]
        paired = pair >= 0
        key = fb[paired] * L + lid[paired]
        clash = np.zeros(B, bool)
        clash[fb[paired][np.bincount(key, minlength=B * L)[key] > 1]] = True
        if clash.any():
            mine = np.flatnonzero(clash[fb])  # their rows, by filter then reading
            rank = mine - np.searchsorted(fb, fb[mine])  # of a row within its filter
            col = np.cumsum(clash) - 1  # the filter's place among them
            at = (rank, col[fb[mine]])
            padded = np.full((int(rank.max()) + 1, cost.shape[0], int(clash.sum())), np.inf)
            padded[rank, :, at[1]] = cost[:, mine].T
            pair[mine] = _greedy(padded)[at]
            paired = pair >= 0
        kk = np.maximum(pair, 0)
        nearest = np.where(allow, grid, np.inf).min(axis=0, initial=np.inf)
        landmark[j, fb] = np.where(paired, columns[kk, rr], -1)
        out_d2[j, fb] = np.where(paired, grid[kk, rr], nearest)
        status[j, fb] = np.where(paired, GATED, np.where(allow.any(axis=0), LOST, UNKNOWN))

    def general(
        self, associate: Association, pairing: Pairing
    ) -> tuple[IntArray, FloatArray, IntArray, AT]:
        """Euclidean association or the lecture's Eq. 21, on the full reading×landmark grid."""
        p = _predict(self.f, self._landmarks(None), self.sensor)
        d2, vr, vb = _innovations(p, self.zr, self.ez)
        allowed = np.ones(d2.shape, bool)
        self._restrict(allowed, None, None)
        cost = np.where(allowed, vr * vr + vb * vb if associate == "euclidean" else d2, np.inf)
        could = allowed.any(axis=1)
        gate2, cols = self.gate2, self.cols
        if pairing == "per_landmark":
            # Eq. 21: each landmark takes its nearest reading; a reading may serve several
            best = cost.argmin(axis=0)  # (L, …)
            at_best = (
                (best, np.arange(self.L))
                if self.single
                else (best, np.arange(self.L)[:, None], cols)
            )
            reach = np.isfinite(cost[at_best])
            use_l = reach & (d2[at_best] <= gate2)
            gated_l = reach & ~use_l
            chosen = best == np.arange(self.m).reshape((-1,) + (1,) * best.ndim)  # (m, L, …)
            served, refused = chosen & use_l, chosen & gated_l
            used_r = served.any(axis=1)
            gated_r = refused.any(axis=1) & ~used_r
            landmark = np.where(
                used_r, served.argmax(axis=1), np.where(gated_r, refused.argmax(axis=1), -1)
            )
            status = np.where(
                used_r, USED, np.where(gated_r, GATED, np.where(could, LOST, self.base))
            )
            out_d2 = np.where(landmark >= 0, _at(d2, np.maximum(landmark, 0), cols), np.inf)
            new = self._update(p, vr[at_best], vb[at_best], use_l)
            return landmark, out_d2, status, new
        pair = _one_to_one(cost)
        paired = pair >= 0
        k = np.maximum(pair, 0)
        pair_d2 = _at(d2, k, cols)
        used = paired & (pair_d2 <= gate2)
        status = np.where(used, USED, np.where(paired, GATED, np.where(could, LOST, self.base)))
        out_d2 = np.where(paired, pair_d2, np.where(allowed, d2, np.inf).min(axis=1))
        new = self._update(p.pick(k, cols), _at(vr, k, cols), _at(vb, k, cols), used)
        return np.where(paired, pair, -1), out_d2, status, new

    # ---------------------------------------------------------------- update
    def _update(self, p: _Pred, vr: FloatArray, vb: FloatArray, use: np.ndarray) -> AT:
        """The stacked update (Eqs. 26-28, Joseph form) over the pairs (n, …) marked ``use``:
        innovations ``(vr, vb)`` and their landmarks' predictions ``p`` (n, …).

        3×3 algebra (see the module notes), except for ill-conditioned filters and a sensor
        without noise: those take the 2n×2n solve.
        """
        if not use.any():
            return self.state
        if self.sensor.sigma_range == 0 or self.sensor.sigma_bearing == 0:
            mean, cov = self._update_stacked(p, vr, vb, use, None)
        elif self.single:  # as _correct_one does it
            new = _update_one(self.f, _pairs_one(p, vr, vb, use))
            if new is not None:
                return new
            mean, cov = self._update_stacked(p, vr, vb, use, None)
        else:
            mean, cov, ill = self._update_3x3(p, vr, vb, use)
            if ill.any():
                F = np.flatnonzero(ill)
                mean[F], cov[F] = self._update_stacked(p, vr, vb, use, F)
        return AT._trusted(mean.reshape(*self.batch, 3), cov.reshape(*self.batch, 3, 3))

    def _update_3x3(
        self, p: _Pred, vr: FloatArray, vb: FloatArray, use: np.ndarray
    ) -> tuple[FloatArray, FloatArray, np.ndarray]:
        """Mean (B, 3), covariance (B, 3, 3) and which filters are ill-conditioned."""
        w0 = use / p.var_r  # R⁻¹, zero for pairs not used
        w1 = use / p.var_b
        ir, u = p.ir, p.u
        wq, wr, e0, e2 = w1 * ir * ir, w1 * ir, w0 * vr, w1 * vb
        e1 = e2 * ir
        s_a, n1, s2 = (w0 + wq).sum(axis=0), w1.sum(axis=0), e2.sum(axis=0)
        s_w, s_u, s_d = (
            (a * b).sum(axis=0) for a, b in ((w0 - wq, u * u), (wr, u), (e0 + 1j * e1, u))
        )
        f = self.f
        dx, cov, trace = _posterior_stacked(f, (s_a, n1, s2, s_w, s_u, s_d))
        mean = np.empty((3, self.B))
        np.add(f.x, dx[0], out=mean[0])
        np.add(f.y, dx[1], out=mean[1])
        mean[2] = se2.wrap_angle(f.t + dx[2])
        return mean.T, np.moveaxis(cov, 2, 0), ~(trace <= _ILL_CONDITIONED)

    def _update_stacked(
        self, p: _Pred, vr: FloatArray, vb: FloatArray, use: np.ndarray, F: IntArray | None
    ) -> tuple[FloatArray, FloatArray]:
        """The textbook stacked update (a 2n×2n solve) of filters F (None: all)."""
        f, mean, P = self.f, self.mean, self.cov
        if F is not None:
            p, f, mean, P = p.take(F), f.take(F), mean[F], P[F]
            vr, vb, use = vr[:, F], vb[:, F], use[:, F]
        ax, ay, ux, uy, ir = f.ax, f.ay, p.u.real, p.u.imag, p.ir
        rows = (
            (-ux, -uy, ux * ay - uy * ax),
            (uy * ir, -ux * ir, -(uy * ay + ux * ax) * ir - 1.0),
        )
        n = use.shape[0]
        lead = mean.shape[:-1]
        H = np.empty((*lead, n, 2, 3))
        for a in range(2):
            for c in range(3):
                H[..., a, c] = np.where(use, rows[a][c], 0.0).T
        v = np.stack([np.where(use, vr, 0.0).T, np.where(use, vb, 0.0).T], axis=-1)
        Rd = np.stack([np.where(use, p.var_r, 1.0).T, np.where(use, p.var_b, 1.0).T], axis=-1)
        Hs = H.reshape(*lead, 2 * n, 3)
        Rs = np.zeros((*lead, 2 * n, 2 * n))
        i = np.arange(2 * n)
        Rs[..., i, i] = Rd.reshape(*lead, 2 * n)
        PHt = P @ np.swapaxes(Hs, -1, -2)
        S = Hs @ PHt + Rs  # Eq. 27's H Σ⁻ Hᵀ + R
        K = np.swapaxes(np.linalg.solve(S, np.swapaxes(PHt, -1, -2)), -1, -2)  # Σ⁻ Hᵀ S⁻¹
        new_mean = se2.plus(mean, np.einsum("...ij,...j->...i", K, v.reshape(*lead, 2 * n)))
        I_KH = np.eye(3) - K @ Hs
        cov = I_KH @ P @ np.swapaxes(I_KH, -1, -2) + K @ Rs @ np.swapaxes(K, -1, -2)
        return new_mean, 0.5 * (cov + np.swapaxes(cov, -1, -2))

    # ---------------------------------------------------------------- results
    def finish(
        self, landmark: IntArray, out_d2: FloatArray, status: IntArray, new: AT
    ) -> LandmarkUpdate:
        """Back to the caller's layout: (…, m) arrays."""
        if not self.single:
            shape = (*self.batch, self.m)
            landmark, out_d2, status = (
                np.ascontiguousarray(a.T).reshape(shape) for a in (landmark, out_d2, status)
            )
        return LandmarkUpdate(new, landmark.astype(np.int64), out_d2, status.astype(np.int64))


# ------------------------------------------------------------------ one filter
# One filter (a single state, readings (m, 2), one to one) takes its own path: with about ten
# readings, a numpy call (about a microsecond) costs as much as dozens of operations on Python
# floats, so the readings are handled one by one in Python numbers — the formulas of _predict,
# _innovations and _mahalanobis2 pair by pair, the sums of A = HᵀR⁻¹H and b = HᵀR⁻¹v pair by
# pair and the 3×3 algebra of the update written out (_update_one).
# - Known association: each reading's one landmark, looked up in a dict of the signatures.
# - Nearest neighbour (constant sensor noise): a landmark l can be inside the gate of a reading
#   (ρ, φ) only if it lies within a disc around the reading's point p = s + ρ e^{i(φ + θs)}
#   (s, θs: the sensor): with ρ_l, β_l its range and bearing, |l - p|² = (ρ_l - ρ)² +
#   4 ρ_l ρ sin²((β_l - φ - θs)/2) ≤ v_r² + ρ_l ρ v_φ², and inside the gate v_r² ≤ k² S_rr ≤
#   k² (λ + σr²) = τ² and v_φ² ≤ k² S_φφ ≤ k² ((λ/ρ_l + 2|g|)/ρ_l + Σθθ + σφ²) (the bounds of
#   _Job._gate_candidates), with ρ_l within ρ ± τ. The landmarks in a disc are found by
#   bisection in the map sorted by x (cached with the map); d² is computed for those only
#   (about one per reading), and the nearest inside the gate is taken (ties to the lowest row,
#   as argmin).
#   Readings with no landmark inside the gate get their full row of d² (numpy), and the pairing
#   among them goes on as in _Job._nearest_single.
# Anything out of the ordinary (input to validate or reject, shared or non-integer signatures, a
# signature read twice, a sensor without noise, nearest neighbour with range-dependent noise,
# an ill-conditioned update) returns None: the general path then runs.

_CACHE_SIZE = 16
# Relative widening of the discs, far above the rounding of their radii and distances.
_DISC_SLACK = 1e-9


class _Map(NamedTuple):
    """A landmark map as the single-filter path uses it (cached by content)."""

    lc: np.ndarray  # complex positions (L,)
    points: list[complex]
    at: frozenset[complex]  # the positions, to tell a landmark at the sensor
    xs: list[float]  # the landmarks' x, increasing
    by_x: list[int]  # their rows in that order


_MAPS: dict[bytes, _Map] = {}
_LAST_MAP: list[tuple[bytes | None, _Map | None]] = [(None, None)]  # the last call's
# integer landmark signatures (dtype number, bytes) → {signature: row}, None when shared
_SIGNATURE_ROWS: dict[tuple[int, bytes], dict[int, int] | None] = {}
_LAST_ROWS: list[tuple[tuple | None, dict[int, int] | None]] = [(None, None)]


def _landmark_map(lm: FloatArray) -> _Map | None:
    """The landmarks ``(L, 2)`` for the single-filter path; None if not finite."""
    key = lm.tobytes()
    last_key, last = _LAST_MAP[0]  # one tuple: consistent under threads
    if last_key == key:  # the same map as last time (compared, not hashed)
        return last
    hit = _MAPS.get(key)
    if hit is None:
        if not np.isfinite(lm).all():
            return None
        lc = np.ascontiguousarray(lm).view(np.complex128)[:, 0].copy()
        lc.flags.writeable = False
        points = lc.tolist()
        by_x = np.argsort(lm[:, 0], kind="stable")
        hit = _Map(lc, points, frozenset(points), lm[by_x, 0].tolist(), by_x.tolist())
        if len(_MAPS) >= _CACHE_SIZE:
            _MAPS.clear()
        _MAPS[key] = hit
    _LAST_MAP[0] = (key, hit)
    return hit


def _signature_rows(lsig: np.ndarray) -> dict[int, int] | None:
    """Integer landmark signatures → {signature: row}, cached by content; None if shared."""
    key = (lsig.dtype.num, lsig.tobytes())
    last_key, last = _LAST_ROWS[0]
    if last_key == key:
        return last
    if key in _SIGNATURE_ROWS:
        out = _SIGNATURE_ROWS[key]
        _LAST_ROWS[0] = (key, out)
        return out
    values = lsig.tolist()
    rows = dict(zip(values, range(len(values)), strict=True))
    out = rows if len(rows) == len(values) else None
    if len(_SIGNATURE_ROWS) >= _CACHE_SIZE:
        _SIGNATURE_ROWS.clear()
    _SIGNATURE_ROWS[key] = out
    _LAST_ROWS[0] = (key, out)
    return out


def _correct_one(
    state: AT,
    readings: ArrayLike,
    sensor: RangeBearingSensor,
    landmarks: ArrayLike,
    associate: str,
    signatures: ArrayLike | None,
    landmark_signatures: ArrayLike | None,
    gate: float,
    valid: ArrayLike | None,
) -> LandmarkUpdate | None:
    """:func:`correct_landmarks` of one filter, one to one (see the notes above), or None."""
    if not (isinstance(gate, float) and 0.0 < gate < 1.0):
        return None
    if associate not in ("signatures", "mahalanobis") or not isinstance(sensor, RangeBearingSensor):
        return None
    if not (sensor.sigma_range > 0.0 and sensor.sigma_bearing > 0.0):
        return None
    inputs = _single_inputs(readings, landmarks, valid)
    if inputs is None:
        return None
    z, lm, v = inputs
    m, L = len(z), len(lm)
    present = None if v is None else v.tolist()
    lmap = _landmark_map(lm)
    if lmap is None:
        return None
    zl = z.tolist()
    status = [UNKNOWN] * m
    usable = []
    for j, (r, b) in enumerate(zl):
        if present is not None and not present[j]:
            status[j] = ABSENT
        elif 0.0 < r < math.inf and -math.inf < b < math.inf:
            usable.append(j)
        else:
            status[j] = INVALID
    known = signatures is not None or associate == "signatures"
    if known:
        if signatures is None or landmark_signatures is None:
            return None
        lsig, sig = np.asarray(landmark_signatures), np.asarray(signatures)
        if lsig.shape != (L,) or sig.shape != (m,):
            return None
        if lsig.dtype.kind not in "iu" or sig.dtype.kind not in "iu":
            return None
        rows = _signature_rows(lsig)
        if rows is None:
            return None
        sl = sig.tolist()
        cand = []
        for j in usable:
            k = rows.get(sl[j])
            if k is not None:
                cand.append((j, k))
        if len({k for _, k in cand}) < len(cand):
            return None  # a signature read twice: the general path pairs by distance
    elif sensor.noise_model != "constant":
        return None
    f = _frame_one(state, sensor)
    if f.sc in lmap.at:
        return None  # a landmark at the sensor: the general path raises
    gate2 = _gate2(gate)
    ez: dict[int, complex] = {}
    if not known:
        cand = _disc_candidates(f, zl, usable, lmap, sensor, gate2, ez)
    landmark, out_d2 = [-1] * m, [math.inf] * m
    pairs = _exact_pairs(f, zl, cand, lmap.points, sensor, ez)
    if pairs is None:
        return None
    used: list[tuple] = []
    if known:
        for j, k, d2, pair in pairs:
            landmark[j], out_d2[j] = k, d2
            if d2 <= gate2:
                status[j] = USED
                used.append(pair)
            else:
                status[j] = GATED
    else:
        used = _pair_nearest(f, z, usable, lmap, sensor, gate2, pairs, landmark, out_d2, status)
    new = state
    if used:
        new = _update_one(f, used)  # type: ignore[assignment]
        if new is None:
            return None
    ints = np.array(landmark + status, np.int64)
    return LandmarkUpdate(new, ints[:m], np.array(out_d2), ints[m:])


def _frame_one(state: AT, sensor: RangeBearingSensor) -> _Frame:
    """:meth:`_Frame.build` for one filter."""
    x, y, t = state.mean.tolist()
    (p00, p01, p02), (_, p11, p12), (_, _, p22) = state.cov.tolist()
    c, s = math.cos(t), math.sin(t)
    mx, my, mt = sensor.mount.tolist()
    ax, ay = c * mx - s * my, s * mx + c * my
    v00 = p00 - 2 * ay * p02 + ay * ay * p22
    v01 = p01 + ax * p02 - ay * p12 - ax * ay * p22
    v11 = p11 + 2 * ax * p12 + ax * ax * p22
    return _Frame(
        x, y, t, (p00, p01, p02, p11, p12, p22), ax, ay, complex(x + ax, y + ay),
        _wrap_scalar(t + mt), 0.5 * (v00 + v11), complex(0.5 * (v00 - v11), -v01),
        complex(p02 - ay * p22, -(p12 + ax * p22)),
    )  # fmt: skip


def _disc_candidates(
    f: _Frame,
    zl: list[list[float]],
    usable: list[int],
    lmap: _Map,
    sensor: RangeBearingSensor,
    gate2: float,
    ez: dict[int, complex],
) -> list[tuple[int, int]]:
    """(reading, landmark) pairs that may lie inside the gate: the landmarks in each reading's
    disc (see the notes above), by reading then landmark. Fills ``ez`` with the readings'
    directions ``exp(i(φ + θs))``."""
    if not usable:
        return []
    k2 = gate2 * _SLACK
    var_r, var_b = sensor.sigma_range**2, sensor.sigma_bearing**2
    lam = max(f.h + abs(f.cbar), 0.0)
    g2 = 2.0 * abs(f.gbar)
    pb = f.p[5] + var_b
    tau2 = k2 * (lam + var_r)
    tau = math.sqrt(tau2)
    sx, sy, st = f.sc.real, f.sc.imag, f.st
    grow = 1.0 + _DISC_SLACK
    points, xs, by_x = lmap.points, lmap.xs, lmap.by_x
    out = []
    for j in usable:
        r, b = zl[j]
        e = ez[j] = cmath.rect(1.0, b + st)
        p = complex(sx + r * e.real, sy + r * e.imag)
        lo = r - tau
        disc = r + r + tau
        disc *= disc  # |l - p| ≤ |l - s| + |s - p| ≤ (ρ + τ) + ρ
        if lo > 0.0:
            near = tau2 + r * k2 * (lam / lo + g2 + (r + tau) * pb)
            if near < disc:
                disc = near
        disc *= grow
        R = math.sqrt(disc)
        # the landmarks within R of p in x (sorted by x), then in the disc
        found = []
        for k in by_x[bisect.bisect_left(xs, p.real - R) : bisect.bisect_right(xs, p.real + R)]:
            d = points[k] - p
            if d.real * d.real + d.imag * d.imag <= disc:
                found.append(k)
        if len(found) > 1:
            found.sort()
        for k in found:
            out.append((j, k))
    return out


def _exact_pairs(
    f: _Frame,
    zl: list[list[float]],
    cand: list[tuple[int, int]],
    points: list[complex],
    sensor: RangeBearingSensor,
    ez: dict[int, complex],
) -> list[tuple[int, int, float, tuple]] | None:
    """``(reading, landmark, d², update pair)`` of the candidate pairs: :func:`_predict` and
    :func:`_innovations` in Python numbers; None if some S is not positive definite. ``ez``:
    the readings' ``exp(i(φ + θs))`` known so far (completed here)."""
    sc, st, h, cbar, gbar = f.sc, f.st, f.h, f.cbar, f.gbar
    p22, h2 = f.p[5], 2.0 * f.h
    model = sensor.noise_model
    sr, sb = sensor.sigma_range, sensor.sigma_bearing
    var_r, var_b = sr**2, sb**2
    out = []
    for j, k in cand:
        zr, zb = zl[j]
        e = ez.get(j)
        if e is None:
            a = zb + st
            e = ez[j] = cmath.rect(1.0, a)
        d = points[k] - sc
        r = abs(d)
        if r == 0.0:
            return None
        ir = 1.0 / r
        u = d * ir
        cw = cbar * (u * u)
        gu = gbar * u
        if model != "constant":
            scale = r if model == "proportional" else r * r
            var_r, var_b = (sr * scale) ** 2, (sb * scale) ** 2
        uvu = h + cw.real
        s00 = uvu + var_r
        s01 = gu.real - cw.imag * ir
        s11 = ((h2 - uvu) * ir - 2 * gu.imag) * ir + (p22 + var_b)
        det = s00 * s11 - s01 * s01
        if not (det > 0.0 and s11 > 0.0):
            return None
        w = e * u.conjugate()
        vr, vb = zr - r, math.atan2(w.imag, w.real)
        x = vr - s01 / s11 * vb  # d² = x² s11/det + v_φ²/s11: S⁻¹ factored as in _predict
        out.append((j, k, x * x * (s11 / det) + vb * vb / s11, (ir, u, vr, vb, var_r, var_b)))
    return out


def _pair_nearest(
    f: _Frame,
    z: FloatArray,
    usable: list[int],
    lmap: _Map,
    sensor: RangeBearingSensor,
    gate2: float,
    pairs: list[tuple[int, int, float, tuple]],
    landmark: list[int],
    out_d2: list[float],
    status: list[int],
) -> list[tuple]:
    """One to one by Mahalanobis distance as :meth:`_Job._nearest_single` pairs, from the
    candidate pairs' d²: fills the outputs, returns the used pairs for the update."""
    inside = [q for q in pairs if q[2] <= gate2]
    best: dict[int, tuple] = {}
    for q in inside:  # by reading, then landmark: the first of equal d² stays, as argmin
        b = best.get(q[0])
        if b is None or q[2] < b[2]:
            best[q[0]] = q
    chosen = list(best.values())
    if len({q[1] for q in chosen}) < len(chosen):  # two want one landmark: the greedy pairing
        cost = np.full((len(z), len(lmap.points)), np.inf)
        for j, k, d2, _ in inside:
            cost[j, k] = d2
        pair = _one_to_one(cost).tolist()
        chosen = [q for q in inside if pair[q[0]] == q[1]]
    for j, k, d2, _ in chosen:
        landmark[j], out_d2[j], status[j] = k, d2, USED
    if len(chosen) < len(usable):  # the others, as in _Job._nearest_single
        taken = {q[0] for q in chosen}
        rej = np.array([j for j in usable if j not in taken])
        p = _predict(f, lmap.lc, sensor)
        c, _, _ = _innovations(p, z[rej, 0], np.exp(1j * (z[rej, 1] + f.st)))
        nearest = c.min(axis=1)
        free = c.copy()
        free[:, [q[1] for q in chosen]] = np.inf
        pair = _one_to_one(free)
        paired = pair >= 0
        got = np.where(paired, c[np.arange(len(rej)), np.maximum(pair, 0)], nearest)
        st = np.where(paired, GATED, np.where(np.isfinite(nearest), LOST, UNKNOWN))
        for j, pj, gj, sj in zip(
            rej.tolist(), pair.tolist(), got.tolist(), st.tolist(), strict=True
        ):
            landmark[j], out_d2[j], status[j] = pj, gj, sj
    return [q[3] for q in chosen]


def _pairs_one(p: _Pred, vr: FloatArray, vb: FloatArray, use: np.ndarray) -> list[tuple]:
    """The used pairs of one filter (arrays (m,)) as :func:`_update_one` takes them."""
    idx = np.flatnonzero(use)
    n = len(idx)
    var_r, var_b = p.var_r, p.var_b
    var_r = var_r[idx].tolist() if isinstance(var_r, np.ndarray) else [var_r] * n
    var_b = var_b[idx].tolist() if isinstance(var_b, np.ndarray) else [var_b] * n
    return list(zip(p.ir[idx].tolist(), p.u[idx].tolist(), vr[idx].tolist(), vb[idx].tolist(),
                    var_r, var_b, strict=True))  # fmt: skip


def _update_one(f: _Frame, pairs: list[tuple]) -> AT | None:
    """The 3×3 update (:func:`_posterior_stacked`, written out on Python floats) of one filter
    from its used pairs ``(1/ρ, u, v_r, v_φ, σr², σφ²)``; None when ill-conditioned (the
    stacked solve's case)."""
    s_a = n1 = s2 = 0.0
    s_w = s_u = s_d = 0j
    for ir, u, vr, vb, var_r, var_b in pairs:
        w0, w1 = 1.0 / var_r, 1.0 / var_b
        wq, e2 = w1 * ir * ir, w1 * vb
        s_a += w0 + wq
        n1 += w1
        s2 += e2
        s_w += (w0 - wq) * (u * u)
        s_u += (w1 * ir) * u
        s_d += complex(w0 * vr, e2 * ir) * u
    a00, a11, a01 = 0.5 * (s_a + s_w.real), 0.5 * (s_a - s_w.real), 0.5 * s_w.imag
    c0, c1, b0, b1 = s_u.imag, -s_u.real, -s_d.real, -s_d.imag
    ax, ay = f.ax, f.ay
    a02 = -ay * a00 + ax * a01 - c0
    a12 = -ay * a01 + ax * a11 - c1
    a22 = ay * ay * a00 - 2 * ax * ay * a01 + ax * ax * a11 - 2 * (ax * c1 - ay * c0) + n1
    b2 = ax * b1 - ay * b0 - s2
    p00, p01, p02, p11, p12, p22 = f.p
    # M = I + A Σ⁻
    m00 = a00 * p00 + a01 * p01 + a02 * p02
    m11 = a01 * p01 + a11 * p11 + a12 * p12
    m22 = a02 * p02 + a12 * p12 + a22 * p22
    if not m00 + m11 + m22 <= _ILL_CONDITIONED:
        return None
    m00 += 1.0
    m11 += 1.0
    m22 += 1.0
    m01 = a00 * p01 + a01 * p11 + a02 * p12
    m02 = a00 * p02 + a01 * p12 + a02 * p22
    m10 = a01 * p00 + a11 * p01 + a12 * p02
    m12 = a01 * p02 + a11 * p12 + a12 * p22
    m20 = a02 * p00 + a12 * p01 + a22 * p02
    m21 = a02 * p01 + a12 * p11 + a22 * p12
    # W = M⁻¹ by the adjugate (det M ≥ 1)
    i00, i10, i20 = m11 * m22 - m12 * m21, m12 * m20 - m10 * m22, m10 * m21 - m11 * m20
    rd = 1.0 / (m00 * i00 + m01 * i10 + m02 * i20)
    w00, w01, w02 = i00 * rd, (m02 * m21 - m01 * m22) * rd, (m01 * m12 - m02 * m11) * rd
    w10, w11, w12 = i10 * rd, (m00 * m22 - m02 * m20) * rd, (m02 * m10 - m00 * m12) * rd
    w20, w21, w22 = i20 * rd, (m01 * m20 - m00 * m21) * rd, (m00 * m11 - m01 * m10) * rd
    # G = Σ⁻ W
    g00, g01, g02 = (p00 * w00 + p01 * w10 + p02 * w20, p00 * w01 + p01 * w11 + p02 * w21,
                     p00 * w02 + p01 * w12 + p02 * w22)  # fmt: skip
    g10, g11, g12 = (p01 * w00 + p11 * w10 + p12 * w20, p01 * w01 + p11 * w11 + p12 * w21,
                     p01 * w02 + p11 * w12 + p12 * w22)  # fmt: skip
    g20, g21, g22 = (p02 * w00 + p12 * w10 + p22 * w20, p02 * w01 + p12 * w11 + p22 * w21,
                     p02 * w02 + p12 * w12 + p22 * w22)  # fmt: skip
    # K v = Σ⁻ y with M y = b, refined once
    y0 = w00 * b0 + w01 * b1 + w02 * b2
    y1 = w10 * b0 + w11 * b1 + w12 * b2
    y2 = w20 * b0 + w21 * b1 + w22 * b2
    r0 = b0 - (m00 * y0 + m01 * y1 + m02 * y2)
    r1 = b1 - (m10 * y0 + m11 * y1 + m12 * y2)
    r2 = b2 - (m20 * y0 + m21 * y1 + m22 * y2)
    y0, y1, y2 = (y0 + (w00 * r0 + w01 * r1 + w02 * r2), y1 + (w10 * r0 + w11 * r1 + w12 * r2),
                  y2 + (w20 * r0 + w21 * r1 + w22 * r2))  # fmt: skip
    # K H = G A, and the Joseph form (I - GA) Σ⁻ (I - GA)ᵀ + GA Gᵀ
    k00, k01, k02 = (g00 * a00 + g01 * a01 + g02 * a02, g00 * a01 + g01 * a11 + g02 * a12,
                     g00 * a02 + g01 * a12 + g02 * a22)  # fmt: skip
    k10, k11, k12 = (g10 * a00 + g11 * a01 + g12 * a02, g10 * a01 + g11 * a11 + g12 * a12,
                     g10 * a02 + g11 * a12 + g12 * a22)  # fmt: skip
    k20, k21, k22 = (g20 * a00 + g21 * a01 + g22 * a02, g20 * a01 + g21 * a11 + g22 * a12,
                     g20 * a02 + g21 * a12 + g22 * a22)  # fmt: skip
    j00, j01, j02, j10, j11, j12, j20, j21, j22 = (
        1.0 - k00,
        -k01,
        -k02,
        -k10,
        1.0 - k11,
        -k12,
        -k20,
        -k21,
        1.0 - k22,
    )
    t00, t01, t02 = (j00 * p00 + j01 * p01 + j02 * p02, j00 * p01 + j01 * p11 + j02 * p12,
                     j00 * p02 + j01 * p12 + j02 * p22)  # fmt: skip
    t10, t11, t12 = (j10 * p00 + j11 * p01 + j12 * p02, j10 * p01 + j11 * p11 + j12 * p12,
                     j10 * p02 + j11 * p12 + j12 * p22)  # fmt: skip
    t20, t21, t22 = (j20 * p00 + j21 * p01 + j22 * p02, j20 * p01 + j21 * p11 + j22 * p12,
                     j20 * p02 + j21 * p12 + j22 * p22)  # fmt: skip
    c00 = (t00 * j00 + t01 * j01 + t02 * j02) + (k00 * g00 + k01 * g01 + k02 * g02)
    c01 = (t00 * j10 + t01 * j11 + t02 * j12) + (k00 * g10 + k01 * g11 + k02 * g12)
    c02 = (t00 * j20 + t01 * j21 + t02 * j22) + (k00 * g20 + k01 * g21 + k02 * g22)
    c11 = (t10 * j10 + t11 * j11 + t12 * j12) + (k10 * g10 + k11 * g11 + k12 * g12)
    c12 = (t10 * j20 + t11 * j21 + t12 * j22) + (k10 * g20 + k11 * g21 + k12 * g22)
    c22 = (t20 * j20 + t21 * j21 + t22 * j22) + (k20 * g20 + k21 * g21 + k22 * g22)
    return AT._single([
        f.x + (p00 * y0 + p01 * y1 + p02 * y2),
        f.y + (p01 * y0 + p11 * y1 + p12 * y2),
        _wrap_scalar(f.t + (p02 * y0 + p12 * y1 + p22 * y2)),
        c00, c01, c02, c11, c12, c22,
    ])  # fmt: skip


def _posterior_stacked(f: _Frame, sums: tuple[Value, ...]) -> tuple[FloatArray, ...]:
    """``(Δmean (3, B), covariance (3, 3, B), tr(AΣ⁻) (B,))`` of the 3×3 update from the sums
    over the used pairs, per filter (arrays (B,); :func:`_update_one` for one filter), its 3×3
    matrices stacked as (3, 3, B) arrays (a few numpy calls per product).

    H₀ = -E u, H₁ = E u⊥/ρ - (0, 0, 1): A = HᵀR⁻¹H and b = HᵀR⁻¹v reduce to weighted sums over
    the pairs (u as a complex number, u⊥ = -iu), mapped through E per filter: Q = Σ w0 uuᵀ +
    wq u⊥u⊥ᵀ from ``s_a = Σ (w0 + wq)`` and ``s_w = Σ (w0 - wq) u²``, ``c = Σ wr u⊥`` from
    ``s_u = Σ wr u``, ``d = Σ e1 u⊥ - e0 u`` from ``s_d = Σ (e0 + i e1) u``, ``n1 = Σ w1``,
    ``s2 = Σ e2``; then A = E Q Eᵀ - (E c) kᵀ - k (E c)ᵀ + n1 kkᵀ, b = E d - k s2 (w0, w1 the
    weights R⁻¹, wq = w1/ρ², wr = w1/ρ, e0 = w0 v_r, e2 = w1 v_φ, e1 = e2/ρ).
    """
    s_a, n1, s2, s_w, s_u, s_d = sums
    q00, q11, q01 = 0.5 * (s_a + s_w.real), 0.5 * (s_a - s_w.real), 0.5 * s_w.imag
    c0, c1, d0, d1 = s_u.imag, -s_u.real, -s_d.real, -s_d.imag
    ax, ay = f.ax, f.ay
    a02 = -ay * q00 + ax * q01 - c0
    a12 = -ay * q01 + ax * q11 - c1
    a22 = ay * ay * q00 - 2 * ax * ay * q01 + ax * ax * q11 - 2 * (ax * c1 - ay * c0) + n1
    A = _sym3((q00, q01, a02, q11, a12, a22))
    P = _sym3(f.p)
    bv = np.stack([d0, d1, ax * d1 - ay * d0 - s2])
    M = _mm3(A, P)
    trace = M[0, 0] + M[1, 1] + M[2, 2]
    for i in range(3):
        M[i, i] += 1.0  # I + A Σ⁻
    W = _inv3_stacked(M)
    G = _mm3(P, W)
    # K v = Σ⁻ y with M y = b, refined once
    y = _mv3(W, bv)
    y += _mv3(W, bv - _mv3(M, y))
    dx = _mv3(P, y)
    # Joseph form with K H = G A formed from G: an exact Joseph form of the gain actually
    # computed, so that rounding in W enters the covariance only to second order
    GA = _mm3(G, A)
    J = np.negative(GA)
    for i in range(3):
        J[i, i] += 1.0  # I - K H
    cov = _abt3(_mm3(J, P), J)
    cov += _abt3(GA, G)
    for i, j in ((0, 1), (0, 2), (1, 2)):
        cov[j, i] = cov[i, j]  # exactly symmetric
    return dx, cov, trace


def _sym3(p: tuple[FloatArray, ...]) -> FloatArray:
    """The symmetric (3, 3, B) matrix of upper entries ``(00, 01, 02, 11, 12, 22)``."""
    out = np.empty((3, 3, len(p[0])))
    for (i, j), v in zip(((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)), p, strict=True):
        out[i, j] = v
        out[j, i] = v
    return out


def _mm3(X: FloatArray, Y: FloatArray) -> FloatArray:
    """``X Y`` of (3, 3, B) stacks."""
    return (X[:, :, None] * Y[None]).sum(axis=1)


def _mv3(X: FloatArray, v: FloatArray) -> FloatArray:
    """``X v`` of a (3, 3, B) stack and a (3, B) stack."""
    return (X * v[None]).sum(axis=1)


def _abt3(X: FloatArray, Y: FloatArray) -> FloatArray:
    """``X Yᵀ`` of (3, 3, B) stacks."""
    return (X[:, None] * Y[None]).sum(axis=2)


_NEXT, _AFTER = [1, 2, 0], [2, 0, 1]


def _inv3_stacked(M: FloatArray) -> FloatArray:
    """Inverse of a (3, 3, B) stack by the adjugate (on ``I + AΣ``: determinant at least 1):
    column i is ``row(i+1) × row(i+2)`` over the determinant."""
    N1, N2 = M[_NEXT], M[_AFTER]  # rows i+1 and i+2
    C = N1[:, _NEXT] * N2[:, _AFTER]
    C -= N1[:, _AFTER] * N2[:, _NEXT]  # C[i] = row(i+1) × row(i+2)
    r = 1.0 / (M[0] * C[0]).sum(axis=0)
    C *= r
    return C.transpose(1, 0, 2)


# ------------------------------------------------------------------ compiled (numba)
# With numba (relmap._numba.enabled()), correct_landmarks' one-to-one association by signatures
# or Mahalanobis distance runs in relmap._ekf_kernels: one kernel call per correction, of one
# filter or of a whole batch (the loop over filters inside). Those kernels compute what
# _correct_one computes, formula by formula; anything they do not cover (Euclidean distance,
# Eq. 21, a sensor without noise, signatures that are not integers int64 holds) and anything
# they leave to numpy (a landmark at the sensor, an ill-conditioned update, an innovation
# covariance not positive definite) takes the paths above.

_NOISE_MODELS = {"constant": 0.0, "proportional": 1.0, "quadratic": 2.0}
_NO_BOOL = np.zeros(0, np.bool_)
_NO_INT = np.zeros(0, np.int64)


@functools.cache
def _kernels() -> Any:
    from relmap import _ekf_kernels  # imports numba: only when relmap._numba.enabled()

    return _ekf_kernels


def _kernel_sensor(sensor: RangeBearingSensor, gate: float) -> FloatArray | None:
    """The kernels' parameters ``(mount x, y, θ, σr, σφ, noise model, χ²₂(gate))``, or None."""
    if not isinstance(sensor, RangeBearingSensor):
        return None
    sr, sb = sensor.sigma_range, sensor.sigma_bearing
    if not (sr > 0.0 and sb > 0.0) or not (isinstance(gate, float) and 0.0 < gate < 1.0):
        return None
    mx, my, mt = sensor.mount.tolist()
    return np.array([mx, my, mt, sr, sb, _NOISE_MODELS[sensor.noise_model], _gate2(gate)])


def _read_only_c(a: np.ndarray) -> np.ndarray:
    """``a`` C-contiguous and read-only (a copy if it is not): the kernels are compiled once per
    type of their arguments (layout and writability included), so a few types are kept."""
    if a.flags.c_contiguous and not a.flags.writeable:
        return a
    out = np.array(a, order="C")
    out.flags.writeable = False
    return out


def _int_signatures(a: ArrayLike) -> np.ndarray | None:
    """Signatures as int64 (None unless of an integer type int64 holds)."""
    a = np.asarray(a)
    if a.dtype.kind == "i" or (a.dtype.kind == "u" and a.dtype.itemsize < 8):
        return a if a.dtype == np.int64 else a.astype(np.int64)
    return None


def _single_inputs(
    readings: ArrayLike, landmarks: ArrayLike, valid: ArrayLike | None
) -> tuple[FloatArray, FloatArray, np.ndarray | None] | None:
    """Readings (m, 2), landmarks (L, 2) and the mask of present readings (m,) or None, of a
    single-filter call that the fast paths take (m, L ≥ 1); None when they do not take it."""
    z = np.asarray(readings, dtype=np.float64)
    lm = np.asarray(landmarks, dtype=np.float64)
    if z.ndim != 2 or z.shape[1] != 2 or lm.ndim != 2 or lm.shape[1] != 2:
        return None
    if len(z) == 0 or len(lm) == 0:
        return None
    v = None
    if valid is not None:
        v = np.asarray(valid, bool)
        if v.shape != (len(z),):
            return None
    return z, lm, v


def _compiled_one(
    state: AT,
    readings: ArrayLike,
    sensor: RangeBearingSensor,
    landmarks: ArrayLike,
    associate: str,
    signatures: ArrayLike | None,
    landmark_signatures: ArrayLike | None,
    gate: float,
    valid: ArrayLike | None,
) -> LandmarkUpdate | None:
    """:func:`correct_landmarks` of one filter in one kernel call, or None (see above)."""
    if associate not in ("signatures", "mahalanobis"):
        return None
    par = _kernel_sensor(sensor, gate)
    if par is None:
        return None
    inputs = _single_inputs(readings, landmarks, valid)
    if inputs is None:
        return None
    z, lm, v = inputs
    m, L = len(z), len(lm)
    if v is None:
        v = _NO_BOOL
    sig = lsig = _NO_INT
    if signatures is not None or associate == "signatures":
        if signatures is None or landmark_signatures is None:
            return None
        sig, lsig = _int_signatures(signatures), _int_signatures(landmark_signatures)  # type: ignore[assignment]
        if sig is None or lsig is None or sig.shape != (m,) or lsig.shape != (L,):
            return None
    ints, d2, buf = np.empty(2 * m, np.int64), np.empty(m), np.empty(12)
    c = np.ascontiguousarray
    code = _kernels().correct_one(
        _read_only_c(state.mean), _read_only_c(state.cov), c(z), c(v), c(sig), c(lm), c(lsig),
        par, ints, d2, buf,
    )  # fmt: skip
    if code == 1:  # FALLBACK
        return None
    new = state
    if code == 0:  # UPDATED: buf holds (x, y, θ, Σ row by row), as AT._single builds it
        buf.flags.writeable = False
        new = object.__new__(AT)
        object.__setattr__(new, "_mean", buf[:3])
        object.__setattr__(new, "_cov", buf[3:].reshape(3, 3))
    return LandmarkUpdate(new, ints[:m], d2, ints[m:])


def _compiled_batch(
    state: AT,
    z: FloatArray,
    batch: tuple[int, ...],
    valid: ArrayLike | None,
    signatures: ArrayLike | None,
    lsig: np.ndarray | None,
    sensor: RangeBearingSensor,
    lm: FloatArray,
    gate: float,
) -> LandmarkUpdate | None:
    """:func:`correct_landmarks` of a batch (inputs validated) in one kernel call, or None."""
    if type(state) is not AT:
        return None
    par = _kernel_sensor(sensor, gate)
    if par is None:
        return None
    B, m = math.prod(batch), z.shape[-2]
    sig = _NO_INT
    if lsig is not None:
        sig_in = _int_signatures(signatures)  # type: ignore[arg-type]
        lsig = _int_signatures(lsig)
        if sig_in is None or lsig is None:
            return None
        sig = np.broadcast_to(sig_in, (*batch, m)).reshape(B, m)
    else:
        lsig = _NO_INT
    v = None
    if valid is not None:
        v = np.broadcast_to(np.asarray(valid, bool), (*batch, m)).reshape(B, m)
    mean, cov = state.mean, state.cov
    if mean.shape[:-1] != batch:
        mean = np.broadcast_to(mean, (*batch, 3))
        cov = np.broadcast_to(cov, (*batch, 3, 3))
    if z.shape[:-2] != batch:
        z = np.broadcast_to(z, (*batch, m, 2))
    out_lm, out_st = np.empty((B, m), np.int64), np.empty((B, m), np.int64)
    out_d2, out_mean, out_cov = np.empty((B, m)), np.empty((3, B)), np.empty((3, 3, B))
    code = _kernels().correct_batch(
        mean.reshape(B, 3), cov.reshape(B, 3, 3), np.ascontiguousarray(z.reshape(B, m, 2)),
        np.empty((B, 0), np.bool_) if v is None else np.ascontiguousarray(v),
        np.empty((B, 0), np.int64) if sig is _NO_INT else np.ascontiguousarray(sig),
        np.ascontiguousarray(lm), np.ascontiguousarray(lsig), par, out_lm, out_st, out_d2,
        out_mean, out_cov,
    )  # fmt: skip
    if code == 1:  # FALLBACK
        return None
    cov_out = np.moveaxis(out_cov, 2, 0).reshape(*batch, 3, 3)
    new = AT._trusted(out_mean.T.reshape(*batch, 3), cov_out)
    shape = (*batch, m)
    return LandmarkUpdate(new, out_lm.reshape(shape), out_d2.reshape(shape), out_st.reshape(shape))
