"""Monte Carlo validation of any estimate (the paper's §6.3).

Draw every input AT from its Gaussian, push the samples through the same operation with exact
(nonlinear) arithmetic, and compare the empirical distribution with relmap's estimate:

>>> import relmap as rm
>>> from relmap.lie import se2
>>> from relmap.sim import montecarlo
>>> a = rm.AT.from_sigmas([1.0, 0.0, 0.3], [0.05, 0.05, 0.03])
>>> b = rm.AT.from_sigmas([2.0, 0.5, 0.1], [0.05, 0.05, 0.03])
>>> mc = montecarlo.simulate(se2.compose, a, b, n=100_000, seed=1)
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
from typing import Any, NamedTuple

import numpy as np

from relmap.errors import ArgumentTypeError, ChunkError, ParameterError, ShapeError
from relmap.lie.group import SE2, Group
from relmap.typing import FloatArray, SeedLike
from relmap.uncertain import gaussian
from relmap.uncertain.algebra import merge
from relmap.uncertain.at import AT
from relmap.uncertain.at3 import AT3
from relmap.uncertain.pose import UncertainPose

__all__ = [
    "Agreement",
    "Check",
    "SampleSet",
    "Summary",
    "Tally",
    "block_rng",
    "block_seed",
    "check",
    "root_seed",
    "run",
    "sample_moments",
    "simulate",
    "simulate_merge",
]


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
        d2 = gaussian.mahalanobis2(minus(self.samples, estimate.mean), 0.0, estimate.cov)
        tally = Tally.of(minus(self.samples, self.mean), d2, _k2(estimate.cov, probability, dof))
        return _agreement(tally, self.mean, estimate, probability)


def _mardia(
    m3: FloatArray, m4: FloatArray, n: int, cov: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Mardia's skewness b₁ and excess kurtosis b₂ - p(p+2) from central co-moment sums.

    ``m3 (..., p, p, p)`` and ``m4 (..., p, p, p, p)`` are the sums over the ``n`` samples of
    ``e⊗e⊗e`` and ``e⊗e⊗e⊗e`` (``e`` the deviation from the sample mean), ``cov`` the sample
    covariance; p counts its rank (an exactly known component adds no dimension). With the
    whitener W (``z = W e``, ``P = WᵀW``): ``b₁ = Σ_abc (Σ_ijk W_ai W_bj W_ck m3_ijk / n)²``,
    Mardia's double sum over sample pairs in O(n); ``b₂ = Σ P_ij P_kl m4_ijkl / n``
    ``= mean((zᵀz)²)``.
    """
    W, rank = _whitener(cov)
    z3 = np.einsum("...ai,...bj,...ck,...ijk->...abc", W, W, W, m3) / n
    P = np.swapaxes(W, -1, -2) @ W
    b2 = np.einsum("...ij,...kl,...ijkl->...", P, P, m4) / n
    return (z3**2).sum(axis=(-3, -2, -1)), b2 - rank * (rank + 2)


def _whitener(cov: FloatArray) -> tuple[FloatArray, FloatArray]:
    """W with ``W C Wᵀ = I`` on C's support (zero on exactly known directions), and C's rank."""
    lam, U = np.linalg.eigh(cov)
    keep = lam > 1e-12 * lam[..., -1:]
    inv_sqrt = np.where(keep, 1.0 / np.sqrt(np.where(keep, lam, 1.0)), 0.0)
    return np.swapaxes(U * inv_sqrt[..., None, :], -1, -2), keep.sum(axis=-1)


def _check_inputs(inputs: tuple[object, ...]) -> None:
    for i, a in enumerate(inputs):
        if not isinstance(a, UncertainPose):
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


# --------------------------------------------------------------------- partial moments, merged
#: Rows of samples whose fourth-order products are formed at once inside :meth:`Tally.of`.
_ROWS = 16_384


class Tally(NamedTuple):
    """Partial sums of a Monte Carlo sample: everything :class:`Agreement` needs, for a part of
    the samples, merged exactly with another part's (so no sample is kept).

    Deviations ``d (n, ..., dof)`` are chart deviations of the samples from a fixed reference
    pose. ``mean`` is their mean; ``m2``, ``m3``, ``m4`` are the sums of ``e⊗e``, ``e⊗e⊗e``,
    ``e⊗e⊗e⊗e`` with ``e = d - mean`` (central co-moment sums); ``nees`` is the sum of the
    samples' squared Mahalanobis distances under the estimate, ``inside`` how many lie in its
    ellipsoid. :meth:`merge` combines two tallies by the pairwise update of Chan, Golub & LeVeque
    (1979) extended to third and fourth co-moments by Pébay (2008), numerically stable (no raw
    power sums, so nothing cancels when the spread is tiny next to the offset).
    """

    n: int
    mean: FloatArray  #: (..., dof)
    m2: FloatArray  #: (..., dof, dof)
    m3: FloatArray  #: (..., dof, dof, dof)
    m4: FloatArray  #: (..., dof, dof, dof, dof)
    nees: FloatArray  #: (...)
    inside: FloatArray  #: (...)

    @classmethod
    def of(cls, d: FloatArray, d2: FloatArray, k2: FloatArray | float) -> Tally:
        """The tally of deviations ``d (n, ..., dof)`` with squared Mahalanobis distances
        ``d2 (n, ...)`` under the estimate and its ellipsoid's ``k2`` (two passes: mean, then
        central sums, in slices of a fixed number of rows)."""
        d = np.asarray(d, dtype=np.float64)
        n, dof = d.shape[0], d.shape[-1]
        mean = d.mean(axis=0)
        e = d - mean
        m2 = np.einsum("n...i,n...j->...ij", e, e)
        m3 = np.zeros((*mean.shape, dof, dof))
        m4 = np.zeros((*mean.shape[:-1], dof * dof, dof * dof))
        for lo in range(0, n, _ROWS):
            s = e[lo : lo + _ROWS]
            ee = (s[..., :, None] * s[..., None, :]).reshape(*s.shape[:-1], dof * dof)
            m3 += np.einsum("n...a,n...k->...ak", ee, s).reshape(m3.shape)
            m4 += np.einsum("n...a,n...b->...ab", ee, ee)
        d2 = np.asarray(d2, dtype=np.float64)
        return cls(
            n,
            mean,
            m2,
            m3,
            m4.reshape(*mean.shape[:-1], dof, dof, dof, dof),
            d2.sum(axis=0),
            (d2 <= k2).sum(axis=0).astype(np.float64),
        )

    def merge(self, other: Tally) -> Tally:
        """The tally of both parts' samples together (Chan et al.; Pébay, Eqs. 2.1-2.3 of
        SAND2008-6212 in tensor form). Merging in a fixed order gives fixed bits."""
        na, nb = float(self.n), float(other.n)
        n = na + nb
        d = other.mean - self.mean
        A2, B2, A3, B3 = self.m2, other.m2, self.m3, other.m3
        dd = np.einsum("...i,...j->...ij", d, d)
        ddd = np.einsum("...ij,...k->...ijk", dd, d)
        m2 = A2 + B2 + dd * (na * nb / n)
        m3 = A3 + B3 + ddd * (na * nb * (na - nb) / n**2) + _sym3(d, (na * B2 - nb * A2) / n)
        m4 = (
            self.m4
            + other.m4
            + np.einsum("...ijk,...l->...ijkl", ddd, d)
            * (na * nb * (na * na - na * nb + nb * nb) / n**3)
            + _sym6(dd, (na * na * B2 + nb * nb * A2) / n**2)
            + _sym4(d, (na * B3 - nb * A3) / n)
        )
        return Tally(
            self.n + other.n,
            self.mean + d * (nb / n),
            m2,
            m3,
            m4,
            self.nees + other.nees,
            self.inside + other.inside,
        )


def _sym3(d: FloatArray, A: FloatArray) -> FloatArray:
    """``d_i A_jk + d_j A_ik + d_k A_ij`` (A symmetric)."""
    t = np.einsum("...i,...jk->...ijk", d, A)
    return t + np.swapaxes(t, -3, -2) + np.moveaxis(t, -3, -1)


def _sym4(d: FloatArray, C: FloatArray) -> FloatArray:
    """``d_i C_jkl + d_j C_ikl + d_k C_ijl + d_l C_ijk`` (C symmetric)."""
    return (
        np.einsum("...i,...jkl->...ijkl", d, C)
        + np.einsum("...j,...ikl->...ijkl", d, C)
        + np.einsum("...k,...ijl->...ijkl", d, C)
        + np.einsum("...l,...ijk->...ijkl", d, C)
    )


def _sym6(D: FloatArray, B: FloatArray) -> FloatArray:
    """The six placements ``D_ij B_kl + D_ik B_jl + D_il B_jk + D_jk B_il + D_jl B_ik +
    D_kl B_ij`` (D and B symmetric)."""
    return (
        np.einsum("...ij,...kl->...ijkl", D, B)
        + np.einsum("...ik,...jl->...ijkl", D, B)
        + np.einsum("...il,...jk->...ijkl", D, B)
        + np.einsum("...jk,...il->...ijkl", D, B)
        + np.einsum("...jl,...ik->...ijkl", D, B)
        + np.einsum("...kl,...ij->...ijkl", D, B)
    )


def _k2(cov: FloatArray, probability: float, dof: int) -> FloatArray:
    """k² of the ``probability`` ellipsoid in as many dimensions as ``cov`` has uncertain
    directions (its rank), batched."""
    rank = _whitener(cov)[1]
    table = np.array([0.0, *(gaussian.confidence_k2(probability, k) for k in range(1, dof + 1))])
    return table[rank]


def _agreement(
    t: Tally, reference: FloatArray, estimate: AT | AT3, probability: float
) -> Agreement:
    """:class:`Agreement` of an estimate with the sample whose tally is ``t`` (deviations taken
    from the pose ``reference``)."""
    group = estimate.group
    n = t.n
    cov = t.m2 / (n - 1)
    mean = group.plus(reference, t.mean)
    sig = np.sqrt(np.diagonal(cov, axis1=-2, axis2=-1))
    err = group.minus(estimate.mean, mean)
    diff_norm = np.linalg.norm(estimate.cov - cov, axis=(-2, -1))
    mc_norm = np.linalg.norm(cov, axis=(-2, -1))
    var = np.diagonal(cov, axis1=-2, axis2=-1)
    cov_se = np.sqrt((var[..., :, None] * var[..., None, :] + cov**2).sum((-2, -1)) / n)
    skew, kurt = _mardia(t.m3, t.m4, n, cov)
    with np.errstate(divide="ignore", invalid="ignore"):
        return Agreement(
            n=n,
            mean_error=err,
            mean_error_sigmas=np.where(sig > 0, err / np.where(sig > 0, sig, 1.0), 0.0),
            mean_standard_error=sig / np.sqrt(n),
            cov_rel_error=diff_norm / mc_norm,
            cov_rel_standard_error=cov_se / mc_norm,
            nees=t.nees / n,
            probability=float(probability),
            coverage=t.inside / n,
            skewness=skew,
            excess_kurtosis=kurt,
        )


# ------------------------------------------------------------- a check in blocks, anywhere
#: Samples of one block of :func:`check` (every block has its own random stream).
CHECK_BLOCK = 65_536
#: How many samples a streamed check keeps for plots (the first ones, in sample order).
KEEP = 5_000


class Summary(NamedTuple):
    """The moments of a Monte Carlo sample that was never held whole (:func:`run`).

    ``mean`` and ``cov`` are the sample's mean pose and covariance, with deviations taken in
    the chart at ``reference`` (the estimate's mean: where the estimate's covariance lives; for
    SE(2) the same as at the sample mean, for SE(3) different at second order in the mean
    error); ``samples`` holds the first ``min(n, keep)`` samples, for plots; ``tally`` the
    partial sums.
    """

    n: int
    mean: FloatArray
    cov: FloatArray
    group: Group
    samples: FloatArray
    reference: FloatArray
    tally: Tally

    def as_at(self) -> AT | AT3:
        """The sample mean and covariance as an AT (or AT3)."""
        return (
            AT(self.mean, self.cov) if self.group is SE2 else AT3.from_matrix(self.mean, self.cov)
        )


class Check(NamedTuple):
    """What :func:`run` and :func:`check` return."""

    samples: Summary
    agreement: Agreement
    seed: np.random.SeedSequence  #: the root of every block's stream (its entropy reproduces)
    blocks: int
    work: Any = None  #: :class:`relmap.sim.distributed.Work`: chunks, busy seconds, worker threads


def root_seed(seed: SeedLike | np.random.SeedSequence) -> np.random.SeedSequence:
    """The root :class:`numpy.random.SeedSequence` of a run: from an int (or None: fresh
    entropy, reported by the run), as given, or drawn from a Generator (which advances)."""
    if isinstance(seed, np.random.SeedSequence):
        return seed
    if isinstance(seed, np.random.Generator):
        return np.random.SeedSequence(int(seed.integers(2**63)))
    if seed is not None and (int(seed) != seed or seed < 0):
        raise ParameterError(f"seed must be a non-negative integer; got {seed!r}")
    return np.random.SeedSequence(None if seed is None else int(seed))


def block_seed(seed: SeedLike | np.random.SeedSequence, j: int) -> np.random.SeedSequence:
    """The stream of block ``j``: ``SeedSequence(seed).spawn(j + 1)[j]``, built directly, so
    it depends on the seed and ``j`` only (not on how blocks are grouped or where they run)."""
    root = root_seed(seed)
    return np.random.SeedSequence(
        root.entropy, spawn_key=(*root.spawn_key, int(j)), pool_size=root.pool_size
    )


def block_rng(seed: SeedLike | np.random.SeedSequence, j: int) -> np.random.Generator:
    """The generator of block ``j`` (:func:`block_seed`)."""
    return np.random.default_rng(block_seed(seed, j))


Draw = Callable[[Any, np.random.Generator, int], FloatArray]


class _Job(NamedTuple):
    """Everything a worker needs for any block (sent to each worker once)."""

    draw: Draw
    problem: Any
    mean: FloatArray
    cov: FloatArray
    k2: FloatArray
    group: Group
    root: np.random.SeedSequence
    n: int
    block: int
    keep: int


def _run_block(job: _Job, j: int) -> tuple[Tally, FloatArray | None]:
    """Block ``j`` of a run: its samples drawn from their own stream, tallied against the
    estimate; the samples themselves too if they are among the first ``keep``."""
    start = j * job.block
    m = min(job.block, job.n - start)
    seed = block_seed(job.root, j)
    try:
        out = np.asarray(job.draw(job.problem, np.random.default_rng(seed), m), dtype=np.float64)
        d = job.group.minus(out, job.mean)
        tally = Tally.of(d, gaussian.mahalanobis2(d, 0.0, job.cov), job.k2)
    except Exception as exc:
        raise ChunkError(
            f"Monte Carlo block {j} (samples {start}-{start + m - 1}, seed "
            f"SeedSequence(entropy={seed.entropy}, spawn_key={seed.spawn_key})) failed: "
            f"{type(exc).__name__}: {exc}",
            block=j,
            seed=(seed.entropy, seed.spawn_key),
        ) from exc
    return tally, (out[: job.keep - start] if start < job.keep else None)


def run(
    draw: Draw,
    problem: Any,
    estimate: AT | AT3,
    *,
    n: int,
    seed: SeedLike | np.random.SeedSequence = 0,
    block: int,
    probability: float = 0.9,
    client: Any = None,
    keep: int = KEEP,
    progress: Callable[[int, int], None] | None = None,
    chunk_seconds: float | None = None,
) -> Check:
    """Check ``estimate`` against ``n`` samples of ``draw(problem, rng, m) -> (m, *point)``,
    in blocks of ``block`` samples, here or on a Dask cluster, keeping no more than ``keep``.

    Block ``j`` draws samples ``j·block …`` from its own stream (:func:`block_seed`), is
    tallied where it runs (:class:`Tally`, deviations from the estimate's mean), and the
    tallies are merged on the caller's side in block order. The blocks are grouped into
    chunks sized to ``chunk_seconds`` of work (:func:`relmap.sim.distributed.map_blocks`), which
    changes nothing in the result: the same seed gives the same bits in one process or on any
    number of workers, provided they run the same versions of relmap and numpy on the same
    kind of CPU. ``client``: None (this process), a ``distributed.Client`` or a scheduler
    address. ``progress(k, n)`` is called as chunks complete. A block that raises stops the
    run with :class:`relmap.errors.ChunkError` naming its seed.
    """
    from relmap.sim import distributed

    if int(n) != n or n < 2:
        raise ParameterError(f"n must be an integer ≥ 2; got {n}")
    if int(block) != block or block < 1:
        raise ParameterError(f"block must be a positive integer; got {block}")
    if int(keep) != keep or keep < 0:
        raise ParameterError(f"keep must be a non-negative integer; got {keep}")
    n, block, keep = int(n), int(block), int(keep)
    group = estimate.group
    root = root_seed(seed)
    k2 = _k2(estimate.cov, probability, group.dof)
    job = _Job(draw, problem, estimate.mean, estimate.cov, k2, group, root, n, block, keep)
    blocks = -(-n // block)
    ready: dict[int, tuple[Tally, FloatArray | None]] = {}
    state: dict[str, Any] = {"next": 0, "total": None, "done": 0}
    kept: list[FloatArray] = []

    def consume(j: int, result: tuple[Tally, FloatArray | None]) -> None:
        ready[j] = result
        while state["next"] in ready:  # merge in block order: fixed bits, bounded memory
            tally, samples = ready.pop(state["next"])
            state["total"] = tally if state["total"] is None else state["total"].merge(tally)
            if samples is not None:
                kept.append(samples)
            state["next"] += 1
        state["done"] += min(block, n - j * block)

    def chunk_done() -> None:
        if progress is not None:
            progress(state["done"], n)

    work = distributed.map_blocks(
        _run_block, job, blocks, consume, client=client, chunk_seconds=chunk_seconds,
        on_chunk=chunk_done,
    )  # fmt: skip
    total: Tally = state["total"]
    cov = total.m2 / (n - 1)
    summary = Summary(
        n,
        group.plus(estimate.mean, total.mean),
        cov,
        group,
        np.concatenate(kept) if kept else np.empty((0, *group.point_shape)),
        estimate.mean,
        total,
    )
    agreement = _agreement(total, estimate.mean, estimate, probability)
    return Check(summary, agreement, root, blocks, work)


def _draw_operation(problem: tuple[Callable[..., FloatArray], tuple[AT | AT3, ...]],
                    rng: np.random.Generator, m: int) -> FloatArray:  # fmt: skip
    operation, inputs = problem
    return operation(*(a.sample(m, rng) for a in inputs))


def check(
    operation: Callable[..., FloatArray],
    *inputs: AT | AT3,
    estimate: AT | AT3,
    n: int = 100_000,
    seed: SeedLike | np.random.SeedSequence = 0,
    probability: float = 0.9,
    client: Any = None,
    keep: int = KEEP,
    progress: Callable[[int, int], None] | None = None,
) -> Check:
    """:func:`simulate` and :meth:`SampleSet.compare` for samples that need not fit in memory,
    here or on a Dask cluster (``client``: a ``distributed.Client`` or a scheduler address).

    Blocks of :data:`CHECK_BLOCK` samples, each from its own stream (:func:`run`): the same seed
    gives the same numbers wherever it runs (but not the numbers of :func:`simulate`, which
    draws all samples from one generator). ``operation`` must be picklable for a cluster (a
    module-level function such as ``relmap.lie.se2.compose``).
    """
    if not inputs:
        raise ParameterError("check needs at least one input AT")
    if any(a.group is not estimate.group for a in inputs):
        raise ParameterError("the inputs and the estimate must be in the same group")
    return run(
        _draw_operation, (operation, inputs), estimate, n=n, seed=seed, block=CHECK_BLOCK,
        probability=probability, client=client, keep=keep, progress=progress,
    )  # fmt: skip
