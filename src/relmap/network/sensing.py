"""The sensing procedure of §6.2, and decisions about sensing made before any reading.

1. *Can the sensor see it?* The AT of the object seen from the sensor is predicted from the
   map; the probability that it lies in the field of view is computed
   (:func:`relmap.models.decisions.in_view`).
2. *Is the reading reasonable?* The reading is compared with the prediction: its squared
   Mahalanobis distance ``d² = vᵀ (P + R)⁻¹ v`` (v the wrapped innovation) against the χ²
   quantile of the chosen probability (:func:`glitch_test`). A glitch is reported, never merged.
3. *Combine.* An accepted reading becomes an AT of the map.

And ahead of time: the covariance a proposed sensing would leave (:func:`covariance_after`,
a merge that needs no reading), and its effect on any other relation of the map
(:meth:`RelationalMap.forecast_sensing`).
"""

from __future__ import annotations

from collections.abc import Hashable
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from relmap.errors import DisconnectedError, ParameterError, ShapeError, UnknownFrameError
from relmap.network.query import Estimate, QueryMethod, query
from relmap.typing import ArrayLike, FloatArray
from relmap.uncertain import gaussian
from relmap.uncertain.algebra import merge
from relmap.uncertain.at import AT
from relmap.uncertain.at3 import AT3
from relmap.uncertain.pose import UncertainPose

if TYPE_CHECKING:
    from relmap.network.parts import EditableMap

__all__ = [
    "GlitchTest",
    "SensingDecision",
    "SensingForecast",
    "covariance_after",
    "forecast_sensing",
    "glitch_test",
    "sense",
]

Frame = Hashable


class GlitchTest(NamedTuple):
    """The outcome of testing a reading against its prediction."""

    mahalanobis2: float  #: d² of the innovation under P + R
    threshold: float  #: the χ² quantile at ``probability`` with ``dof`` degrees of freedom
    dof: int  #: the rank of P + R (exactly known directions add none)
    p_value: float  #: probability of a reading at least this far from the prediction
    accepted: bool  #: d² ≤ threshold


def glitch_test(predicted: AT | AT3, reading: AT | AT3, probability: float = 0.99) -> GlitchTest:
    """Is ``reading`` (an AT of the same relation as ``predicted``) plausible? (§6.2 step 2)

    Innovation ``v = reading ⊟ predicted`` (heading wrapped; in 3-D the chart difference
    ``(δt, δφ)``), ``S = P + R`` (independent), and
    ``d² = vᵀ S⁻¹ v``; accepted when ``d² ≤ χ²_dof(probability)``. A reading that leaves the
    subspace where S has variance (disagrees with an exactly known component) has d² = ∞.
    """
    from scipy.special import gammaincc

    gaussian.check_probability(probability)
    if predicted.ndim or reading.ndim:
        raise ShapeError("glitch_test compares single ATs")
    if type(predicted) is not type(reading):
        raise TypeError(
            f"cannot compare a {type(reading).__name__} with a {type(predicted).__name__}"
        )
    group = predicted.group
    v = group.minus(reading.mean, predicted.mean)
    S = predicted.cov + reading.cov
    d2 = float(gaussian.mahalanobis2(v, np.zeros(group.dof), S))
    _, null = gaussian.generalized_inverse(S)
    dof = group.dof - int((np.abs(null).sum(axis=0) > 0).sum())
    threshold = float(gaussian.confidence_k2(probability, dof)) if dof else 0.0
    p_value = float(gammaincc(dof / 2, d2 / 2)) if dof and np.isfinite(d2) else float(d2 == 0)
    return GlitchTest(d2, threshold, dof, p_value, bool(d2 <= threshold))


def covariance_after(prior: AT | AT3, sensor_cov: ArrayLike) -> FloatArray:
    """The covariance of a relation after a proposed sensing of it, before any reading.

    Merging (Eqs. 8-10) needs the readings only for the mean: the covariance it leaves is known
    ahead of time. ``sensor_cov`` (3, 3), or (6, 6) for an AT3, is the sensing's covariance in
    the relation's frame.
    """
    cov = gaussian.validate_covariance(sensor_cov, dim=prior.group.dof, name="sensor cov")
    return merge(prior, type(prior)._trusted(prior.mean, cov)).cov


class SensingForecast(NamedTuple):
    """The relation of interest before and after a proposed sensing elsewhere in the map."""

    before: Estimate
    after: Estimate
    #: ratio of the 90% position-ellipse areas (ellipsoid volumes in 3-D), after / before
    position_shrink: float
    #: ratio of the heading standard deviations (in 3-D: of √trace of the rotation covariance)
    heading_shrink: float


def forecast_sensing(
    g: EditableMap,
    sensed: tuple[Frame, Frame],
    sensor_cov: ArrayLike,
    of_interest: tuple[Frame, Frame],
    *,
    method: QueryMethod | str = QueryMethod.AUTO,
) -> SensingForecast:
    """How much would sensing the relation ``sensed = (a, b)`` improve ``of_interest = (c, d)``?

    The sensing is added to a copy of the map as an AT from a to b, its mean the current
    estimate (a reading's value does not change covariances to first order) and its covariance
    ``sensor_cov``; the relation of interest is queried before and after. Nothing is read and
    the map is not changed.
    """
    before = query(g, *of_interest, method=method)
    predicted = query(g, *sensed, method=method).at
    cov = gaussian.validate_covariance(sensor_cov, dim=predicted.group.dof, name="sensor cov")
    trial = g.copy()
    proposed = type(predicted)._trusted(predicted.mean, cov)
    trial.add(sensed[0], sensed[1], proposed, name=_fresh(trial, "proposed sensing"))
    after = query(trial, *of_interest, method=method)
    k = predicted.dim  # the position block; the rotation block follows it
    C0, C1 = before.at.cov, after.at.cov
    area = np.sqrt(np.linalg.det(C1[:k, :k]) / max(np.linalg.det(C0[:k, :k]), 1e-300))
    rot0, rot1 = np.trace(C0[k:, k:]), np.trace(C1[k:, k:])
    heading = float(np.sqrt(rot1 / rot0)) if rot0 > 0 else 1.0
    return SensingForecast(before, after, float(area), heading)


class SensingDecision(NamedTuple):
    """What :func:`sense` decided, and why."""

    added: bool  #: whether the reading was added to the map
    name: str | None  #: its AT name if added
    reason: str  #: a sentence saying why
    predicted: (
        AT | AT3 | None
    )  #: the map's prediction of the relation before the reading (None: none)
    visible_probability: float | None  #: probability the object was in view (if a view was given)
    glitch: GlitchTest | None  #: the test of the reading against the prediction


def sense(
    g: EditableMap,
    src: Frame,
    dst: Frame,
    reading: AT | AT3,
    *,
    name: str | None = None,
    probability: float = 0.99,
    fov: float | None = None,
    max_range: float | None = None,
    min_visible: float = 0.9,
    method: QueryMethod | str = QueryMethod.AUTO,
) -> SensingDecision:
    """Perform §6.2: predict the sensed relation, check it can be sensed, test the reading,
    and add it to the map as an AT from ``src`` (the sensor's frame) to ``dst``.

    With ``fov``/``max_range`` the object must be in view with probability ≥ ``min_visible``
    (else the sensing is declined before the reading is used). The reading must pass
    :func:`glitch_test` at ``probability``. The map changes only if the reading is added.
    """
    gaussian.check_probability(min_visible, "min_visible")
    if not isinstance(reading, UncertainPose):
        raise ParameterError(
            f"the reading must be an AT (or an AT3 in a 3-D map); got {type(reading).__name__}"
        )
    for label, value in (("fov", fov), ("max_range", max_range)):
        if value is not None and not (
            isinstance(value, (int, float, np.floating, np.integer)) and np.isfinite(value)
        ):
            raise ParameterError(f"{label} must be a finite number; got {value!r}")
    try:
        predicted: AT | AT3 | None = query(g, src, dst, method=method).at
    except (DisconnectedError, UnknownFrameError):
        predicted = None  # a new frame, or frames not yet related: nothing to predict
    visible = None
    if fov is not None or max_range is not None:
        if predicted is None:
            return SensingDecision(
                False,
                None,
                "no prediction of the relation to check visibility against",
                None,
                None,
                None,
            )
        if predicted.dim != 2:
            raise ParameterError("field-of-view and range checks are planar; this map is 3-D")
        from relmap.models.decisions import in_view

        # Without a range limit the view is the sector alone: a range far beyond every
        # plausible position (50 σ past the mean's distance) changes nothing.
        reach = float(np.hypot(*predicted.mean[:2])) + 50.0 * float(
            np.sqrt(np.trace(predicted.cov[:2, :2]))
        )
        view = in_view(
            predicted,
            2 * np.pi if fov is None else fov,
            max(reach, 1.0) if max_range is None else max_range,
        )
        visible = float(view.probability)
        if visible < min_visible:
            return SensingDecision(
                False,
                None,
                f"the object is in view with probability {visible:.3g} only "
                f"(< {min_visible:g}): not sensed",
                predicted,
                visible,
                None,
            )
    if predicted is None:
        added = g.add(src, dst, reading, name=name)
        return SensingDecision(
            True,
            added,
            "no prior relation between the frames: the reading is the first",
            None,
            visible,
            None,
        )
    test = glitch_test(predicted, reading, probability)
    if not test.accepted:
        return SensingDecision(
            False,
            None,
            f"glitch: the reading is {np.sqrt(test.mahalanobis2):.3g} standard deviations from "
            f"the prediction (d² = {test.mahalanobis2:.3g} > {test.threshold:.3g}, "
            f"p = {test.p_value:.2g}); rejected",
            predicted,
            visible,
            test,
        )
    added = g.add(src, dst, reading, name=name)
    return SensingDecision(
        True,
        added,
        f"consistent with the prediction (d² = {test.mahalanobis2:.3g} ≤ "
        f"{test.threshold:.3g}): added",
        predicted,
        visible,
        test,
    )


def _fresh(g: EditableMap, base: str) -> str:
    name, k = base, 1
    while name in g:
        k += 1
        name = f"{base} {k}"
    return name
