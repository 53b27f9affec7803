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
makes ``Σ_k`` a quadratic in ``t_k`` whose coefficients are prefix sums over the steps: one
vectorized pass over the whole log, for a whole batch of noise parameters.
"""

from __future__ import annotations

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
    cov: FloatArray  #: (*batch, K, 3, 3) its covariance


def _restart_cumsum(a: FloatArray, start: np.ndarray, axis: int) -> FloatArray:
    """Prefix sums of ``a`` along ``axis`` that restart wherever ``start`` (along that axis) is
    True: each restart's entry has the previous segment's total (``np.add.reduceat``) taken
    off, so the running sum never carries more than one segment's."""
    a = np.moveaxis(np.array(a, dtype=np.float64), axis, -1)
    starts = np.flatnonzero(start)
    totals = np.add.reduceat(a, starts, axis=-1)
    a[..., starts[1:]] -= totals[..., :-1]
    return np.moveaxis(np.cumsum(a, axis=-1), -1, axis)


def chains(
    motion: RelativeMotion, u: FloatArray, cut: np.ndarray, at: IntArray | None = None
) -> Chains:
    """The chains of the steps ``u`` (N, k) of ``motion`` (its parameters: any batch shape),
    restarting at the time indices where ``cut`` (N + 1,) is True (module docstring): at time
    k the chain of steps ``c..k-1``, c the last cut before k (a cut at k itself ends there).
    ``at``: the time indices (≥ 1) to return (default all, 0..N, with the identity at 0)."""
    N = len(u)
    delta, Jw, Qw = motion.step(u)  # (N, 3), (N, 3, w), (*batch, N, w, w)
    seg_start = cut[:N].copy()  # step j starts a chain when its time j is a cut
    seg_start[0] = True
    # the headings and positions after each step, in its segment's start frame
    theta = _restart_cumsum(delta[:, 2], seg_start, 0)
    before = theta - delta[:, 2]  # the heading at each step's start
    c, s = np.cos(before), np.sin(before)
    rot = np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)  # (N, 2, 2)
    t = _restart_cumsum((rot @ delta[:, :2, None])[..., 0], seg_start, 0)  # (N, 2)
    # each step's covariance in its segment's frame: C' = M Q_w Mᵀ, M = blkdiag(R, 1) J_w
    M = Jw.copy()
    M[:, :2] = rot @ Jw[:, :2]
    C = M @ Qw @ np.swapaxes(M, -1, -2)
    q, cv, Ctt = C[..., 2, 2], C[..., :2, 2], C[..., :2, :2]
    # the lever's prefix sums: Σq, Σq t_j, Σq t_j t_jᵀ, Σc', Σ t_j c'ᵀ, ΣC'_tt (over j ≤ k)
    tt = t[:, :, None] * t[:, None, :]
    parts = [q[..., None], q[..., None] * t, (q[..., None, None] * tt).reshape(*q.shape, 4),
             cv, (t[:, :, None] * cv[..., None, :]).reshape(*q.shape, 4), Ctt.reshape(*q.shape, 4)]  # fmt: skip
    parts = [np.broadcast_to(x, (*q.shape, x.shape[-1])) for x in parts]
    sums = _restart_cumsum(np.concatenate(parts, axis=-1), seg_start, -2)
    if at is not None:  # the chains ending at these times: after step k - 1
        sums, t, theta = sums[..., at - 1, :], t[at - 1], theta[at - 1]
    Q0, Q1, Q2 = sums[..., 0], sums[..., 1:3], sums[..., 3:7].reshape(*sums.shape[:-1], 2, 2)
    C0, C1 = sums[..., 7:9], sums[..., 9:13].reshape(*sums.shape[:-1], 2, 2)
    A0 = sums[..., 13:17].reshape(*sums.shape[:-1], 2, 2)
    # Σ_j T_jk C'_j T_jkᵀ with ℓ = t_k - t_j, at k = each step's end
    tk = t
    outer_q = Q0[..., None, None] * (tk[:, :, None] * tk[:, None, :]) - tk[:, :, None] * Q1[..., None, :]
    outer_q = outer_q - Q1[..., :, None] * tk[:, None, :] + Q2
    lever_c = tk[:, :, None] * C0[..., None, :] - C1  # Σ ℓ_j c'_jᵀ
    P_tt = A0 + _J @ lever_c + np.swapaxes(_J @ lever_c, -1, -2) + _J @ outer_q @ _J.T
    P_tq = C0 + (_J @ (Q0[..., None] * tk - Q1)[..., None])[..., 0]
    first = 0 if at is not None else 1  # (all times: the identity at 0 first)
    cov = np.zeros((*P_tt.shape[:-3], len(t) + first, 3, 3))
    cov[..., first:, :2, :2] = 0.5 * (P_tt + np.swapaxes(P_tt, -1, -2))
    cov[..., first:, :2, 2] = cov[..., first:, 2, :2] = P_tq
    cov[..., first:, 2, 2] = Q0
    mean = np.zeros((len(t) + first, 3))
    mean[first:, :2], mean[first:, 2] = t, theta
    return Chains(mean, cov)
