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

The comparison (:class:`relmap.montecarlo.Agreement`): mean error, relative Frobenius error
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
"""

from __future__ import annotations

import time
from collections.abc import Callable, Hashable
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from relmap import montecarlo
from relmap.at import AT
from relmap.at3 import AT3
from relmap.errors import ParameterError
from relmap.typing import SeedLike

if TYPE_CHECKING:
    from relmap.network.graph import RelationalMap
    from relmap.network.query import Estimate, LinearizationCheck

__all__ = ["Validation", "validate_query"]

Frame = Hashable
Progress = Callable[[int, int], None]


class Validation(NamedTuple):
    """The query's estimate, the re-estimates of ``n`` sampled maps, and how well they agree."""

    estimate: Estimate
    samples: montecarlo.SampleSet
    agreement: montecarlo.Agreement
    names: tuple[str, ...]  #: the ATs sampled (those that can influence the answer)
    seed: SeedLike
    seconds: float
    #: predicted error of the first-order reduction (SE(2), reduce); None otherwise
    linearization: LinearizationCheck | None = None

    def summary(self) -> dict[str, Any]:
        """A JSON-ready dictionary: predicted and empirical moments and the statistics."""
        est, mc, a = self.estimate, self.samples, self.agreement
        spatial = isinstance(est.at, AT3)

        def vec(at: AT | AT3) -> list[float]:
            return [float(v) for v in (at.vector if isinstance(at, AT3) else at.mean)]

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
            "seconds": self.seconds,
        }


def relevant_names(g: RelationalMap, src: Frame, dst: Frame) -> tuple[str, ...]:
    """The ATs of the 2-connected blocks on the way from ``src`` to ``dst`` (map order): the
    only ones a query between the two frames depends on."""
    from relmap.network.blocks import blocks_between

    incident = {f: [e.name for e in g.incident(f)] for f in g.frames}
    ends = {e.name: (e.src, e.dst) for e in g.edges()}
    in_play = {n for b in blocks_between(incident, ends, src, dst) for n in b.names}
    return tuple(e.name for e in g.edges() if e.name in in_play)


def validate_query(
    g: RelationalMap,
    src: Frame,
    dst: Frame,
    *,
    method: str = "auto",
    n: int = 10_000,
    seed: SeedLike = 0,
    probability: float = 0.9,
    progress: Progress | None = None,
    moments: str = "first_order",
) -> Validation:
    """Monte Carlo check of ``g.query(src, dst, method=method)`` with ``n`` sampled maps.

    Every AT on the way between the two frames is drawn independently from its Gaussian (one
    generator seeded by ``seed``, ATs in map order); the query is re-estimated on each draw by
    the method it used (see the module docstring). ``progress(k, n)`` is called while the
    optimal method works through the samples. ``moments`` (SE(2), reduction) is how the
    query's prediction is computed (module docstring). When the reduction answers an SE(2) query,
    ``Validation.linearization`` holds the predicted error of its first-order version. Maps
    with dependent ATs (joint groups) are not supported yet
    (:class:`relmap.errors.ParameterError`).
    """
    if int(n) != n or n < 2:
        raise ParameterError(f"n must be an integer ≥ 2; got {n}")
    n = int(n)
    if g.groups:
        raise ParameterError("validate does not sample dependent ATs (joint groups) yet")
    if src == dst:
        raise ParameterError("FROM and TO are the same frame: nothing to validate")
    t0 = time.perf_counter()
    est = g.query(src, dst, method=method, moments=moments)
    check = None
    if est.method == "reduce" and isinstance(est.at, AT):
        from relmap.network.query import linearization_check

        check = linearization_check(g, src, dst)
    names = relevant_names(g, src, dst)
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    edges = [g.edge(name) for name in names]
    draws = [e.at.sample(n, rng) for e in edges]
    kind = type(est.at)
    dof = kind.group.dof
    if est.method == "reduce":
        from relmap.network.reduce import reduce_network

        batched = [
            (e.name, e.src, e.dst, kind._trusted(d, np.broadcast_to(e.at.cov, (n, dof, dof))))
            for e, d in zip(edges, draws, strict=True)
        ]
        out = reduce_network(batched, src, dst).at.mean
    else:
        from relmap.network.graph import RelationalMap

        out = np.empty((n, *kind.group.point_shape))
        for k in range(n):
            h = RelationalMap()
            for e, d in zip(edges, draws, strict=True):
                h.add(e.src, e.dst, kind._trusted(d[k], e.at.cov), name=e.name)
            out[k] = h.query(src, dst, method="optimal").at.mean
            if progress is not None:
                progress(k + 1, n)
    samples = montecarlo.SampleSet.of(out, kind.group)
    agreement = samples.compare(est.at, probability)
    seconds = time.perf_counter() - t0
    return Validation(est, samples, agreement, names, seed, seconds, check)
