"""Real data: the Intel Research Lab odometry chain, compounded by relmap and by GTSAM."""

from __future__ import annotations

import gtsam
import numpy as np

import relmap as rm
from relmap.lie import se2


def _odometry_edges(path):
    """Consecutive EDGE_SE2 i → i+1 of a g2o file as (means, body information matrices)."""
    means, infos = [], []
    with open(path) as fh:
        for line in fh:
            f = line.split()
            if f and f[0] == "EDGE_SE2" and int(f[2]) == int(f[1]) + 1:
                v = [float(x) for x in f[3:12]]
                means.append(v[:3])
                i11, i12, i13, i22, i23, i33 = v[3:]
                infos.append([[i11, i12, i13], [i12, i22, i23], [i13, i23, i33]])
    return np.array(means), np.array(infos)


def test_intel_odometry_chain_matches_gtsam(data_dir):
    means, infos = _odometry_edges(data_dir / "posegraph2d" / "intel.g2o")
    assert len(means) > 1000
    cov_body = np.linalg.inv(infos)  # g2o: information of the error in the measurement's body frame
    steps = rm.AT.from_body(means, cov_body)
    chain = rm.compound_chain(steps)

    pose, cov = gtsam.Pose2(), np.zeros((3, 3))
    for k in range(len(means)):
        H1, H2 = np.zeros((3, 3), order="F"), np.zeros((3, 3), order="F")
        pose = pose.compose(gtsam.Pose2(*means[k]), H1, H2)
        cov = H1 @ cov @ H1.T + H2 @ cov_body[k] @ H2.T
        if k in (10, 500, len(means) - 1):
            expected = rm.AT.from_body([pose.x(), pose.y(), pose.theta()], cov)
            np.testing.assert_allclose(chain.mean[k, :2], expected.mean[:2], atol=1e-9)
            assert abs(se2.angle_difference(chain.mean[k, 2], expected.mean[2])) < 1e-9
            rel = np.linalg.norm(chain.cov[k] - expected.cov) / np.linalg.norm(expected.cov)
            assert rel < 1e-9
