"""3-D real graphs against GTSAM and against ground truth: the figures behind
``tests/test_optimal_real3d.py``.

For sphere2500 and parking-garage: relmap's optimum vs GTSAM LM on the same objective (relmap's
covariances given to ``BetweenFactorPose3`` in GTSAM's body chart): objective gap, pose
differences, relative ATs of far-apart pairs against GTSAM's ``Marginals``. For sphere2500 also
the RMSE against ``sphere2500_groundtruth.txt`` (aligned by the first pose) of the initial guess,
relmap, GTSAM with ``readG2o``'s unscaled information, and relmap with the file's numbers read as
1/σ (the iSAM trap: see ``../shared/data/README.md``), and χ² per edge at the ground truth under
both readings (6 for correctly whitened 6-D errors).

Run from the project root: ``python benchmarks/study_posegraph3d.py`` (data in ``../shared/data``
or ``$RELMAP_DATA``).
"""

from __future__ import annotations

import sys
import time
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import gtsam
import numpy as np

from relmap.io import read_graph, solve_graph
from relmap.lie import se3
from tests.conftest import _data_root
from tests.network.test_optimal_3d import (
    _compare_relative,
    _gtsam_relative,
    _native,
    _optimize,
    _poses,
    _rmse,
    _square_root_corrected,
    _values,
)


def main() -> None:
    warnings.simplefilter("ignore")
    root = _data_root() / "posegraph3d"
    for name in ["sphere2500.g2o", "parking-garage.g2o"]:
        g = read_graph(root / name)
        t = time.perf_counter()
        sol = solve_graph(g)
        ts = time.perf_counter() - t
        f = _native(g)
        t = time.perf_counter()
        prior, res = _optimize(f, g)
        tg = time.perf_counter() - t
        theirs, at_ours = 2 * f.error(res), 2 * f.error(_values(sol.poses, g.vertex_ids))
        d = se3.minus(_poses(res, g.vertex_ids), sol.poses)
        print(
            f"{name}: relmap {ts:.2f} s ({sol.iterations} iterations), GTSAM LM {tg:.2f} s; "
            f"GTSAM's objective at relmap's optimum vs its own minimum: rel gap "
            f"{(at_ours - theirs) / theirs:.2e}; poses differ by ≤ {np.abs(d[:, :3]).max():.2e} m, "
            f"{np.abs(d[:, 3:]).max():.2e} rad"
        )
        m = gtsam.Marginals(prior, res)
        n = len(g.vertex_ids)
        for a, b in [(0, n - 1), (n // 3, 2 * n // 3)]:
            mean, cov = _compare_relative(
                sol.relative(a, b),
                _gtsam_relative(m, res, int(g.vertex_ids[a]), int(g.vertex_ids[b])),
            )
            print(f"  relative AT {a}→{b} vs GTSAM: mean {mean:.2e} σ, covariance {cov:.2e} rel")
        if name.startswith("sphere"):
            truth = read_graph(root / "sphere2500_groundtruth.txt").poses
            print("  RMSE vs ground truth (position m, rotation rad):")
            print("    initial guess              {:.3f}  {:.4f}".format(*_rmse(g.poses, truth)))
            print("    relmap                     {:.3f}  {:.4f}".format(*_rmse(sol.poses, truth)))
            fg, _ = gtsam.readG2o(str(root / name), True)
            _, r2 = _optimize(fg, g)
            print(
                "    GTSAM, readG2o             {:.3f}  {:.4f}".format(
                    *_rmse(_poses(r2, g.vertex_ids), truth)
                )
            )
            fx = _square_root_corrected(g)
            print(
                "    relmap, numbers as 1/σ     {:.3f}  {:.4f}".format(
                    *_rmse(solve_graph(fx).poses, truth)
                )
            )
            i, j = g.edge_indices()
            r = se3.minus(se3.between(truth[i], truth[j]), g.measurements.matrix)
            for label, meas in (("as written", g.measurements), ("as 1/σ", fx.measurements)):
                chi2 = np.einsum("ka,kab,kb->k", r, np.linalg.inv(meas.cov), r).mean()
                print(f"  χ² per edge at the ground truth, information {label}: {chi2:.2f}")


if __name__ == "__main__":
    main()
