"""The clutter of the autocalibration (relmap.filter.autocalibration): the likelihood of a
reading that is of a landmark or of clutter uniform over the measurement volume, against
scipy's densities, and the clutter fraction recovered on a simulated robot whose clutter is
known."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

import relmap.filter as rf
from relmap.filter import autocalibration as ac
from tests.filter.test_autocalibration import (
    CAUTIOUS,
    LANDMARKS,
    MOTION,
    SENSOR,
    SIGMA_B,
    SIGMA_R,
    simulate,
    start,
)
from tests.filter.test_landmarks_clutter import with_clutter


def test_no_clutter_is_the_likelihood_without_it_bit_for_bit():
    rec, _truth = simulate(3, steps=300)
    tr = rf.run(rec.log(), MOTION, SENSOR, LANDMARKS, start=start(0.0), associate="mahalanobis")
    for nu in (np.inf, 4.0):
        assert np.array_equal(ac.loglik(tr, nu, 0.0, 5.0), ac.loglik(tr, nu))


def test_the_mixture_likelihood_is_landmark_or_uniform_clutter():
    """Per paired reading log(g + λ) - log(1 + λV) (the mixture (1 - π) g + π/V over
    1 - π, λ = π/((1 - π) V)), g scipy's Student-t of covariance S (each reading's innovation
    given the readings before it at its time); a LOST reading is clutter."""
    rec, truth = simulate(3, steps=300)
    rec = with_clutter(rec, truth, 7, mover=False)
    tr = rf.run(rec.log(), MOTION, SENSOR, LANDMARKS, start=start(0.0), associate="mahalanobis")
    nu, V, lam = 5.0, 2.5, 0.3
    paired = np.flatnonzero((tr.status == rf.Status.USED) | (tr.status == rf.Status.GATED))
    assert (tr.status == rf.Status.GATED).sum() > 10
    want = 0.0
    for i in paired:
        t = stats.multivariate_t(np.zeros(2), tr.S_given[i] * (nu - 2) / nu, df=nu)
        want += np.log(t.pdf(tr.y_given[i]) + lam) - np.log1p(lam * V)
    want += (tr.status == rf.Status.LOST).sum() * (np.log(lam) - np.log1p(lam * V))
    assert float(ac.loglik(tr, nu, lam, V)) == pytest.approx(want, rel=1e-10)


@pytest.mark.slow
def test_calibration_recovers_the_clutter_fraction():
    """Without signatures the autocalibration fits λ with the rest: the fraction λV/(1 + λV)
    within 0.05 of the simulated one, σ within 10%, from a run of 150 s (measured: 0.409
    against 0.407, σ_r +6.2%, σ_b +4.1%; seeds 2 and 3: 0.397 against 0.395 and 0.413 against
    0.412, σ within 2.4%)."""
    rec, truth = simulate(1, steps=1500)
    rec = with_clutter(rec, truth, 5, radius=0.3)
    cal = ac.calibrate(rec, *CAUTIOUS, LANDMARKS, start=start, associate="mahalanobis")
    frac = float((rec.signature < 0).mean())
    assert cal.clutter_fraction == pytest.approx(frac, abs=0.05)
    assert float(cal.sensor.sigma_range) == pytest.approx(SIGMA_R, rel=0.1)
    assert float(cal.sensor.sigma_bearing) == pytest.approx(SIGMA_B, rel=0.1)
    assert cal.as_dict()["clutter_fraction"] == cal.clutter_fraction
    assert cal.options == {"inflation": cal.inflation, "clutter": cal.clutter} and cal.clutter > 0
    # with signatures the signature names the landmark: no clutter fitted (a short run)
    short, short_truth = simulate(1, steps=300)
    sig = ac.calibrate(with_clutter(short, short_truth, 5, radius=0.3), *CAUTIOUS, LANDMARKS,
                       start=start)  # fmt: skip
    assert sig.clutter == 0.0 and sig.clutter_fraction == 0.0
