"""``relmap demo``: the paper reproduced, on data shipped with the package.

Fig. 1: four moves A, B, C, D take the robot from W to L4; compounding gives E = A ⊕ B,
F = E ⊕ C and G = F ⊕ D (§3), with uncertainty growing at each move. From L4 the robot senses W
(AT S); reversing S and merging it with G (§4) shrinks the uncertainty of L4 relative to W. A
Monte Carlo simulation checks G (§6.3).

:func:`run` computes, beyond Fig. 1, the Wheatstone bridge of Figs. 3-4 (reduction, Delta-Y,
the optimal estimate, Monte Carlo), the §6.3 study of Fig. 5 (first order against Monte Carlo
as the angular error grows), decisions ahead of time (§6: door, field of view) before and after
the sensing, and the lecture's examples (arm, dead reckoning, EKF localization, simulated and,
with ``data``, on MRCLAM). :func:`print_demo` prints the key numbers;
:func:`relmap.app.demo_report.write_report` writes the HTML report with its figures. Every number
shown is computed here.
"""

from __future__ import annotations

import functools
import os
import sys
import time
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Protocol, TextIO

import numpy as np

from relmap.errors import IrreducibleNetworkError
from relmap.io.mapfile import ATRecord, read_records
from relmap.lie import se2
from relmap.models.arm import PlanarArm
from relmap.models.decisions import DoorDecision, ViewDecision
from relmap.network.graph import RelationalMap
from relmap.sim import montecarlo
from relmap.uncertain import gaussian
from relmap.uncertain.algebra import compound_chain, merge
from relmap.uncertain.at import AT
from relmap.uncertain.propagate import Moments

if TYPE_CHECKING:  # pragma: no cover
    from relmap.app.localize import Localization, Score
    from relmap.app.validate import Validation
    from relmap.network.query import Estimate

__all__ = [
    "Bridge",
    "ChainCheck",
    "DeltaYRow",
    "Demo",
    "Fig1",
    "Fig5",
    "Lecture",
    "bridge",
    "decisions",
    "delta_y_study",
    "fig1",
    "fig5",
    "lecture",
    "print_demo",
    "print_fig1",
    "run",
]

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


def _shipped(name: str) -> list[ATRecord]:
    with resources.as_file(resources.files("relmap") / "data" / name) as path:
        return read_records(path)


def fig1(seed: int = 0, n: int = MC_SAMPLES) -> Fig1:
    """Run the Fig. 1 example on the shipped ``fig1.json`` (Monte Carlo with ``n`` samples)."""
    records = _shipped("fig1.json")
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
        n=n,
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


# =============================================================================== the rest
# Scenario parameters (inputs, not results): every number shown is computed from these.
BRIDGE_PAIRS = (("t", "v"), ("w", "u"))  # t→v: series-parallel; w→u: needs Delta-Y
BRIDGE_SAMPLES_REDUCE = 20_000  # the reduction runs once on a batch of sampled maps
BRIDGE_SAMPLES_OPTIMAL = 500  # the optimal method solves each sampled map in turn
LINK = (1.0, 0.0, 0.0)  # §6.3 study: each link 1 m straight ahead ...
LINK_SIGMA_XY = 0.02  # ... with σx = σy = 2 cm and an angular σ from SIGMAS_DEG
SIGMAS_DEG = (1.0, 3.0, 6.0, 10.0)
CHAIN_LINKS = 20
DOOR_AHEAD = (1.5, 0.0, 0.0)  # the door, 1.5 m ahead of L4's nominal pose, facing along it
DOOR_WIDTH, ROBOT_WIDTH = 0.9, 0.6  # m
OBJECT_AHEAD = (3.0, 0.55)  # the object, ahead of L4's nominal pose and to its left (m)
FOV_DEG, MAX_RANGE = 30.0, 5.0  # the camera's field of view (full angle) and range (m)


class Progress(Protocol):
    def __call__(self, text: str) -> None: ...


def _quiet(text: str) -> None:
    return None


@dataclass(frozen=True)
class Bridge:
    """Figs. 3-4 on the shipped ``fig3.json``: estimates ``(src, dst, method)`` and their Monte
    Carlo checks (:func:`relmap.app.validate.validate_query`)."""

    records: list[ATRecord]
    estimates: dict[tuple[str, str, str], Estimate]
    checks: dict[tuple[str, str, str], Validation]

    def map(self) -> RelationalMap:
        return RelationalMap.from_records(self.records)


def bridge(
    seed: int = 0, n_reduce: int = BRIDGE_SAMPLES_REDUCE, n_optimal: int = BRIDGE_SAMPLES_OPTIMAL
) -> Bridge:
    """The Wheatstone bridge: t→v by reduction, w→u by Delta-Y and by the optimal estimate,
    each checked by Monte Carlo."""
    from relmap.app.validate import validate_query

    records = _shipped("fig3.json")
    g = RelationalMap.from_records(records)
    estimates, checks = {}, {}
    for src, dst in BRIDGE_PAIRS:
        for method, n in (("reduce", n_reduce), ("optimal", n_optimal)):
            v = validate_query(g, src, dst, method=method, n=n, seed=seed)
            estimates[src, dst, method] = v.estimate
            checks[src, dst, method] = v
    return Bridge(records, estimates, checks)


DELTA_Y_SIGMAS_DEG = (0.5, 1.0, 3.0, 5.0, 10.0)
DELTA_Y_SAMPLES = 20_000


@dataclass(frozen=True)
class DeltaYRow:
    """w→u on the bridge at one heading σ (all five ATs): the consistent and the paper's
    Delta-Y against the optimal estimate and Monte Carlo (relative Frobenius errors)."""

    sigma_deg: float
    sigma_y: float  #: the ATs' σy (m): fig3.json's 0.05 (isotropic) or an anisotropic 0.01
    consistent_vs_optimal: float
    paper_vs_optimal: float
    consistent_vs_reversed: float  #: w→u against the reversed u→w (NaN: u→w refused)
    paper_vs_reversed: float
    consistent_vs_mc: float  #: the reduction re-run on sampled ATs (batched), its spread
    mc_standard_error: float
    paper_vs_mc: float


def delta_y_study(seed: int = 0, n: int = DELTA_Y_SAMPLES) -> list[DeltaYRow]:
    """The bridge of ``fig3.json`` with every AT's heading σ set to each of
    :data:`DELTA_Y_SIGMAS_DEG` (and once more with σy = 1 cm): w→u by the consistent Delta-Y
    (default), by the paper's formulas, and optimally; each reduction also re-run on ``n``
    sampled maps (:func:`relmap.network.reduce.reduce_network`, batched) against the truth
    taken as the file's means of the loop-free part (the optimal estimate's mean)."""
    from relmap.network.reduce import DeltaY, reduce_network

    rng = np.random.default_rng(seed)
    records = _shipped("fig3.json")
    rows = []
    for sigma_y in (0.05, 0.01):
        for sigma in DELTA_Y_SIGMAS_DEG:
            g = RelationalMap()
            for r in records:
                sig = np.array([0.05, sigma_y, np.radians(sigma)])
                g.add(r.src, r.dst, AT.from_sigmas(r.at.mean, sig), name=r.name)
            opt = g.query("w", "u", method="optimal").at
            # loop-consistent means (the optimal poses), so that sampling has a truth
            sol = g.solve("w")
            h = RelationalMap()
            for e in g.edges():
                h.add(e.src, e.dst, AT(se2.between(sol.pose(e.src), sol.pose(e.dst)), e.at.cov))
            truth = se2.between(sol.pose("w"), sol.pose("u"))
            out = {}
            for how in DeltaY:
                est = h.query("w", "u", method="reduce", delta_y=how).at
                try:
                    back = h.query("u", "w", method="reduce", delta_y=how).at.reverse()
                except IrreducibleNetworkError:  # an indefinite result, refused
                    back = None
                edges = [
                    (e.name, e.src, e.dst, AT._trusted(e.at.sample(n, rng), e.at.cov))
                    for e in h.edges()
                ]
                try:
                    spread = montecarlo.SampleSet.of(
                        reduce_network(edges, "w", "u", delta_y=how).at.mean
                    ).compare(AT(truth, est.cov))
                except IrreducibleNetworkError:  # indefinite on some sampled map: refused
                    spread = None
                out[how] = (est, back, spread)
            opt_h = h.query("w", "u", method="optimal").at

            def rel(a: np.ndarray | None, b: np.ndarray) -> float:
                return np.nan if a is None else float(np.linalg.norm(a - b) / np.linalg.norm(b))

            c, p = out[DeltaY.CONSISTENT], out[DeltaY.PAPER]
            del opt
            rows.append(
                DeltaYRow(
                    sigma,
                    sigma_y,
                    rel(c[0].cov, opt_h.cov),
                    rel(p[0].cov, opt_h.cov),
                    rel(None if c[1] is None else c[1].cov, c[0].cov),
                    rel(None if p[1] is None else p[1].cov, p[0].cov),
                    np.nan if c[2] is None else float(c[2].cov_rel_error),
                    np.nan if c[2] is None else float(c[2].cov_rel_standard_error),
                    np.nan if p[2] is None else float(p[2].cov_rel_error),
                )
            )
    return rows


DELTA_Y_HEADER = [
    "σθ",
    "σy [m]",
    "consistent vs optimal",
    "paper vs optimal",
    "consistent w→u vs (u→w)ᴿ",
    "paper w→u vs (u→w)ᴿ",
    "consistent vs Monte Carlo",
    "paper vs Monte Carlo",
]


def delta_y_rows(rows: list[DeltaYRow]) -> list[list[str]]:
    """The Delta-Y table's rows (strings)."""
    return [
        [
            f"{r.sigma_deg:g}°",
            f"{r.sigma_y:g}",
            _pct(r.consistent_vs_optimal),
            _pct(r.paper_vs_optimal),
            _pct(r.consistent_vs_reversed),
            _pct(r.paper_vs_reversed),
            f"{_pct(r.consistent_vs_mc)} ± {_pct(r.mc_standard_error)}",
            _pct(r.paper_vs_mc),
        ]
        for r in rows
    ]


@dataclass(frozen=True)
class ChainCheck:
    """First order against Monte Carlo for a chain of ``links`` equal links (§6.3)."""

    sigma_deg: float
    links: int
    predicted: AT
    samples: montecarlo.SampleSet
    agreement: montecarlo.Agreement

    @property
    def mean_rel_error(self) -> float:
        """‖first-order position mean − sample mean‖ / ‖sample mean position‖."""
        d = self.agreement.mean_error[:2]
        return float(np.linalg.norm(d) / np.linalg.norm(self.samples.mean[:2]))

    @property
    def var_rel_error(self) -> float:
        """The largest relative error of a variance (x, y, θ): |C_ii − Ĉ_ii| / Ĉ_ii."""
        est, mc = np.diagonal(self.predicted.cov), np.diagonal(self.samples.cov)
        return float(np.max(np.abs(est - mc) / mc))


@dataclass(frozen=True)
class Fig5:
    """The §6.3 study: one compounding (2 links) and a chain, at every angular σ."""

    checks: list[ChainCheck]
    n: int

    def get(self, links: int, sigma_deg: float) -> ChainCheck:
        return next(c for c in self.checks if c.links == links and c.sigma_deg == sigma_deg)


def fig5(seed: int = 0, n: int = MC_SAMPLES) -> Fig5:
    """Compound ``LINK`` with itself once and along ``CHAIN_LINKS`` links, for each angular σ
    of ``SIGMAS_DEG``, and compare with ``n`` Monte Carlo samples."""
    checks = []
    for k, sigma in enumerate(SIGMAS_DEG):
        link = AT.from_sigmas(LINK, [LINK_SIGMA_XY, LINK_SIGMA_XY, np.radians(sigma)])
        for links in (2, CHAIN_LINKS):
            predicted = compound_chain(AT.stack([link] * links))[-1]
            mc = montecarlo.simulate(
                lambda *xs: functools.reduce(se2.compose, xs), *[link] * links, n=n, seed=seed + k
            )
            checks.append(ChainCheck(sigma, links, predicted, mc, mc.compare(predicted)))
    return Fig5(checks, n)


@dataclass(frozen=True)
class Decisions:
    """§6: will the robot at L4 pass the door, and see the object, before and after sensing S?

    ``door`` and ``view`` hold the relations (robot in the door frame; object seen from the
    robot) for G (before) and G ⊗ Sᴿ (after); ``door_decision`` and ``view_decision`` the
    decisions (:func:`relmap.models.decisions.through_door`,
    :func:`~relmap.models.decisions.in_view`)."""

    door_pose: np.ndarray  # the door frame in W
    object_position: np.ndarray  # the object in W
    door: tuple[AT, AT]
    door_decision: tuple[DoorDecision, DoorDecision]
    view: tuple[AT, AT]
    view_decision: tuple[ViewDecision, ViewDecision]


def decisions(f1: Fig1) -> Decisions:
    """The door and field-of-view decisions for L4, before (G) and after (G ⊗ Sᴿ) sensing."""
    from relmap.models.decisions import in_view, through_door

    G = f1.compounds[-1][3]
    door_W = se2.compose(G.mean, np.array(DOOR_AHEAD))
    object_W = se2.compose(G.mean, np.array([*OBJECT_AHEAD, 0.0]))
    door_rev = AT(door_W).reverse()  # exactly known door
    door = tuple(door_rev @ at for at in (G, f1.merged))
    view = tuple(at.reverse() @ AT(object_W) for at in (G, f1.merged))
    return Decisions(
        door_W,
        object_W[:2],
        door,  # type: ignore[arg-type]
        tuple(through_door(d, DOOR_WIDTH, ROBOT_WIDTH) for d in door),  # type: ignore[arg-type]
        view,  # type: ignore[arg-type]
        tuple(in_view(v, np.radians(FOV_DEG), MAX_RANGE) for v in view),  # type: ignore[arg-type]
    )


@dataclass(frozen=True)
class Lecture:
    """The lecture's examples: the arm, dead reckoning, EKF localization."""

    arm: PlanarArm
    arm_q: np.ndarray
    arm_cov_q: np.ndarray
    gripper: Moments
    gripper_samples: np.ndarray  # Monte Carlo of the grip point (n, 2)
    odometry: AT  # dead reckoning of a differential-drive robot, every pose
    wheel_steps: int
    ekf_truth: np.ndarray
    ekf_estimate: AT
    ekf_dead_reckoning: AT
    ekf_landmarks: np.ndarray
    ekf_score: Score
    ekf_baseline: Score
    mrclam: Localization | None


ARM = (0.4, 0.3)  # link lengths (m)
ARM_Q_DEG, ARM_SIGMA_DEG = (30.0, -60.0), 2.0
WHEELS = (0.05, 0.3)  # wheel radius, baseline (m)
WHEEL_STEPS, WHEEL_STEP = 400, (0.30, 0.36)  # (Δφl, Δφr) per step (rad): a slow left turn
WHEEL_NOISE = (0.005, 0.002)  # σ (rad) and k (rad) of WheelNoise
EKF_STEPS, EKF_STEP = 250, (0.15, 0.025)  # (Δs, Δθ): a circle of radius 6 m
EKF_NOISE = (0.005, 0.005, 0.002)  # DistanceNoise k_s, k_θ, k_θs
EKF_LANDMARKS = 12


def lecture(
    seed: int = 0, n: int = MC_SAMPLES, data: str | os.PathLike[str] | None = None
) -> Lecture:
    """Run the lecture's examples; with ``data`` (the shared data folder) also EKF localization
    of MRCLAM robot 1 (:func:`relmap.app.localize.localize`)."""
    from relmap.app.localize import score
    from relmap.filter.logs import Log, run
    from relmap.models.odometry import (
        DiffDrive,
        DistanceNoise,
        Odometry,
        WheelNoise,
        dead_reckon,
        increment,
    )
    from relmap.models.range_bearing import RangeBearingSensor

    rng = np.random.default_rng(seed)
    arm = PlanarArm(*ARM)
    q = np.radians(ARM_Q_DEG)
    cov_q = np.diag(np.radians([ARM_SIGMA_DEG, ARM_SIGMA_DEG]) ** 2)
    gripper = arm.gripper(q, cov_q)
    grip_mc = arm.forward(rng.multivariate_normal(q, cov_q, size=min(n, 20_000)))

    drive = DiffDrive(*WHEELS)
    odometry = dead_reckon(
        np.tile(WHEEL_STEP, (WHEEL_STEPS, 1)), WheelNoise(*WHEEL_NOISE), drive=drive
    )

    # EKF: a robot drives a circle among landmarks, sensing range and bearing (lecture 13-28);
    # the simulated log is replayed by relmap.filter.run (the odometry between scans composed,
    # every scan one stacked correction).
    sensor = RangeBearingSensor(0.1, np.radians(1.0), fov=np.pi, max_range=8.0, min_range=1.0)
    noise = DistanceNoise(*EKF_NOISE)
    step_u = np.array(EKF_STEP)
    landmarks = rng.uniform(-10.0, 10.0, (EKF_LANDMARKS, 2))
    prior = AT([6.0, 0.0, np.pi / 2], np.diag([0.01, 0.01, 0.001]))
    truth = [prior.sample(1, rng)[0]]
    Su = noise.covariance(step_u)
    index, readings, seen_ids = [], [], []
    for k in range(1, EKF_STEPS + 1):
        moved = step_u + rng.multivariate_normal([0.0, 0.0], Su)
        truth.append(se2.compose(truth[-1], increment(moved)))
        z = sensor.h(truth[-1], landmarks)
        seen = sensor.in_view(z)
        z = z + rng.normal(size=z.shape) * [sensor.sigma_range, sensor.sigma_bearing]
        index += [k] * int(seen.sum())
        readings.append(z[seen])
        seen_ids.append(np.flatnonzero(seen))
    log = Log(
        np.arange(EKF_STEPS + 1.0), np.tile(step_u, (EKF_STEPS, 1)), np.array(index, np.int64),
        np.concatenate(readings), np.concatenate(seen_ids),
    )  # fmt: skip
    trace = run(log, Odometry(noise), sensor, landmarks, start=prior, associate="signatures")
    truth_arr = np.array(truth)
    estimate = trace.estimate()
    dr = dead_reckon(np.tile(step_u, (EKF_STEPS, 1)), noise, start=prior)
    mrclam = None
    if data is not None:
        from relmap.app.localize import localize

        mrclam = localize(Path(data) / "landmarks" / "mrclam6", robot=1)
    return Lecture(
        arm,
        q,
        cov_q,
        gripper,
        grip_mc,
        odometry,
        WHEEL_STEPS,
        truth_arr,
        estimate,
        dr,
        landmarks,
        score(estimate, truth_arr),
        score(dr, truth_arr),
        mrclam,
    )


@dataclass(frozen=True)
class Demo:
    """Everything ``relmap demo`` computes."""

    fig1: Fig1
    bridge: Bridge
    fig5: Fig5
    decisions: Decisions
    lecture: Lecture
    samples: int
    seed: int
    seconds: float
    delta_y: tuple[DeltaYRow, ...] = ()


def run(
    *,
    seed: int = 0,
    samples: int = MC_SAMPLES,
    data: str | os.PathLike[str] | None = None,
    progress: Progress = _quiet,
) -> Demo:
    """Compute every section of the demo. ``samples`` is the Monte Carlo sample size of Fig. 1
    and of the §6.3 study (the bridge uses ``samples/5`` for the reduction and
    ``BRIDGE_SAMPLES_OPTIMAL`` for the optimal method, at most ``samples/10``). ``progress``
    is called with the name of each section as it starts."""
    t0 = time.perf_counter()
    progress("Fig. 1: compounding and merging")
    f1 = fig1(seed, samples)
    progress("Figs. 3-4: the Wheatstone bridge")
    br = bridge(seed, max(samples // 5, 2), max(min(BRIDGE_SAMPLES_OPTIMAL, samples // 10), 2))
    progress("Fig. 5: Monte Carlo against first order")
    f5 = fig5(seed, samples)
    progress("decisions ahead of time")
    dec = decisions(f1)
    progress("the lecture: arm, dead reckoning, EKF" + (", MRCLAM" if data else ""))
    lec = lecture(seed, samples, data)
    progress("Delta-Y with heading error: consistent and the paper's")
    dy = tuple(delta_y_study(seed, max(samples // 5, 2)))
    return Demo(f1, br, f5, dec, lec, samples, seed, time.perf_counter() - t0, dy)


# ------------------------------------------------------------------------------ printing
def _pct(x: float) -> str:
    return "refused (indefinite)" if np.isnan(x) else f"{x:.2%}"


def fig5_rows(f5: Fig5) -> list[list[str]]:
    """The §6.3 table's rows (strings), one per angular σ."""
    rows = []
    for sigma in SIGMAS_DEG:
        row = [f"{sigma:g}°"]
        for links in (2, CHAIN_LINKS):
            c = f5.get(links, sigma)
            row += [
                _pct(c.mean_rel_error),
                _pct(c.var_rel_error),
                _pct(float(c.agreement.cov_rel_error)),
                f"{float(c.agreement.skewness):.3f}",
            ]
        rows.append(row)
    return rows


FIG5_HEADER = [
    "σθ per link",
    "1 compounding: mean",
    "variances (max)",
    "covariance (F)",
    "Mardia skew",
    f"{CHAIN_LINKS}-link chain: mean",
    "variances (max)",
    "covariance (F)",
    "Mardia skew",
]


def print_demo(demo: Demo, out: TextIO = sys.stdout) -> None:
    """Print the key numbers of every section."""
    w = out.write
    print_fig1(demo.fig1, out)
    br = demo.bridge
    w("\nFigs. 3-4, the Wheatstone bridge (relmap/data/fig3.json): reduction vs optimal\n")
    w(f"{'query':<8}{'method':<9}{'σx [m]':>9}{'σy [m]':>9}{'σθ [°]':>8}{'MC cov err':>12}"
      f"{'± sampling':>12}{'NEES':>7}{'n':>8}  expression\n")  # fmt: skip
    for (src, dst, method), v in br.checks.items():
        sx, sy, st = v.estimate.at.sigmas
        a = v.agreement
        w(
            f"{f'{src}→{dst}':<8}{method:<9}{sx:9.4f}{sy:9.4f}{np.degrees(st):8.3f}"
            f"{_pct(float(a.cov_rel_error)):>12}{_pct(float(a.cov_rel_standard_error)):>12}"
            f"{float(a.nees):7.2f}{a.n:>8,}  {v.estimate.expression or '(joint least squares)'}\n"
        )
    if demo.delta_y:
        w("\nDelta-Y, w→u on the bridge (every AT's σθ as given): relative Frobenius errors\n")
        widths = [7, 8, 23, 18, 26, 22, 28, 22]
        w("".join(f"{h:>{wd}}" for h, wd in zip(DELTA_Y_HEADER, widths, strict=True)) + "\n")
        for row in delta_y_rows(list(demo.delta_y)):
            w("".join(f"{c:>{wd}}" for c, wd in zip(row, widths, strict=True)) + "\n")
    f5 = demo.fig5
    w(
        f"\n§6.3: first order vs Monte Carlo ({f5.n:,} samples each), links {LINK[0]:g} m, "
        f"σxy {LINK_SIGMA_XY * 100:g} cm; relative errors of the first-order mean position, "
        "of the variances, and of the covariance (Frobenius)\n"
    )
    widths = [12, 21, 16, 15, 12, 22, 16, 15, 12]
    w("".join(f"{h:>{wd}}" for h, wd in zip(FIG5_HEADER, widths, strict=True)) + "\n")
    for row in fig5_rows(f5):
        w("".join(f"{c:>{wd}}" for c, wd in zip(row, widths, strict=True)) + "\n")
    d = demo.decisions
    w("\n§6, decisions ahead of time for the robot at L4: before (G) and after (G ⊗ Sᴿ) sensing\n")
    for label, (b, a) in (
        (f"passes the {DOOR_WIDTH:g} m door ({ROBOT_WIDTH:g} m wide robot)", d.door_decision),
        (f"sees the object ({FOV_DEG:g}° view, {MAX_RANGE:g} m)", d.view_decision),
    ):
        w(f"  {label}: P = {float(b.probability):.5f} → {float(a.probability):.5f}\n")
    lec = demo.lecture
    e = gaussian.ellipse(lec.gripper.mean, lec.gripper.cov, PROBABILITY)
    w(
        f"\nLecture: arm gripper 90% ellipse {float(e.semi_major) * 1000:.1f} × "
        f"{float(e.semi_minor) * 1000:.1f} mm; dead reckoning after {lec.wheel_steps} steps: "
        f"90% ellipse half-axis {float(lec.odometry[-1].ellipse(PROBABILITY).semi_major):.3f} m\n"
    )
    w(
        f"Simulated EKF localization ({len(lec.ekf_landmarks)} landmarks): position RMSE "
        f"{lec.ekf_score.rmse_position:.3f} m (dead reckoning {lec.ekf_baseline.rmse_position:.3f}"
        f" m), ANEES {lec.ekf_score.anees:.2f} (1 if consistent)\n"
    )
    if lec.mrclam is not None:
        m = lec.mrclam
        w(
            f"MRCLAM robot {m.robot} EKF: position RMSE {m.score.rmse_position:.3f} m "
            f"(dead reckoning {m.baseline.rmse_position:.3f} m), ANEES {m.score.anees:.2f} "
            f"(1 if consistent)\n"
        )
