"""3-D pose-graph optimization and a relative query: relmap vs GTSAM, side by side.

For sphere2500 (and parking-garage, torus3D on request; ``../shared/data/posegraph3d``), the
contenders interleaved in one run (a slow spell hits both), medians of ``--repeat``:

1. relmap end to end: ``read_graph`` + ``solve_graph`` + ``Solution.relative(0, n-1)`` (the AT
   of the last pose seen from the first, with its covariance);
2. GTSAM end to end: ``readG2o(file, True)`` + prior on pose 0 + ``LevenbergMarquardtOptimizer``
   (default parameters: relative and absolute error tolerance 1e-5) + ``Marginals`` +
   ``jointMarginalCovariance(0, n-1)``. GTSAM's reader does not rescale g2o's rotation
   information (g2o's rotation error is the quaternion's vector part, about θ/2; relmap's reader
   converts it to a rotation vector), so this GTSAM solves a slightly different objective;
3. GTSAM on relmap's exact objective, like for like: ``BetweenFactorPose3`` with noise models
   from relmap's covariances (``AT3.to_body``: GTSAM's body, rotation-first convention), from
   relmap's parsed graph (parsing by relmap's reader is included in the time), then as in 2.
   Its residual ``Log(z⁻¹ d)`` agrees with relmap's chart residual to first order, so the two
   objectives at their optima agree to second order in the residuals.

Reported: times, iterations (relmap: accepted steps; factorizations = iterations + 1), final
objectives (``Σ rᵀ Σ⁻¹ r``; GTSAM prints half of it: doubled here), relmap's objective evaluated
at GTSAM's optimum, the relative AT against GTSAM's, and the ratio.

Run: ``python benchmarks/bench_posegraph3d.py [--repeat 5] [--graphs sphere2500 parking-garage torus3D]``.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import gtsam
import numpy as np

import relmap as rm
from relmap.io import read_graph, solve_graph
from relmap.lie import SE3
from relmap.network.optimal import residuals3

DATA = Path(os.environ.get("RELMAP_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))
PRIOR = gtsam.noiseModel.Diagonal.Variances(np.full(6, 1e-10))


def relmap_e2e(path: Path):
    t0 = time.perf_counter()
    graph = read_graph(path)
    sol = solve_graph(graph)
    rel = sol.relative(0, len(graph.vertex_ids) - 1)
    return time.perf_counter() - t0, graph, sol, rel


def _gtsam_solve(graph, initial, n: int):
    graph.add(gtsam.PriorFactorPose3(0, initial.atPose3(0), PRIOR))
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, initial, gtsam.LevenbergMarquardtParams())
    result = optimizer.optimize()
    keys = gtsam.KeyVector()
    keys.append(0)
    keys.append(n - 1)
    joint = gtsam.Marginals(graph, result).jointMarginalCovariance(keys).fullMatrix()
    return graph, result, joint, optimizer.iterations()


def gtsam_e2e(path: Path):
    """GTSAM as it reads g2o files (rotation information not rescaled)."""
    t0 = time.perf_counter()
    graph, initial = gtsam.readG2o(str(path), True)
    out = _gtsam_solve(graph, initial, initial.size())
    return (time.perf_counter() - t0, *out)


def relmap_objective_graph(g) -> gtsam.NonlinearFactorGraph:
    """BetweenFactorPose3 with relmap's covariances in GTSAM's convention (no prior)."""
    m = g.measurements
    body = m.to_body()
    i, j = g.edge_indices()
    graph = gtsam.NonlinearFactorGraph()
    for k in range(len(i)):
        noise = gtsam.noiseModel.Gaussian.Covariance(body[k])
        graph.add(gtsam.BetweenFactorPose3(int(i[k]), int(j[k]), gtsam.Pose3(m.mean[k]), noise))
    return graph


def gtsam_same_objective(path: Path):
    """GTSAM on relmap's objective, from relmap's reader (its parsing time included)."""
    t0 = time.perf_counter()
    g = read_graph(path)
    graph = relmap_objective_graph(g)
    initial = gtsam.Values()
    for k in range(len(g.vertex_ids)):
        initial.insert(k, gtsam.Pose3(g.poses[k]))
    out = _gtsam_solve(graph, initial, len(g.vertex_ids))
    return (time.perf_counter() - t0, *out)


def poses_of(values, n: int) -> np.ndarray:
    return np.array([values.atPose3(k).matrix() for k in range(n)])


def relmap_objective(graph, poses: np.ndarray) -> float:
    """relmap's Σ rᵀ Σ⁻¹ r at the given poses (n, 4, 4), frame rows as in the graph."""
    i, j = graph.edge_indices()
    r, _, _ = residuals3(poses, i, j, graph.measurements.mean)
    W = np.linalg.inv(graph.measurements.cov)
    return float(np.einsum("ka,kab,kb->", r, W, r))


def gtsam_relative(result, joint, n: int) -> rm.AT3:
    """GTSAM's AT of pose n-1 seen from pose 0, in relmap's convention."""
    p0, p1 = result.atPose3(0), result.atPose3(n - 1)
    H0, H1 = np.zeros((6, 6), order="F"), np.zeros((6, 6), order="F")
    d = p0.between(p1, H0, H1)
    J = np.hstack([H0, H1])
    return rm.AT3.from_body(d.matrix(), J @ joint @ J.T)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--graphs", nargs="+", default=["sphere2500"])
    args = parser.parse_args()
    for name in args.graphs:
        path = DATA / "posegraph3d" / f"{name}.g2o"
        t_rel, t_gt, t_same = [], [], []
        for _ in range(args.repeat):
            r = relmap_e2e(path)
            g = gtsam_e2e(path)
            s = gtsam_same_objective(path)
            t_rel.append(r[0])
            t_gt.append(g[0])
            t_same.append(s[0])
        _, graph, sol, rel = r
        _, _, g_result, _, g_iters = g
        _, s_graph, s_result, s_joint, s_iters = s
        n = len(graph.vertex_ids)
        tr, tg, ts = np.median(t_rel), np.median(t_gt), np.median(t_same)
        print(f"\n{name}: {n} poses, {len(graph.edge_from)} edges (medians of {args.repeat})")
        print(
            f"  relmap  read_graph + solve_graph + relative(0, {n - 1})        {tr * 1e3:8.1f} ms"
            f"   ({sol.iterations} iterations, {sol.iterations + 1} factorizations,"
            f" {sol.factor.nnz_L} entries in L)"
        )
        ranges = ", ".join(
            f"{label} {min(t) * 1e3:.0f}-{max(t) * 1e3:.0f} ms"
            for label, t in (("relmap", t_rel), ("GTSAM g2o", t_gt), ("GTSAM same", t_same))
        )
        pairs = [g_ / r_ for r_, g_ in zip(t_rel, t_gt, strict=True)]
        print(
            f"    ranges: {ranges}; run by run relmap {min(pairs):.2f}-{max(pairs):.2f}x faster"
            " than GTSAM g2o   (target >= 3x)"
        )
        print(
            f"  GTSAM   readG2o + LM + Marginals + joint (g2o's objective)    {tg * 1e3:8.1f} ms"
            f"   ({g_iters} iterations)   relmap {tg / tr:.2f}x faster"
        )
        print(
            f"  GTSAM   relmap's objective (read_graph + factors + LM + ...)  {ts * 1e3:8.1f} ms"
            f"   ({s_iters} iterations)   relmap {ts / tr:.2f}x faster"
        )
        s_poses = poses_of(s_result, n)
        g_poses = poses_of(g_result, n)
        print("  objective Σ rᵀΣ⁻¹r (relmap's residual unless stated):")
        print(f"    relmap at its optimum                  {sol.final_error:.10g}")
        print(f"    relmap's at GTSAM's optimum (same obj) {relmap_objective(graph, s_poses):.10g}")
        print(f"    GTSAM's own at its optimum (same obj)  {2 * s_graph.error(s_result):.10g}")
        ours = gtsam.Values()
        for k in range(n):
            ours.insert(k, gtsam.Pose3(sol.poses[k]))
        print(f"    GTSAM's own at relmap's optimum        {2 * s_graph.error(ours):.10g}")
        print(f"    relmap's at GTSAM-g2o's optimum        {relmap_objective(graph, g_poses):.10g}")
        theirs = gtsam_relative(s_result, s_joint, n)
        dm = np.abs(SE3.minus(rel.mean, theirs.mean)).max()
        dc = np.linalg.norm(rel.cov - theirs.cov) / np.linalg.norm(theirs.cov)
        print(
            f"  relative AT 0→{n - 1} vs GTSAM (same objective): mean {dm:.2e} m/rad,"
            f" covariance {dc:.2e} (relative)"
        )
        std = np.sqrt(np.diag(rel.cov))
        print(f"    relmap σ (x y z φx φy φz): {np.array2string(std, precision=4)}")


if __name__ == "__main__":
    main()
