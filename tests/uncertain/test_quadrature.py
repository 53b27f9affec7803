"""relmap.uncertain.quadrature: the adaptive Gauss-Legendre engine against integrals known in
closed form, many elements at once, each to its tolerance."""

from __future__ import annotations

import math

import numpy as np
import pytest

from relmap.errors import NumericalError, SolverError
from relmap.uncertain.quadrature import adaptive, panels, split_panels


def test_integrals_in_closed_form_each_to_its_tolerance():
    # element k: ∫ cos(ω_k x) dx over [0, b_k] = sin(ω_k b_k) / ω_k, one panel each
    omega = np.array([0.5, 3.0, 40.0, 200.0])
    b = np.array([1.0, 2.0, 1.5, 0.7])
    for tol in (1e-6, 1e-12):
        value, error = adaptive(
            lambda x, e: np.cos(omega[e][:, None] * x), np.zeros(4), b, np.arange(4), 4, tol, "t"
        )
        np.testing.assert_allclose(value, np.sin(omega * b) / omega, rtol=0, atol=tol)
        assert (error <= tol).all()


def test_a_narrow_peak_cut_at_its_centre():
    """A Gaussian of σ 0.02 inside [-1, 2], cut at its centre: the integral is 1 (to 1e-12)."""
    s = 0.02
    lo, hi, owner = split_panels(np.array([-1.0]), np.array([2.0]), np.array([[0.3]]))
    assert owner.tolist() == [0, 0] and lo.tolist() == [-1.0, 0.3] and hi.tolist() == [0.3, 2.0]

    def pdf(x, e):
        return np.exp(-0.5 * ((x - 0.3) / s) ** 2) / (s * math.sqrt(2 * math.pi))

    value, _ = adaptive(pdf, lo, hi, owner, 1, 1e-12, "peak")
    assert value[0] == pytest.approx(1.0, abs=1e-12)


def test_panels_ignore_non_finite_cuts_and_clip_the_rest():
    lo, hi, owner = panels(
        np.array([0.0, 5.0]),
        np.array([1.0, 6.0]),
        np.array([0, 0, 1]),
        np.array([np.nan, 3.0, 5.5]),
    )
    assert list(zip(lo, hi, owner, strict=True)) == [(0.0, 1.0, 0), (5.0, 5.5, 1), (5.5, 6.0, 1)]


def test_overflow_is_a_numerical_error():
    with pytest.raises(NumericalError, match="overflow"):
        adaptive(
            lambda x, e: np.exp(1e3 * x), np.zeros(1), np.ones(1), np.zeros(1, int), 1, 1e-9, "o"
        )


def test_no_convergence_within_the_levels_is_a_solver_error(monkeypatch):
    from relmap.uncertain import quadrature

    monkeypatch.setattr(quadrature, "MAX_LEVELS", 2)  # cos(200 x) on [0, 1] needs more
    with pytest.raises(SolverError, match="did not reach tol=1e-12 after 2"):
        adaptive(lambda x, e: np.cos(200 * x), np.zeros(1), np.ones(1), np.zeros(1, int), 1,
                 1e-12, "c")  # fmt: skip
