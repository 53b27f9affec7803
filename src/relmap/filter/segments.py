"""The steps of a relative motion between readings, compounded before the filter meets them.

A :class:`relmap.models.RelativeMotion` moves the pose by ``x⁻ = x ⊕ Δ(u)``. Compounding is
associative, and so is its first-order covariance (the Jacobians of a chain are products of its
steps'), so the steps between two reading times compound into one step ``Δ_seg`` first, and the
filter predicts once per reading time: ``x ⊕ Δ_seg`` with ``P⁻ = J₁ P J₁ᵀ + J₂ Σ_seg J₂ᵀ`` — the
prediction step by step would give, to rounding (Eqs. 1-4; lecture Eq. 12 unrolled).

The chain from a segment's start to time k, in the segment's start frame: the poses ``(t_j, θ_j)``
after each step j of the segment (prefix sums of the steps), and the covariance
``Σ_k = Σ_{j<k} T_jk C'_j T_jkᵀ`` where ``C'_j`` is step j's covariance ``J_w Q_w J_wᵀ`` turned
into the segment's frame and ``T_jk = [[I, J ℓ], [0, 1]]``, ``ℓ = t_k - t_j``, ``J = [[0, -1],
[1, 0]]``: a step's heading error turns the rest of the chain about the step's end (relmap's chart:
translation along the parent's axes, heading about the child's origin). Expanding the lever ℓ
makes ``Σ_k`` a quadratic in ``t_k`` whose coefficients are sums over the segment's steps
before k: one vectorized pass over the whole log, for a whole batch of noise parameters.
"""

from __future__ import annotations

import weakref
from typing import NamedTuple

import numpy as np

from relmap.models.base import RelativeMotion
from relmap.typing import FloatArray, IntArray

__all__ = ["Chains", "chains"]

_J = np.array([[0.0, -1.0], [1.0, 0.0]])


class Chains(NamedTuple):
    """For time indices k of a log of N steps: the chain from the start of k's segment (the
    last cut before k) to k, in the segment's start frame."""

    mean: FloatArray  #: (K, 3) the composed step (x, y, θ)
    cov: FloatArray  #: (*β, K, 3, 3) its covariance (β: the motion's batch of parameters)


def _restart_cumsum(a: FloatArray, starts: IntArray) -> FloatArray:
    """Prefix sums of ``a`` (..., N) along its last axis that restart at the indices ``starts``
    (increasing, from 0). One cumsum over all: each restart's entry has the previous segment's
    total (``np.add.reduceat``) taken off, so the running sum stays at one segment's size; the
    rounding of that total, which the running sum would carry on, is then taken off each
    segment (its first sum must be its first entry)."""
    a = np.asarray(a, dtype=np.float64)
    shifted = a.copy()
    shifted[..., starts[1:]] -= np.add.reduceat(a, starts, axis=-1)[..., :-1]
    sums = np.cumsum(shifted, axis=-1)
    drift = sums[..., starts] - a[..., starts]
    return sums - np.repeat(drift, np.diff(starts, append=a.shape[-1]), axis=-1)


def chains(
    motion: RelativeMotion, u: FloatArray, cut: np.ndarray, at: IntArray | None = None
) -> Chains:
    """The chains of the steps ``u`` (N, k) of ``motion`` (its parameters: a batch shape β),
    restarting at the time indices where ``cut`` (N + 1,) is True (module docstring): at time
    k the chain of steps ``c..k-1``, c the last cut before k (a cut at k itself ends there).
    ``at``: the time indices (≥ 1) to return (default all, 0..N, with the identity at 0).

    A motion whose step covariance is linear in its noise parameters (``linear_basis``) has
    its chains' covariances computed once for each basis element and combined."""
    basis = motion.linear_basis()
    if basis is None:
        return Chains(*_chains(motion.batched(1), u, cut, at))
    unit, weights = basis  # the model with the basis's parameters (P,), and (..., P)
    # a log's chains on the basis serve every parameter set: kept while its steps live (when
    # they cannot change: a read-only array, as Log.from_velocities makes)
    key = (repr(unit), cut.tobytes(), None if at is None else np.asarray(at).tobytes())
    memo = _memo(u)
    if key not in memo:
        memo[key] = _chains(unit.batched(1), u, cut, at)
    mean, cov = memo[key]
    # Σ_p w_p cov_p elementwise (not a matrix product: a filter of a batch adds the same numbers
    # in the same order as alone)
    w = weights[..., None, None, None]
    return Chains(mean, sum(w[..., p, :, :, :] * cov[p] for p in range(len(cov))))


Memo = dict[tuple[object, ...], tuple[FloatArray, FloatArray]]
#: The chains on a linear basis, by the id of the steps' array (while it lives), then the model
#: and the cuts.
_MEMO: dict[int, Memo] = {}


def _memo(u: FloatArray) -> Memo:
    """The memo of the steps ``u``: kept while ``u`` lives, when it cannot change (read-only)."""
    if u.flags.writeable:
        return {}
    if id(u) not in _MEMO:
        _MEMO[id(u)] = {}
        weakref.finalize(u, _MEMO.pop, id(u), None)
    return _MEMO[id(u)]


def _chains(
    motion: RelativeMotion, u: FloatArray, cut: np.ndarray, at: IntArray | None
) -> tuple[FloatArray, FloatArray]:
    """:func:`chains`, on the motion's own parameters."""
    N = len(u)
    delta, Jw, Qw = motion.step(u)  # (N, 3), (N, 3, w), (*batch, N, w, w)
    start = cut[:N].copy()  # step j starts a chain when its time j is a cut
    start[0] = True
    starts = np.flatnonzero(start)
    # the headings and positions after each step, in its segment's start frame
    theta = _restart_cumsum(delta[:, 2], starts)
    before = theta - delta[:, 2]  # the heading at each step's start
    c, s = np.cos(before), np.sin(before)
    t = np.stack(
        [
            _restart_cumsum(c * delta[:, 0] - s * delta[:, 1], starts),
            _restart_cumsum(s * delta[:, 0] + c * delta[:, 1], starts),
        ]
    )  # (2, N)
    # each step's covariance in its segment's frame: C' = M Q_w Mᵀ, M = blkdiag(R, 1) J_w
    Jt = np.moveaxis(Jw, 0, -1)  # (3, w, N)
    M = np.stack([c * Jt[0] - s * Jt[1], s * Jt[0] + c * Jt[1], Jt[2]])
    MQ = np.einsum("awn,...nwv->...avn", M, Qw)  # (*batch, 3, w, N)
    C = np.einsum("...avn,bvn->...abn", MQ, M)  # (*batch, 3, 3, N)
    q, cv = C[..., 2, 2, :], C[..., :2, 2, :]
    # the lever's sums over the steps j before k, as channels (*batch, 15, N): Σq, Σq t_j,
    # Σq t_j t_jᵀ (xx, xy, yy), Σc', Σ t_j c'ᵀ (xx, xy, yx, yy), ΣC'_tt (xx, xy, yy)
    parts = np.empty((*q.shape[:-1], 15, N))
    parts[..., 0, :] = q
    parts[..., 1:3, :] = q[..., None, :] * t
    tt = t[[0, 0, 1]] * t[[0, 1, 1]]
    parts[..., 3:6, :] = q[..., None, :] * tt
    parts[..., 6:8, :] = cv
    parts[..., 8:12, :] = (t[:, None] * cv[..., None, :, :]).reshape(*q.shape[:-1], 4, N)
    parts[..., 12:15, :] = C[..., [0, 0, 1], [0, 1, 1], :]
    # summed over the pieces between the cuts and the times asked for, then run over the pieces
    # of each segment: the sums over the steps j < k of k's segment
    ends = np.arange(1, N + 1) if at is None else np.asarray(at, dtype=np.int64)
    bounds = np.union1d(starts, ends[ends < N])
    pieces = np.add.reduceat(parts, bounds, axis=-1)
    sums = _restart_cumsum(pieces, np.flatnonzero(np.isin(bounds, starts)))
    sums = sums[..., np.searchsorted(bounds, ends) - 1]
    t, theta = t[:, ends - 1], theta[ends - 1]  # after step k - 1
    Q0, Q1 = sums[..., 0, :], sums[..., 1:3, :]
    Q2 = sums[..., [3, 4, 4, 5], :].reshape(*sums.shape[:-2], 2, 2, -1)
    C0, C1 = sums[..., 6:8, :], sums[..., 8:12, :].reshape(*sums.shape[:-2], 2, 2, -1)
    A0 = sums[..., [12, 13, 13, 14], :].reshape(*sums.shape[:-2], 2, 2, -1)
    # Σ_j T_jk C'_j T_jkᵀ with ℓ = t_k - t_j (J ℓ = (-ℓy, ℓx)): the (x, y) block is
    # A0 + J L + (J L)ᵀ + J Λ Jᵀ with L = Σ ℓ c'ᵀ = t_k C0ᵀ - C1 and Λ = Σ q ℓ ℓᵀ
    L = t[:, None] * C0[..., None, :, :] - C1
    Lam = Q0[..., None, None, :] * t[:, None] * t[None] - t[:, None] * Q1[..., None, :, :]
    Lam = Lam - Q1[..., :, None, :] * t[None] + Q2
    JL = np.stack([-L[..., 1, :, :], L[..., 0, :, :]], axis=-3)
    JOJ = np.stack([np.stack([Lam[..., 1, 1, :], -Lam[..., 1, 0, :]], -2),
                    np.stack([-Lam[..., 0, 1, :], Lam[..., 0, 0, :]], -2)], -3)  # fmt: skip
    Ptt = A0 + JL + np.swapaxes(JL, -3, -2) + JOJ
    Ptq = C0 + np.stack([-(Q0 * t[1] - Q1[..., 1, :]), Q0 * t[0] - Q1[..., 0, :]], axis=-2)
    first = 0 if at is not None else 1  # (all times: the identity at 0 first)
    K = t.shape[-1]
    cov = np.zeros((*Q0.shape[:-1], K + first, 3, 3))
    cov[..., first:, :2, :2] = np.moveaxis(0.5 * (Ptt + np.swapaxes(Ptt, -3, -2)), -1, -3)
    cov[..., first:, :2, 2] = cov[..., first:, 2, :2] = np.moveaxis(Ptq, -1, -2)
    cov[..., first:, 2, 2] = Q0
    mean = np.zeros((K + first, 3))
    mean[first:, :2], mean[first:, 2] = t.T, theta
    return mean, cov
