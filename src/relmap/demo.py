"""``relmap demo``: the paper reproduced, on data shipped with the package.

Fig. 1: four moves A, B, C, D take the robot from W to L4; compounding gives E = A ⊕ B,
F = E ⊕ C and G = F ⊕ D (§3), with uncertainty growing at each move. From L4 the robot senses W
(AT S); reversing S and merging it with G (§4) shrinks the uncertainty of L4 relative to W. A
Monte Carlo simulation checks G (§6.3).

:func:`run` computes, beyond Fig. 1, the Wheatstone bridge of Figs. 3-4 (reduction, Delta-Y,
the optimal estimate, Monte Carlo), the §6.3 study of Fig. 5 (first order against Monte Carlo
as the angular error grows), decisions ahead of time (§6: door, field of view) before and after
the sensing, and the lecture's examples (arm, dead reckoning, EKF localization, simulated and,
with ``data``, on MRCLAM). :func:`print_demo` prints the key numbers, :func:`write_report` the
HTML report with its figures (:mod:`relmap.report`). Every number shown is computed here.
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

from relmap import gaussian, montecarlo
from relmap.at import AT, compound_chain, merge
from relmap.decisions import DoorDecision, ViewDecision
from relmap.io.mapfile import ATRecord, read_records
from relmap.lie import se2
from relmap.network.graph import RelationalMap
from relmap.propagate import Moments
from relmap.robot import PlanarArm

if TYPE_CHECKING:  # pragma: no cover
    from relmap.localize import Localization, Score
    from relmap.network.query import Estimate
    from relmap.validate import Validation

__all__ = [
    "Bridge",
    "ChainCheck",
    "Demo",
    "Fig1",
    "Fig5",
    "Lecture",
    "bridge",
    "decisions",
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
    Carlo checks (:func:`relmap.validate.validate_query`)."""

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
    from relmap.validate import validate_query

    records = _shipped("fig3.json")
    g = RelationalMap.from_records(records)
    estimates, checks = {}, {}
    for src, dst in BRIDGE_PAIRS:
        for method, n in (("reduce", n_reduce), ("optimal", n_optimal)):
            v = validate_query(g, src, dst, method=method, n=n, seed=seed)
            estimates[src, dst, method] = v.estimate
            checks[src, dst, method] = v
    return Bridge(records, estimates, checks)


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
    decisions (:func:`relmap.decisions.through_door`, :func:`~relmap.decisions.in_view`)."""

    door_pose: np.ndarray  # the door frame in W
    object_position: np.ndarray  # the object in W
    door: tuple[AT, AT]
    door_decision: tuple[DoorDecision, DoorDecision]
    view: tuple[AT, AT]
    view_decision: tuple[ViewDecision, ViewDecision]


def decisions(f1: Fig1) -> Decisions:
    """The door and field-of-view decisions for L4, before (G) and after (G ⊗ Sᴿ) sensing."""
    from relmap.decisions import in_view, through_door

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
    of MRCLAM robot 1 (:func:`relmap.localize.localize`)."""
    from relmap import ekf
    from relmap.localize import score
    from relmap.robot import DiffDrive, DistanceNoise, WheelNoise, dead_reckon, increment
    from relmap.sensors import RangeBearingSensor

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

    # EKF: a robot drives a circle among landmarks, sensing range and bearing (lecture 13-28).
    sensor = RangeBearingSensor(0.1, np.radians(1.0), fov=np.pi, max_range=8.0, min_range=1.0)
    noise = DistanceNoise(*EKF_NOISE)
    step_u = np.array(EKF_STEP)
    landmarks = rng.uniform(-10.0, 10.0, (EKF_LANDMARKS, 2))
    prior = AT([6.0, 0.0, np.pi / 2], np.diag([0.01, 0.01, 0.001]))
    truth = [prior.sample(1, rng)[0]]
    state, estimates = prior, [prior]
    Su = noise.covariance(step_u)
    for _ in range(EKF_STEPS):
        moved = step_u + rng.multivariate_normal([0.0, 0.0], Su)
        truth.append(se2.compose(truth[-1], increment(moved)))
        z = sensor.predict(truth[-1], landmarks)
        seen = sensor.in_view(z)
        z = z + rng.normal(size=z.shape) * [sensor.sigma_range, sensor.sigma_bearing]
        state = ekf.predict(state, step_u, noise)
        state = ekf.correct_landmarks(
            state,
            z[seen],
            sensor,
            landmarks,
            associate="signatures",
            signatures=np.flatnonzero(seen),
            landmark_signatures=np.arange(EKF_LANDMARKS),
        ).state
        estimates.append(state)
    truth_arr = np.array(truth)
    estimate = AT.stack(estimates)
    dr = dead_reckon(np.tile(step_u, (EKF_STEPS, 1)), noise, start=prior)
    mrclam = None
    if data is not None:
        from relmap.localize import localize

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
    return Demo(f1, br, f5, dec, lec, samples, seed, time.perf_counter() - t0)


# ------------------------------------------------------------------------------ printing
def _pct(x: float) -> str:
    return f"{x:.2%}"


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
        f" m), ANEES {lec.ekf_score.anees:.2f}\n"
    )
    if lec.mrclam is not None:
        m = lec.mrclam
        w(
            f"MRCLAM robot {m.robot} EKF: position RMSE {m.score.rmse_position:.3f} m "
            f"(dead reckoning {m.baseline.rmse_position:.3f} m), ANEES {m.score.anees:.2f}\n"
        )


# ------------------------------------------------------------------------------- figures
def _legend_line(ax, **style) -> None:  # type: ignore[no-untyped-def]
    """A legend entry without data."""
    ax.plot([], [], **style)


def figure_fig1(f1: Fig1):  # type: ignore[no-untyped-def]
    """Fig. 1: the moves with relative (solid) and world (dashed) ellipses; the merge at L4."""
    from relmap import plot

    fig, (ax, zoom) = plot.figure(figsize=(12, 5.6), ncols=2)
    ats = {r.name: r.at for r in f1.inputs}
    world = [ats["A"]] + [c[3] for c in f1.compounds]  # W→L1 … W→L4
    frames = ["W", "L1", "L2", "L3", "L4"]
    poses = np.vstack([se2.identity(()), *[at.mean for at in world]])
    # Each move's own (relative) uncertainty, placed at its nominal end: (exact start) ⊕ move.
    relative = AT.stack(
        [AT(poses[k]) @ ats[m] for k, m in enumerate("ABCD")]  # start known exactly
    )
    for k, m in enumerate("ABCD"):
        ax.annotate(
            "",
            xy=poses[k + 1, :2],
            xytext=poses[k, :2],
            arrowprops={"arrowstyle": "-|>", "color": "0.4", "shrinkA": 3, "shrinkB": 3},
        )
        mid = (poses[k, :2] + poses[k + 1, :2]) / 2
        ax.annotate(m, mid, color="0.3", fontweight="bold", ha="center", va="center",
                    bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none"})  # fmt: skip
    ax.annotate(
        "",
        xy=poses[0, :2],
        xytext=poses[4, :2],
        arrowprops={"arrowstyle": "-|>", "color": "C2", "linestyle": ":", "shrinkA": 3},
    )
    ax.annotate("S (sensed)", (poses[0, :2] + poses[4, :2]) / 2, color="C2", ha="left",
                xytext=(6, 0), textcoords="offset points")  # fmt: skip
    plot.ellipse(ax, relative, PROBABILITY, tick=0, color="C1", linewidth=1.6)
    plot.ellipse(ax, AT.stack(world), PROBABILITY, tick=0, color="C0", linestyle="--")
    for name, p in zip(frames, poses, strict=True):
        ax.annotate(name, p[:2], xytext=(-30, 4), textcoords="offset points", fontsize="large")
    ax.plot(*poses[:, :2].T, "k.", markersize=6)
    _legend_line(ax, color="C1", linewidth=1.6, label="90% ellipse of each move (relative)")
    _legend_line(ax, color="C0", linestyle="--", label="90% ellipse relative to W (compounded)")
    ax.set_title("(a) Four moves: uncertainty grows by compounding")
    ax.set_xlabel("x in W [m]")
    ax.set_ylabel("y in W [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend(loc="lower right", fontsize="small")

    G, Sr, M = f1.compounds[-1][3], f1.sensed_reversed, f1.merged
    plot.ellipse(zoom, G, PROBABILITY, tick=0, color="C0", linestyle="--", linewidth=1.6)
    plot.ellipse(zoom, Sr, PROBABILITY, tick=0, color="C2", linestyle=":", linewidth=1.6)
    plot.ellipse(zoom, M, PROBABILITY, tick=0, color="C3", linewidth=2.0)
    for at, c in ((G, "C0"), (Sr, "C2"), (M, "C3")):
        zoom.plot(*at.mean[:2], "+", color=c, markersize=9)
    _legend_line(zoom, color="C0", linestyle="--", label="before: G = A ⊕ B ⊕ C ⊕ D")
    _legend_line(zoom, color="C2", linestyle=":", label="sensed: Sᴿ")
    _legend_line(zoom, color="C3", linewidth=2, label="after: G ⊗ Sᴿ (merged)")
    zoom.set_title("(b) L4 relative to W: before and after merging S")
    zoom.set_xlabel("x in W [m]")
    zoom.set_ylabel("y in W [m]")
    zoom.set_aspect("equal", adjustable="datalim")
    zoom.legend(loc="upper right", fontsize="small")
    zoom.margins(0.25)
    fig.tight_layout()
    return fig


def figure_bridge(br: Bridge):  # type: ignore[no-untyped-def]
    """The bridge drawn relative to w, and w→u: Delta-Y and optimal against Monte Carlo."""
    from relmap import plot

    fig, axes = plot.figure(figsize=(15, 5), ncols=3)
    plot.relational_map(axes[0], br.map(), "w", PROBABILITY, method="optimal")
    axes[0].set_title("(a) The bridge relative to w (optimal), 90% ellipses")
    axes[0].margins(0.15)
    for ax, method, title in (
        (axes[1], "reduce", "(b) w→u by Delta-Y"),
        (axes[2], "optimal", "(c) w→u optimal (joint least squares)"),
    ):
        v = br.checks["w", "u", method]
        plot.monte_carlo(ax, v.samples, v.estimate.at, PROBABILITY)  # type: ignore[arg-type]
        a = v.agreement
        ax.set_title(
            f"{title}\ncovariance error {float(a.cov_rel_error):.1%} "
            f"(± {float(a.cov_rel_standard_error):.1%}), n = {a.n:,}"
        )
        ax.set_xlabel("x in w [m]")
        ax.set_ylabel("y in w [m]")
    fig.tight_layout()
    return fig


def figure_fig5(f5: Fig5):  # type: ignore[no-untyped-def]
    """Fig. 5: the crescent of one compounding and a long chain, against the 90% ellipse; and
    the first-order errors against the angular σ."""
    from relmap import plot

    fig, axes = plot.figure(figsize=(15, 5), ncols=3)
    big = max(SIGMAS_DEG)
    for ax, tag, links, sigma in (
        (axes[0], "(a)", 2, big),
        (axes[1], "(b)", CHAIN_LINKS, SIGMAS_DEG[1]),
    ):
        c = f5.get(links, sigma)
        plot.monte_carlo(ax, c.samples, c.predicted, PROBABILITY)
        what = "one compounding" if links == 2 else f"a {links}-link chain"
        ax.set_title(
            f"{tag} {what}, σθ = {sigma:g}° per link\n(links {LINK[0]:g} m straight ahead; "
            f"Mardia skewness {float(c.agreement.skewness):.2f})"
        )
    ax = axes[2]
    for links, marker, color in ((2, "o", "C0"), (CHAIN_LINKS, "s", "C2")):
        cs = [f5.get(links, s) for s in SIGMAS_DEG]
        label = "1 compounding" if links == 2 else f"{links}-link chain"
        ax.semilogy(SIGMAS_DEG, [float(c.agreement.cov_rel_error) for c in cs], marker + "-",
                    color=color, label=f"{label}: covariance (Frobenius)")  # fmt: skip
        ax.semilogy(SIGMAS_DEG, [c.mean_rel_error for c in cs], marker + "--", color=color,
                    markerfacecolor="white", label=f"{label}: mean position")  # fmt: skip
    se = max(float(c.agreement.cov_rel_standard_error) for c in f5.checks)
    ax.axhline(se, color="0.5", linewidth=0.8, linestyle=":")
    ax.annotate(f"sampling error of the covariance (n = {f5.n:,})", (SIGMAS_DEG[-1], se),
                xytext=(0, -11), textcoords="offset points", fontsize="small", color="0.4",
                ha="right", bbox={"fc": "white", "ec": "none", "pad": 1})  # fmt: skip
    ax.axhline(0.01, color="C3", linewidth=0.8)
    ax.annotate("1%: the paper's 'typically less than'", (SIGMAS_DEG[0], 0.01), xytext=(0, 4),
                textcoords="offset points", fontsize="small", color="C3",
                bbox={"fc": "white", "ec": "none", "pad": 1})  # fmt: skip
    ax.set_xlabel("angular σ per link [°]")
    ax.set_ylabel("relative error of first order vs Monte Carlo")
    ax.set_xticks(SIGMAS_DEG)
    ax.set_title("(c) §6.3 measured")
    ax.legend(loc="lower right", fontsize="small")
    fig.tight_layout()
    return fig


def figure_decisions(dec: Decisions):  # type: ignore[no-untyped-def]
    """The door (in the door frame) and the field of view (from the robot), before and after."""
    from matplotlib.patches import Wedge

    from relmap import plot

    fig, (ax, av) = plot.figure(figsize=(12, 5.2), ncols=2)
    half = DOOR_WIDTH / 2
    for sgn in (-1, 1):
        ax.plot([0, 0], [sgn * half, sgn * (half + 0.8)], color="k", linewidth=4,
                label="door jambs" if sgn > 0 else None)  # fmt: skip
    for (at, d), style, when in zip(
        zip(dec.door, dec.door_decision, strict=True),
        ({"color": "C0", "linestyle": "--"}, {"color": "C3"}),
        ("before sensing", "after sensing"),
        strict=True,
    ):
        plot.ellipse(ax, at, PROBABILITY, linewidth=1.6, **style)
        _legend_line(ax, label=f"{when}: P(pass) = {float(d.probability):.5f}", **style)
    x0 = float(dec.door[0].mean[0])
    ax.fill_between([x0, 0.4], -ROBOT_WIDTH / 2, ROBOT_WIDTH / 2, color="0.8", alpha=0.5,
                    label=f"nominal swept path ({ROBOT_WIDTH:g} m robot)")  # fmt: skip
    ax.set_title(f"(a) Through the {DOOR_WIDTH:g} m door? (robot at L4, door frame)")
    ax.set_xlabel("x, through the door [m]")
    ax.set_ylabel("y, along the door [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend(loc="upper left", fontsize="small")

    half_fov = FOV_DEG / 2
    av.add_patch(Wedge((0, 0), MAX_RANGE, -half_fov, half_fov, color="C2", alpha=0.12,
                       label=f"field of view ({FOV_DEG:g}°, {MAX_RANGE:g} m)"))  # fmt: skip
    for (at, d), style, when in zip(
        zip(dec.view, dec.view_decision, strict=True),
        ({"color": "C0", "linestyle": "--"}, {"color": "C3"}),
        ("before sensing", "after sensing"),
        strict=True,
    ):
        plot.ellipse(av, at, PROBABILITY, tick=0, linewidth=1.6, **style)
        _legend_line(av, label=f"{when}: P(in view) = {float(d.probability):.5f}", **style)
    av.plot(0, 0, "k>", markersize=9)
    av.set_title("(b) Object in the camera's view? (seen from the robot at L4)")
    av.set_xlabel("x, camera axis [m]")
    av.set_ylabel("y [m]")
    av.set_xlim(-0.3, MAX_RANGE + 0.3)
    av.set_aspect("equal", adjustable="datalim")
    av.legend(loc="lower left", fontsize="small")
    fig.tight_layout()
    return fig


def figure_lecture(lec: Lecture):  # type: ignore[no-untyped-def]
    """The arm's gripper ellipse, dead reckoning, simulated EKF localization."""
    from relmap import plot

    fig, (aa, ad, ae) = plot.figure(figsize=(16, 6), ncols=3)
    arm, q = lec.arm, lec.arm_q
    elbow = arm.shoulder + arm.L0 * np.array([np.cos(q[0]), np.sin(q[0])])
    grip = arm.forward(q)
    aa.plot(*lec.gripper_samples.T, ".", color="0.5", markersize=1, alpha=0.4, rasterized=True)
    _legend_line(aa, marker=".", linestyle="none", color="0.5",
                 label=f"grip point, Monte Carlo ({len(lec.gripper_samples):,})")  # fmt: skip
    aa.plot(*np.array([arm.shoulder, elbow, grip]).T, "-o", color="k", linewidth=3, label="arm")
    e = gaussian.ellipse(lec.gripper.mean, lec.gripper.cov, PROBABILITY)
    plot.ellipse(aa, e, color="C3", linewidth=1.8)
    _legend_line(aa, color="C3", label="gripper 90% ellipse (first order)")
    aa.set_title(
        f"(a) Arm: joint σ = {np.degrees(np.sqrt(lec.arm_cov_q[0, 0])):g}°, "
        f"links {arm.L0:g} m and {arm.L1:g} m"
    )
    aa.set_xlabel("x [m]")
    aa.set_ylabel("z [m]")
    aa.set_aspect("equal", adjustable="datalim")
    aa.legend(loc="upper left", fontsize="small")

    plot.trajectory(ad, lec.odometry, ats=lec.odometry, label="dead reckoning", color="C0")
    _legend_line(ad, color="C0", linewidth=0.9, label="90% ellipses along the path")
    ad.set_title(f"(b) Dead reckoning, {lec.wheel_steps} odometry steps: ellipses grow")
    ad.set_xlabel("x [m]")
    ad.set_ylabel("y [m]")
    ad.set_aspect("equal", adjustable="datalim")
    ad.legend(loc="best", fontsize="small")

    ae.plot(*lec.ekf_landmarks.T, "^", color="C3", label="landmarks")
    plot.trajectory(ae, lec.ekf_truth, color="k", linewidth=1.0, label="ground truth")
    plot.trajectory(ae, lec.ekf_dead_reckoning, ats=lec.ekf_dead_reckoning, every=50,
                    color="C1", linestyle="--", label="dead reckoning")  # fmt: skip
    plot.trajectory(ae, lec.ekf_estimate, ats=lec.ekf_estimate, every=50, color="C0",
                    label="EKF")  # fmt: skip
    ae.set_title(
        f"(c) Simulated EKF: RMSE {lec.ekf_score.rmse_position:.2f} m\n"
        f"(dead reckoning {lec.ekf_baseline.rmse_position:.2f} m)"
    )
    ae.set_xlabel("x [m]")
    ae.set_ylabel("y [m]")
    ae.set_aspect("equal", adjustable="datalim")
    ae.legend(loc="upper center", bbox_to_anchor=(0.5, -0.12), ncols=4, fontsize="small")
    fig.tight_layout()
    return fig


def _at_cells(at: AT) -> list[str]:
    x, y, t = at.mean
    sx, sy, st = at.sigmas
    e = at.ellipse(PROBABILITY)
    return [
        f"{x:.3f}",
        f"{y:.3f}",
        f"{np.degrees(t):.2f}",
        f"{sx:.4f}",
        f"{sy:.4f}",
        f"{np.degrees(st):.3f}",
        f"{float(e.semi_major):.4f}",
        f"{float(e.semi_minor):.4f}",
    ]


_AT_HEADER = ["x [m]", "y [m]", "θ [°]", "σx [m]", "σy [m]", "σθ [°]", "a90 [m]", "b90 [m]"]


def write_report(demo: Demo, folder: str | os.PathLike[str], progress: Progress = _quiet) -> Path:
    """Write ``folder/index.html`` with its figures (PNG files beside it); return its path."""
    import matplotlib

    matplotlib.use("Agg")  # files only: never a display
    from relmap.report import Report

    rep = Report("relmap: Smith & Cheeseman (1986) reproduced")
    f1, br, f5, dec, lec = demo.fig1, demo.bridge, demo.fig5, demo.decisions, demo.lecture
    rep.paragraph(
        "R. Smith and P. Cheeseman, On the Representation and Estimation of Spatial Uncertainty "
        "(IJRR 5(4), 1986), computed by relmap: every number and figure on this page comes from "
        f"the run that wrote it (`relmap demo`, seed {demo.seed}, Monte Carlo samples "
        f"{demo.samples:,}, {demo.seconds:.1f} s of computation). Ellipses hold 90% of the "
        "position's Gaussian (Appendix A); short ticks from an ellipse's centre show the heading."
    )

    progress("report: Fig. 1")
    rep.heading("1. Fig. 1: compounding four moves, then merging a sensed AT", anchor="fig1")
    rep.paragraph(
        "Four moves A, B, C, D take the robot from W to L4 (relmap/data/fig1.json). Compounding "
        "(Eqs. 1-4) gives L2, L3, L4 relative to W with growing uncertainty. From L4 the robot "
        "senses W (AT S); reversed (Eqs. 5-7) and merged with G (Eqs. 8-10), it shrinks the "
        "uncertainty of L4."
    )
    rep.figure(
        figure_fig1(f1),
        "fig1.png",
        "Fig. 1: relative (solid) and world (dashed) 90% "
        "ellipses of the four moves; L4 before and after merging the sensed S.",
    )
    rows = [[r.name, f"{r.src}→{r.dst}", *_at_cells(r.at)] for r in f1.inputs]  # type: ignore[arg-type]
    rows += [[label, f"{s}→{d}", *_at_cells(at)] for label, s, d, at in f1.compounds]
    rows += [["Sᴿ", "W→L4", *_at_cells(f1.sensed_reversed)]]
    rows += [["G ⊗ Sᴿ", "W→L4", *_at_cells(f1.merged)]]
    rep.table(["AT", "frames", *_AT_HEADER], rows, caption="Inputs, compounds and the merge")
    G, mc = f1.compounds[-1][3], f1.monte_carlo
    before, after = G.ellipse(PROBABILITY), f1.merged.ellipse(PROBABILITY)
    ratio = float(after.semi_major * after.semi_minor / (before.semi_major * before.semi_minor))
    rep.paragraph(
        f"Merging shrinks the 90% ellipse of L4 to {ratio:.1%} of its area and σθ from "
        f"{np.degrees(G.sigmas[2]):.2f}° to {np.degrees(f1.merged.sigmas[2]):.2f}°. "
        f"Monte Carlo of G ({mc.n:,} samples): covariance relative error "
        f"{float(mc.cov_rel_error):.2%} (sampling error ±{float(mc.cov_rel_standard_error):.2%}),"
        f" {float(mc.coverage):.1%} of the samples inside the 90% ellipsoid."
    )

    progress("report: the bridge")
    rep.heading("2. Figs. 3-4: the Wheatstone bridge, reduction and the optimal estimate",
                anchor="bridge")  # fmt: skip
    rep.paragraph(
        "ATs A w→t, B w→v, C t→v, D t→u, E u→v (relmap/data/fig3.json). t→v reduces by "
        "compounding and merging alone; w→u needs the Delta-Y transformation (Fig. 4), which is "
        "exact only in the linear isotropic case. The optimal method estimates all frames "
        "jointly (nonlinear least squares). Each estimate is checked by Monte Carlo "
        "(`relmap validate`): every AT drawn from its Gaussian, the query re-estimated on each "
        "drawn map by the same method, the spread compared with the predicted covariance."
    )
    brows = []
    for (src, dst, method), v in br.checks.items():
        a = v.agreement
        brows.append(
            [
                f"{src}→{dst}",
                method,
                v.estimate.expression or "(joint least squares)",
                *_at_cells(v.estimate.at)[3:6],  # type: ignore[arg-type]
                f"{float(a.cov_rel_error):.2%} ± {float(a.cov_rel_standard_error):.2%}",
                f"{float(a.nees):.2f}",
                f"{a.n:,}",
            ]
        )
    rep.table(
        ["query", "method", "expression", "σx [m]", "σy [m]", "σθ [°]",
         "Monte Carlo cov error", "NEES (3 if right)", "samples"],
        brows,
        caption="Predicted uncertainty and its Monte Carlo check",
    )  # fmt: skip
    dy = br.checks["w", "u", "reduce"].estimate
    if dy.definitions:
        rep.items([f"`{k}`: `{v}`" for k, v in dy.definitions.items()])
    rep.figure(
        figure_bridge(br),
        "bridge.png",
        "The bridge relative to w (optimal estimate); "
        "w→u by Delta-Y and by the optimal method against the Monte Carlo re-estimates.",
    )

    progress("report: Fig. 5")
    rep.heading("3. Fig. 5 and §6.3: when is first order good enough?", anchor="fig5")
    rep.paragraph(
        f"Links of {LINK[0]:g} m straight ahead with σx = σy = {LINK_SIGMA_XY * 100:g} cm and "
        f"the angular σ below; one compounding (two links) and a {CHAIN_LINKS}-link chain, "
        f"first order against {f5.n:,} Monte Carlo samples each. The paper: errors 'typically "
        "less than 1%, unless the angular errors are large (e.g. ... greater than 6 degrees)'. "
        "Columns: relative error of the first-order mean position; the largest relative error "
        "of a variance (x, y, θ); the Frobenius relative error of the covariance; Mardia's "
        "skewness of the samples (0 for a Gaussian; the crescent shows as skewness). Along a "
        "straight chain the x variance is second order in the heading errors, which first "
        "order leaves out: its relative error is the largest variance error."
    )
    rep.table(FIG5_HEADER, fig5_rows(f5), caption=f"§6.3 measured ({f5.n:,} samples per cell)")
    rep.figure(
        figure_fig5(f5),
        "fig5.png",
        "Fig. 5: Monte Carlo samples against the "
        "first-order 90% ellipse, and the errors of first order against the angular σ.",
    )

    progress("report: decisions")
    rep.heading("4. Decisions ahead of time (§6)", anchor="decisions")
    (db, da), (vb, va) = dec.door_decision, dec.view_decision
    rep.paragraph(
        f"The robot at L4 wants to drive through a {DOOR_WIDTH:g} m door {DOOR_AHEAD[0]:g} m "
        f"ahead ({ROBOT_WIDTH:g} m wide robot) and to see an object with a camera "
        f"({FOV_DEG:g}° field of view, {MAX_RANGE:g} m range). Before sensing (G) and after "
        "merging the sensed S (G ⊗ Sᴿ): the probability of success (the Gaussian integrated "
        "over the region) and the paper's test (the 90% ellipse or box inside the region)."
    )
    rep.table(
        ["decision", "P before", "paper's test before", "P after", "paper's test after"],
        [
            ["passes the door", f"{float(db.probability):.5f}", str(bool(db.paper_test)),
             f"{float(da.probability):.5f}", str(bool(da.paper_test))],
            ["object in view", f"{float(vb.probability):.5f}", str(bool(vb.ellipse_inside)),
             f"{float(va.probability):.5f}", str(bool(va.ellipse_inside))],
        ],
        caption="Decisions before and after the sensing",
    )  # fmt: skip
    rep.figure(
        figure_decisions(dec),
        "decisions.png",
        "The door in its frame and the field of "
        "view from the robot: 90% ellipses before (dashed) and after (solid) sensing.",
    )

    progress("report: the lecture")
    rep.heading("5. The lecture: error propagation and EKF localization", anchor="lecture")
    e = gaussian.ellipse(lec.gripper.mean, lec.gripper.cov, PROBABILITY)
    rep.paragraph(
        f"The planar arm's gripper (lecture Eqs. 1-8): 90% ellipse {float(e.semi_major) * 1e3:.1f}"
        f" × {float(e.semi_minor) * 1e3:.1f} mm. Dead reckoning of a differential-drive robot "
        f"(Eqs. 11-12), {lec.wheel_steps} steps: the 90% ellipse's half-axis reaches "
        f"{float(lec.odometry[-1].ellipse(PROBABILITY).semi_major):.3f} m. Simulated EKF "
        f"localization (Eqs. 13-28) with {len(lec.ekf_landmarks)} landmarks: position RMSE "
        f"{lec.ekf_score.rmse_position:.3f} m against {lec.ekf_baseline.rmse_position:.3f} m by "
        f"dead reckoning; ANEES {lec.ekf_score.anees:.2f} (3 if consistent), "
        f"{lec.ekf_score.coverage_90:.0%} of the true poses inside the 90% ellipsoid."
    )
    rep.figure(
        figure_lecture(lec),
        "lecture.png",
        "The arm's gripper ellipse, dead reckoning "
        "with growing ellipses, and a simulated EKF localization.",
    )
    if lec.mrclam is not None:
        from relmap import plot

        m = lec.mrclam
        rep.paragraph(
            f"MRCLAM dataset 6, robot {m.robot} (real data, `--data`): {m.steps:,} filter times; "
            f"EKF position RMSE {m.score.rmse_position:.3f} m (dead reckoning "
            f"{m.baseline.rmse_position:.3f} m), ANEES {m.score.anees:.2f}, "
            f"{m.score.coverage_90:.0%} of the true poses inside the 90% ellipsoid."
        )
        fig, ax = plot.figure(figsize=(8, 7))
        plot.localization(ax, m)
        fig.tight_layout()
        rep.figure(fig, "mrclam.png", f"MRCLAM robot {m.robot}: EKF against ground truth.")
    else:
        rep.paragraph(
            "Real data: run `relmap demo --data ../shared/data` to add EKF localization of "
            "MRCLAM robot 1."
        )
    progress("writing the report")
    return rep.write(folder)
