"""Monte Carlo validation of any estimate (the paper's §6.3).

Draw every input AT from its Gaussian, push the samples through the same operation with exact
(nonlinear) arithmetic, and compare the empirical distribution with relmap's estimate:

>>> import relmap as rm
>>> from relmap.lie import SE2, Group
>>> a = rm.AT.from_sigmas([1.0, 0.0, 0.3], [0.05, 0.05, 0.03])
>>> b = rm.AT.from_sigmas([2.0, 0.5, 0.1], [0.05, 0.05, 0.03])
>>> mc = rm.montecarlo.simulate(se2.compose, a, b, n=100_000, seed=1)
>>> report = mc.compare(a @ b)
>>> bool(report.cov_rel_error < 0.02)
True

Samples are vectorized over the sample axis (no Python loop per sample). Sample means and
covariances are taken in relmap's chart: headings are averaged as wrapped deviations from a
reference sample, so a distribution straddling ±π is handled. AT3 estimates are checked the same
way in the SE(3) chart.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from relmap import gaussian
from relmap.at import AT, merge
from relmap.at3 import AT3
from relmap.errors import ArgumentTypeError, ParameterError, ShapeError
from relmap.lie import SE2, Group
from relmap.typing import FloatArray, SeedLike

__all__ = ["Agreement", "SampleSet", "sample_moments", "simulate", "simulate_merge"]


def sample_moments(samples: FloatArray, group: Group = SE2) -> tuple[FloatArray, FloatArray]:
    """Mean pose and covariance ``(..., dof, dof)`` of pose samples ``(n, ..., *point)``.

    The mean is the first sample moved by the average chart deviation from it, iterated twice
    more around the result (so the reference does not matter; for SE(2) the heading deviations
    are wrapped, so a distribution straddling ±π is handled); the covariance uses deviations in
    the chart and the unbiased 1/(n-1) normalization.
    """
    samples = gaussian.real_array(samples, "samples")
    gaussian.check_finite(samples, "samples")
    k = group.point_ndim
    if samples.ndim < k + 1 or samples.shape[samples.ndim - k :] != group.point_shape:
        raise ShapeError(
            f"{group} pose samples must have shape "
            f"(n, ..., {', '.join(map(str, group.point_shape))}); got {samples.shape}"
        )
    n = samples.shape[0]
    if n < 2:
        raise ParameterError("at least two samples are needed for a covariance")
    mean = samples[0]
    for _ in range(3):
        mean = group.plus(mean, group.minus(samples, mean).mean(axis=0))
    d = group.minus(samples, mean)
    cov = np.einsum("n...i,n...j->...ij", d, d) / (n - 1)
    return mean, cov


class Agreement(NamedTuple):
    """How well an estimate matches a Monte Carlo sample (all fields batched like the estimate).

    - ``mean_error``: ``(..., dof)`` estimate ⊟ sample mean in the chart (heading wrapped).
    - ``mean_error_sigmas``: the same in units of the sample's standard deviations.
    - ``mean_standard_error``: ``(..., dof)`` the sampling error of the sample mean (σ/√n).
    - ``cov_rel_error``: ``‖C_est - C_mc‖_F / ‖C_mc‖_F`` (Frobenius norm; a per-entry relative
      error is meaningless where a variance is nearly zero).
    - ``cov_rel_standard_error``: the relative sampling error of ``C_mc`` in the same norm,
      ``≈ sqrt(Σ (C_ii C_jj + C_ij²)) / (√n ‖C‖_F)`` for Gaussian samples.
    - ``nees``: mean squared Mahalanobis distance of the samples under the estimate; equal to
      the estimate's rank (3, or fewer with exactly known directions) when its covariance is right.
    - ``coverage``: fraction of samples inside the estimate's ``probability`` ellipsoid
      (on ``(x, y, θ)``, in as many dimensions as the estimate's rank), to compare with
      ``probability``.
    - ``skewness``, ``excess_kurtosis``: Mardia's multivariate statistics of the sample
      (0 and 0 for a Gaussian); the crescent of the paper's Fig. 5 shows as large skewness.
    """

    n: int
    mean_error: FloatArray
    mean_error_sigmas: FloatArray
    mean_standard_error: FloatArray
    cov_rel_error: FloatArray
    cov_rel_standard_error: FloatArray
    nees: FloatArray
    probability: float
    coverage: FloatArray
    skewness: FloatArray
    excess_kurtosis: FloatArray


class SampleSet(NamedTuple):
    """Samples ``(n, ..., 3)`` (SE(2)) or ``(n, ..., 4, 4)`` (SE(3)) of a pose-valued random
    quantity, with their moments."""

    samples: FloatArray
    mean: FloatArray
    cov: FloatArray
    group: Group = SE2

    @classmethod
    def of(cls, samples: FloatArray, group: Group = SE2) -> SampleSet:
        """Wrap pose samples of ``group`` and compute their moments."""
        mean, cov = sample_moments(samples, group)
        return cls(np.asarray(samples, dtype=np.float64), mean, cov, group)

    @property
    def n(self) -> int:
        """Number of samples."""
        return int(self.samples.shape[0])

    def as_at(self) -> AT | AT3:
        """The sample mean and covariance as an AT (or AT3)."""
        return (
            AT(self.mean, self.cov) if self.group is SE2 else AT3.from_matrix(self.mean, self.cov)
        )

    def compare(self, estimate: AT | AT3, probability: float = 0.90) -> Agreement:
        """Compare an estimate (batch shape matching the samples') with this sample."""
        if estimate.group is not self.group:
            raise ParameterError(
                f"the estimate is in {estimate.group} but the samples are in {self.group}"
            )
        minus, dof = self.group.minus, self.group.dof
        n = self.n
        sig = np.sqrt(np.diagonal(self.cov, axis1=-2, axis2=-1))
        err = minus(estimate.mean, self.mean)
        diff_norm = np.linalg.norm(estimate.cov - self.cov, axis=(-2, -1))
        mc_norm = np.linalg.norm(self.cov, axis=(-2, -1))
        var = np.diagonal(self.cov, axis1=-2, axis2=-1)
        cov_se = np.sqrt((var[..., :, None] * var[..., None, :] + self.cov**2).sum((-2, -1)) / n)
        d = minus(self.samples, estimate.mean)
        d2 = gaussian.mahalanobis2(d, 0.0, estimate.cov)
        # The ellipsoid lives in as many dimensions as the estimate has uncertain directions.
        rank = _whitener(estimate.cov)[1]
        k2_by_dof = np.array(
            [0.0, *(gaussian.confidence_k2(probability, k) for k in range(1, dof + 1))]
        )
        k2 = k2_by_dof[rank]
        skew, kurt = _mardia(minus(self.samples, self.mean), self.cov)
        with np.errstate(divide="ignore", invalid="ignore"):
            return Agreement(
                n=n,
                mean_error=err,
                mean_error_sigmas=np.where(sig > 0, err / np.where(sig > 0, sig, 1.0), 0.0),
                mean_standard_error=sig / np.sqrt(n),
                cov_rel_error=diff_norm / mc_norm,
                cov_rel_standard_error=cov_se / mc_norm,
                nees=d2.mean(axis=0),
                probability=float(probability),
                coverage=(d2 <= k2).mean(axis=0),
                skewness=skew,
                excess_kurtosis=kurt,
            )


def _mardia(d: FloatArray, cov: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Mardia's skewness b₁ and excess kurtosis b₂ - p(p+2) of centred samples ``(n, ..., dof)``.

    p is the rank of the sample covariance (an exactly known component adds no dimension).
    ``b₁ = Σ_ijk m_ijk²`` with ``m_ijk`` the third moments of the whitened sample: the same as
    Mardia's double sum over sample pairs, in O(n) instead of O(n²).
    """
    W, rank = _whitener(cov)
    z = np.einsum("...ij,n...j->n...i", W, d)
    m3 = np.einsum("n...i,n...j,n...k->...ijk", z, z, z) / z.shape[0]
    b1 = (m3**2).sum(axis=(-3, -2, -1))
    b2 = ((z**2).sum(axis=-1) ** 2).mean(axis=0)
    return b1, b2 - rank * (rank + 2)


def _whitener(cov: FloatArray) -> tuple[FloatArray, FloatArray]:
    """W with ``W C Wᵀ = I`` on C's support (zero on exactly known directions), and C's rank."""
    lam, U = np.linalg.eigh(cov)
    keep = lam > 1e-12 * lam[..., -1:]
    inv_sqrt = np.where(keep, 1.0 / np.sqrt(np.where(keep, lam, 1.0)), 0.0)
    return np.swapaxes(U * inv_sqrt[..., None, :], -1, -2), keep.sum(axis=-1)


def _check_inputs(inputs: tuple[object, ...]) -> None:
    for i, a in enumerate(inputs):
        if not isinstance(a, (AT, AT3)):
            raise ArgumentTypeError(f"input {i} is a {type(a).__name__}, not an AT or AT3")


def simulate(
    operation: Callable[..., FloatArray],
    *inputs: AT | AT3,
    n: int = 100_000,
    seed: SeedLike = 0,
) -> SampleSet:
    """Sample every input AT independently, apply ``operation`` to the sampled means, collect.

    ``operation`` takes one sample array per input (``(n, ..., 3)`` for AT, ``(n, ..., 4, 4)``
    for AT3) and returns pose samples of the same group, exactly (no linearization): e.g.
    ``relmap.lie.se2.compose``. Inputs are drawn from one generator seeded by ``seed``, in order.
    """
    if not inputs:
        raise ParameterError("simulate needs at least one input AT")
    _check_inputs(inputs)
    rng = gaussian._rng(seed)
    draws = [a.sample(n, rng) for a in inputs]
    return SampleSet.of(np.asarray(operation(*draws), dtype=np.float64), inputs[0].group)


def simulate_merge(
    *inputs: AT | AT3, truth: FloatArray | None = None, n: int = 100_000, seed: SeedLike = 0
) -> SampleSet:
    """Monte Carlo of the merge *estimator*: its error distribution around a known truth.

    Merging treats each input AT as an independent noisy measurement of one true relation
    (§4). Each trial draws measurements ``zᵢ = truth ⊞ N(0, Cᵢ)`` and merges
    ``AT(zᵢ, Cᵢ)`` (batched over the n trials). The returned sample of merged means should be
    centred on ``truth`` (default: the merge of the inputs' means) with the merged covariance;
    compare it with ``AT(truth, merge(*inputs).cov)``.
    """
    _check_inputs(inputs)
    rng = gaussian._rng(seed)
    center = merge(*inputs).mean if truth is None else gaussian.real_array(truth, "truth")
    kind = type(inputs[0])
    measured = [kind._trusted(kind._trusted(center, a.cov).sample(n, rng), a.cov) for a in inputs]
    return SampleSet.of(merge(*measured).mean, kind.group)
