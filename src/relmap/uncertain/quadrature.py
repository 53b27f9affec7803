"""Vectorized adaptive Gauss-Legendre quadrature over many intervals at once.

A batch of 1-D integrals (one or more panels per element, pre-cut at the integrand's narrow
features with :func:`panels`) is integrated to an absolute tolerance per element; the only
Python loop is over bisection levels, never over elements or nodes. On every panel the
``GL_POINTS``-point rule is compared with the same rule on the panel's two halves; the
difference (an estimate of the coarser rule's error) is accepted when it is at most ``tol/2``
times the panel's share of the element's interval, and an element is finished as soon as its
accepted and pending error estimates add up to at most ``tol``; unfinished panels are bisected.
The returned value is the sum of the finer estimates. Used by :mod:`relmap.models.decisions`.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from relmap.errors import NumericalError, SolverError
from relmap.typing import FloatArray, IntArray

__all__ = ["GL_POINTS", "MAX_LEVELS", "adaptive", "panels", "split_panels"]

#: Gauss-Legendre points per panel of the adaptive quadrature.
GL_POINTS = 10
#: Bisection levels before the adaptive quadrature gives up (raises SolverError).
MAX_LEVELS = 60


def adaptive(
    func: Callable[[FloatArray, IntArray], FloatArray],
    lo: FloatArray,
    hi: FloatArray,
    elem: IntArray,
    n_elem: int,
    tol: float,
    what: str,
) -> tuple[FloatArray, FloatArray]:
    """Integrate ``func`` over the panels ``[lo, hi]`` of each element, to ``tol`` absolute.

    ``func(x, e)`` evaluates the integrand at points ``x`` (P, n) of panels belonging to elements
    ``e`` (P,). Returns the integral per element ``(n_elem,)`` and its error estimate.
    Panels are processed all at once; the only Python loop is over bisection levels.
    """
    xg, wg = np.polynomial.legendre.leggauss(GL_POINTS)
    total_width = np.bincount(elem, weights=hi - lo, minlength=n_elem)
    total_width = np.where(total_width > 0.0, total_width, 1.0)

    def rule(a: FloatArray, b: FloatArray, e: IntArray) -> FloatArray:
        half = 0.5 * (b - a)
        vals = func(0.5 * (a + b)[:, None] + half[:, None] * xg, e)
        return half * (vals @ wg)

    value = np.zeros(n_elem)
    error = np.zeros(n_elem)
    coarse = rule(lo, hi, elem)
    for _ in range(MAX_LEVELS):
        if lo.size == 0:
            break
        n = lo.size
        mid = 0.5 * (lo + hi)
        halves = rule(np.concatenate([lo, mid]), np.concatenate([mid, hi]), np.tile(elem, 2))
        left, right = halves[:n], halves[n:]
        fine = left + right
        err = np.abs(fine - coarse)
        if not np.isfinite(err).all():  # bisecting would not help: stop before memory runs out
            k = int(elem[np.flatnonzero(~np.isfinite(err))[0]])
            raise NumericalError(
                f"{what}: the integrand overflowed the floating-point range (batch element {k} "
                "of the flattened batch; variances or positions too large)"
            )
        accept = err <= 0.5 * tol * (hi - lo) / total_width[elem]
        done = error + np.bincount(elem, weights=err, minlength=n_elem) <= tol
        accept |= done[elem]
        value += np.bincount(elem, weights=fine * accept, minlength=n_elem)
        error += np.bincount(elem, weights=err * accept, minlength=n_elem)
        go = ~accept
        lo, hi = np.concatenate([lo[go], mid[go]]), np.concatenate([mid[go], hi[go]])
        elem = np.concatenate([elem[go], elem[go]])
        coarse = np.concatenate([left[go], right[go]])
    if lo.size:
        raise SolverError(
            f"{what}: adaptive quadrature did not reach tol={tol:g} after {MAX_LEVELS} "
            f"bisection levels (batch element {int(elem[0])} of the flattened batch)"
        )
    return value, error


def panels(
    lo: FloatArray, hi: FloatArray, cut_owner: IntArray, cut_value: FloatArray
) -> tuple[FloatArray, FloatArray, IntArray]:
    """Cut the intervals ``[lo_i, hi_i]`` (n,) at the points ``cut_value`` of ``cut_owner``.

    Cuts may come in any order, number and value (non-finite ones are ignored, the others are
    clipped to their interval). Returns flat ``(lo, hi, owner)`` of the non-empty panels.
    """
    ok = np.isfinite(cut_value)
    cut_owner, cut_value = cut_owner[ok], cut_value[ok]
    n = lo.size
    owner = np.concatenate([np.arange(n), np.arange(n), cut_owner])
    value = np.concatenate([lo, hi, np.clip(cut_value, lo[cut_owner], hi[cut_owner])])
    order = np.lexsort((value, owner))
    owner, value = owner[order], value[order]
    keep = (owner[1:] == owner[:-1]) & (value[1:] > value[:-1])
    return value[:-1][keep], value[1:][keep], owner[:-1][keep]


def split_panels(
    lo: FloatArray, hi: FloatArray, cuts: FloatArray
) -> tuple[FloatArray, FloatArray, IntArray]:
    """:func:`panels` with ``cuts`` given as a ``(n, K)`` array."""
    owner = np.repeat(np.arange(lo.size), cuts.shape[1])
    return panels(lo, hi, owner, cuts.ravel())
