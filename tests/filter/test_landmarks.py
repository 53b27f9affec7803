"""relmap.filter.landmarks: readings of point landmarks — association, gating, statuses and
one stacked update per time stamp — against the mathematics written out here: Eqs. 26-28 for
a known association; the textbook procedure (every landmark's predicted reading, the m×L
Mahalanobis distances, greedy one-to-one pairing or Eq. 21, the χ² gate, an ambiguous reading
as the moment-matched mixture of its landmarks, one stacked update in Joseph form) on random
problems; JCBB against a brute-force search of the jointly compatible sets; range-only,
bearing-only and a user's model."""

from __future__ import annotations

import dataclasses
import itertools
from typing import ClassVar

import numpy as np
import pytest

import relmap as rm
import relmap.filter as rf
from relmap import models
from relmap.errors import NonFiniteError, ParameterError, ShapeError
from relmap.lie import se2
from relmap.models import (
    BearingOnly,
    DistanceNoise,
    Measurement,
    Odometry,
    RangeBearingSensor,
    RangeOnly,
)
from relmap.uncertain import gaussian
from relmap.uncertain.propagate import SE2, numerical_jacobian

SENSOR = RangeBearingSensor(0.1, 0.02, mount=[0.1, 0.0, 0.0], fov=np.radians(180), max_range=10.0)
LANDMARKS = np.array([[3.0, 1.0], [4.0, -2.0], [6.0, 0.5], [2.0, 3.0], [-3.0, 0.0]])
PRIOR = rm.AT(
    [0.2, -0.1, 0.1], np.array([[0.04, 0.01, 0.0], [0.01, 0.05, 0.002], [0.0, 0.002, 0.003]])
)


def manual_update(state: rm.AT, z: np.ndarray, idx: list[int]) -> rm.AT:
    """Eqs. 26-28 written out for a known association (the lecture's Σ - K S Kᵀ form)."""
    h, H, _ = SENSOR.linearize(state.mean, LANDMARKS[idx])
    v = (z - h).reshape(-1)
    v[1::2] = se2.wrap_angle(v[1::2])
    Hs = H.reshape(-1, 3)
    R = np.zeros((2 * len(idx), 2 * len(idx)))
    for k, Rk in enumerate(SENSOR.noise(h)):
        R[2 * k : 2 * k + 2, 2 * k : 2 * k + 2] = Rk
    S = Hs @ state.cov @ Hs.T + R
    K = state.cov @ Hs.T @ np.linalg.inv(S)
    return rm.AT._trusted(se2.plus(state.mean, K @ v), state.cov - K @ S @ K.T)


def readings(state_mean, idx, noise=0.0, rng=None):
    z = SENSOR.h(state_mean, LANDMARKS[idx])
    if noise:
        z = z + rng.normal(size=z.shape) * np.array([0.1, 0.02]) * noise
    return z


@pytest.mark.parametrize("associate", ["mahalanobis", "euclidean", "signatures"])
def test_landmark_update_equals_eqs_26_to_28(associate):
    rng = np.random.default_rng(1)
    idx = [0, 1, 2, 3]
    z = readings(np.array([0.25, -0.05, 0.12]), idx, noise=1.0, rng=rng)
    kw, lmap = {}, LANDMARKS
    if associate == "signatures":
        kw = {"signatures": np.array([10, 11, 12, 13])}
        lmap = rf.LandmarkMap(LANDMARKS, signatures=np.arange(10, 15))
    up = rf.correct_landmarks(PRIOR, z, SENSOR, lmap, associate=associate, **kw)
    np.testing.assert_array_equal(up.landmark, idx)
    assert (up.status == rf.Status.USED).all()
    expected = manual_update(PRIOR, z, idx)
    np.testing.assert_allclose(up.state.mean, expected.mean, atol=1e-12)
    np.testing.assert_allclose(up.state.cov, expected.cov, rtol=1e-9, atol=1e-14)


def test_statuses_are_reported_and_only_used_readings_count():
    z = readings(PRIOR.mean, [0, 1, 2])
    z = np.vstack([z, [np.nan, 0.1], [2.0, 3.0], [1.0, 0.0]])  # NaN, far from all, padding
    valid = np.array([True, True, True, True, True, False])
    up = rf.correct_landmarks(PRIOR, z, SENSOR, LANDMARKS, valid=valid)
    assert list(up.status[:3]) == [rf.Status.USED] * 3
    assert up.status[3] == rf.Status.INVALID and up.status[5] == rf.Status.ABSENT
    assert up.status[4] in (rf.Status.GATED, rf.Status.LOST)
    assert up.report()["used"] == 3
    only = rf.correct_landmarks(PRIOR, z[:3], SENSOR, LANDMARKS)
    np.testing.assert_allclose(up.state.cov, only.state.cov)
    assert np.isfinite(up.state.mean).all()


def test_unknown_signature_is_not_merged():
    z = readings(PRIOR.mean, [0, 1])
    up = rf.correct_landmarks(
        PRIOR,
        z,
        SENSOR,
        LANDMARKS,
        associate="signatures",
        signatures=[0, 99],
    )
    assert list(up.status) == [rf.Status.USED, rf.Status.UNKNOWN] and up.landmark[1] == -1


def test_one_to_one_versus_the_lectures_eq21():
    """Two readings near one landmark: one to one uses one of them; Eq. 21 too (the landmark takes
    its nearest), and a lone reading between two landmarks may serve both under Eq. 21."""
    z = readings(PRIOR.mean, [0, 0])
    z[1, 0] += 0.05
    a = rf.correct_landmarks(PRIOR, z, SENSOR, LANDMARKS)
    assert a.status[0] == rf.Status.USED and a.status[1] in (
        rf.Status.GATED,
        rf.Status.LOST,
    )  # its next landmark is far
    b = rf.correct_landmarks(PRIOR, z, SENSOR, LANDMARKS, pairing="per_landmark")
    assert b.report()["used"] == 1
    close = np.array([[2.0, 0.0], [2.0, 0.3]])
    mid = SENSOR.h(PRIOR.mean, close.mean(axis=0))[None]
    c = rf.correct_landmarks(PRIOR, mid, SENSOR, close, pairing="per_landmark", gate=0.9999)
    d = rf.correct_landmarks(PRIOR, mid, SENSOR, close, gate=0.9999)
    assert c.status[0] == rf.Status.USED and d.status[0] == rf.Status.USED
    assert np.trace(c.state.cov) < np.trace(d.state.cov)  # one reading counted twice


def test_batched_filters_equal_one_by_one():
    rng = np.random.default_rng(2)
    B = 7
    means = PRIOR.mean + rng.normal(size=(B, 3)) * 0.05
    states = rm.AT(means, np.broadcast_to(PRIOR.cov, (B, 3, 3)))
    z = np.stack([readings(means[b], [0, 2, 3], noise=1.0, rng=rng) for b in range(B)])
    valid = rng.random((B, 3)) > 0.3
    up = rf.correct_landmarks(states, z, SENSOR, LANDMARKS, valid=valid)
    for b in range(B):
        one = rf.correct_landmarks(states[b], z[b], SENSOR, LANDMARKS, valid=valid[b])
        np.testing.assert_allclose(up.state.mean[b], one.state.mean, atol=1e-12)
        np.testing.assert_allclose(up.state.cov[b], one.state.cov, atol=1e-14)
        np.testing.assert_array_equal(up.status[b], one.status)


def test_consistency_over_many_runs():
    """A simulated run, 200 filters at once with known association: NEES within its χ² band."""
    rng = np.random.default_rng(3)
    B, T = 200, 60
    noise = DistanceNoise(0.005, 0.005, 0.002)
    odometry = Odometry(noise)
    truth = np.zeros((B, 3))
    state = rm.AT(np.zeros((B, 3)), np.zeros((B, 3, 3)))
    nees = []
    motion = np.array([0.15, 0.04])
    for _ in range(T):
        S = noise.covariance(motion)
        m = motion + rng.multivariate_normal([0, 0], S, size=B)
        truth = se2.compose(truth, models.increment(m))
        state = rf.predict(state, motion, odometry)
        z = SENSOR.h(truth[:, None, :], LANDMARKS)
        z = z + rng.normal(size=z.shape) * np.array([0.1, 0.02])
        vis = SENSOR.in_view(z)
        up = rf.correct_landmarks(
            state,
            z,
            SENSOR,
            LANDMARKS,
            associate="signatures",
            signatures=np.broadcast_to(np.arange(5), (B, 5)),
            valid=vis,
        )
        state = up.state
        e = se2.minus(truth, state.mean)
        nees.append(gaussian.mahalanobis2(e, 0.0, state.cov).mean())
    nees = np.array(nees)
    # B·(average NEES) ~ χ² with 3B degrees of freedom: its 95% band, per step
    lo, hi = (gaussian.confidence_k2(p, 3 * B) / B for p in (0.025, 0.975))
    inside = (nees[5:] >= lo) & (nees[5:] <= hi)
    assert inside.mean() >= 0.85
    assert abs(nees[5:].mean() - 3.0) < 0.25


def test_bad_input():
    z = readings(PRIOR.mean, [0])
    # an empty map: every reading UNKNOWN (counted), the state unchanged
    empty = rf.correct_landmarks(PRIOR, z, SENSOR, np.zeros((0, 2)))
    assert list(empty.status) == [rf.Status.UNKNOWN]
    np.testing.assert_array_equal(empty.state.mean, PRIOR.mean)
    with pytest.raises(ShapeError):
        rf.correct_landmarks(PRIOR, z[0], SENSOR, LANDMARKS)
    with pytest.raises(ParameterError):
        rf.correct_landmarks(PRIOR, z, SENSOR, LANDMARKS, associate="psychic")
    with pytest.raises(ParameterError):
        rf.correct_landmarks(PRIOR, z, SENSOR, LANDMARKS, associate="signatures")
    with pytest.raises(ParameterError):
        rf.correct_landmarks(PRIOR, z, SENSOR, LANDMARKS, gate=1.0)


def test_a_landmark_map_checked_once_gives_what_the_array_gives():
    """A map given as an array is a LandmarkMap of signatures 0..L-1 built at the call; a map
    of signatures not in row order pairs a reading with its signature's row."""
    rng = np.random.default_rng(4)
    z = readings(PRIOR.mean, [3, 0, 2], noise=1.0, rng=rng)
    lm = rf.LandmarkMap(LANDMARKS)
    assert len(lm) == 5 and repr(lm) == "LandmarkMap(5 landmarks)"
    np.testing.assert_array_equal(lm.signatures, np.arange(5))
    for kw in ({"associate": "signatures", "signatures": [3, 0, 99]}, {}, {"associate": "jcbb"}):
        a = rf.correct_landmarks(PRIOR, z, SENSOR, LANDMARKS, **kw)
        b = rf.correct_landmarks(PRIOR, z, SENSOR, lm, **kw)
        for x, y in zip(a, b, strict=True):
            x, y = (x.mean, y.mean) if isinstance(x, rm.AT) else (x, y)
            np.testing.assert_array_equal(x, y)
    sig = np.array([30, 10, 20, 40, 50])  # signatures not in row order
    lm = rf.LandmarkMap(LANDMARKS, signatures=sig)
    assert not lm.xy.flags.writeable and not lm.signatures.flags.writeable
    with pytest.raises(AttributeError):
        lm.xy = LANDMARKS  # type: ignore[misc]
    up = rf.correct_landmarks(PRIOR, z, SENSOR, lm, associate="signatures", signatures=[40, 30, 99])
    assert list(up.landmark) == [3, 0, -1]  # rows; signature 99 is no landmark's
    assert list(up.status) == [rf.Status.USED, rf.Status.USED, rf.Status.UNKNOWN]
    with pytest.raises(ShapeError, match="2 coordinates"):  # the sensor reads (x, y)
        rf.correct_landmarks(PRIOR, z, SENSOR, rf.LandmarkMap(LANDMARKS[:, :1]))
    with pytest.raises(ShapeError):
        rf.LandmarkMap(LANDMARKS, signatures=[1, 2])
    with pytest.raises(ShapeError):
        rf.LandmarkMap(LANDMARKS, signatures=[0.5, 1, 2, 3, 4])
    with pytest.raises(NonFiniteError):
        rf.LandmarkMap([[0.0, np.nan]])


def mixture_update(state: rm.AT, z: np.ndarray, cluster: np.ndarray) -> rm.AT:
    """A reading of one landmark of ``cluster``, which one unknown, written out: association
    probabilities β_j ∝ |S_j|^(-1/2) exp(-d²_j/2), the moment-matched virtual landmark
    ẑ = Σβ h_j, H = Σβ H_j, R = Σβ R_j + Σβ (h_j - ẑ)(h_j - ẑ)ᵀ, then Eqs. 26-28."""
    h, H, _ = SENSOR.linearize(state.mean, cluster)
    R = SENSOR.noise(h)
    S = H @ state.cov @ np.swapaxes(H, -1, -2) + R
    v = z - h
    v[:, 1] = se2.wrap_angle(v[:, 1])
    d2 = np.einsum("ji,jik,jk->j", v, np.linalg.inv(S), v)
    beta = np.exp(-0.5 * d2) / np.sqrt(np.linalg.det(S))
    beta /= beta.sum()
    zhat = beta @ h
    e = h - zhat
    Hm = np.einsum("j,jab->ab", beta, H)
    Rm = np.einsum("j,jab->ab", beta, R) + np.einsum("j,ja,jb->ab", beta, e, e)
    Sm = Hm @ state.cov @ Hm.T + Rm
    K = state.cov @ Hm.T @ np.linalg.inv(Sm)
    y = z - zhat
    y[1] = se2.wrap_angle(y[1])
    return rm.AT._trusted(se2.plus(state.mean, K @ y), state.cov - K @ Sm @ K.T)


@pytest.mark.parametrize("associate", ["mahalanobis", "jcbb"])
def test_a_reading_of_an_ambiguous_cluster_is_the_mixture_of_its_landmarks(associate):
    # two landmarks 0.1 m apart at 3 m: both inside the gate of a reading of either
    cluster = np.array([[3.0, 1.0], [3.0, 1.1]])
    z = SENSOR.h(PRIOR.mean, cluster[:1])
    up = rf.correct_landmarks(PRIOR, z, SENSOR, cluster, associate=associate)
    assert up.status.tolist() == [rf.Status.USED]
    want = mixture_update(PRIOR, z[0], cluster)
    np.testing.assert_allclose(up.state.mean, want.mean, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(up.state.cov, want.cov, rtol=1e-9, atol=1e-12)
    # neither landmark taken with full confidence: the update lies between the two
    one = [manual_update(PRIOR, z, [0]).mean]
    lm = LANDMARKS.copy()
    LANDMARKS[0] = cluster[1]
    try:
        one.append(manual_update(PRIOR, z, [0]).mean)
    finally:
        LANDMARKS[:] = lm
    lo, hi = np.minimum(*one), np.maximum(*one)
    assert ((up.state.mean >= lo - 1e-12) & (up.state.mean <= hi + 1e-12)).all()
    # and it is less sure than a reading of a known landmark
    assert np.linalg.det(up.state.cov) > np.linalg.det(manual_update(PRIOR, z, [0]).cov)


def test_a_lone_candidate_inside_the_gate_is_its_own_update():
    # the second landmark far outside the gate: the plain update (Eqs. 26-28)
    cluster = np.array([[3.0, 1.0], [3.0, 4.0]])
    z = SENSOR.h(PRIOR.mean, cluster[:1])
    up = rf.correct_landmarks(PRIOR, z, SENSOR, cluster, associate="mahalanobis")
    assert up.status.tolist() == [rf.Status.USED]
    want = manual_update(PRIOR, z, [0])  # LANDMARKS[0] is cluster[0]
    np.testing.assert_allclose(up.state.mean, want.mean, rtol=1e-10)
    np.testing.assert_allclose(up.state.cov, want.cov, rtol=1e-9, atol=1e-12)


# ------------------------------------------------------- against the textbook procedure
def reference(state, readings, sensor, landmarks, *, associate="mahalanobis",
              pairing="one_to_one", signatures=None, gate=0.99, valid=None):  # fmt: skip
    """The textbook procedure, batched, for a range-bearing sensor and a LandmarkMap."""
    z = np.asarray(readings, dtype=np.float64)
    lm, landmark_signatures = landmarks.xy, landmarks.signatures
    batch = np.broadcast_shapes(state.batch_shape, z.shape[:-2])
    m, L = z.shape[-2], len(lm)
    z = np.broadcast_to(z, (*batch, m, 2))
    present = np.ones((*batch, m), bool) if valid is None else np.broadcast_to(valid, (*batch, m))
    usable = present & np.isfinite(z).all(axis=-1) & (z[..., 0] > 0)
    z = np.where(usable[..., None], z, np.array([1.0, 0.0]))
    h, H, _ = sensor.linearize(state.mean[..., None, :], lm)
    h = np.broadcast_to(h, (*batch, L, 2))
    H = np.broadcast_to(H, (*batch, L, 2, 3))
    k = {"constant": np.ones(h.shape[:-1]), "proportional": h[..., 0],
         "quadratic": h[..., 0] ** 2}[sensor.noise_model.value]  # fmt: skip
    R = np.diag([sensor.sigma_range**2, sensor.sigma_bearing**2]) * (k**2)[..., None, None]
    S = H @ state.cov[..., None, :, :] @ np.swapaxes(H, -1, -2) + R
    v = z[..., :, None, :] - h[..., None, :, :]
    v[..., 1] = se2.wrap_angle(v[..., 1])
    d2 = np.einsum("...mla,...lab,...mlb->...ml", v, np.linalg.inv(S), v)
    cost = d2 if associate != "euclidean" else np.einsum("...a,...a->...", v, v)
    allowed = np.broadcast_to(usable[..., None], cost.shape).copy()
    if signatures is not None:
        allowed &= np.broadcast_to(signatures, (*batch, m))[..., :, None] == landmark_signatures
    cost = np.where(allowed, cost, np.inf)
    status = np.where(
        ~present, rf.Status.ABSENT, np.where(~usable, rf.Status.INVALID, rf.Status.UNKNOWN)
    )
    candidate = np.isfinite(cost).any(axis=-1) & usable
    gate2 = float(gaussian.confidence_k2(gate, 2))
    if pairing == "per_landmark":
        best = np.argmin(cost, axis=-2)
        best_cost = np.take_along_axis(cost, best[..., None, :], axis=-2)[..., 0, :]
        best_d2 = np.take_along_axis(d2, best[..., None, :], axis=-2)[..., 0, :]
        use_l = np.isfinite(best_cost) & (best_d2 <= gate2)
        gated_l = np.isfinite(best_cost) & ~use_l
        chosen = best[..., None, :] == np.arange(m)[:, None]
        served, refused = chosen & use_l[..., None, :], chosen & gated_l[..., None, :]
        used_r, gated_r = served.any(axis=-1), refused.any(axis=-1) & ~served.any(axis=-1)
        landmark = np.where(used_r, served.argmax(-1), np.where(gated_r, refused.argmax(-1), -1))
        status = np.where(
            used_r,
            rf.Status.USED,
            np.where(gated_r, rf.Status.GATED, np.where(candidate, rf.Status.LOST, status)),
        )
        zr = np.take_along_axis(z, best[..., None], axis=-2)
        new = _stacked(state, zr, h, H, R, use_l)
        out = np.take_along_axis(d2, np.maximum(landmark, 0)[..., None], -1)[..., 0]
        return new, landmark, np.where(landmark >= 0, out, np.inf), status
    landmark = np.full((*batch, m), -1)
    c = cost.copy()
    for _ in range(min(m, L)):
        flat = c.reshape(*batch, m * L)
        k = np.argmin(flat, axis=-1)
        found = np.isfinite(np.take_along_axis(flat, k[..., None], axis=-1)[..., 0])
        if not found.any():
            break
        ri, li = k // L, k % L
        hit = found[..., None] & (np.arange(m) == ri[..., None])
        landmark = np.where(hit, li[..., None], landmark)
        taken = (
            hit[..., :, None] | (found[..., None] & (np.arange(L) == li[..., None]))[..., None, :]
        )
        c = np.where(taken, np.inf, c)
    paired = landmark >= 0
    pair_d2 = np.take_along_axis(d2, np.maximum(landmark, 0)[..., None], axis=-1)[..., 0]
    used = paired & (pair_d2 <= gate2)
    status = np.where(
        used,
        rf.Status.USED,
        np.where(paired, rf.Status.GATED, np.where(candidate, rf.Status.LOST, status)),
    )
    nearest = np.where(np.isfinite(cost), d2, np.inf).min(axis=-1)
    lk = np.maximum(landmark, 0)
    hr = np.take_along_axis(h, lk[..., None], axis=-2)
    Hr = np.take_along_axis(H, lk[..., None, None], axis=-3)
    Rr = np.take_along_axis(R, lk[..., None, None], axis=-3)
    if associate != "euclidean":  # several landmarks in the gate: their mixture, moment-matched
        inside = np.isfinite(cost) & (d2 <= gate2)
        mixed = used & (inside.sum(axis=-1) >= 2)
        logb = np.where(inside, -0.5 * d2 - 0.5 * np.log(np.linalg.det(S))[..., None, :], -np.inf)
        top = np.argmax(np.where(mixed[..., None], logb, 0.0), axis=-1)
        top_logb = np.take_along_axis(logb, top[..., None], axis=-1)
        beta = np.where(mixed[..., None], np.exp(logb - np.where(mixed[..., None], top_logb, 0)), 0)
        beta /= np.where(mixed, beta.sum(axis=-1), 1.0)[..., None]
        hb = np.take_along_axis(h, top[..., None], axis=-2)  # (..., m, 2)
        dh = h[..., None, :, :] - hb[..., :, None, :]  # (..., m, L, 2) relative to the top one
        dh[..., 1] = se2.wrap_angle(dh[..., 1])
        mean_dh = np.einsum("...ml,...mla->...ma", beta, dh)
        e = dh - mean_dh[..., None, :]
        zhat = hb + mean_dh
        Hbar = np.einsum("...ml,...lab->...mab", beta, H)
        Rbar = np.einsum("...ml,...lab->...mab", beta, R) + np.einsum(
            "...ml,...mla,...mlb->...mab", beta, e, e
        )
        hr = np.where(mixed[..., None], zhat, hr)
        Hr = np.where(mixed[..., None, None], Hbar, Hr)
        Rr = np.where(mixed[..., None, None], Rbar, Rr)
        Sm = Hr @ state.cov[..., None, :, :] @ np.swapaxes(Hr, -1, -2) + Rr
        vm = z - hr
        vm[..., 1] = se2.wrap_angle(vm[..., 1])
        dm = np.einsum("...a,...ab,...b->...", vm, np.linalg.inv(Sm), vm)
        pair_d2 = np.where(mixed, dm, pair_d2)
    new = _stacked(state, z, hr, Hr, Rr, used)
    return new, np.where(paired, landmark, -1), np.where(paired, pair_d2, nearest), status


def _stacked(state, z, h, H, R, use):
    """One stacked update (Eqs. 26-28), Joseph form; unused pairs get H = 0, v = 0."""
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
    K = np.swapaxes(np.linalg.solve(Hs @ PHt + Rs, np.swapaxes(PHt, -1, -2)), -1, -2)
    mean = se2.plus(
        np.broadcast_to(state.mean, (*batch, 3)),
        np.einsum("...ij,...j->...i", K, v.reshape(*batch, 2 * k)),
    )
    I_KH = np.eye(3) - K @ Hs
    cov = I_KH @ P @ np.swapaxes(I_KH, -1, -2) + K @ Rs @ np.swapaxes(K, -1, -2)
    return rm.AT._trusted(mean, 0.5 * (cov + np.swapaxes(cov, -1, -2)))


def scenario(rng, batch, m, L, *, dense=False, zero_noise=False):
    """Random filters, map, sensor and readings: true landmarks (some read twice), clutter,
    wrapped and unwrapped bearings, NaN and negative ranges, padding."""
    lm = rng.uniform(-3, 3, (L, 2)) if dense else rng.uniform(-8, 8, (L, 2))
    sensor = RangeBearingSensor(
        0.0 if zero_noise else rng.uniform(0.02, 0.3),
        rng.uniform(0.005, 0.05),
        mount=[rng.uniform(-0.3, 0.3), rng.uniform(-0.2, 0.2), rng.choice([0.0, 0.5, -3.0])],
        fov=rng.choice([np.pi, 2 * np.pi]),
        max_range=rng.uniform(4, 15),
        noise_model=rng.choice(["constant", "proportional", "quadratic"]),
    )
    n = int(np.prod(batch))
    scale = rng.choice([0.02, 0.1, 0.5])
    mean = np.column_stack(
        [rng.uniform(-3, 3, n), rng.uniform(-3, 3, n), rng.uniform(-np.pi, np.pi, n)]
    ).reshape(*batch, 3)
    A = rng.normal(size=(*batch, 3, 3)) * scale * np.array([1, 1, 0.3])[:, None]
    state = rm.AT(mean, A @ np.swapaxes(A, -1, -2) + 1e-6 * np.eye(3))
    truth = se2.plus(mean, rng.normal(size=mean.shape) * scale * 0.5)
    idx = rng.integers(0, L, (*batch, m))
    z = sensor.h(truth[..., None, :], lm[idx])
    z = z + rng.normal(size=z.shape) * [max(sensor.sigma_range, 0.01), sensor.sigma_bearing]
    clutter = rng.random((*batch, m)) < 0.2
    fake = np.stack(
        [rng.uniform(0.3, 12, (*batch, m)), rng.uniform(-np.pi, np.pi, (*batch, m))], -1
    )
    z = np.where(clutter[..., None], fake, z)
    z[..., 1] += rng.choice([0.0, 0.0, 2 * np.pi, -2 * np.pi], size=z.shape[:-1])
    z[..., 0] = np.where(rng.random((*batch, m)) < 0.05, np.nan, z[..., 0])
    z[..., 0] = np.where(rng.random((*batch, m)) < 0.03, -1.0, z[..., 0])
    valid = rng.random((*batch, m)) > 0.1
    signature = np.where(clutter, -5, idx)
    return state, z, sensor, lm, valid, signature


def assert_same(new, ref, *, atol_mean=1e-9, rtol_cov=1e-9):
    state, landmark, d2, status = ref
    np.testing.assert_array_equal(new.status, status)
    np.testing.assert_array_equal(new.landmark, landmark)
    np.testing.assert_array_equal(np.isfinite(new.mahalanobis2), np.isfinite(d2))
    fin = np.isfinite(d2)
    np.testing.assert_allclose(new.mahalanobis2[fin], d2[fin], rtol=1e-9, atol=1e-12)
    assert np.abs(se2.minus(new.state.mean, state.mean)).max() <= atol_mean
    scale = np.linalg.norm(state.cov, axis=(-2, -1), keepdims=True)
    assert (np.abs(new.state.cov - state.cov) / scale).max() <= rtol_cov


OPTIONS = [
    dict(associate=a, pairing=p, signatures=s)
    for a, p, s in itertools.product(
        ["mahalanobis", "euclidean", "signatures"], ["one_to_one", "per_landmark"], [False, True]
    )
    if not (a == "signatures" and not s)
]


@pytest.mark.parametrize("batch", [(), (9,), (2, 4)], ids=str)
def test_correct_landmarks_equals_the_textbook_procedure(batch):
    rng = np.random.default_rng(sum(batch) + 17 * len(batch))
    for trial in range(12):
        m, L = int(rng.integers(1, 8)), int(rng.integers(1, 25))
        state, z, sensor, lm, valid, signature = scenario(rng, batch, m, L, dense=trial % 3 == 0)
        gate = float(rng.choice([0.5, 0.99, 0.9999]))
        for opt in OPTIONS:
            kw = dict(associate=opt["associate"], pairing=opt["pairing"], gate=gate, valid=valid)
            lmap = rf.LandmarkMap(lm)
            if opt["signatures"]:  # unique landmark signatures, or shared ones
                lsig = np.arange(L) if trial % 2 else rng.integers(0, max(1, L // 2), L)
                lmap = rf.LandmarkMap(lm, lsig)
                kw |= dict(signatures=signature)
            up = rf.correct_landmarks(state, z, sensor, lmap, **kw)
            # ill-conditioned random problems: agreement to ~cond(S)·eps, not better
            assert_same(up, reference(state, z, sensor, lmap, **kw), atol_mean=1e-8, rtol_cov=1e-8)


def test_well_conditioned_problems_agree_to_1e_12():
    rng = np.random.default_rng(7)
    sensor = RangeBearingSensor(0.1, 0.02, mount=[0.1, 0.0, 0.0], fov=np.pi, max_range=10.0)
    lm = rf.LandmarkMap(rng.uniform(-8, 8, (40, 2)))
    for batch in [(), (50,)]:
        n = int(np.prod(batch))
        mean = np.column_stack([rng.normal(0, 1, n), rng.normal(0, 1, n), rng.uniform(-3, 3, n)])
        mean = mean.reshape(*batch, 3)
        state = rm.AT(mean, np.diag([0.02, 0.03, 0.002]))
        truth = se2.plus(mean, rng.normal(size=mean.shape) * [0.1, 0.1, 0.03])
        z = sensor.h(truth[..., None, :], lm.xy)
        seen = sensor.in_view(z)
        z = z + rng.normal(size=z.shape) * [0.1, 0.02]
        for kw in ({}, dict(associate="signatures", signatures=np.arange(40))):
            up = rf.correct_landmarks(state, z, sensor, lm, valid=seen, **kw)
            ref = reference(state, z, sensor, lm, valid=seen, **kw)
            assert_same(up, ref, atol_mean=1e-12, rtol_cov=1e-12)


def test_precise_reading_against_vague_prior():
    """tr(AΣ) far above 1e5 (quadratic noise at 0.1 m, a 5 m prior): the result must still
    match the stacked (2k×2k) textbook update (to 1e-10: the update solves I + P A, whose
    condition number is about tr(AΣ), in the readings' information)."""
    sensor = RangeBearingSensor(0.1, 0.01, fov=2 * np.pi, noise_model="quadratic")
    lm = rf.LandmarkMap([[0.1, 0.02], [3.0, 1.0], [-2.0, 4.0]])
    state = rm.AT([0.0, 0.0, 0.1], np.diag([25.0, 16.0, 1.0]))
    z = sensor.h(np.array([0.01, -0.02, 0.12]), lm.xy)
    kw = dict(associate="signatures", signatures=np.arange(3))
    up = rf.correct_landmarks(state, z, sensor, lm, gate=0.999999, **kw)
    assert (up.status == rf.Status.USED).all()
    assert_same(up, reference(state, z, sensor, lm, gate=0.999999, **kw), atol_mean=1e-10,
                rtol_cov=1e-10)  # fmt: skip


def test_a_sensor_without_noise_is_refused():
    """σr = 0: R is singular; the update inverts it, so the correction refuses the sensor with
    a clear error (naming the parameter), rather than a NaN state."""
    rng = np.random.default_rng(3)
    state, z, sensor, lm, valid, signature = scenario(rng, (6,), 2, 6, zero_noise=True)
    with pytest.raises(ParameterError, match="sigma_range"):
        rf.correct_landmarks(state, z, sensor, lm, valid=valid, associate="signatures",
                              signatures=signature)  # fmt: skip


def test_broadcasting_and_edge_cases():
    rng = np.random.default_rng(21)
    state, z, sensor, lm, valid, signature = scenario(rng, (5,), 4, 12)
    one = state[2]
    perm = rng.permutation(12)  # unique signatures, not sorted
    lmap, permuted = rf.LandmarkMap(lm), rf.LandmarkMap(lm, perm)
    cases = [
        (one, z, valid, lmap, {}),  # one state, a batch of scans
        (state, z[1], valid[1], lmap, {}),  # a batch of states, one scan
        (one, z, valid, lmap, dict(signatures=signature)),
        (state, z, valid, permuted,
         dict(associate="signatures", signatures=perm[np.maximum(signature, 0)])),
        (state, z[:, :0], valid[:, :0], lmap, {}),  # no readings
        (one, z[0, :0], None, lmap, {}),
        (state, z, np.zeros_like(valid), lmap, {}),  # only padding: no candidate at all
    ]  # fmt: skip
    for st, zz, vv, landmarks, kw in cases:
        up = rf.correct_landmarks(st, zz, sensor, landmarks, valid=vv, **kw)
        ref = reference(st, zz, sensor, landmarks, valid=vv, **kw)
        assert up.status.shape == ref[3].shape
        assert_same(up, ref)


def test_landmark_at_the_sensor_is_a_counted_0_over_0_alone_and_in_a_batch():
    """A landmark at the sensor has no bearing (0/0): its reading is DEGENERATE, the other
    reading of the scan is used, the filter stays finite — the same alone and in a batch."""
    sensor = RangeBearingSensor(0.1, 0.02, mount=[0.5, 0.0, 0.0])
    state = rm.AT([1.0, 2.0, 0.0], np.diag([0.01, 0.01, 0.001]))
    lm = np.array([[1.5, 2.0], [4.0, 4.0]])
    z = np.array([[3.0, 0.5], sensor.h(state.mean, lm[1])])
    kw = dict(associate="signatures", signatures=[0, 1])
    one = rf.correct_landmarks(state, z, sensor, lm, **kw)
    assert list(one.status) == [rf.Status.DEGENERATE, rf.Status.USED]
    assert np.isfinite(one.state.mean).all() and np.isfinite(one.state.cov).all()
    other = rm.AT([0.0, 0.0, 1.0], np.diag([0.02, 0.02, 0.002]))
    batch = rm.AT(np.stack([other.mean, state.mean]), np.stack([other.cov, state.cov]))
    both = rf.correct_landmarks(batch, z, sensor, lm, **kw)
    np.testing.assert_array_equal(both.status[1], one.status)
    np.testing.assert_array_equal(both.state.mean[1], one.state.mean)
    np.testing.assert_array_equal(both.state.cov[1], one.state.cov)


def test_range_bearing_innovation_covariance_uses_the_numeric_jacobian():
    """S = H P Hᵀ + R with H the numeric Jacobian of Eq. 20 through the mount offset."""
    rng = np.random.default_rng(4)
    sensor = RangeBearingSensor(0.08, 0.015, mount=[0.12, 0.04, 0.1])
    state = rm.AT([0.3, -0.2, 0.7], np.diag([0.04, 0.03, 0.01]) + 0.005)
    z = sensor.h(state.mean, LANDMARKS)
    up = rf.correct_landmarks(state, z + rng.normal(size=z.shape) * 0.01, sensor, LANDMARKS,
                               associate="signatures", signatures=np.arange(5))  # fmt: skip
    for k, lm in enumerate(LANDMARKS):
        H = numerical_jacobian(lambda x, lm=lm: sensor.h(x, lm), state.mean, chart_in=SE2)
        S = H @ state.cov @ H.T + np.diag([sensor.sigma_range**2, sensor.sigma_bearing**2])
        np.testing.assert_allclose(up.S[k], S, rtol=1e-7, atol=1e-12)


# ------------------------------------------------------------------------------------ JCBB
def brute_force_jcbb(state, z, sensor, lm, gate):
    """All one-to-one sets of individually compatible pairs: the largest jointly compatible
    one, of least joint d² (Neira & Tardós 2001's objective), searched exhaustively. As in
    JCBB's tree, a set counts as jointly compatible when each of its prefixes (readings in
    order) passes its joint χ² gate."""
    h, H, _ = sensor.linearize(state.mean[None], lm)
    R = np.diag([sensor.sigma_range**2, sensor.sigma_bearing**2])
    S = H @ state.cov @ np.swapaxes(H, -1, -2) + R
    m, L = len(z), len(lm)
    v = z[:, None] - h[None]
    v[..., 1] = se2.wrap_angle(v[..., 1])
    d2 = np.einsum("mla,lab,mlb->ml", v, np.linalg.inv(S), v)
    g2 = float(gaussian.confidence_k2(gate, 2))
    best, best_j = [], np.inf
    options = [[None] + [j for j in range(L) if d2[i, j] <= g2] for i in range(m)]
    for choice in itertools.product(*options):
        pairs = [(i, j) for i, j in enumerate(choice) if j is not None]
        ls = [j for _, j in pairs]
        if len(set(ls)) < len(ls) or len(pairs) < len(best):
            continue
        j2, compatible = 0.0, True
        for k in range(1, len(pairs) + 1):  # every prefix jointly compatible, as JCBB's nodes
            y = np.concatenate([v[i, j] for i, j in pairs[:k]])
            Hs = np.concatenate([H[j] for _, j in pairs[:k]])
            Sj = Hs @ state.cov @ Hs.T + np.kron(np.eye(k), R)
            j2 = float(y @ np.linalg.solve(Sj, y))
            compatible = compatible and j2 <= gaussian.confidence_k2(gate, 2 * k)
        if not compatible:
            continue
        if len(pairs) > len(best) or j2 < best_j:
            best, best_j = pairs, j2
    return dict(best)


def test_jcbb_finds_the_largest_jointly_compatible_set():
    rng = np.random.default_rng(9)
    sensor = RangeBearingSensor(0.1, 0.03)
    found_ambiguous = 0
    for _ in range(60):
        lm = rng.uniform(-3, 3, (5, 2))
        state = rm.AT(rng.normal(size=3) * 0.3, np.diag([0.3, 0.3, 0.05]))
        truth = se2.plus(state.mean, rng.normal(size=3) * [0.4, 0.4, 0.15])
        z = sensor.h(truth, lm[rng.choice(5, 4, replace=False)])
        z += rng.normal(size=z.shape) * [0.1, 0.03]
        up = rf.correct_landmarks(state, z, sensor, lm, associate="jcbb", gate=0.95)
        want = brute_force_jcbb(state, z, sensor, lm, 0.95)
        got = {i: int(j) for i, j in enumerate(up.landmark) if up.status[i] == rf.Status.USED}
        assert got == want
        nn = rf.correct_landmarks(state, z, sensor, lm, gate=0.95)
        found_ambiguous += int(list(nn.landmark) != list(up.landmark))
    assert found_ambiguous > 0  # JCBB differs from nearest neighbour on some scans


# ------------------------------------------------------------------------- other sensors
def test_range_only_correction_is_the_stacked_kalman_update():
    """Range-only readings (Eq. 20's first row) through correct_landmarks, against the
    textbook update written out here."""
    prior = rm.AT([1.0, 2.0, 0.3], np.diag([0.5, 0.3, 0.1]) + 0.05)
    beacons = np.array([[10.0, 2.0], [1.0, -8.0], [-30.0, 40.0]])
    sensor = RangeOnly(0.3)
    r_true = np.hypot(*(beacons - [1.4, 1.7]).T)
    z = r_true[[0, 1]] + [0.1, -0.2]
    kw = dict(associate="signatures")
    up = rf.correct_landmarks(prior, z[:, None], sensor, beacons, signatures=[0, 1], **kw)
    assert list(up.status) == [rf.Status.USED, rf.Status.USED] and list(up.landmark) == [0, 1]
    P, x = prior.cov, prior.mean
    d = beacons[:2] - x[:2]
    r = np.hypot(*d.T)
    H = np.column_stack([-d / r[:, None], np.zeros(2)])
    S = H @ P @ H.T + 0.09 * np.eye(2)
    K = P @ H.T @ np.linalg.inv(S)
    np.testing.assert_allclose(up.state.mean, x + K @ (z - r), atol=1e-12)
    np.testing.assert_allclose(up.state.cov, P - K @ S @ K.T, atol=1e-12)
    np.testing.assert_allclose(up.mahalanobis2, (z - r) ** 2 / np.diag(S))
    np.testing.assert_allclose(up.y[:, 0], z - r)
    np.testing.assert_allclose(up.S[:, 0, 0], np.diag(S))
    # an outlier is gated at the χ²₁ quantile and changes nothing
    far = rf.correct_landmarks(prior, [[r[0] + 20.0]], sensor, beacons, signatures=[0], **kw)
    assert far.status[0] == rf.Status.GATED
    np.testing.assert_array_equal(far.state.mean, prior.mean)
    np.testing.assert_array_equal(far.state.cov, prior.cov)
    # without ids: the nearest beacon in Mahalanobis distance; unknown id: UNKNOWN
    near = rf.correct_landmarks(prior, [[r_true[2]]], sensor, beacons)
    assert near.landmark[0] == 2 and near.status[0] == rf.Status.USED
    unknown = rf.correct_landmarks(prior, [[5.0], [np.nan]], sensor, beacons, signatures=[-1, 0],
                                    **kw)  # fmt: skip
    assert list(unknown.status) == [rf.Status.UNKNOWN, rf.Status.INVALID]
    with pytest.raises(ParameterError):
        rf.correct_landmarks(prior, z[:, None], sensor, beacons, **kw)  # signatures need ids
    with pytest.raises(ShapeError, match=r"\(\.\.\., m, 1\)"):
        rf.correct_landmarks(prior, z[None], sensor, beacons, signatures=[0], **kw)  # (m, 1)


def test_bearing_only_correction_is_the_stacked_kalman_update():
    """Bearing-only readings (Eq. 20's second row, from a mounted camera) against the textbook
    update: bearings wrapped in the innovation, a reading across ±π included."""
    mount = np.array([0.2, -0.1, 0.3])
    sensor = BearingOnly(0.02, mount=mount)
    prior = rm.AT([1.0, 2.0, 2.8], np.diag([0.05, 0.04, 0.01]) + 0.005)
    lm = np.array([[8.0, 1.8], [3.0, 5.0], [-2.0, -1.0]])
    x = prior.mean
    c, s = np.cos(x[2]), np.sin(x[2])
    ox, oy = c * mount[0] - s * mount[1], s * mount[0] + c * mount[1]
    d = lm - (x[:2] + np.array([ox, oy]))
    q = (d * d).sum(axis=1)
    h = se2.wrap_angle(np.arctan2(d[:, 1], d[:, 0]) - x[2] - mount[2])
    z = se2.wrap_angle(h + np.array([0.03, -0.02, 0.01]))
    assert abs(h[0]) > 3.0  # the first reading lies near ±π
    H = np.column_stack([d[:, 1] / q, -d[:, 0] / q, -(d[:, 1] * oy + d[:, 0] * ox) / q - 1.0])
    S = H @ prior.cov @ H.T + 0.02**2 * np.eye(3)
    K = prior.cov @ H.T @ np.linalg.inv(S)
    y = se2.wrap_angle(z - h)
    up = rf.correct_landmarks(prior, z[:, None], sensor, lm, associate="signatures",
                               signatures=[0, 1, 2], gate=0.999999)  # fmt: skip
    assert (up.status == rf.Status.USED).all()
    np.testing.assert_allclose(up.y[:, 0], y, atol=1e-12)
    np.testing.assert_allclose(up.S[:, 0, 0], np.diag(S), rtol=1e-12)
    np.testing.assert_allclose(se2.minus(up.state.mean, se2.plus(x, K @ y)), 0.0, atol=1e-12)
    np.testing.assert_allclose(up.state.cov, prior.cov - K @ S @ K.T, rtol=1e-10, atol=1e-14)


@dataclasses.dataclass(frozen=True)
class Polar(Measurement):
    """Range and bearing of a landmark from the robot's centre (Eq. 20), as a user writes it:
    ``h`` and ``noise`` only, the Jacobians numeric."""

    sigma_range: float
    sigma_bearing: float
    noise_parameters: ClassVar[tuple[str, ...]] = ("sigma_range", "sigma_bearing")
    angles: ClassVar[tuple[int, ...]] = (1,)
    ranges: ClassVar[tuple[int, ...]] = (0,)
    landmark_dim: ClassVar[int] = 2

    def h(self, x, landmark=None):
        d = landmark - x[..., :2]
        phi = se2.wrap_angle(np.arctan2(d[..., 1], d[..., 0]) - x[..., 2])
        return np.stack([np.hypot(d[..., 0], d[..., 1]), phi], axis=-1)

    def noise(self, z):  # (the σ may be arrays: a batch of filters)
        sr, sb = np.asarray(self.sigma_range), np.asarray(self.sigma_bearing)
        R = np.zeros((*np.broadcast_shapes(np.shape(z)[:-1], sr.shape, sb.shape), 2, 2))
        R[..., 0, 0], R[..., 1, 1] = sr**2, sb**2
        return R


@pytest.mark.parametrize("associate", ["signatures", "mahalanobis", "jcbb"])
def test_a_users_model_runs_through_the_same_correction(associate):
    """A user's range-bearing model (numeric Jacobians) and the built-in one, with every
    association: the same pairs and statuses, the same update to the numeric Jacobians'
    precision; a batch of filters with the user's model's parameters as arrays."""
    rng = np.random.default_rng(12)
    B = 6
    states = rm.AT(
        PRIOR.mean + rng.normal(size=(B, 3)) * 0.05, np.broadcast_to(PRIOR.cov, (B, 3, 3))
    )
    plain = RangeBearingSensor(0.1, 0.02)
    z = plain.h(states.mean[:, None], LANDMARKS[[0, 2, 3]])
    z = z + rng.normal(size=z.shape) * [0.1, 0.02]
    sig = np.broadcast_to([0, 2, 3], (B, 3))
    sr = np.linspace(0.08, 0.2, B)
    built_in = RangeBearingSensor(sr, 0.02)
    users = Polar(sr, 0.02)
    a = rf.correct_landmarks(states, z, built_in, LANDMARKS, associate=associate, signatures=sig)
    b = rf.correct_landmarks(states, z, users, LANDMARKS, associate=associate, signatures=sig)
    np.testing.assert_array_equal(a.status, b.status)
    np.testing.assert_array_equal(a.landmark, b.landmark)
    assert (a.status == rf.Status.USED).sum() >= B * 2
    np.testing.assert_allclose(b.state.mean, a.state.mean, atol=1e-9)
    np.testing.assert_allclose(b.state.cov, a.state.cov, rtol=1e-6, atol=1e-12)
    np.testing.assert_allclose(b.mahalanobis2, a.mahalanobis2, rtol=1e-6)
    np.testing.assert_allclose(b.loglik, a.loglik, rtol=1e-8)
