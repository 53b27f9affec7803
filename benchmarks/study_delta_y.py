"""Delta-Y with heading error: the tables of docs/delta_y.md.

1. The bridge of Figs. 3-4: w→u on ``relmap/data/fig3.json`` with every AT's heading σ set to
   0.5°, 1°, 3°, 5°, 10° (means made loop-consistent), σx = σy = 5 cm as in the file and once
   more with σy = 1 cm: the first-order-consistent Delta-Y (relmap's default) and the paper's
   formulas against the optimal estimate, w→u against the reversed u→w, and each reduction
   re-run on sampled ATs against its own prediction (Monte Carlo). Relative Frobenius errors
   of the 3×3 covariance.
2. ``--solves N``: the optimal estimator (Gauss-Newton) re-run on N sampled bridges at
   σy = 1 cm, σθ = 5° against its own prediction, for comparison with the reduction's row.
3. ``--maps N`` random small maps (8-12 ATs over 5-8 frames, a spanning tree plus loops,
   anisotropic rotated position errors, σθ up to 10°, means made loop-consistent): the
   reduction (first frame to last) against the optimal estimate.

Run: ``python benchmarks/study_delta_y.py [--samples 20000] [--seed 0] [--solves 2000]
[--maps 300]``.
"""

from __future__ import annotations

import argparse

import numpy as np

import relmap as rm
from relmap.app.demo import DELTA_Y_HEADER, _shipped, delta_y_rows, delta_y_study
from relmap.errors import IrreducibleNetworkError
from relmap.lie import se2
from relmap.sim import montecarlo
from relmap.uncertain import gaussian


def random_map(rng: np.random.Generator) -> list[tuple[str, str, rm.AT]]:
    """(src, dst, AT) of a random small map with loop-consistent means."""
    nf = int(rng.integers(5, 9))
    m = int(rng.integers(max(8, nf), 13))
    truth = np.column_stack([rng.uniform(-3, 3, (nf, 2)), rng.uniform(-np.pi, np.pi, nf)])
    pairs = [(int(rng.integers(0, k)), k) for k in range(1, nf)]
    while len(pairs) < m:
        a, b = (int(x) for x in rng.choice(nf, 2, replace=False))
        pairs.append((a, b))
    out = []
    for a, b in pairs:
        sig = [rng.uniform(0.01, 0.3), rng.uniform(0.01, 0.3), np.radians(rng.uniform(0.1, 10))]
        C = np.zeros((3, 3))
        C[:2, :2] = gaussian.rotated_covariance(sig[0], sig[1], rng.uniform(0, np.pi))
        C[2, 2] = sig[2] ** 2
        out.append((f"f{a}", f"f{b}", rm.AT(se2.between(truth[a], truth[b]), C)))
    return out


def random_maps(n: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    errors, refused = [], 0
    for _ in range(n):
        g = rm.RelationalMap()
        for a, b, at in random_map(rng):
            g.add(a, b, at)
        s, t = g.frames[0], g.frames[-1]
        opt = g.query(s, t, method="optimal").at.cov
        try:
            red = g.query(s, t, method="reduce").at.cov
        except IrreducibleNetworkError:
            refused += 1
            continue
        errors.append(np.linalg.norm(red - opt) / np.linalg.norm(opt))
    e = np.array(errors)
    print(
        f"\n{n} random maps (seed {seed}), reduction vs optimal estimate: refused {refused}; "
        f"within 1e-9: {np.mean(e < 1e-9):.0%}; median {np.median(e):.2e}; "
        f"90th percentile {np.quantile(e, 0.9):.2%}; worst {e.max():.1%}"
    )


def optimal_spread(n: int, seed: int, sigma_y: float = 0.01, sigma_deg: float = 5.0) -> None:
    """Gauss-Newton on n sampled bridges (loop-consistent means) against its prediction."""
    sig = np.array([0.05, sigma_y, np.radians(sigma_deg)])
    g = rm.RelationalMap()
    for r in _shipped("fig3.json"):
        g.add(r.src, r.dst, rm.AT.from_sigmas(r.at.mean, sig), name=r.name)
    sol = g.solve("w")
    h = rm.RelationalMap()
    for e in g.edges():
        h.add(
            e.src,
            e.dst,
            rm.AT(se2.between(sol.pose(e.src), sol.pose(e.dst)), e.at.cov),
            name=e.name,
        )
    truth = se2.between(sol.pose("w"), sol.pose("u"))
    rng = np.random.default_rng(seed)
    draws = {e.name: e.at.sample(n, rng) for e in h.edges()}
    est = []
    for i in range(n):
        k = rm.RelationalMap()
        for e in h.edges():
            k.add(e.src, e.dst, rm.AT(draws[e.name][i], e.at.cov), name=e.name)
        est.append(k.query("w", "u", method="optimal").at.mean)
    pred = h.query("w", "u", method="optimal").at
    rep = montecarlo.SampleSet.of(np.array(est)).compare(rm.AT(truth, pred.cov))
    print(
        f"\noptimal estimator on {n} sampled bridges (σy {sigma_y:g} m, σθ {sigma_deg:g}°) vs its "
        f"prediction: {rep.cov_rel_error:.1%} ± {rep.cov_rel_standard_error:.1%}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=20_000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--solves", type=int, default=2000)
    parser.add_argument("--maps", type=int, default=300)
    args = parser.parse_args()
    rows = delta_y_rows(delta_y_study(args.seed, args.samples))
    print("| " + " | ".join(DELTA_Y_HEADER) + " |")
    print("|" + "---|" * len(DELTA_Y_HEADER))
    for row in rows:
        print("| " + " | ".join(row) + " |")
    if args.solves:
        optimal_spread(args.solves, args.seed)
    if args.maps:
        random_maps(args.maps, args.seed + 1)


if __name__ == "__main__":
    main()
