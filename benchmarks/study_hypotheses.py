"""Multiple-hypothesis localization without barcodes (issue 14's Mahalanobis target): a prototype.

With ``associate="mahalanobis"`` the other robots' readings are offered to the filter, and a
robot seen near a landmark while the heading is uncertain captures it (``relmap.app.localize``'s
docstring). This study asks whether keeping several association hypotheses instead of one (a
Gaussian-sum filter pruned to the ``--hypotheses`` most likely, Reid 1979) avoids the capture.
Each hypothesis is a pose belief of ``relmap.filter.ekf.run`` with the run's autocalibrated noise (its
clutter weighting off: the branches model the clutter); its weight is the product of its
readings' densities (the autocalibration's Student-t, given the readings before it). Each
reading branches every hypothesis:

- ``--model clutter``: every subset of the time stamp's readings is offered to the association
  (``ekf.run``, Mahalanobis, gated); a reading not used is clutter, density λ (the fitted
  ``NoiseParameters.clutter``, i.i.d. readings of nothing in the map).
- ``--model objects``: readings one at a time, of a landmark (as ``ekf.run`` pairs it), of an
  unknown object the hypothesis already tracks (a world point from its last reading, static but
  for a random walk of ``--object-walk`` m²/s; its predicted reading's covariance is the
  odometry's since that reading, both readings' noise with the update's σ factor), or of a new
  object (density λ). Objects unseen for ``--expire`` s are dropped. This models what the
  clutter of the first model cannot: an unknown object persists, so its later readings are
  explained by it, not by a landmark.
- ``--model confusers``: as ``objects``, but an object is born only from a reading inside a
  landmark's gate (one that could be confused with a landmark); any other reading of no
  landmark or object is clutter.

``--inflate-landmarks`` (object models): a landmark reading's density with the update's σ
factor too (``S + (c² - 1) R``), as the objects' readings have it; ``--exclusion E``: no object
born within E m of a landmark.

The estimate at every time is the mixture's moments. Scored against the ground truth (RMSE m /
coverage_90 / ANEES), beside the one-hypothesis filter of ``relmap localize``, with per-minute
error and, for the most likely final hypothesis, how it explained the readings of landmarks and
of no landmark (barcodes read only to count). Ground truth scores; the method never reads it.

Run: ``python benchmarks/study_hypotheses.py [--model objects] [--hypotheses 16]
[--robots 1 2 3 4 5] [--gate 0.99] [--inflate-landmarks] [--exclusion 0.5] [--minutes]``.
"""

from __future__ import annotations

import argparse
import itertools
import os
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np

from relmap.app import localize
from relmap.filter import autocalibration, ekf
from relmap.io.datasets import read_mrclam
from relmap.lie import se2
from relmap.models import RangeBearingSensor
from relmap.models.range_bearing import polar_to_cartesian
from relmap.uncertain import gaussian
from relmap.uncertain.at import AT

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("RELMAP_DATA", ROOT.parent / "shared" / "data"))
LANDMARK, OBJECT, NEW = 0, 1, 2  # how a hypothesis explained a reading
SENSOR = RangeBearingSensor(1.0, 1.0)  # its predict: h and its Jacobians (MRCLAM: no mount)


class Hypothesis(NamedTuple):
    x: np.ndarray  # (3,) pose mean
    P: np.ndarray  # (3, 3)
    logw: float
    objects: tuple  # (q (2,), Cq (2, 2), Q since last reading (3, 3), time of last reading)
    history: tuple | None  # (reading, how, parent's history): the lineage's explanations


class Study:
    def __init__(
        self, log, landmarks, cal, start, *, gate, hypotheses, walk, expire, inflate, exclusion
    ):
        self.log, self.lmap, self.start = log, landmarks, start
        self.params = cal.parameters._replace(clutter=0.0)
        self.nu, self.loglam = cal.nu, float(np.log(float(cal.parameters.clutter)))
        c2 = float(cal.parameters.inflation) ** 2
        self.R = c2 * np.diag(
            [float(cal.parameters.sigma_r) ** 2, float(cal.parameters.sigma_b) ** 2]
        )
        # --inflate-landmarks: a landmark's reading density with the update's σ factor too
        self.dR = (1.0 - 1.0 / c2) * self.R if inflate else 0.0 * self.R
        self.gate, self.gate2 = gate, float(gaussian.confidence_k2(gate, 2))
        self.N, self.walk, self.expire = hypotheses, walk, expire
        self.xy, self.exclusion = np.asarray(landmarks.xy), exclusion
        T = len(log.t)
        self.mean, self.cov = np.empty((T, 3)), np.empty((T, 3, 3))

    def _run(self, k0, k1, x, P, rows=None, keep="all"):
        """``ekf.run`` of hypotheses (H,) from time index k0 to k1, with readings ``rows`` at k1."""
        lg, H = self.log, len(x)
        if rows is None:
            sub = ekf.Log(lg.t[k0 : k1 + 1], lg.motion[k0:k1], lg.reading_index[:0], lg.z[:0])
        else:
            sub = ekf.Log(lg.t[k1 : k1 + 1], lg.motion[:0], np.zeros(len(rows), np.int64),
                          lg.z[rows], lg.signature[rows])  # fmt: skip
        p = ekf.NoiseParameters(*(np.full(H, float(v)) for v in self.params))
        return ekf.run(sub, self.lmap, p, start=AT._trusted(x, P), association="mahalanobis",
                       gate=self.gate, keep=keep, readings=rows is not None)  # fmt: skip

    def _record(self, k0, k1, X, C, logw):
        w = np.exp(logw - logw.max())
        w /= w.sum()
        ref = X[np.argmax(w)]
        d = X - ref
        d[..., 2] = se2.wrap_angle(d[..., 2])
        mu = ref + np.einsum("h,hti->ti", w, d)
        e = X - mu
        e[..., 2] = se2.wrap_angle(e[..., 2])
        self.cov[k0 : k1 + 1] = np.einsum("h,htij->tij", w, C) + np.einsum(
            "h,hti,htj->tij", w, e, e
        )
        mu[..., 2] = se2.wrap_angle(mu[..., 2])
        self.mean[k0 : k1 + 1] = mu

    def _predict(self, k0, k1, hyps):
        x, P = np.array([h.x for h in hyps]), np.array([h.P for h in hyps])
        tr = self._run(k0, k1, x, P)
        self._record(k0, k1, tr.mean, tr.cov, np.array([h.logw for h in hyps]))
        Q = self._run(k0, k1, x, np.zeros_like(P), keep="summary").cov[:, -1]  # odometry's own
        now = self.log.t[k1]
        return [h._replace(x=tr.mean[i, -1], P=tr.cov[i, -1], objects=tuple(
                    (q, Cq, Qo + Q[i], t) for q, Cq, Qo, t in h.objects if now - t < self.expire))
                for i, h in enumerate(hyps)]  # fmt: skip

    def _density(self, y, S):
        d2 = float(y @ np.linalg.solve(S, y))
        return float(autocalibration.logpdf(d2, np.log(np.linalg.det(S)), 2, self.nu)), d2

    def _point(self, x, z):
        """Where reading ``z`` puts its object from pose ``x`` (the pose taken as exact), and
        the covariance of the reading's noise there (Appendix B)."""
        C = np.zeros((3, 3))
        C[:2, :2] = self.R
        p = polar_to_cartesian([z[0], x[2] + z[1], 0.0], C)
        return x[:2] + p.mean[:2], p.cov[:2, :2]

    def _object_density(self, x, obj, z, now):
        q, Cq, Q, t = obj
        zh, Hx, Hq = SENSOR.predict(x, q, jacobians=True)
        S = Hx @ Q @ Hx.T + Hq @ (Cq + self.walk * (now - t) * np.eye(2)) @ Hq.T + self.R
        y = z - zh
        y[1] = se2.wrap_angle(y[1])
        return self._density(y, S)

    def _prune(self, children):
        kept: list[Hypothesis] = []
        for c in sorted(children, key=lambda c: -c.logw):
            if len(kept) == self.N:
                break
            if not any(
                abs(c.logw - k.logw) < 1e-9 and np.abs(c.x - k.x).max() < 1e-9 for k in kept
            ):
                kept.append(c)
        top = kept[0].logw
        return [k._replace(logw=k.logw - top) for k in kept]

    def _clutter_stamp(self, k, rows, hyps):
        """Every subset of the stamp's readings offered (the rest clutter); more than 4
        readings: all, all but one, none."""
        m = len(rows)
        subsets = ([s for n in range(m, -1, -1) for s in itertools.combinations(range(m), n)]
                   if m <= 4 else [tuple(range(m)), *itertools.combinations(range(m), m - 1), ()])  # fmt: skip
        x, P = np.array([h.x for h in hyps]), np.array([h.P for h in hyps])
        children = []
        for s in subsets:
            if not s:
                children += [h._replace(logw=h.logw + m * self.loglam) for h in hyps]
                continue
            tr = self._run(k, k, x, P, rows[list(s)], keep="summary")
            for i, h in enumerate(hyps):
                ll, hist = (m - len(s)) * self.loglam, h.history
                for j, row in enumerate(rows[list(s)]):
                    if tr.status[i, j] == ekf.Status.USED:
                        ll += self._density(tr.y_given[i, j], tr.S_given[i, j])[0]
                        hist = (row, LANDMARK, hist)
                    else:
                        ll += self.loglam
                children.append(Hypothesis(tr.mean[i, -1], tr.cov[i, -1], h.logw + ll,
                                           h.objects, hist))  # fmt: skip
        return self._prune(children)

    def _objects_stamp(self, k, rows, hyps):
        now = self.log.t[k]
        for row in rows:
            z = self.log.z[row]
            x, P = np.array([h.x for h in hyps]), np.array([h.P for h in hyps])
            tr = self._run(k, k, x, P, np.array([row]), keep="summary")
            children = []
            for i, h in enumerate(hyps):
                paired = tr.status[i, 0] == ekf.Status.USED
                if paired:
                    lp = self._density(tr.y_given[i, 0], tr.S_given[i, 0] + self.dR)[0]
                    children.append(Hypothesis(tr.mean[i, -1], tr.cov[i, -1], h.logw + lp,
                                               h.objects, (row, LANDMARK, h.history)))  # fmt: skip
                seen = (*self._point(h.x, z), np.zeros((3, 3)), now)
                for j, obj in enumerate(h.objects):
                    lp, d2 = self._object_density(h.x, obj, z, now)
                    if d2 <= self.gate2:
                        objects = (*h.objects[:j], seen, *h.objects[j + 1 :])
                        children.append(h._replace(logw=h.logw + lp, objects=objects,
                                                   history=(row, OBJECT, h.history)))  # fmt: skip
                apart = np.hypot(*(self.xy - seen[0]).T).min() >= self.exclusion
                born = (*h.objects, seen) if (self.all_objects or paired) and apart else h.objects
                children.append(h._replace(logw=h.logw + self.loglam, objects=born,
                                           history=(row, NEW, h.history)))  # fmt: skip
            hyps = self._prune(children)
        return hyps

    def run(self, model):
        lg = self.log
        stamp = self._clutter_stamp if model == "clutter" else self._objects_stamp
        self.all_objects = model == "objects"
        hyps = [Hypothesis(self.start.mean, self.start.cov, 0.0, (), None)]
        stamps, first = np.unique(lg.reading_index, return_index=True)
        ends = [*first[1:], len(lg.reading_index)]
        k0 = 0
        for k, a, b in zip(stamps, first, ends, strict=True):
            if k > k0:
                hyps = self._predict(k0, k, hyps)
            hyps, k0 = stamp(k, np.arange(a, b), hyps), k
        T = len(lg.t)
        if T - 1 > k0:
            hyps = self._predict(k0, T - 1, hyps)
        else:
            self._record(k0, k0, np.array([h.x for h in hyps])[:, None],
                         np.array([h.P for h in hyps])[:, None], np.array([h.logw for h in hyps]))  # fmt: skip
        how, node = np.full(len(lg.z), NEW), hyps[0].history
        while node is not None:
            how[node[0]], node = node[1], node[2]
        return AT._trusted(self.mean, self.cov), how


def recording(data, robot):
    """``relmap localize``'s recording of every reading of ``robot`` (barcodes as labels)."""
    log = data.robots[robot - 1]
    inside = localize._inside_truth(log.odometry_t, log.truth_t)
    first, end = np.flatnonzero(inside)[[0, -1]]
    z = np.column_stack([log.meas_range, log.meas_bearing])
    rec = autocalibration.Recording(
        log.odometry_t[first:], log.odometry_v[first:], log.odometry_w[first:], log.meas_t, z,
        data.landmark_index(log.meas_subject), float(log.odometry_t[end]),
    )  # fmt: skip
    return rec, log.truth_at


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--model", choices=("clutter", "objects", "confusers"), default="objects")
    ap.add_argument("--hypotheses", type=int, default=16)
    ap.add_argument("--robots", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    ap.add_argument("--gate", type=float, default=0.99)
    ap.add_argument("--object-walk", type=float, default=0.05, help="m²/s")
    ap.add_argument("--expire", type=float, default=10.0, help="s")
    ap.add_argument(
        "--inflate-landmarks",
        action="store_true",
        help="a landmark's reading density with the update's σ factor (objects')",
    )
    ap.add_argument(
        "--exclusion", type=float, default=0.0, help="m: no object born this close to a landmark"
    )
    ap.add_argument("--minutes", action="store_true", help="error and explanations per minute")
    a = ap.parse_args()
    data = read_mrclam(DATA / "landmarks" / "mrclam6")
    landmarks = ekf.LandmarkMap(data.landmark_xy)

    def fmt(s):
        return f"{s.rmse_position:.3f}/{s.coverage_90:.2f}/{s.anees:.2f}"

    for robot in a.robots:
        one = localize.localize_mrclam(data, robot, associate="mahalanobis", gate=a.gate)
        cal = one.calibration
        rec, truth_at = recording(data, robot)
        log = rec.log(*cal.clock)
        truth = truth_at(log.t)
        t0 = time.perf_counter()
        study = Study(log, landmarks, cal, localize._start(truth[0]), gate=a.gate,
                      hypotheses=a.hypotheses, walk=a.object_walk, expire=a.expire,
                      inflate=a.inflate_landmarks, exclusion=a.exclusion)  # fmt: skip
        est, how = study.run(a.model)
        s = localize.score(est, truth)
        print(f"robot {robot}: one hypothesis {fmt(one.score)}; {a.hypotheses} ({a.model}) "
              f"{fmt(s)}  [{time.perf_counter() - t0:.1f} s]")  # fmt: skip
        in_map = log.signature >= 0
        for name, m in (("landmarks", in_map), ("no landmark", ~in_map)):
            n = [int((how[m] == v).sum()) for v in (LANDMARK, OBJECT, NEW)]
            print(
                f"  readings of {name}: as a landmark {n[0]}, an object {n[1]}, new/clutter {n[2]}"
            )
        if a.minutes:
            err = np.hypot(*(est.mean[:, :2] - truth[:, :2]).T)
            rt = log.t[log.reading_index]
            for m0 in np.arange(log.t[0], log.t[-1], 60.0):
                w, r = (log.t >= m0) & (log.t < m0 + 60), (rt >= m0) & (rt < m0 + 60)
                print(f"  {m0 - log.t[0]:4.0f} s: error mean {err[w].mean():.2f} max "
                      f"{err[w].max():.2f} m; landmarks' readings L/O/N "
                      f"{[int((how[r & in_map] == v).sum()) for v in (0, 1, 2)]}")  # fmt: skip


if __name__ == "__main__":
    main()
