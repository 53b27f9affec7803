"""Monte Carlo check of a map query (``relmap validate``; the paper's §6.3 applied to any map).

Every AT of the map that can influence the answer is drawn from its Gaussian, ``n`` times; the
query is re-estimated on each drawn map by the method the query used; the spread of the
re-estimates is compared with the covariance the query predicted. This is the estimator's own
error distribution: for a chain it is the exact (nonlinear) distribution of the compound; with
loops it is the distribution of the merged / jointly optimized estimate when every AT is
perturbed by its stated noise (for a linear problem its covariance is exactly the predicted one,
Gauss-Markov).

- **Reduction** (``method`` ``"reduce"``, or ``"auto"`` when it chose the reduction): the
  paper's procedure runs once on ATs that carry a sample axis, ``mean (n, 3)`` with their
  covariance broadcast: every compounding, merge and Delta-Y step broadcasts over the batch,
  so the ``n`` re-estimates cost one reduction (no Python loop over samples).
- **Optimal**: the joint nonlinear least-squares solve is per map (a map holds single ATs and
  the solver one problem), so each sample is solved in turn; keep ``n`` in the hundreds to
  thousands.

The comparison (:class:`relmap.sim.montecarlo.Agreement`): mean error, relative Frobenius error
of the covariance with its sampling error, NEES (the estimate's rank when it is right),
coverage of the ``probability`` ellipsoid, Mardia's skewness and excess kurtosis (0 and 0 for a
Gaussian).

For SE(2) maps queried by the reduction, the *predicted* error of the first-order answer is
reported beside the sampled one (:class:`relmap.network.query.LinearizationCheck`: first-order
versus exact-moments reduction, no sampling). For a first-order query of a chain it predicts
the sampled covariance error; it does not see non-Gaussianity (Mardia's skewness does) nor the
approximation of merges and Delta-Y.

With ``moments="exact"`` or ``"unscented"`` (SE(2), reduction) only the *prediction* uses
those moments: each sampled map is still reduced with Eqs. (1)-(10), because compounding the
sampled ATs themselves is the true nonlinear function whose distribution the moments describe
(an exact-moments re-estimate would average each sampled map over its own noise once more).
Merges on sampled maps use first-order gains; the exact-moments prediction fuses with gains
from its own covariances, which is the same estimator to first order in the gains.

**Blocks, and clusters.** Samples come in blocks of :data:`BLOCK` (by method); block ``j``
draws from its own stream (``SeedSequence(seed).spawn(j + 1)[j]``) and is reduced to partial
sums (:class:`relmap.sim.montecarlo.Tally`) where it runs; the client merges them in block order.
Memory does not grow with ``n``, and the same seed gives the same bits in this process or on
a Dask cluster of any size (``client=``; :mod:`relmap.sim.distributed`).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Hashable
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from relmap.errors import ParameterError
from relmap.network.query import QueryMethod
from relmap.sim import montecarlo
from relmap.typing import SeedLike
from relmap.uncertain.at import AT
from relmap.uncertain.at3 import AT3

if TYPE_CHECKING:
    from relmap.network.graph import RelationalMap
    from relmap.network.query import Estimate, LinearizationCheck
    from relmap.uncertain.moments import MomentsMethod

__all__ = ["BLOCK", "Plan", "Validation", "plan", "run", "validate_query"]

Frame = Hashable
Progress = Callable[[int, int], None]


class Validation(NamedTuple):
    """The query's estimate, the re-estimates of ``n`` sampled maps, and how well they agree."""

    estimate: Estimate
    samples: montecarlo.Summary  #: moments, and the first samples (for plots)
    agreement: montecarlo.Agreement
    names: tuple[str, ...]  #: the ATs sampled (those that can influence the answer)
    seed: SeedLike
    seconds: float
    #: predicted error of the first-order reduction (SE(2), reduce); None otherwise
    linearization: LinearizationCheck | None = None
    blocks: int = 0  #: blocks of samples, each from its own random stream
    reason: str = ""  #: why the method was used

    def summary(self) -> dict[str, Any]:
        """A JSON-ready dictionary: predicted and empirical moments and the statistics."""
        est, mc, a = self.estimate, self.samples, self.agreement
        spatial = est.at.dim == 3

        def vec(at: AT | AT3) -> list[float]:
            return [float(v) for v in at.vector]

        empirical = mc.as_at()
        return {
            "from": est.src,
            "to": est.dst,
            "method": est.method,
            "expression": est.expression,
            "n": int(mc.n),
            "seed": self.seed if isinstance(self.seed, (int, type(None))) else None,
            "sampled": list(self.names),
            "predicted": {"mean": vec(est.at), "cov": est.at.cov.tolist()},
            "empirical": {"mean": vec(empirical), "cov": empirical.cov.tolist()},
            "mean_error": a.mean_error.tolist(),
            "mean_error_sigmas": a.mean_error_sigmas.tolist(),
            "mean_standard_error": a.mean_standard_error.tolist(),
            "cov_rel_error": float(a.cov_rel_error),
            "cov_rel_standard_error": float(a.cov_rel_standard_error),
            "nees": float(a.nees),
            "nees_expected": int(np.linalg.matrix_rank(est.at.cov)),
            "probability": a.probability,
            "coverage": float(a.coverage),
            "mardia_skewness": float(a.skewness),
            "mardia_excess_kurtosis": float(a.excess_kurtosis),
            "moments": est.moments,
            # first-order vs exact-moments reduction, predicted without sampling (or None)
            "predicted_linearization": (
                None if self.linearization is None else self.linearization.as_dict()
            ),
            "dof": 6 if spatial else 3,
            "blocks": self.blocks,
            "reason": self.reason,
            "seconds": self.seconds,
        }


#: Samples per block, by method: a block is the unit of the random streams and of the partial
#: sums (chunks of blocks go to workers; see :func:`relmap.sim.montecarlo.run`).
BLOCK = {QueryMethod.REDUCE: 4096, QueryMethod.OPTIMAL: 4}


class Plan(NamedTuple):
    """A validation about to run: the query's estimate, what is sampled, the method and why."""

    estimate: Estimate
    names: tuple[str, ...]  #: the ATs sampled (those that can influence the answer)
    reason: str  #: why this method (a sentence)
    query_seconds: float  #: how long the query took
    pilot_seconds: float  #: one sampled map re-estimated (optimal), or 256 at once (reduce)
    linearization: LinearizationCheck | None
    problem: _Problem

    def expected_seconds(self, n: int, workers: int = 1) -> float:
        """A rough forecast of the sampling's time on ``workers`` processes, from the pilot
        (the optimal method re-solves one map per sample; the reduction runs per block)."""
        method = self.estimate.method
        per_block = self.pilot_seconds * (BLOCK[method] if method is QueryMethod.OPTIMAL else 4)
        blocks = -(-int(n) // BLOCK[method])
        return per_block * -(-blocks // max(1, workers))


class _Problem(NamedTuple):
    """What a worker needs to re-estimate sampled maps (sent once per worker): the ATs as two
    stacked arrays, so the message is a few large buffers whatever the map's size."""

    names: tuple[str, ...]
    ends: tuple[tuple[Frame, Frame], ...]
    means: np.ndarray  #: (E, *point) every AT's mean
    covs: np.ndarray  #: (E, dof, dof)
    kind: type  #: AT or AT3
    src: Frame
    dst: Frame
    method: QueryMethod

    @classmethod
    def of(
        cls, g: RelationalMap, names: tuple[str, ...], src: Frame, dst: Frame, method: QueryMethod
    ) -> _Problem:
        edges = [g.edge(name) for name in names]
        return cls(
            names,
            tuple((e.src, e.dst) for e in edges),
            np.stack([e.at.mean for e in edges]),
            np.stack([e.at.cov for e in edges]),
            type(edges[0].at),
            src,
            dst,
            method,
        )


def _draw(problem: _Problem, rng: np.random.Generator, m: int) -> np.ndarray:
    """``m`` sampled maps re-estimated: every AT drawn from its Gaussian (in map order, from
    ``rng``), then one batched reduction, or one optimal solve per sampled map."""
    kind, covs = problem.kind, problem.covs
    ats = [kind._trusted(mean, cov) for mean, cov in zip(problem.means, covs, strict=True)]
    draws = [at.sample(m, rng) for at in ats]
    dof = kind.group.dof
    edges = list(zip(problem.names, problem.ends, covs, draws, strict=True))
    if problem.method is QueryMethod.REDUCE:
        from relmap.network.reduce import reduce_network

        batched = [
            (name, s, t, kind._trusted(d, np.broadcast_to(cov, (m, dof, dof))))
            for name, (s, t), cov, d in edges
        ]
        return reduce_network(batched, problem.src, problem.dst).at.mean
    from relmap.network.graph import RelationalMap

    out = np.empty((m, *kind.group.point_shape))
    for k in range(m):
        h = RelationalMap()
        for name, (s, t), cov, d in edges:
            h.add(s, t, kind._trusted(d[k], cov), name=name)
        out[k] = h.query(problem.src, problem.dst, method=QueryMethod.OPTIMAL).at.mean
    return out


def plan(
    g: RelationalMap,
    src: Frame,
    dst: Frame,
    *,
    method: QueryMethod | str = QueryMethod.AUTO,
    moments: MomentsMethod | str = "first_order",
) -> Plan:
    """Answer the query and decide what :func:`run` will sample and how (see
    :func:`validate_query`)."""
    from relmap.network.blocks import blocks_between

    if g.groups:
        raise ParameterError("validate does not sample dependent ATs (joint groups) yet")
    if src == dst:
        raise ParameterError("FROM and TO are the same frame: nothing to validate")
    t0 = time.perf_counter()
    est = g.query(src, dst, method=method, moments=moments)
    seconds = time.perf_counter() - t0
    check = None
    if est.method is QueryMethod.REDUCE and est.at.dim == 2:  # exact moments are SE(2)'s
        from relmap.network.query import linearization_check

        check = linearization_check(g, src, dst)
    incident = {f: [e.name for e in g.incident(f)] for f in g.frames}
    ends = {e.name: (e.src, e.dst) for e in g.edges()}
    blocks = blocks_between(incident, ends, src, dst)
    in_play = {n for b in blocks for n in b.names}
    names = tuple(e.name for e in g.edges() if e.name in in_play)
    loops = [b for b in blocks if len(b.names) > 1]
    if method != QueryMethod.AUTO:
        reason = f"method {est.method}, as asked"
    elif est.method is QueryMethod.REDUCE:
        reason = (
            "auto chose reduce: no loop lies between the frames, so compounding along the "
            "chain is the first-order answer (one batched reduction per block of samples)"
        )
    else:
        reason = (
            f"auto chose optimal: a loop between the frames matters ({len(loops)} "
            f"2-connected block{'s' if len(loops) > 1 else ''} of "
            f"{sum(len(b.names) for b in loops)} ATs on the way), where the reduction's merges "
            "and Delta-Y are approximations (one joint solve per sampled map)"
        )
    problem = _Problem.of(g, names, src, dst, est.method)
    t1 = time.perf_counter()
    pilot_samples = 1 if est.method is QueryMethod.OPTIMAL else 256
    _draw(problem, np.random.default_rng(0), pilot_samples)  # a pilot
    pilot = time.perf_counter() - t1
    return Plan(est, names, reason, seconds, pilot, check, problem)


def run(
    p: Plan,
    *,
    n: int = 10_000,
    seed: SeedLike | np.random.SeedSequence = 0,
    probability: float = 0.9,
    progress: Progress | None = None,
    client: Any = None,
    keep: int = montecarlo.KEEP,
    chunk_seconds: float | None = None,
) -> Validation:
    """Sample the plan's maps ``n`` times and compare (:func:`validate_query`)."""
    if int(n) != n or n < 2:
        raise ParameterError(f"n must be an integer ≥ 2; got {n}")
    t0 = time.perf_counter() - p.query_seconds - p.pilot_seconds
    mc = montecarlo.run(
        _draw, p.problem, p.estimate.at, n=int(n), seed=seed, block=BLOCK[p.estimate.method],
        probability=probability, client=client, keep=keep, progress=progress,
        chunk_seconds=chunk_seconds,
    )  # fmt: skip
    shown = mc.seed.entropy if seed is None else seed
    return Validation(
        p.estimate, mc.samples, mc.agreement, p.names, shown, time.perf_counter() - t0,
        p.linearization, mc.blocks, p.reason,
    )  # fmt: skip


def validate_query(
    g: RelationalMap,
    src: Frame,
    dst: Frame,
    *,
    method: QueryMethod | str = QueryMethod.AUTO,
    n: int = 10_000,
    seed: SeedLike | np.random.SeedSequence = 0,
    probability: float = 0.9,
    progress: Progress | None = None,
    moments: MomentsMethod | str = "first_order",
    client: Any = None,
    keep: int = montecarlo.KEEP,
) -> Validation:
    """Monte Carlo check of ``g.query(src, dst, method=method)`` with ``n`` sampled maps.

    Every AT on the way between the two frames is drawn independently from its Gaussian, the
    query is re-estimated on each draw by the method it used (see the module docstring), in
    blocks of :data:`BLOCK` samples (block ``j`` from the stream
    :func:`relmap.sim.montecarlo.block_seed` ``(seed, j)``, ATs in map order). The sample is
    summarized by partial sums merged in block order, so memory does not grow with ``n``
    (``Validation.samples.samples`` keeps the first ``keep``), and the same ``seed`` gives the
    same bits here or on a Dask cluster: ``client`` is None (this process), a
    ``distributed.Client`` or a scheduler address (``relmap[distributed]``).
    ``progress(k, n)`` is called as chunks of blocks complete. ``moments`` (SE(2),
    reduction) is how the query's prediction is computed (module docstring). When the
    reduction answers an SE(2) query, ``Validation.linearization`` holds the predicted error of
    its first-order version. Maps with dependent ATs (joint groups) are not supported yet
    (:class:`relmap.errors.ParameterError`).
    """
    if int(n) != n or n < 2:
        raise ParameterError(f"n must be an integer ≥ 2; got {n}")
    p = plan(g, src, dst, method=method, moments=moments)
    return run(
        p, n=n, seed=seed, probability=probability, progress=progress, client=client, keep=keep
    )
