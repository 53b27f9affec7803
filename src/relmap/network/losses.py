"""Losses of the pose-graph optimizer (:mod:`relmap.network.optimal`): robust costs as weights.

Convention. An AT's residual ``r = between(p_i, p_j) ⊟ z`` (relmap's chart, in frame i;
:mod:`relmap.network.problem`) is whitened by its covariance, ``e = L⁻¹ r`` with ``L Lᵀ = Σ``,
so ``s² = |e|² = rᵀ Σ⁻¹ r`` is its squared Mahalanobis norm (a dependent group of ATs is one
joint residual). A loss ``ρ`` makes the optimizer's cost ``Σ_i ρ(s_i²)`` instead of ``Σ_i s_i²``;
it is minimized by iteratively reweighted least squares: at every linearization the AT's
information ``Σ⁻¹`` is multiplied by its weight ``w = ρ'(s²)``, so that the Gauss-Newton
gradient is that of ``Σ ρ(s_i²)`` (the Hessian drops the ``ρ''`` term; Triggs et al. 2000,
"Bundle adjustment — a modern synthesis", on robustified least squares), and
Levenberg-Marquardt accepts a step by the robust cost. Least squares is ``ρ(s²) = s²``,
``w = 1`` (:class:`L2`).

A loss is any object with ``value`` and ``weight`` (:class:`Loss`), vectorized over ATs; a new
one is a small class here and an entry in :data:`LOSSES` (its name for ``relmap solve --loss``).
"""

from __future__ import annotations

import math
from collections.abc import Collection, Mapping
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from relmap.errors import ParameterError
from relmap.typing import FloatArray

__all__ = ["L2", "LOSSES", "Huber", "Loss", "LossChoice", "parse_loss", "restrict"]


@runtime_checkable
class Loss(Protocol):
    """A loss of the squared normalized residual ``s²`` (an array, one entry per AT)."""

    def value(self, s2: FloatArray) -> FloatArray:
        """``ρ(s²)``: the AT's term in the cost (``s²`` for least squares)."""
        ...

    def weight(self, s2: FloatArray) -> FloatArray:
        """``ρ'(s²) = dρ/d(s²)``: the factor on the AT's information (1 for least squares)."""
        ...


#: The losses :mod:`relmap.network.optimal` takes: one for every AT, or by AT name (ATs not
#: named keep least squares); None is least squares.
LossChoice = Loss | Mapping[str, Loss] | None


@dataclass(frozen=True)
class L2:
    """Least squares: ``ρ(s²) = s²``, ``w = 1`` (the optimizer's default)."""

    def value(self, s2: FloatArray) -> FloatArray:
        return np.asarray(s2, dtype=np.float64)

    def weight(self, s2: FloatArray) -> FloatArray:
        return np.ones_like(s2, dtype=np.float64)


@dataclass(frozen=True)
class Huber:
    """Huber's loss on ``s`` (Huber 1964): ``ρ = s²`` for ``s ≤ k``, ``2k s - k²`` beyond (linear
    growth: an AT's pull on the poses is bounded); ``w = min(1, k/s)``. ``k`` in units of the
    whitened residual (σ); default 1.345, the usual constant (GTSAM's ``mEstimator.Huber``,
    whose ρ is half of this one: the same minimizer and weights)."""

    k: float = 1.345

    def __post_init__(self) -> None:
        object.__setattr__(self, "k", _positive(self.k, "Huber's k"))

    def value(self, s2: FloatArray) -> FloatArray:
        s2 = np.asarray(s2, dtype=np.float64)
        s = np.sqrt(s2)
        out = s2.copy()
        beyond = s > self.k
        out[beyond] = self.k * (2.0 * s[beyond] - self.k)
        return out

    def weight(self, s2: FloatArray) -> FloatArray:
        return self.k / np.maximum(np.sqrt(s2), self.k)  # exactly 1 for s ≤ k


def _positive(value: object, what: str) -> float:
    """``value`` as a positive finite float, or a :class:`ParameterError` naming ``what``."""
    try:
        x = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        x = math.nan
    if not (math.isfinite(x) and x > 0):
        raise ParameterError(f"{what} must be a positive finite number; got {value!r}")
    return x


def restrict(loss: LossChoice, names: Collection[str]) -> LossChoice:
    """The choice ``loss`` for a part of the ATs, ``names``: a mapping keeps the names in it
    (None when it names none of them); one loss for all stays as it is."""
    if not isinstance(loss, Mapping):
        return loss
    kept = {name: value for name, value in loss.items() if name in names}
    return kept or None


#: Every loss by its name in ``relmap solve --loss NAME[:PARAMETERS]``.
LOSSES: dict[str, type] = {"l2": L2, "huber": Huber}


def parse_loss(text: str) -> Loss:
    """A loss from ``NAME[:P1,P2,...]`` (e.g. ``huber``, ``huber:2.5``, ``l2``): the class of
    :data:`LOSSES` named, called with the numbers. Bad text raises
    :class:`relmap.errors.ParameterError` naming what was wrong."""
    name, _, params = text.strip().partition(":")
    cls = LOSSES.get(name.strip().lower())
    if cls is None:
        raise ParameterError(
            f"unknown loss {name!r}: expected one of {', '.join(LOSSES)} (e.g. huber:1.345)"
        )
    try:
        args = [float(v) for v in params.split(",")] if params.strip() else []
    except ValueError:
        raise ParameterError(f"loss parameters must be numbers; got {params!r}") from None
    try:
        loss: Loss = cls(*args)
        return loss
    except TypeError:
        raise ParameterError(f"loss {name!r} takes other parameters than {params!r}") from None
