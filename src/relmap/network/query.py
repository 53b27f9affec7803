"""``RelationalMap.query``: the AT between any two frames, by the paper's reduction or optimally.

Methods:

- ``"reduce"``: the paper's procedure (§5) — compound, merge, Delta-Y — evaluated once, and
  reported as an expression over the map's AT names, e.g. ``(Aᴿ ⊕ B) ⊗ C ⊗ (D ⊕ E)``.
- ``"optimal"``: the paper's "general method": every frame of the part of the network that
  matters estimated jointly by nonlinear least squares, the AT read off the joint covariance.
- ``"auto"``: where no loop lies between the two frames (every block on the way is a single
  AT), compounding is already the exact first-order answer and ``"reduce"`` is used; wherever
  a loop matters, ``"optimal"`` is used. The estimate reports the method actually used.

Only the 2-connected blocks on the way between the two frames are used (see
:mod:`relmap.network.blocks`); consecutive blocks share one frame, and their ATs compound.

**Beyond first order** (SE(2) maps, ``method="reduce"``): ``moments="exact"`` or
``"unscented"`` makes every compounding (serial chains, and the three inside Delta-Y) and
reversal of the reduction use exact or unscented moments (:mod:`relmap.uncertain.moments`); merges
stay
the Gaussian update of Eqs. (8)-(10) of the moment-matched inputs (see
:mod:`relmap.network.reduce`). ``diagnose=True`` adds :class:`LinearizationCheck` to the
estimate: how far the first-order reduction is from the exact-moments one, predicted without
sampling.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable, Mapping
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from relmap.errors import NumericalError, ParameterError, UnknownATError, UnknownFrameError
from relmap.lie import se2
from relmap.network.blocks import blocks_between
from relmap.network.reduce import DeltaY, OnIrreducible, Reduction, position_trace, reduce_network
from relmap.typing import Option
from relmap.uncertain.algebra import compound, reverse
from relmap.uncertain.at import AT
from relmap.uncertain.at3 import AT3
from relmap.uncertain.moments import MomentsMethod

if TYPE_CHECKING:
    from relmap.network.losses import LossChoice
    from relmap.network.parts import MapView

__all__ = ["Estimate", "LinearizationCheck", "QueryMethod", "linearization_check", "query"]

Frame = Hashable


class QueryMethod(Option):
    """How :func:`query` estimates an AT (the module docstring): the paper's reduction
    (``"reduce"``), the optimal joint estimate (``"optimal"``), or the first wherever no loop lies
    in the way and the second elsewhere (``"auto"``)."""

    AUTO = "auto"
    REDUCE = "reduce"
    OPTIMAL = "optimal"


class LinearizationCheck(NamedTuple):
    """How far the first-order reduction is from the reduction with exact compounding moments:
    the predicted error of the first-order answer, computed without sampling.

    Both reductions evaluate the same expression; they differ in every compounding and
    reversal (Eqs. 1-7 versus :func:`relmap.uncertain.moments.chain_moments` /
    :func:`relmap.uncertain.moments.reverse_moments`). For a chain this is exactly
    :func:`relmap.uncertain.moments.linearization_error` of its last prefix, and predicts the
    relative
    covariance error that Monte Carlo (``relmap validate``) measures. What it does not
    capture: how far from Gaussian the true distribution is (the crescent of Fig. 5; read
    Mardia's skewness from a sample); the error of the merge step itself (merging moment-matched
    Gaussians is not the exact posterior, and both reductions merge alike); and Delta-Y's own
    approximation when there is angular error. Where merges follow compounding, a large value
    says that the branches are far from Gaussian and the answer depends on how they are
    summarized; it is then a warning, not the error of the first-order answer, which can be
    the better of the two (see :mod:`relmap.network.reduce`).
    """

    cov_rel_error: float  #: ‖C_first - C_exact‖_F / ‖C_exact‖_F
    mean_error: np.ndarray  #: (3,) first-order mean ⊟ exact-moments mean (heading wrapped)
    mean_error_sigmas: float  #: Mahalanobis length of mean_error under the first-order cov
    exact: AT  #: the exact-moments reduction (``moments="exact"``)

    def as_dict(self) -> dict[str, object]:
        """JSON-ready: the three figures (the exact AT left out)."""
        return {
            "cov_rel_error": float(self.cov_rel_error),
            "mean_error": [float(v) for v in self.mean_error],
            "mean_error_sigmas": float(self.mean_error_sigmas),
        }


class Estimate(NamedTuple):
    """The estimated AT of frame ``dst`` seen from frame ``src``, and how it was obtained."""

    at: AT | AT3
    method: QueryMethod  #: ``REDUCE`` or ``OPTIMAL``: the method actually used
    expression: str | None  #: the reduction evaluated (AT names, ⊕ ⊗ ᴿ); None when optimal
    src: Frame
    dst: Frame
    dropped: tuple[str, ...] = ()  #: ATs deleted by best deletion (reduce)
    definitions: dict[str, str] = {}  #: Delta-Y star ATs in the expression (reduce)  # noqa: RUF012
    iterations: int | None = None  #: Gauss-Newton/LM iterations (optimal)
    moments: MomentsMethod = MomentsMethod.FIRST_ORDER  #: how compoundings were evaluated (reduce)
    linearization: LinearizationCheck | None = None  #: with ``diagnose=True`` (reduce, SE(2))
    converged: bool | None = None  #: whether the joint solve met its stopping rule (optimal)


def query(
    g: MapView,
    src: Frame,
    dst: Frame,
    *,
    method: QueryMethod | str = QueryMethod.AUTO,
    on_irreducible: OnIrreducible | str = OnIrreducible.RAISE,
    criterion: Callable[[AT | AT3], float] = position_trace,
    moments: MomentsMethod | str = MomentsMethod.FIRST_ORDER,
    diagnose: bool = False,
    delta_y: DeltaY | str = DeltaY.CONSISTENT,
    progress: Callable[[int, int], None] | None = None,
    loss: LossChoice = None,
) -> Estimate:
    """The AT of frame ``dst`` seen from frame ``src`` (mean in ``src``'s frame, covariance
    on ``(x, y, θ)`` in ``src``'s frame).

    ``method`` is a :class:`QueryMethod`: ``"auto"``, ``"reduce"`` or ``"optimal"`` (see the
    module docstring). ``on_irreducible`` (reduce only, an
    :class:`~relmap.network.reduce.OnIrreducible`) is ``"raise"`` or ``"drop"``: delete the
    loop-forming AT whose deletion minimizes ``criterion`` of the result (default: trace of the
    position covariance, m²) when even Delta-Y cannot reduce the network; ``delta_y`` (a
    :class:`~relmap.network.reduce.DeltaY`) chooses Delta-Y's star. Raises
    :class:`relmap.errors.UnknownFrameError` or :class:`relmap.errors.DisconnectedError`.

    ``moments`` (a :class:`~relmap.uncertain.moments.MomentsMethod`; SE(2) maps, reduction
    only): ``"first_order"`` (Eqs. 1-7, default),
    ``"exact"`` or ``"unscented"`` for every compounding and reversal of the reduction.
    Exact: a serial chain gets the exact mean and covariance of its true distribution for
    Gaussian ATs (as ``compound_chain(..., moments="exact")``). Merges remain the Gaussian
    update of Eqs. (8)-(10) applied to the moment-matched inputs — the best linear fusion of
    those means and covariances, *not* the exact posterior of the non-Gaussian inputs (and
    not necessarily closer to it than first order; :mod:`relmap.network.reduce`).
    ``"auto"`` with other moments uses the reduction only where it would anyway (no loop in
    the way) and raises otherwise; ``method="optimal"`` is a joint Gauss-Newton solve, whose
    covariance is the inverse information at the optimum (first order by construction), so
    other moments raise :class:`ParameterError` there, as they do for 3-D maps.

    ``diagnose=True`` (reduction, SE(2)) also evaluates the first-order and the exact-moments
    reductions and reports their difference as ``Estimate.linearization``
    (:class:`LinearizationCheck`); it roughly doubles the cost of the query.

    ``loss`` (:mod:`relmap.network.losses`; one for every AT or by AT name) makes the joint
    solves minimize ``Σ ρ(s²)`` (:func:`relmap.network.optimal.optimize`). It changes nothing
    where no loop lies in the way (every residual is zero at the optimum, every weight 1), so
    ``"auto"`` takes it; ``"reduce"`` refuses any but least squares.
    """
    method = QueryMethod.parse(method, "method")
    moments = MomentsMethod.parse(moments, "moments")
    if loss is not None:  # (imported only when used: dataclasses)
        from relmap.network.losses import L2

        loss = None if isinstance(loss, L2) else loss
    if loss is not None and method is QueryMethod.REDUCE:
        raise ParameterError(
            "a loss applies to method='optimal' (or 'auto'): the reduction is least squares"
        )
    if isinstance(loss, Mapping):
        ends = g.ends()
        unknown = [name for name in loss if name not in ends]
        if unknown:
            raise UnknownATError(f"no AT named {unknown[0]!r} in the map to take a loss")
    src = src.item() if isinstance(src, np.generic) else src  # np.int64(5) is frame 5
    dst = dst.item() if isinstance(dst, np.generic) else dst
    for frame in (src, dst):
        if not g.has_frame(frame):
            raise UnknownFrameError(f"no frame {frame!r} in the map")
    first_order = moments is MomentsMethod.FIRST_ORDER
    beyond = not first_order or diagnose
    what = f"moments={moments.value!r}" if not first_order else "diagnose=True"
    if beyond and g.at_type.dim != 2:
        raise ParameterError(
            f"{what} is available for SE(2) maps only; this map holds 3-D ATs (first order)"
        )
    if beyond and method is QueryMethod.OPTIMAL:
        raise ParameterError(
            f"{what} applies to method='reduce': the optimal method's covariance is the "
            "inverse information matrix at the least-squares optimum, first order by "
            "construction; use method='reduce' (or 'auto' on a map without loops)"
        )
    if method is not QueryMethod.REDUCE and not beyond:
        kept = _from_kept_solve(g, src, dst, loss)  # a kept solve of a part with both frames
        if kept is not None:
            return kept
    ends = g.ends()
    blocks = blocks_between(g.incidence(), ends, src, dst)
    if not blocks:
        at = g.at_type.identity()
        check = LinearizationCheck(0.0, np.zeros(3), 0.0, at) if diagnose else None  # type: ignore[arg-type]
        return Estimate(at, QueryMethod.REDUCE, "I", src, dst, moments=moments, linearization=check)
    if method is QueryMethod.AUTO:
        serial = all(len(b.names) == 1 for b in blocks)
        method = QueryMethod.REDUCE if serial else QueryMethod.OPTIMAL
        if beyond and method is QueryMethod.OPTIMAL:
            raise ParameterError(
                f"{what} applies to the reduction, and method='auto' chose the optimal method "
                "(a loop lies between the frames); ask for method='reduce'"
            )
    order = g.order()
    names = sorted((n for b in blocks for n in b.names), key=order.__getitem__)
    if method is QueryMethod.REDUCE:
        in_play = set(names)
        groups = [(grp.names, grp.cov) for grp in g.groups if in_play & set(grp.names)]
        edges = [(n, *ends[n], g.edge(n).at) for n in names]

        def run(how: MomentsMethod) -> Reduction:
            return reduce_network(
                edges,
                src,
                dst,
                on_irreducible=on_irreducible,
                criterion=criterion,
                groups=groups,
                moments=how,
                delta_y=delta_y,
                progress=progress,
            )

        result = run(moments)
        _check_finite(result.at, src, dst)
        check = None
        if diagnose:
            first = result if first_order else run(MomentsMethod.FIRST_ORDER)
            exact = result if moments is MomentsMethod.EXACT else run(MomentsMethod.EXACT)
            check = _compare(first.at, exact.at)  # type: ignore[arg-type]
        return Estimate(
            result.at,
            QueryMethod.REDUCE,
            result.expression,
            src,
            dst,
            result.dropped,
            result.definitions,
            moments=moments,
            linearization=check,
        )

    from relmap.network.optimal import solve_part  # scipy.sparse: imported only when used

    total: AT | AT3 | None = None
    iterations = 0
    converged = True
    for part in _solve_regions(g, blocks):
        if len(part.names) == 1:
            e = g.edge(part.names[0])
            at = e.at if e.src == part.entry else reverse(e.at)
        else:
            sol = solve_part(g, part.names, part.entry, loss)
            at, iterations = sol.relative(part.entry, part.exit), max(iterations, sol.iterations)
            converged = converged and sol.converged
        total = at if total is None else compound(total, at)
    assert total is not None
    _check_finite(total, src, dst)
    return Estimate(
        total, QueryMethod.OPTIMAL, None, src, dst, iterations=iterations, converged=converged
    )


def _from_kept_solve(g: MapView, src: Frame, dst: Frame, loss: LossChoice) -> Estimate | None:
    """The estimate from a joint solve kept on the map whose part holds both frames (two
    frames of one solved region: the blocks between them lie inside it) under the same
    ``loss``, or None."""
    if src == dst:
        return None
    for key, sol in g.memos():
        if isinstance(key, tuple) and key[0] == "solved":
            if not isinstance(loss, Mapping):
                same = sol.loss == loss
            else:
                from relmap.network.losses import restrict

                same = restrict(loss, frozenset(sol.problem.names)) == sol.loss
            if same and sol.has_frame(src) and sol.has_frame(dst):
                at = sol.relative(src, dst)
                _check_finite(at, src, dst)
                return Estimate(
                    at,
                    QueryMethod.OPTIMAL,
                    None,
                    src,
                    dst,
                    iterations=sol.iterations,
                    converged=sol.converged,
                )
    return None


def _check_finite(at: AT | AT3, src: Frame, dst: Frame) -> None:
    if not (np.all(np.isfinite(at.mean)) and np.all(np.isfinite(at.cov))):
        raise NumericalError(
            f"the AT of frame {dst!r} seen from frame {src!r} overflowed (inf/NaN): the "
            "measurements are too large for floating point"
        )


def _compare(first: AT, exact: AT) -> LinearizationCheck:
    norm = float(np.linalg.norm(exact.cov))
    rel = float(np.linalg.norm(first.cov - exact.cov)) / norm if norm > 0 else 0.0
    err = se2.minus(first.mean, exact.mean)
    # Mahalanobis under the first-order covariance (pseudo-inverse: exactly known directions)
    d2 = float(err @ np.linalg.pinv(first.cov, rcond=1e-12, hermitian=True) @ err)
    return LinearizationCheck(rel, err, float(np.sqrt(max(d2, 0.0))), exact)


def linearization_check(
    g: MapView, src: Frame, dst: Frame, *, on_irreducible: OnIrreducible | str = OnIrreducible.RAISE
) -> LinearizationCheck:
    """Predicted error of the first-order reduction from ``src`` to ``dst`` (SE(2) maps):
    ``query(g, src, dst, method="reduce", diagnose=True).linearization``."""
    est = query(
        g, src, dst, method=QueryMethod.REDUCE, on_irreducible=on_irreducible, diagnose=True
    )
    assert est.linearization is not None
    return est.linearization


class _Region(NamedTuple):
    entry: Frame
    exit: Frame
    names: tuple[str, ...]


def _solve_regions(g: MapView, blocks: list) -> list[_Region]:  # type: ignore[type-arg]
    """Blocks to solve one by one; blocks tied by a dependent group are solved together."""
    regions = [_Region(b.entry, b.exit, b.names) for b in blocks]
    block_of = {n: i for i, r in enumerate(regions) for n in r.names}
    spans: list[list[int]] = []
    for grp in g.groups:
        touched = sorted({block_of[n] for n in grp.names if n in block_of})
        if len(touched) > 1:
            spans.append([touched[0], touched[-1]])
    merged: list[list[int]] = []
    for lo, hi in sorted(spans):
        if merged and lo <= merged[-1][1]:
            merged[-1][1] = max(merged[-1][1], hi)
        else:
            merged.append([lo, hi])
    for lo, hi in reversed(merged):
        lo_region, hi_region = regions[lo], regions[hi]
        fused = tuple(n for r in regions[lo : hi + 1] for n in r.names)
        regions[lo : hi + 1] = [_Region(lo_region.entry, hi_region.exit, fused)]
    return regions
