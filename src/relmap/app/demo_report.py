"""The ``relmap demo`` report: figures of the demo's results and the HTML page that shows them
(:mod:`relmap.viz.report`). matplotlib is imported here only, when a report is written."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from relmap.app.demo import (
    CHAIN_LINKS,
    DOOR_AHEAD,
    DOOR_WIDTH,
    FIG5_HEADER,
    FOV_DEG,
    LINK,
    LINK_SIGMA_XY,
    MAX_RANGE,
    PROBABILITY,
    ROBOT_WIDTH,
    SIGMAS_DEG,
    Bridge,
    Decisions,
    Demo,
    Fig1,
    Fig5,
    Lecture,
    Progress,
    _quiet,
    fig5_rows,
)
from relmap.lie import se2
from relmap.uncertain import gaussian
from relmap.uncertain.at import AT

__all__ = ["write_report"]


def _legend_line(ax, **style) -> None:  # type: ignore[no-untyped-def]
    """A legend entry without data."""
    ax.plot([], [], **style)


def figure_fig1(f1: Fig1):  # type: ignore[no-untyped-def]
    """Fig. 1: the moves with relative (solid) and world (dashed) ellipses; the merge at L4."""
    from relmap.viz import plot

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
    from relmap.viz import plot

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
    from relmap.viz import plot

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

    from relmap.viz import plot

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
    from relmap.viz import plot

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
    """Write ``folder/index.html`` with its figures (PNG files beside it); return its path.
    The folder is checked first (:class:`relmap.errors.OutputError` before any figure is drawn)."""
    import matplotlib

    from relmap.io.atomic import check_writable_folder

    check_writable_folder(folder)

    matplotlib.use("Agg")  # files only: never a display
    from relmap.viz.report import Report

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
         "Monte Carlo cov error", "NEES of the 3-dof error (3 if right)", "samples"],
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

    if demo.delta_y:
        from relmap.app.demo import DELTA_Y_HEADER, delta_y_rows

        rep.paragraph(
            "Delta-Y with heading error. The paper's star formulas ignore how compounding "
            "carries heading error into position; relmap's default Delta-Y chooses the star so "
            "that it reproduces, to first order, the joint covariance of the triangle's corners "
            "(network/reduce.py derives it). Below, w→u on this bridge with every AT's heading "
            "σ set as shown (means made loop-consistent), σx = 5 cm and σy = 5 cm (as in "
            "fig3.json) or 1 cm (anisotropic): both Delta-Y rules against the optimal estimate, "
            "w→u against the reversed u→w, and each reduction re-run on sampled ATs against its "
            "own prediction (Monte Carlo)."
        )
        rep.table(
            DELTA_Y_HEADER,
            delta_y_rows(list(demo.delta_y)),
            caption="Relative Frobenius error of the w→u covariance",
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
        f"dead reckoning; ANEES {lec.ekf_score.anees:.2f} (mean NEES of the 3-dof pose error / 3: "
        f"1 if consistent), {lec.ekf_score.coverage_90:.0%} of the true positions inside the 90% "
        f"ellipse."
    )
    rep.figure(
        figure_lecture(lec),
        "lecture.png",
        "The arm's gripper ellipse, dead reckoning "
        "with growing ellipses, and a simulated EKF localization.",
    )
    if lec.mrclam is not None:
        from relmap.viz import plot

        m = lec.mrclam
        rep.paragraph(
            f"MRCLAM dataset 6, robot {m.robot} (real data, `--data`): {m.steps:,} filter times; "
            f"EKF position RMSE {m.score.rmse_position:.3f} m (dead reckoning "
            f"{m.baseline.rmse_position:.3f} m), ANEES {m.score.anees:.2f} (1 if consistent), "
            f"{m.score.coverage_90:.0%} of the true positions inside the 90% ellipse."
        )
        from relmap.viz.localization import map_axes

        fig, ax = plot.figure(figsize=(8, 7))
        map_axes(ax, m)
        fig.tight_layout()
        rep.figure(fig, "mrclam.png", f"MRCLAM robot {m.robot}: EKF against ground truth.")
    else:
        rep.paragraph(
            "Real data: run `relmap demo --data ../shared/data` to add EKF localization of "
            "MRCLAM robot 1."
        )
    progress("writing the report")
    return rep.write(folder)
