"""relmap.filter.ekf (the compiled core) against the textbook procedure, on random inputs.

The reference below is the plain algorithm written in numpy: predict every landmark's reading,
the m×L innovations and Mahalanobis distances, greedy one-to-one pairing over the whole matrix
(or Eq. 21), χ² gate, a reading with several landmarks inside its gate replaced by the
moment-matched mixture of them (relmap.filter.ekf.correct_landmarks), one stacked 2k×2k update in
Joseph form. The core (the shortcut of
distinct nearest landmarks, the sorted greedy, signature lookup by binary search, candidates
pruned by a range-only bound on d², the stacked update done as k 2×2 blocks in turn) must give
the same pairings and statuses exactly and the same states to rounding.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

import relmap as rm
from relmap.filter import ekf
from relmap.lie import se2
from relmap.models import RangeBearingSensor
from relmap.uncertain import gaussian


def reference(state, readings, sensor, landmarks, *, associate="mahalanobis",
              pairing="one_to_one", signatures=None, landmark_signatures=None, gate=0.99,
              valid=None):  # fmt: skip
    """The textbook procedure, batched (as in relmap before the fast paths)."""
    z = np.asarray(readings, dtype=np.float64)
    lm = np.asarray(landmarks, dtype=np.float64)
    batch = np.broadcast_shapes(state.batch_shape, z.shape[:-2])
    m, L = z.shape[-2], len(lm)
    z = np.broadcast_to(z, (*batch, m, 2))
    present = np.ones((*batch, m), bool) if valid is None else np.broadcast_to(valid, (*batch, m))
    usable = present & np.isfinite(z).all(axis=-1) & (z[..., 0] > 0)
    z = np.where(usable[..., None], z, np.array([1.0, 0.0]))
    h, H, _ = sensor.predict(state.mean[..., None, :], lm, jacobians=True)
    h = np.broadcast_to(h, (*batch, L, 2))
    H = np.broadcast_to(H, (*batch, L, 2, 3))
    R = sensor.noise(h[..., 0])
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
        ~present, ekf.Status.ABSENT, np.where(~usable, ekf.Status.INVALID, ekf.Status.UNKNOWN)
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
            ekf.Status.USED,
            np.where(gated_r, ekf.Status.GATED, np.where(candidate, ekf.Status.LOST, status)),
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
        ekf.Status.USED,
        np.where(paired, ekf.Status.GATED, np.where(candidate, ekf.Status.LOST, status)),
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
    z = sensor.predict(truth[..., None, :], lm[idx])
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
def test_core_equals_the_textbook_procedure(batch):
    rng = np.random.default_rng(sum(batch) + 17 * len(batch))
    for trial in range(12):
        m, L = int(rng.integers(1, 8)), int(rng.integers(1, 25))
        state, z, sensor, lm, valid, signature = scenario(rng, batch, m, L, dense=trial % 3 == 0)
        gate = float(rng.choice([0.5, 0.99, 0.9999]))
        for opt in OPTIONS:
            kw = dict(associate=opt["associate"], pairing=opt["pairing"], gate=gate, valid=valid)
            if opt["signatures"]:  # unique landmark signatures, or shared ones
                lsig = np.arange(L) if trial % 2 else rng.integers(0, max(1, L // 2), L)
                kw |= dict(signatures=signature, landmark_signatures=lsig)
            up = ekf.correct_landmarks(state, z, sensor, lm, **kw)
            # ill-conditioned random problems: agreement to ~cond(S)·eps, not better
            assert_same(up, reference(state, z, sensor, lm, **kw), atol_mean=1e-8, rtol_cov=1e-8)


def test_well_conditioned_problems_agree_to_1e_12():
    rng = np.random.default_rng(7)
    sensor = RangeBearingSensor(0.1, 0.02, mount=[0.1, 0.0, 0.0], fov=np.pi, max_range=10.0)
    lm = rng.uniform(-8, 8, (40, 2))
    for batch in [(), (50,)]:
        n = int(np.prod(batch))
        mean = np.column_stack([rng.normal(0, 1, n), rng.normal(0, 1, n), rng.uniform(-3, 3, n)])
        mean = mean.reshape(*batch, 3)
        state = rm.AT(mean, np.diag([0.02, 0.03, 0.002]))
        truth = se2.plus(mean, rng.normal(size=mean.shape) * [0.1, 0.1, 0.03])
        z = sensor.predict(truth[..., None, :], lm)
        seen = sensor.in_view(z)
        z = z + rng.normal(size=z.shape) * [0.1, 0.02]
        for kw in (
            {},
            dict(
                associate="signatures", signatures=np.arange(40), landmark_signatures=np.arange(40)
            ),
        ):
            up = ekf.correct_landmarks(state, z, sensor, lm, valid=seen, **kw)
            ref = reference(state, z, sensor, lm, valid=seen, **kw)
            assert_same(up, ref, atol_mean=1e-12, rtol_cov=1e-12)


def test_precise_reading_against_vague_prior_takes_the_stacked_solve():
    """tr(AΣ) far above 1e5 (quadratic noise at 0.1 m, a 5 m prior): the 3×3 form would lose
    digits; the result must still match the stacked solve."""
    sensor = RangeBearingSensor(0.1, 0.01, fov=2 * np.pi, noise_model="quadratic")
    lm = np.array([[0.1, 0.02], [3.0, 1.0], [-2.0, 4.0]])
    state = rm.AT([0.0, 0.0, 0.1], np.diag([25.0, 16.0, 1.0]))
    z = sensor.predict(np.array([0.01, -0.02, 0.12]), lm)
    kw = dict(associate="signatures", signatures=np.arange(3), landmark_signatures=np.arange(3))
    up = ekf.correct_landmarks(state, z, sensor, lm, gate=0.999999, **kw)
    assert (up.status == ekf.Status.USED).all()
    assert_same(up, reference(state, z, sensor, lm, gate=0.999999, **kw), atol_mean=1e-11,
                rtol_cov=1e-11)  # fmt: skip


def test_sensor_without_noise():
    """σr = 0: no R⁻¹, the stacked solve (with up to 3 readings S stays regular)."""
    rng = np.random.default_rng(3)
    for batch in [(), (6,)]:
        state, z, sensor, lm, valid, signature = scenario(rng, batch, 2, 6, zero_noise=True)
        kw = dict(associate="signatures", signatures=signature, landmark_signatures=np.arange(6))
        up = ekf.correct_landmarks(state, z, sensor, lm, valid=valid, **kw)
        assert_same(up, reference(state, z, sensor, lm, valid=valid, **kw))


def test_broadcasting_and_edge_cases():
    rng = np.random.default_rng(21)
    state, z, sensor, lm, valid, signature = scenario(rng, (5,), 4, 12)
    one = state[2]
    perm = rng.permutation(12)  # unique signatures, not sorted
    cases = [
        (one, z, valid, {}),  # one state, a batch of scans
        (state, z[1], valid[1], {}),  # a batch of states, one scan
        (one, z, valid, dict(signatures=signature, landmark_signatures=np.arange(12))),
        (
            state,
            z,
            valid,
            dict(
                associate="signatures",
                signatures=perm[np.maximum(signature, 0)],
                landmark_signatures=perm,
            ),
        ),
        (state, z[:, :0], valid[:, :0], {}),  # no readings
        (one, z[0, :0], None, {}),
        (state, z, np.zeros_like(valid), {}),  # only padding: no candidate at all
    ]
    for st, zz, vv, kw in cases:
        up = ekf.correct_landmarks(st, zz, sensor, lm, valid=vv, **kw)
        ref = reference(st, zz, sensor, lm, valid=vv, **kw)
        assert up.status.shape == ref[3].shape
        assert_same(up, ref)


def test_landmark_at_the_sensor_is_a_counted_0_over_0_alone_and_in_a_batch():
    """A landmark at the sensor has no bearing (0/0): its reading is DEGENERATE, the other
    reading of the scan is used, the filter stays finite — the same alone and in a batch."""
    sensor = RangeBearingSensor(0.1, 0.02, mount=[0.5, 0.0, 0.0])
    state = rm.AT([1.0, 2.0, 0.0], np.diag([0.01, 0.01, 0.001]))
    lm = np.array([[1.5, 2.0], [4.0, 4.0]])
    z = np.array([[3.0, 0.5], sensor.predict(state.mean, lm[1])])
    kw = dict(associate="signatures", signatures=[0, 1], landmark_signatures=[0, 1])
    one = ekf.correct_landmarks(state, z, sensor, lm, **kw)
    assert list(one.status) == [ekf.Status.DEGENERATE, ekf.Status.USED]
    assert np.isfinite(one.state.mean).all() and np.isfinite(one.state.cov).all()
    other = rm.AT([0.0, 0.0, 1.0], np.diag([0.02, 0.02, 0.002]))
    batch = rm.AT(np.stack([other.mean, state.mean]), np.stack([other.cov, state.cov]))
    both = ekf.correct_landmarks(batch, z, sensor, lm, **kw)
    np.testing.assert_array_equal(both.status[1], one.status)
    np.testing.assert_array_equal(both.state.mean[1], one.state.mean)
    np.testing.assert_array_equal(both.state.cov[1], one.state.cov)
