"""relmap.uncertain._sym3 (SE(2)'s fused 3×3 congruences) and relmap.uncertain.gaussian.congruence
against the
matrix products they write out: ``K C Kᵀ``, ``H C Hᵀ``, ``J S Jᵀ``."""

from __future__ import annotations

import numpy as np

from relmap.uncertain import _sym3 as sym3
from relmap.uncertain.gaussian import congruence
from tests.helpers import random_covs


def test_fused_congruences_are_the_matrix_products(rng):
    C = random_covs(rng, (50,))
    t, dx, dy = rng.uniform(-3, 3, 50), rng.normal(size=50), rng.normal(size=50)
    c, s = np.cos(t), np.sin(t)
    K = np.zeros((50, 3, 3))
    K[:, 0, 0], K[:, 0, 1], K[:, 1, 0], K[:, 1, 1], K[:, 2, 2] = c, -s, s, c, 1.0
    H = np.broadcast_to(np.eye(3), (50, 3, 3)).copy()
    H[:, 0, 2], H[:, 1, 2] = -dy, dx
    e = sym3.entries(C)
    np.testing.assert_allclose(sym3.to_matrix(e), C, rtol=0, atol=0)
    np.testing.assert_allclose(sym3.to_matrix(sym3.rotate(e, c, s)), K @ C @ K.transpose(0, 2, 1),
                               rtol=1e-13, atol=1e-15)  # fmt: skip
    np.testing.assert_allclose(sym3.to_matrix(sym3.shear(e, dx, dy)), H @ C @ H.transpose(0, 2, 1),
                               rtol=1e-13, atol=1e-15)  # fmt: skip
    S = random_covs(rng, (50,), n=2)
    a, b, ee, f = rng.normal(size=(4, 50))
    J = np.zeros((50, 3, 2))
    J[:, 0], J[:, 1], J[:, 2, 1] = np.stack([a, ee], -1), np.stack([b, f], -1), 1.0
    out = sym3.congruence_3x2(a, ee, b, f, S[:, 0, 0], S[:, 0, 1], S[:, 1, 1])
    np.testing.assert_allclose(sym3.to_matrix(out), J @ S @ J.transpose(0, 2, 1),
                               rtol=1e-13, atol=1e-15)  # fmt: skip
    np.testing.assert_allclose(congruence(J, S), J @ S @ J.transpose(0, 2, 1), rtol=1e-13)
    assert (congruence(J, S) == congruence(J, S).transpose(0, 2, 1)).all()


def test_one_matrix_gives_python_floats():
    e = sym3.entries(np.diag([1.0, 2.0, 3.0]))
    assert all(type(v) is float for v in e)
    assert sym3.to_matrix(sym3.rotate(e, 0.0, 1.0)).shape == (3, 3)
