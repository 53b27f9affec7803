"""``relmap demo``: the paper's Fig. 1 robot, end to end, on data shipped with the package.

Four moves A, B, C, D take the robot from W to L4; compounding gives E = A ⊕ B, F = E ⊕ C and
G = F ⊕ D (§3), with uncertainty growing at each move. From L4 the robot senses W (AT S);
reversing S and merging it with G (§4) shrinks the uncertainty of L4 relative to W. A Monte
Carlo simulation checks G (§6.3).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from importlib import resources
from typing import TextIO

import numpy as np

from relmap import montecarlo
from relmap.at import AT, merge
from relmap.io.mapfile import ATRecord, read_records
from relmap.lie import se2

__all__ = ["Fig1", "fig1", "print_fig1"]

MC_SAMPLES = 100_000
PROBABILITY = 0.90


@dataclass(frozen=True)
class Fig1:
    """Everything the Fig. 1 demo computes (rows as ``(label, from, to, AT)``)."""

    inputs: list[ATRecord]
    compounds: list[tuple[str, str, str, AT]]
    sensed_reversed: AT
    merged: AT
    monte_carlo: montecarlo.Agreement


def fig1(seed: int = 0) -> Fig1:
    """Run the Fig. 1 example on the shipped ``fig1.json``."""
    with resources.as_file(resources.files("relmap") / "data" / "fig1.json") as path:
        records = read_records(path)
    at = {r.name: r.at for r in records}
    E = at["A"] @ at["B"]
    F = E @ at["C"]
    G = F @ at["D"]
    S_rev = at["S"].reverse()
    mc = montecarlo.simulate(
        lambda a, b, c, d: se2.compose(se2.compose(se2.compose(a, b), c), d),
        at["A"],
        at["B"],
        at["C"],
        at["D"],
        n=MC_SAMPLES,
        seed=seed,
    ).compare(G, PROBABILITY)
    return Fig1(
        inputs=records,
        compounds=[
            ("E = A ⊕ B", "W", "L2", E),
            ("F = E ⊕ C", "W", "L3", F),
            ("G = F ⊕ D", "W", "L4", G),
        ],
        sensed_reversed=S_rev,
        merged=merge(G, S_rev),
        monte_carlo=mc,
    )


_HEAD = (
    f"{'AT':<12}{'frames':<10}{'x [m]':>9}{'y [m]':>9}{'θ [°]':>9}{'σx [m]':>9}{'σy [m]':>9}"
    f"{'σθ [°]':>8}{'a90 [m]':>9}{'b90 [m]':>9}{'φ90 [°]':>9}"
)


def _row(label: str, src: object, dst: object, at: AT) -> str:
    x, y, t = at.mean
    sx, sy, st = at.sigmas
    e = at.ellipse(PROBABILITY)
    return (
        f"{label:<12}{f'{src}→{dst}':<10}{x:9.3f}{y:9.3f}{np.degrees(t):9.2f}{sx:9.4f}{sy:9.4f}"
        f"{np.degrees(st):8.3f}{float(e.semi_major):9.4f}{float(e.semi_minor):9.4f}"
        f"{np.degrees(float(e.angle)):9.2f}"
    )


def print_fig1(result: Fig1, out: TextIO = sys.stdout) -> None:
    """Print the demo's tables."""
    w = out.write
    w("relmap demo: Smith & Cheeseman (1986), Fig. 1 - four moves, then a sensed AT merged\n")
    w(
        f"a90, b90, φ90: half-axes and major-axis direction of the {PROBABILITY:.0%} "
        "confidence ellipse\n\n"
    )
    w("Input ATs (relmap/data/fig1.json)\n" + _HEAD + "\n")
    for r in result.inputs:
        w(_row(r.name, r.src, r.dst, r.at) + "\n")
    w("\nCompounding (Eqs. 1-4): uncertainty of each position relative to W grows\n" + _HEAD + "\n")
    for label, src, dst, at in result.compounds:
        w(_row(label, src, dst, at) + "\n")
    G = result.compounds[-1][3]
    w("\nSensing W from L4, reversed (Eqs. 5-7), and merged with G (Eqs. 8-10)\n" + _HEAD + "\n")
    w(_row("Sᴿ", "W", "L4", result.sensed_reversed) + "\n")
    w(_row("G ⊗ Sᴿ", "W", "L4", result.merged) + "\n")
    before, after = G.ellipse(PROBABILITY), result.merged.ellipse(PROBABILITY)
    ratio = float(after.semi_major * after.semi_minor / (before.semi_major * before.semi_minor))
    w(
        f"\nMerging shrinks the {PROBABILITY:.0%} ellipse of L4 to {ratio:.1%} of its area; "
        f"σθ {np.degrees(G.sigmas[2]):.2f}° → {np.degrees(result.merged.sigmas[2]):.2f}°\n"
    )
    mc = result.monte_carlo
    w(
        f"\nMonte Carlo check of G (§6.3, {mc.n:,} samples): covariance relative error "
        f"{float(mc.cov_rel_error):.2%} (sampling error ±{float(mc.cov_rel_standard_error):.2%}), "
        f"mean error {np.hypot(*mc.mean_error[:2]) * 1000:.1f} mm, "
        f"{float(mc.coverage):.1%} of samples inside the {PROBABILITY:.0%} ellipsoid\n"
    )
