"""APE and RPE against evo (the peer, GPL, in the test extra) on the same files and options.

Every estimate of the shared trajectories folder, with and without alignment (SE(3), Sim(3) —
the monocular KITTI ORB estimate —, scale only, origin), every pose relation, RPE deltas in
frames and metres, consecutive and all pairs; and random trajectories with jittered, repeated
and offset stamps, so that association and pairing rules are exercised beyond these files.
Agreement: |relmap - evo| ≤ 1e-9·max(1, |evo|) (the sse of KITTI's APE is ~2.5e5; both sum in
different orders).
"""

from __future__ import annotations

import copy

import numpy as np
import pytest

pytest.importorskip("evo")
from evo.core import metrics as evo_metrics
from evo.core import sync
from evo.core.filters import FilterException
from evo.core.metrics import PoseRelation, Unit
from evo.core.trajectory import PosePath3D, PoseTrajectory3D
from evo.tools import file_interface as fi

from relmap.errors import ParameterError
from relmap.evaluate import align, ape, associate, rpe
from relmap.io.trajectory import read_trajectory
from relmap.uncertain.trajectory import Trajectory

RELATIONS = {
    "trans": PoseRelation.translation_part,
    "angle_rad": PoseRelation.rotation_angle_rad,
    "angle_deg": PoseRelation.rotation_angle_deg,
    "rot": PoseRelation.rotation_part,
    "full": PoseRelation.full_transformation,
}
CASES = [
    ("KITTI_00_gt.txt", "KITTI_00_ORB.txt", 100.0),
    ("V102_groundtruth.csv", "V102.txt", 1.0),
    ("freiburg1_xyz-groundtruth.txt", "freiburg1_xyz-rgbdslam.txt", 0.5),
    ("ROS_example.bag:groundtruth", "ROS_example.bag:ORB-SLAM", 5.0),
    ("ROS_example.bag:groundtruth", "ROS_example.bag:S-PTAM", 5.0),
    ("nav2_turtlebot.mcap:/odom", "nav2_turtlebot.mcap:/amcl_pose", 1.0),
]
MODES = ("none", "se3", "sim3", "scale", "origin")


def close(mine: dict[str, float], theirs: dict[str, float]) -> None:
    for k, v in theirs.items():
        assert abs(mine[k] - float(v)) <= 1e-9 * max(1.0, abs(float(v))), (k, mine[k], v)


def evo_read(folder, name):  # type: ignore[no-untyped-def]
    if ":" in name:
        from rosbags.rosbag1 import Reader as Reader1
        from rosbags.rosbag2 import Reader as Reader2

        bag, topic = name.split(":")
        with (Reader1 if bag.endswith(".bag") else Reader2)(folder / bag) as r:
            return fi.read_bag_trajectory(r, topic)
    if name.endswith(".csv"):
        return fi.read_euroc_csv_trajectory(folder / name)
    if name.startswith("KITTI"):
        return fi.read_kitti_poses_file(folder / name)
    return fi.read_tum_trajectory_file(folder / name)


def relmap_read(folder, name):  # type: ignore[no-untyped-def]
    if ":" in name:
        bag, topic = name.split(":")
        return read_trajectory(folder / bag, topic=topic)
    return read_trajectory(folder / name)


def evo_align(est, ref, mode):  # type: ignore[no-untyped-def]
    est = copy.deepcopy(est)
    if mode == "se3":
        est.align(ref)
    elif mode == "sim3":
        est.align(ref, correct_scale=True)
    elif mode == "scale":
        est.align(ref, correct_only_scale=True)
    elif mode == "origin":
        est.align_origin(ref)
    return est


def compare(er, ee, rr, re_, rpe_cases, modes=MODES, angles=("none",), degrees=True):  # type: ignore[no-untyped-def]
    """Every relation in the modes ``angles`` (degrees too if ``degrees``); elsewhere the fast
    ones (evo's rotation angle costs ~1 ms a pose)."""
    for mode in modes:
        e2 = evo_align(ee, er, mode)
        al, _ = align(re_, rr, mode)
        P, Q = al.matrices, rr.matrices
        relations = tuple(RELATIONS) if mode in angles else ("trans", "rot", "full")
        if not degrees:
            relations = tuple(r for r in relations if r != "angle_deg")
        for name in relations:
            m = evo_metrics.APE(RELATIONS[name])
            m.process_data((er, e2))
            close(ape(P, Q, name).stats(), m.get_all_statistics())
            for unit, delta, all_pairs in rpe_cases:
                m = evo_metrics.RPE(
                    RELATIONS[name],
                    delta,
                    Unit.frames if unit == "frames" else Unit.meters,
                    all_pairs=all_pairs,
                )
                try:
                    m.process_data((er, e2))
                except FilterException:  # no pairs: relmap says so too
                    with pytest.raises(ParameterError, match="no pose pairs"):
                        rpe(P, Q, name, delta=delta, unit=unit, all_pairs=all_pairs)
                    continue
                mine = rpe(P, Q, name, delta=delta, unit=unit, all_pairs=all_pairs)
                assert len(mine.values) == len(m.error)
                close(mine.stats(), m.get_all_statistics())


@pytest.mark.real_data
@pytest.mark.slow
@pytest.mark.parametrize(("ref", "est", "metres"), CASES, ids=[c[1] for c in CASES])
def test_real_estimates_equal_evo(data_dir, ref, est, metres):  # type: ignore[no-untyped-def]
    folder = data_dir / "trajectories"
    er, ee = evo_read(folder, ref), evo_read(folder, est)
    rr, re_ = relmap_read(folder, ref), relmap_read(folder, est)
    if isinstance(er, PoseTrajectory3D):
        er, ee = sync.associate_trajectories(er, ee, max_diff=0.01)
    pairing = associate(rr, re_, max_diff=0.01)
    assert len(pairing.ref) == er.num_poses
    np.testing.assert_array_equal(pairing.ref.matrices[:, :3, 3], er.positions_xyz)
    np.testing.assert_array_equal(pairing.est.matrices[:, :3, 3], ee.positions_xyz)
    cases = [("frames", 1, False), ("frames", 10, True), ("m", metres, False), ("m", metres, True)]
    # The angle relations unaligned only (evo's angle costs ~0.35 ms a pose; on KITTI the Sim(3)
    # angles were a third of this test): every alignment's error poses are checked through rot
    # and full, whose rotation part fixes the angle (‖R - I‖_F = 2√2 sin(θ/2)), and the angle on
    # every alignment through the random trajectories (angles=MODES).
    compare(er, ee, pairing.ref, pairing.est, cases, angles=("none",), degrees=False)


def _random_trajectory(rng, n, t0=100.0):  # type: ignore[no-untyped-def]
    stamps = t0 + np.cumsum(rng.uniform(0.0, 0.05, n))
    stamps[rng.integers(1, n, 3)] = stamps[rng.integers(1, n, 3) - 1]  # a few repeats
    stamps = np.maximum.accumulate(stamps)
    xyz = np.cumsum(rng.normal(0, 0.3, (n, 3)), axis=0)
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return stamps, xyz, q


@pytest.mark.parametrize(
    "seed", [0, *(pytest.param(s, marks=pytest.mark.slow) for s in range(1, 6))]
)  # one seed in the quick subset, all six in the whole suite
def test_random_trajectories_equal_evo(seed):  # type: ignore[no-untyped-def]
    """Association with tolerance, offset and repeated stamps; alignment; APE; RPE."""
    rng = np.random.default_rng(seed)
    ts, xs, qs = _random_trajectory(rng, 300)
    te, xe, qe = _random_trajectory(rng, int(rng.integers(150, 450)), t0=100.0 + rng.uniform(-1, 1))
    xe = xe * rng.uniform(0.5, 2.0) + rng.normal(0, 0.1, xe.shape)
    max_diff, offset = float(rng.uniform(0.005, 0.03)), float(rng.uniform(-0.5, 0.5))
    er = PoseTrajectory3D(xs, np.roll(qs, 1, axis=1), ts)
    ee = PoseTrajectory3D(xe, np.roll(qe, 1, axis=1), te)
    er, ee = sync.associate_trajectories(er, ee, max_diff=max_diff, offset_2=offset)
    rr = Trajectory.from_quaternions(xs, qs, ts)
    re_ = Trajectory.from_quaternions(xe, qe, te)
    pairing = associate(rr, re_, max_diff=max_diff, offset=offset)
    np.testing.assert_array_equal(pairing.ref.stamps, er.timestamps)
    np.testing.assert_array_equal(pairing.est.stamps, ee.timestamps)
    compare(
        er,
        ee,
        pairing.ref,
        pairing.est,
        [("frames", 3, False), ("frames", 2, True), ("m", 1.5, False), ("m", 1.5, True)],
        angles=MODES,
    )


def test_pairs_from_reference_like_evo():  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(11)
    ts, xs, qs = _random_trajectory(rng, 200)
    _, xe, qe = _random_trajectory(rng, 200)
    er = PoseTrajectory3D(xs, np.roll(qs, 1, axis=1), ts)
    ee = PoseTrajectory3D(xe * 0.5, np.roll(qe, 1, axis=1), ts)
    rr = Trajectory.from_quaternions(xs, qs, ts)
    re_ = Trajectory.from_quaternions(xe * 0.5, qe, ts)
    for unit, delta, all_pairs in [("frames", 4, False), ("m", 2.0, False), ("m", 2.0, True)]:
        m = evo_metrics.RPE(
            PoseRelation.translation_part,
            delta,
            Unit.frames if unit == "frames" else Unit.meters,
            all_pairs=all_pairs,
            pairs_from_reference=True,
        )
        m.process_data((er, ee))
        mine = rpe(
            re_.matrices,
            rr.matrices,
            "trans",
            delta=delta,
            unit=unit,
            all_pairs=all_pairs,
            pairs_from_reference=True,
        )
        close(mine.stats(), m.get_all_statistics())


def test_kitti_paths_pair_by_index_like_evo():  # type: ignore[no-untyped-def]
    """Trajectories without stamps (PosePath3D) pair by index."""
    rng = np.random.default_rng(7)
    _, xs, qs = _random_trajectory(rng, 50)
    _, xe, qe = _random_trajectory(rng, 50)
    er = PosePath3D(xs, np.roll(qs, 1, axis=1))
    ee = PosePath3D(xe, np.roll(qe, 1, axis=1))
    rr, re_ = Trajectory.from_quaternions(xs, qs), Trajectory.from_quaternions(xe, qe)
    pairing = associate(rr, re_)
    compare(
        er,
        ee,
        pairing.ref,
        pairing.est,
        [("frames", 1, False), ("m", 2.0, True)],
        modes=("none", "sim3"),
    )
