"""relmap.network.problem.compose_tree: poses composed along a spanning tree, against the poses
that generated noise-free measurements (SE(2) and SE(3), disconnected parts, reversed ATs, a
chain deeper than one pointer-jumping round)."""

from __future__ import annotations

import numpy as np
import pytest

from relmap.lie import SE2, SE3
from relmap.network.problem import compose_tree


@pytest.mark.parametrize("group", [SE2, SE3], ids=["SE2", "SE3"])
def test_compose_tree_recovers_the_poses_of_noise_free_measurements(group):
    """Two parts, frames 0-39 (a long chain with loops and ATs stored backwards) and 40-49 (a
    star) plus a frame with no AT: each part comes back relative to its lowest frame, which is
    at the identity (1e-9), the frame alone at the identity."""
    rng = np.random.default_rng(4)
    n = 51
    truth = group.plus(group.identity((n,)), rng.normal(size=(n, group.dof)))
    chain = np.arange(39)
    i = np.concatenate([chain, [0, 5, 30], np.full(9, 45)])
    j = np.concatenate([chain + 1, [39, 20, 7], [40, 41, 42, 43, 44, 46, 47, 48, 49]])
    flip = rng.random(len(i)) < 0.4  # some ATs stored the other way round
    i, j = np.where(flip, j, i), np.where(flip, i, j)
    order = rng.permutation(len(i))
    i, j = i[order], j[order]
    z = group.between(truth[i], truth[j])
    poses = compose_tree(n, i, j, z, group)
    assert poses.shape == truth.shape
    for part in (np.arange(40), np.arange(40, 50)):
        expected = group.between(truth[part[0]], truth[part])
        np.testing.assert_allclose(group.minus(poses[part], expected), 0.0, atol=1e-9)
        np.testing.assert_array_equal(poses[part[0]], group.identity(()))
    np.testing.assert_array_equal(poses[50], group.identity(()))
