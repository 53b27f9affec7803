"""Evaluating an estimated trajectory against a reference: evo's APE and RPE, and what evo has
not — whether the estimate's covariance is honest (:mod:`.consistency`).

:func:`evaluate` runs the steps in order: associate (:mod:`.association`), align
(:mod:`.alignment`), the errors and their statistics (:mod:`.metrics`), the consistency when
the estimate carries a covariance. ``relmap eval`` prints its :meth:`Evaluation.summary`.
"""

from __future__ import annotations

from typing import NamedTuple

from relmap.errors import ParameterError
from relmap.evaluate.alignment import Alignment, AlignMode, align, umeyama
from relmap.evaluate.association import Association, associate, interpolate
from relmap.evaluate.consistency import Consistency, consistency, relative_consistency
from relmap.evaluate.metrics import (
    STATISTICS,
    DeltaUnit,
    Errors,
    Relation,
    ape,
    pairs,
    rpe,
    statistics,
)
from relmap.uncertain.trajectory import Trajectory

__all__ = [
    "STATISTICS",
    "AlignMode",
    "Alignment",
    "Association",
    "Consistency",
    "DeltaUnit",
    "Errors",
    "Evaluation",
    "Relation",
    "align",
    "ape",
    "associate",
    "consistency",
    "evaluate",
    "interpolate",
    "pairs",
    "relative_consistency",
    "rpe",
    "statistics",
    "umeyama",
]


class Evaluation(NamedTuple):
    """The result of :func:`evaluate`."""

    ref: Trajectory  #: the reference at the associated times
    est: Trajectory  #: the estimate at the associated times, aligned
    association: Association
    alignment: Alignment
    ape: dict[str, Errors]  #: relation → per-pose errors
    rpe: dict[str, Errors]  #: relation → per-pair errors (empty unless asked)
    rpe_options: dict[str, object]
    consistency: Consistency | None  #: None when the estimate has no covariance

    def summary(self) -> dict[str, object]:
        """JSON-able: pairs, alignment, APE/RPE statistics, consistency."""
        a = self.alignment
        out: dict[str, object] = {
            "reference": self.ref.source,
            "estimate": self.est.source,
            "pairs": len(self.est),
            "alignment": {
                "mode": a.mode,
                "rotation": a.rotation.tolist(),
                "translation": a.translation.tolist(),
                "scale": a.scale,
            },
            "ape": {k: e.stats() for k, e in self.ape.items()},
        }
        if self.rpe:
            out["rpe"] = {k: e.stats() for k, e in self.rpe.items()}
            out["rpe_options"] = self.rpe_options
        out["consistency"] = None if self.consistency is None else self.consistency.summary()
        return out


def evaluate(
    ref: Trajectory,
    est: Trajectory,
    *,
    align_mode: AlignMode | str = AlignMode.NONE,
    n_align: int | None = None,
    max_diff: float = 0.01,
    offset: float = 0.0,
    interpolate_ref: bool = False,
    relations: tuple[Relation | str, ...] = (Relation.TRANS, Relation.ANGLE_DEG),
    rpe_delta: float | None = None,
    rpe_unit: DeltaUnit | str = DeltaUnit.FRAMES,
    all_pairs: bool = False,
    rel_tol: float = 0.1,
    pairs_from_reference: bool = False,
) -> Evaluation:
    """Associate, align, measure, judge (module docstring); ``rpe_delta=None``: no RPE.
    ``align_mode`` is an :class:`AlignMode`, ``relations`` are :class:`Relation` s,
    ``rpe_unit`` a :class:`DeltaUnit`."""
    relations = tuple(Relation.parse(r, "pose relation") for r in relations)
    rpe_unit = DeltaUnit.parse(rpe_unit, "delta unit")
    if ref.is_planar != est.is_planar:
        raise ParameterError(
            f"{est.source or 'the estimate'} is {'planar' if est.is_planar else '3-D'} and "
            f"{ref.source or 'the reference'} is {'planar' if ref.is_planar else '3-D'}: "
            "both must be of one kind (relmap convert writes either)"
        )
    pairing = (
        interpolate(ref, est, offset=offset)
        if interpolate_ref
        else associate(ref, est, max_diff=max_diff, offset=offset)
    )
    r, e = pairing.ref, pairing.est
    e, alignment = align(e, r, align_mode, n=n_align)
    P, Q = e.matrices, r.matrices
    apes = {rel: ape(P, Q, rel) for rel in relations}
    rpes: dict[str, Errors] = {}
    options: dict[str, object] = {}
    if rpe_delta is not None:
        options = {
            "delta": rpe_delta,
            "unit": rpe_unit,
            "all_pairs": all_pairs,
            "pairs_from_reference": pairs_from_reference,
        }
        rpes = {
            rel: rpe(
                P,
                Q,
                rel,
                delta=rpe_delta,
                unit=rpe_unit,
                all_pairs=all_pairs,
                rel_tol=rel_tol,
                pairs_from_reference=pairs_from_reference,
                stamps=e.stamps,
            )
            for rel in relations
        }
    judged = consistency(r, e) if e.has_cov else None
    return Evaluation(r, e, pairing, alignment, apes, rpes, options, judged)
