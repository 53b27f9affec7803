"""relmap.filter.ekf: prediction, full-pose and landmark corrections, association, gating,
batches."""

from __future__ import annotations

import numpy as np
import pytest

import relmap as rm
from relmap import models
from relmap.errors import NonFiniteError, ParameterError, ShapeError
from relmap.filter import ekf
from relmap.lie import se2
from relmap.models import DistanceNoise, RangeBearingSensor, step
from relmap.uncertain import gaussian

SENSOR = RangeBearingSensor(0.1, 0.02, mount=[0.1, 0.0, 0.0], fov=np.radians(180), max_range=10.0)
LANDMARKS = np.array([[3.0, 1.0], [4.0, -2.0], [6.0, 0.5], [2.0, 3.0], [-3.0, 0.0]])
PRIOR = rm.AT(
    [0.2, -0.1, 0.1], np.array([[0.04, 0.01, 0.0], [0.01, 0.05, 0.002], [0.0, 0.002, 0.003]])
)


def manual_update(state: rm.AT, z: np.ndarray, idx: list[int]) -> rm.AT:
    """Eqs. 26-28 written out for a known association (the lecture's Σ - K S Kᵀ form)."""
    h, H, _ = SENSOR.predict(state.mean, LANDMARKS[idx], jacobians=True)
    v = (z - h).reshape(-1)
    v[1::2] = se2.wrap_angle(v[1::2])
    Hs = H.reshape(-1, 3)
    R = np.zeros((2 * len(idx), 2 * len(idx)))
    for k, Rk in enumerate(SENSOR.noise(h[:, 0])):
        R[2 * k : 2 * k + 2, 2 * k : 2 * k + 2] = Rk
    S = Hs @ state.cov @ Hs.T + R
    K = state.cov @ Hs.T @ np.linalg.inv(S)
    return rm.AT._trusted(se2.plus(state.mean, K @ v), state.cov - K @ S @ K.T)


def readings(state_mean, idx, noise=0.0, rng=None):
    z = SENSOR.predict(state_mean, LANDMARKS[idx])
    if noise:
        z = z + rng.normal(size=z.shape) * np.array([0.1, 0.02]) * noise
    return z


def test_predict_is_the_odometry_step():
    noise = DistanceNoise(0.01, 0.02, 0.005)
    new = ekf.predict(PRIOR, [0.5, 0.2], noise)
    expected, _, _ = step(PRIOR, [0.5, 0.2], noise)
    np.testing.assert_allclose(new.mean, expected.mean)
    np.testing.assert_allclose(new.cov, expected.cov)


def test_full_pose_correction_is_the_paper_merge_with_a_gate():
    reading = rm.AT([0.3, -0.05, 0.12], np.diag([0.01, 0.01, 0.001]))
    up = ekf.correct_pose(PRIOR, reading)
    assert up.accepted
    merged = rm.merge(PRIOR, reading)
    np.testing.assert_allclose(up.state.cov, merged.cov)
    # Eq. 17 in one dimension: x = (σz² x⁻ + σ⁻² z)/(σ⁻² + σz²)
    a, b = rm.AT([1.0, 0, 0], np.diag([4.0, 1, 1])), rm.AT([2.0, 0, 0], np.diag([1.0, 1, 1]))
    assert ekf.correct_pose(a, b).state.mean[0] == pytest.approx((1 * 1 + 4 * 2) / 5)
    wild = rm.AT([5.0, 5.0, 2.0], np.diag([0.01, 0.01, 0.001]))
    out = ekf.correct_pose(PRIOR, wild)
    assert not out.accepted and np.array_equal(out.state.mean, PRIOR.mean)


@pytest.mark.parametrize("associate", ["mahalanobis", "euclidean", "signatures"])
def test_landmark_update_equals_eqs_26_to_28(associate):
    rng = np.random.default_rng(1)
    idx = [0, 1, 2, 3]
    z = readings(np.array([0.25, -0.05, 0.12]), idx, noise=1.0, rng=rng)
    kw = {}
    if associate == "signatures":
        kw = {"signatures": np.array([10, 11, 12, 13]), "landmark_signatures": np.arange(10, 15)}
    up = ekf.correct_landmarks(PRIOR, z, SENSOR, LANDMARKS, associate=associate, **kw)
    np.testing.assert_array_equal(up.landmark, idx)
    assert (up.status == ekf.Status.USED).all()
    expected = manual_update(PRIOR, z, idx)
    np.testing.assert_allclose(up.state.mean, expected.mean, atol=1e-12)
    np.testing.assert_allclose(up.state.cov, expected.cov, rtol=1e-9, atol=1e-14)


def test_statuses_are_reported_and_only_used_readings_count():
    z = readings(PRIOR.mean, [0, 1, 2])
    z = np.vstack([z, [np.nan, 0.1], [2.0, 3.0], [1.0, 0.0]])  # NaN, far from all, padding
    valid = np.array([True, True, True, True, True, False])
    up = ekf.correct_landmarks(PRIOR, z, SENSOR, LANDMARKS, valid=valid)
    assert list(up.status[:3]) == [ekf.Status.USED] * 3
    assert up.status[3] == ekf.Status.INVALID and up.status[5] == ekf.Status.ABSENT
    assert up.status[4] in (ekf.Status.GATED, ekf.Status.LOST)
    assert up.report()["used"] == 3
    only = ekf.correct_landmarks(PRIOR, z[:3], SENSOR, LANDMARKS)
    np.testing.assert_allclose(up.state.cov, only.state.cov)
    assert np.isfinite(up.state.mean).all()


def test_unknown_signature_is_not_merged():
    z = readings(PRIOR.mean, [0, 1])
    up = ekf.correct_landmarks(
        PRIOR,
        z,
        SENSOR,
        LANDMARKS,
        associate="signatures",
        signatures=[0, 99],
        landmark_signatures=np.arange(5),
    )
    assert list(up.status) == [ekf.Status.USED, ekf.Status.UNKNOWN] and up.landmark[1] == -1


def test_one_to_one_versus_the_lectures_eq21():
    """Two readings near one landmark: one to one uses one of them; Eq. 21 too (the landmark takes
    its nearest), and a lone reading between two landmarks may serve both under Eq. 21."""
    z = readings(PRIOR.mean, [0, 0])
    z[1, 0] += 0.05
    a = ekf.correct_landmarks(PRIOR, z, SENSOR, LANDMARKS)
    assert a.status[0] == ekf.Status.USED and a.status[1] in (
        ekf.Status.GATED,
        ekf.Status.LOST,
    )  # its next landmark is far
    b = ekf.correct_landmarks(PRIOR, z, SENSOR, LANDMARKS, pairing="per_landmark")
    assert b.report()["used"] == 1
    close = np.array([[2.0, 0.0], [2.0, 0.3]])
    mid = SENSOR.predict(PRIOR.mean, close.mean(axis=0))[None]
    c = ekf.correct_landmarks(PRIOR, mid, SENSOR, close, pairing="per_landmark", gate=0.9999)
    d = ekf.correct_landmarks(PRIOR, mid, SENSOR, close, gate=0.9999)
    assert c.status[0] == ekf.Status.USED and d.status[0] == ekf.Status.USED
    assert np.trace(c.state.cov) < np.trace(d.state.cov)  # one reading counted twice


def test_batched_filters_equal_one_by_one():
    rng = np.random.default_rng(2)
    B = 7
    means = PRIOR.mean + rng.normal(size=(B, 3)) * 0.05
    states = rm.AT(means, np.broadcast_to(PRIOR.cov, (B, 3, 3)))
    z = np.stack([readings(means[b], [0, 2, 3], noise=1.0, rng=rng) for b in range(B)])
    valid = rng.random((B, 3)) > 0.3
    up = ekf.correct_landmarks(states, z, SENSOR, LANDMARKS, valid=valid)
    for b in range(B):
        one = ekf.correct_landmarks(states[b], z[b], SENSOR, LANDMARKS, valid=valid[b])
        np.testing.assert_allclose(up.state.mean[b], one.state.mean, atol=1e-12)
        np.testing.assert_allclose(up.state.cov[b], one.state.cov, atol=1e-14)
        np.testing.assert_array_equal(up.status[b], one.status)


def test_consistency_over_many_runs():
    """A simulated run, 200 filters at once with known association: NEES within its χ² band."""
    rng = np.random.default_rng(3)
    B, T = 200, 60
    noise = DistanceNoise(0.005, 0.005, 0.002)
    truth = np.zeros((B, 3))
    state = rm.AT(np.zeros((B, 3)), np.zeros((B, 3, 3)))
    nees = []
    motion = np.array([0.15, 0.04])
    for _ in range(T):
        S = noise.covariance(motion)
        m = motion + rng.multivariate_normal([0, 0], S, size=B)
        truth = se2.compose(truth, models.increment(m))
        state = ekf.predict(state, motion, noise)
        z = SENSOR.predict(truth[:, None, :], LANDMARKS)
        z = z + rng.normal(size=z.shape) * np.array([0.1, 0.02])
        vis = SENSOR.in_view(z)
        up = ekf.correct_landmarks(
            state,
            z,
            SENSOR,
            LANDMARKS,
            associate="signatures",
            signatures=np.broadcast_to(np.arange(5), (B, 5)),
            landmark_signatures=np.arange(5),
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
    empty = ekf.correct_landmarks(PRIOR, z, SENSOR, np.zeros((0, 2)))
    assert list(empty.status) == [ekf.Status.UNKNOWN]
    np.testing.assert_array_equal(empty.state.mean, PRIOR.mean)
    with pytest.raises(ShapeError):
        ekf.correct_landmarks(PRIOR, z[0], SENSOR, LANDMARKS)
    with pytest.raises(ParameterError):
        ekf.correct_landmarks(PRIOR, z, SENSOR, LANDMARKS, associate="psychic")
    with pytest.raises(ParameterError):
        ekf.correct_landmarks(PRIOR, z, SENSOR, LANDMARKS, associate="signatures")
    with pytest.raises(ParameterError):
        ekf.correct_landmarks(PRIOR, z, SENSOR, LANDMARKS, gate=1.0)


def test_a_landmark_map_checked_once_gives_what_the_array_gives():
    rng = np.random.default_rng(4)
    z = readings(PRIOR.mean, [3, 0, 2], noise=1.0, rng=rng)
    sig = np.array([30, 10, 20, 40, 50])  # signatures not in row order
    lm = ekf.LandmarkMap(LANDMARKS, signatures=sig)
    assert len(lm) == 5 and repr(lm) == "LandmarkMap(5 landmarks)"
    assert not lm.xy.flags.writeable and not lm.signatures.flags.writeable
    with pytest.raises(AttributeError):
        lm.xy = LANDMARKS  # type: ignore[misc]
    for kw in ({"associate": "signatures", "signatures": [40, 30, 99]}, {}, {"associate": "jcbb"}):
        a = ekf.correct_landmarks(PRIOR, z, SENSOR, LANDMARKS, landmark_signatures=sig, **kw)
        b = ekf.correct_landmarks(PRIOR, z, SENSOR, lm, **kw)
        for x, y in zip(a, b, strict=True):
            x, y = (x.mean, y.mean) if isinstance(x, rm.AT) else (x, y)
            np.testing.assert_array_equal(x, y)
    up = ekf.correct_landmarks(
        PRIOR, z, SENSOR, lm, associate="signatures", signatures=[40, 30, 99]
    )
    assert list(up.landmark) == [3, 0, -1]  # rows; signature 99 is no landmark's
    assert list(up.status) == [ekf.Status.USED, ekf.Status.USED, ekf.Status.UNKNOWN]
    with pytest.raises(ParameterError, match="LandmarkMap"):
        ekf.correct_landmarks(PRIOR, z, SENSOR, lm, landmark_signatures=sig)
    with pytest.raises(ShapeError):
        ekf.LandmarkMap(LANDMARKS[:, :1])
    with pytest.raises(ShapeError):
        ekf.LandmarkMap(LANDMARKS, signatures=[1, 2])
    with pytest.raises(NonFiniteError):
        ekf.LandmarkMap([[0.0, np.nan]])


def test_predict_rejects_non_finite_steps():
    noise = DistanceNoise(0.01, 0.02, 0.005)
    for u in ([np.nan, 0.1], [[0.5, 0.1], [0.5, np.inf]]):
        with pytest.raises(NonFiniteError, match="finite"):
            ekf.predict(PRIOR, u, noise)
    batch = rm.AT.stack([PRIOR, PRIOR])
    with pytest.raises(NonFiniteError):
        ekf.predict(batch, [[0.5, 0.1], [np.nan, 0.1]], noise)


def mixture_update(state: rm.AT, z: np.ndarray, cluster: np.ndarray) -> rm.AT:
    """A reading of one landmark of ``cluster``, which one unknown, written out: association
    probabilities β_j ∝ |S_j|^(-1/2) exp(-d²_j/2), the moment-matched virtual landmark
    ẑ = Σβ h_j, H = Σβ H_j, R = Σβ R_j + Σβ (h_j - ẑ)(h_j - ẑ)ᵀ, then Eqs. 26-28."""
    h, H, _ = SENSOR.predict(state.mean, cluster, jacobians=True)
    R = SENSOR.noise(h[:, 0])
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
    z = SENSOR.predict(PRIOR.mean, cluster[:1])
    up = ekf.correct_landmarks(PRIOR, z, SENSOR, cluster, associate=associate)
    assert up.status.tolist() == [ekf.Status.USED]
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
    z = SENSOR.predict(PRIOR.mean, cluster[:1])
    up = ekf.correct_landmarks(PRIOR, z, SENSOR, cluster, associate="mahalanobis")
    assert up.status.tolist() == [ekf.Status.USED]
    want = manual_update(PRIOR, z, [0])  # LANDMARKS[0] is cluster[0]
    np.testing.assert_allclose(up.state.mean, want.mean, rtol=1e-10)
    np.testing.assert_allclose(up.state.cov, want.cov, rtol=1e-9, atol=1e-12)
