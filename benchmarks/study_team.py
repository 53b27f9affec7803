"""Prototype (issue 14, association without barcodes): the other robots' own estimates as the
explanation of readings of no landmark. Measured: docs/consistency.md.

MRCLAM's robots read each other (robot 1: 407 of its 1 942 readings). Without barcodes such a
reading is offered to the landmarks, and a robot parked near a landmark can capture the filter
(docs/consistency.md, "Several association hypotheses"). The team knows roughly where its
robots are. Each robot runs ``relmap localize --associate mahalanobis`` (or ``jcbb``; its
autocalibration, its gate), and a reading is dropped before the filter when another robot's
estimated position explains it better than every landmark does:

- each reading is judged at the filter's state just before its time stamp;
- a landmark ``l`` explains it with the Gaussian density of ``y`` under ``S = H P Hᵀ + R``;
- robot ``j`` explains it with ``S = H P Hᵀ + H_q (Σ_j + s² I) H_qᵀ + R``, where ``Σ_j`` is
  the covariance of robot j's estimated position at that time and ``s`` = ``--size`` (0.1 m)
  stands for the robot's body;
- with ``--rule inside``, a reading is dropped instead whenever a robot lies inside its gate.

The filter is run again without the dropped readings, and the readings are judged again at
its states, until the dropped set stops changing (at most ``--passes``). A round does this for
every robot against the others' estimates of the round before. The first round uses each
robot's filter alone. No barcode and no ground truth enters a decision: the barcodes only
count the readings of robots that were used, and the truth only scores.

Run: ``python benchmarks/study_team.py [--gate 0.99] [--rounds 3] [--associate mahalanobis]
[--rule density|inside]``.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
from scipy.stats import chi2
from study_bias import recording

from relmap.app.localize import _start, localize_mrclam, score
from relmap.filter import autocalibration, ekf
from relmap.io.datasets import read_mrclam
from relmap.lie import se2
from relmap.models import RangeBearingSensor
from relmap.uncertain.at import AT

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("RELMAP_DATA", ROOT.parent / "shared" / "data"))
SENSOR = RangeBearingSensor(1.0, 1.0)  # its predict: h and its Jacobians (MRCLAM: no mount)


class Robot:
    """One robot's filter with a set of dropped readings."""

    def __init__(self, data, robot: int, associate: str, gate: float):
        self.robot, self.associate, self.gate = robot, associate, gate
        alone = localize_mrclam(data, robot, associate=associate, gate=gate)
        self.alone = alone.score
        cal = alone.calibration
        lg = data.robots[robot - 1]
        self.log = recording(data, robot, associate).log(*cal.clock)  # every reading offered
        inside = (lg.meas_t >= self.log.t[0]) & (lg.meas_t <= self.log.t[-1])
        robots = {
            int(b): int(s)
            for s, b in zip(data.subjects, data.barcodes, strict=True)
            if s <= len(data.robots)
        }  # subjects 1-5 are the robots
        self.of_robot = np.array([robots.get(int(b), 0) for b in lg.meas_barcode[inside]])
        self.params = cal.parameters
        self.start = _start(lg.truth_at(self.log.t[:1])[0])
        self.truth = lg.truth_at(self.log.t)
        self.landmarks = ekf.LandmarkMap(data.landmark_xy)
        self.dropped = np.zeros(len(self.log.z), bool)
        self.trace = self.filter()

    def filter(self) -> ekf.Trace:
        keep = ~self.dropped
        log = self.log._replace(reading_index=self.log.reading_index[keep], z=self.log.z[keep],
                                signature=self.log.signature[keep])  # fmt: skip
        return ekf.run(log, self.landmarks, self.params, start=self.start,
                       association=self.associate, gate=self.gate)  # fmt: skip

    def position(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The estimated position (B, 2) and its covariance (B, 2, 2) at times ``t``."""
        i = np.clip(np.searchsorted(self.log.t, t), 0, len(self.log.t) - 1)
        return self.trace.mean[i, :2], self.trace.cov[i, :2, :2]

    def judge(self, trace: ekf.Trace, team: list[Robot], rule: str, size: float) -> np.ndarray:
        """Which readings another robot explains (module docstring), at ``trace``'s states."""
        before = np.maximum(self.log.reading_index - 1, 0)
        x, P = trace.mean[before], trace.cov[before]
        R = np.diag([float(self.params.sigma_r) ** 2, float(self.params.sigma_b) ** 2])
        n = len(x)

        def density(q, Cq):
            zh, Hx, Hq = SENSOR.predict(x, q, jacobians=True)
            S = Hx @ P @ np.swapaxes(Hx, -1, -2) + Hq @ Cq @ np.swapaxes(Hq, -1, -2) + R
            y = self.log.z - zh
            y[:, 1] = se2.wrap_angle(y[:, 1])
            d2 = np.einsum("ni,ni->n", y, np.linalg.solve(S, y[..., None])[..., 0])
            return autocalibration.logpdf(d2, np.linalg.slogdet(S)[1], 2, np.inf), d2

        none = np.zeros((n, 2, 2))
        landmark = np.max([density(np.broadcast_to(q, (n, 2)), none)[0]
                           for q in self.landmarks.xy], axis=0)  # fmt: skip
        t = self.log.t[self.log.reading_index]
        others = [density(q, Cq + size**2 * np.eye(2))
                  for q, Cq in (o.position(t) for o in team if o is not self)]  # fmt: skip
        if rule == "inside":
            return np.min([d2 for _, d2 in others], axis=0) < chi2.ppf(self.gate, 2)
        return np.max([g for g, _ in others], axis=0) > landmark

    def settle(
        self, team: list[Robot], rule: str, size: float, passes: int
    ) -> tuple[ekf.Trace, int]:
        for k in range(passes):
            trace = self.filter()
            dropped = self.judge(trace, team, rule, size)
            if (dropped == self.dropped).all():
                return trace, k + 1
            self.dropped = dropped
        return self.filter(), passes

    def report(self, trace: ekf.Trace) -> str:
        s = score(AT(trace.mean, trace.cov), self.truth)
        used = np.zeros(len(self.dropped), bool)
        used[~self.dropped] = trace.status == ekf.Status.USED
        of_landmark = self.dropped & (self.log.signature >= 0)
        return (f"{s.rmse_position:.3f}/{s.coverage_90:.2f}/{s.anees:.2f}; readings of robots "
                f"used {int((used & (self.of_robot > 0)).sum())}/{int((self.of_robot > 0).sum())}"
                f", dropped {int(self.dropped.sum())} ({int(of_landmark.sum())} of landmarks)")  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--gate", type=float, default=0.99)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--passes", type=int, default=8)
    ap.add_argument("--associate", choices=("mahalanobis", "jcbb"), default="mahalanobis")
    ap.add_argument("--rule", choices=("density", "inside"), default="density")
    ap.add_argument("--size", type=float, default=0.1)
    args = ap.parse_args()
    data = read_mrclam(DATA / "landmarks" / "mrclam6")
    team = [Robot(data, r, args.associate, args.gate) for r in range(1, len(data.robots) + 1)]
    for r in team:
        s = r.alone
        print(f"robot {r.robot} alone: {s.rmse_position:.3f}/{s.coverage_90:.2f}/{s.anees:.2f}")
    for k in range(args.rounds):
        traces = []
        for r in team:
            trace, passes = r.settle(team, args.rule, args.size, args.passes)
            traces.append(trace)
            print(
                f"round {k + 1}, robot {r.robot} ({passes} passes): {r.report(trace)}", flush=True
            )
        for r, trace in zip(team, traces, strict=True):
            r.trace = trace


if __name__ == "__main__":
    main()
