"""Is the estimate's covariance honest? NEES, ANEES, coverage and a verdict.

At every associated time the error of the estimate is taken in the chart its covariance is in
(``DESIGN.md``): ``δ = truth ⊟ estimate`` — planar ``(x_r - x_e, y_r - y_e, wrap(θ_r - θ_e))``,
3-D ``(t_r - t_e, Log(R_r R_eᵀ))`` (translation in the parent frame, rotation on the left) — and
its normalized estimation error squared ``NEES = δᵀ C⁻¹ δ`` (Bar-Shalom, Li & Kirubarajan 2001,
§5.4) for the position, the orientation and the full pose. A covariance that is singular
(an exactly planar 3-D estimate: no variance in z, roll, pitch) is inverted on its support
(:func:`relmap.uncertain.gaussian.generalized_inverse`): the NEES has as many degrees of freedom as
the
covariance has rank, and an error off the support makes it infinite. When the reference carries
a covariance too (neither is the truth, e.g. AMCL against odometry), the covariance of the
difference is the sum of the two (independent errors, to first order in the same chart).

For a consistent estimator NEES ~ χ²_d. Over N times, the ANEES (the mean NEES divided by d)
has the two-sided interval ``[χ²_{Nd}(α/2), χ²_{Nd}(1-α/2)] / (N d)`` — valid for independent
errors; a filter's errors are correlated in time, so read the interval as a lower bound on
the spread. Coverage: the fraction of times the truth lies inside the p-ellipsoid
(``NEES ≤ χ²_d(p)``), to compare with p. Per-axis normalized errors ``δ_k / σ_k`` should have
mean 0 and standard deviation 1. The verdict compares ANEES with its interval: inside,
consistent; above, overconfident (the covariance too small by about the factor ANEES); below,
underconfident.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from relmap.errors import ParameterError
from relmap.lie import se2, se3
from relmap.typing import FloatArray, IntArray
from relmap.uncertain import gaussian
from relmap.uncertain.trajectory import Trajectory

__all__ = [
    "Consistency",
    "Nees",
    "chart_errors",
    "consistency",
    "nees",
    "relative_consistency",
    "verdict",
]

DEFAULT_COVERAGE = (0.5, 0.9, 0.99)


class Nees(NamedTuple):
    """NEES of one block (position, orientation or full pose) at each time."""

    block: str
    values: FloatArray  #: (n,) NEES
    dof: FloatArray  #: (n,) degrees of freedom (the covariance's rank)
    anees: float  #: sum(NEES) / sum(dof)
    interval: tuple[float, float]  #: two-sided interval of ANEES for a consistent estimate
    coverage: dict[float, float]  #: p → fraction of times with NEES ≤ χ²_dof(p)

    @property
    def verdict(self) -> str:
        return verdict(self.anees, self.interval)


class Consistency(NamedTuple):
    """The consistency of an estimate's covariance against a reference."""

    errors: FloatArray  #: (n, d) chart errors δ = truth ⊟ estimate
    sigmas: FloatArray  #: (n, d) standard deviations of the error's covariance
    normalized: FloatArray  #: (n, d) δ_k / σ_k (NaN where σ_k = 0)
    blocks: dict[str, Nees]  #: "position", "orientation", "pose"
    axes: tuple[str, ...]  #: names of the d chart axes
    confidence: float  #: the two-sided interval's probability

    @property
    def verdict(self) -> str:
        """One line: the full pose's verdict, with its ANEES and interval."""
        b = self.blocks["pose"]
        lo, hi = b.interval
        return (
            f"{b.verdict} (pose ANEES {b.anees:.3g}, "
            f"{self.confidence:.0%} interval [{lo:.3g}, {hi:.3g}])"
        )

    def summary(self) -> dict[str, object]:
        out: dict[str, object] = {"verdict": self.verdict}
        for name, b in self.blocks.items():
            out[name] = {
                "anees": b.anees,
                "interval": list(b.interval),
                "verdict": b.verdict,
                "coverage": {f"{p:g}": c for p, c in b.coverage.items()},
            }
        finite = np.where(np.isfinite(self.normalized), self.normalized, np.nan)
        out["normalized"] = {
            a: {
                "mean": _nanstat(np.nanmean, finite[:, k]),
                "std": _nanstat(np.nanstd, finite[:, k]),
            }
            for k, a in enumerate(self.axes)
        }
        return out


def _nanstat(f, x: FloatArray) -> float | None:  # type: ignore[no-untyped-def]
    return None if not np.isfinite(x).any() else float(f(x))


def chart_errors(ref: Trajectory, est: Trajectory) -> FloatArray:
    """``truth ⊟ estimate`` (n, 3) planar or (n, 6) 3-D, in the estimate's chart."""
    if ref.is_planar and est.is_planar:
        return se2.minus(ref.poses.mean, est.poses.mean)
    return se3.minus(ref.matrices, est.matrices)


def nees(
    delta: FloatArray, cov: FloatArray, *, atol: float = 1e-9
) -> tuple[FloatArray, FloatArray]:
    """``δᵀ C⁺ δ`` (n,) and the rank of C (n,); ``inf`` for an error off C's support."""
    G, null = gaussian.generalized_inverse(cov)
    d2 = np.einsum("...i,...ij,...j->...", delta, G, delta)
    rank = cov.shape[-1] - (np.abs(null).sum(axis=-2) > 0).sum(axis=-1)
    off = np.abs(np.einsum("...ij,...i->...j", null, delta)).max(axis=-1) > atol
    return np.where(off, np.inf, d2), rank.astype(np.float64)


def verdict(anees: float, interval: tuple[float, float]) -> str:
    """``consistent``, ``overconfident by a factor F`` or ``underconfident by a factor F``."""
    lo, hi = interval
    if not np.isfinite(anees):
        return "overconfident: errors where the covariance claims exact knowledge"
    if anees > hi:
        return f"overconfident by a factor {anees:.3g} (covariance too small)"
    if anees < lo:
        factor = 1 / anees if anees > 0 else np.inf
        return f"underconfident by a factor {factor:.3g} (covariance too large)"
    return "consistent"


def consistency(
    ref: Trajectory,
    est: Trajectory,
    *,
    coverage: tuple[float, ...] = DEFAULT_COVERAGE,
    confidence: float = 0.95,
) -> Consistency:
    """NEES, ANEES, coverage and normalized errors of associated ``est`` against ``ref``."""
    if not est.has_cov:
        raise ParameterError(f"{est.source or 'the estimate'} carries no covariance")
    if len(ref) != len(est):
        raise ParameterError("consistency needs associated trajectories (as many poses)")
    gaussian.check_probability(confidence, "confidence")
    planar = ref.is_planar and est.is_planar
    C = np.array(est.poses.cov)
    if not planar and est.is_planar:
        raise ParameterError(
            "a planar estimate's covariance cannot be judged against a 3-D reference"
        )
    if ref.has_cov and ref.is_planar == est.is_planar:
        C = C + ref.poses.cov
    delta = chart_errors(ref, est)
    d = delta.shape[1]
    half = 2 if planar else 3
    slices = {"position": slice(0, half), "orientation": slice(half, d), "pose": slice(0, d)}
    blocks = {}
    alpha = 1.0 - confidence
    for name, sl in slices.items():
        v, dof = nees(delta[:, sl], C[:, sl, sl])
        total = float(dof.sum())
        if total == 0:
            continue
        anees = float(v.sum() / total)
        lo = float(gaussian.confidence_k2(alpha / 2, int(total)) / total)
        hi = float(gaussian.confidence_k2(1 - alpha / 2, int(total)) / total)
        cover = {}
        for p in coverage:
            k2 = np.array(
                [gaussian.confidence_k2(p, int(r)) if r > 0 else np.inf for r in np.unique(dof)]
            )
            limit = k2[np.searchsorted(np.unique(dof), dof)]
            cover[float(p)] = float(np.mean(v <= limit))
        blocks[name] = Nees(name, v, dof, anees, (lo, hi), cover)
    sig = np.sqrt(np.clip(np.diagonal(C, axis1=-2, axis2=-1), 0, None))
    with np.errstate(divide="ignore", invalid="ignore"):
        normalized = np.where(sig > 0, delta / np.where(sig > 0, sig, 1.0), np.nan)
    axes = ("x", "y", "θ") if planar else ("x", "y", "z", "φx", "φy", "φz")
    return Consistency(delta, sig, normalized, blocks, axes, confidence)


def relative_consistency(
    solution: Any,
    truth: FloatArray,
    first: IntArray,
    second: IntArray,
    *,
    confidence: float = 0.95,
) -> Nees:
    """NEES of relative poses where the joint covariance of the two poses is known: a solved
    pose graph (:class:`relmap.network.optimal.Solution`, e.g. from
    :func:`relmap.io.solve_graph`). For each pair ``(a, b)`` the AT of b seen from a with its
    first-order covariance from the joint covariance of a and b
    (:meth:`~relmap.network.optimal.Solution.relative`) is compared with the true relative pose
    from ``truth`` (``(n, 3)`` planar or ``(n, 4, 4)``, the graph's vertex order), the error in
    the chart of frame a."""
    truth = np.asarray(truth, dtype=np.float64)
    a_idx, b_idx = np.asarray(first, dtype=np.intp), np.asarray(second, dtype=np.intp)
    if a_idx.shape != b_idx.shape or not a_idx.size:
        raise ParameterError("need as many first and second frames, at least one pair")
    ats = [solution.relative(int(a), int(b)) for a, b in zip(a_idx, b_idx, strict=True)]
    planar = truth.ndim == 2
    if planar:
        rel_true = se2.between(truth[a_idx], truth[b_idx])
        delta = se2.minus(rel_true, np.array([at.mean for at in ats]))
    else:
        rel_true = se3.between(truth[a_idx], truth[b_idx])
        delta = se3.minus(rel_true, np.array([at.matrix for at in ats]))
    C = np.array([at.cov for at in ats])
    v, dof = nees(delta, C)
    total = float(dof.sum())
    alpha = 1.0 - confidence
    lo = float(gaussian.confidence_k2(alpha / 2, int(total)) / total)
    hi = float(gaussian.confidence_k2(1 - alpha / 2, int(total)) / total)
    d = round(total / len(v))
    cover = {p: float(np.mean(v <= gaussian.confidence_k2(p, d))) for p in DEFAULT_COVERAGE}
    return Nees("relative pose", v, dof, float(v.sum() / total), (lo, hi), cover)
