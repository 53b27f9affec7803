"""ROS bags: every message of the named topics read exactly (stamps, poses, covariances) against
rosbags' own low-level readers; TF chains against evo's TF reader; bad bags give clear errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rosbags")
from rosbags.rosbag1 import Reader as Reader1
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import Reader as Reader2
from rosbags.typesys import Stores, get_typestore

from relmap.errors import FileFormatError, ParameterError
from relmap.io.trajectory import read_trajectory, recognise_trajectory
from relmap.lie import so3


def reference(reader, typestore, topic, ros1):  # type: ignore[no-untyped-def]
    """Stamps (sec + nanosec·1e-9), positions, quaternions, covariances of every message."""
    conns = [c for c in reader.connections if c.topic == topic]
    t, p, q, c = [], [], [], []
    for conn, _, raw in reader.messages(connections=conns):
        f = typestore.deserialize_ros1 if ros1 else typestore.deserialize_cdr
        msg = f(raw, conn.msgtype)
        t.append(msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9)
        pose = msg.pose.pose if hasattr(msg.pose, "pose") else msg.pose
        p.append([pose.position.x, pose.position.y, pose.position.z])
        o = pose.orientation
        q.append([o.x, o.y, o.z, o.w])
        if hasattr(msg.pose, "covariance"):
            c.append(np.asarray(msg.pose.covariance).reshape(6, 6))
    return np.array(t), np.array(p), np.array(q), np.array(c)


def check_exact(traj, t, p, q, c):  # type: ignore[no-untyped-def]
    assert len(traj) == len(t)
    np.testing.assert_array_equal(traj.stamps, t)
    np.testing.assert_array_equal(traj.positions, p)
    np.testing.assert_allclose(traj.matrices[:, :3, :3], so3.from_quaternion(q), atol=1e-15)
    if traj.has_cov:
        np.testing.assert_array_equal(traj.cov, c)


@pytest.mark.real_data
@pytest.mark.parametrize("topic", ["groundtruth", "ORB-SLAM", "S-PTAM"])
def test_ros1_bag_every_message(data_dir, topic):  # type: ignore[no-untyped-def]
    path = data_dir / "trajectories" / "ROS_example.bag"
    assert recognise_trajectory(path) == "bag"
    with Reader1(path) as r:
        ref = reference(r, get_typestore(Stores.ROS1_NOETIC), topic, True)
    traj = read_trajectory(path, topic=topic)
    assert not traj.has_cov and traj.frame == topic
    check_exact(traj, *ref)


@pytest.mark.real_data
@pytest.mark.parametrize("topic", ["/odom", "/amcl_pose"])
def test_mcap_bag_every_message(data_dir, topic):  # type: ignore[no-untyped-def]
    path = data_dir / "trajectories" / "nav2_turtlebot.mcap"
    with Reader2(path) as r:
        ref = reference(r, get_typestore(Stores.LATEST), topic, False)
    traj = read_trajectory(path, topic=topic)
    check_exact(traj, *ref)
    if topic == "/amcl_pose":  # AMCL's covariance, kept exactly (relmap's chart = ROS's)
        assert traj.has_cov and traj.frame == "map"
    else:  # this bag's odometry publishes an all-zero covariance: "not known"
        assert not ref[3].any() and not traj.has_cov
        assert (traj.frame, traj.child) == ("odom", "base_link")


def tf_messages(path, typestore):  # type: ignore[no-untyped-def]
    """(topic, parent, child, stamp, 4×4) of every transform, read by rosbags' own reader."""
    out = []
    with Reader2(path) as r:
        for conn, _, raw in r.messages():
            if conn.msgtype != "tf2_msgs/msg/TFMessage":
                continue
            for tr in typestore.deserialize_cdr(raw, conn.msgtype).transforms:
                a, q = tr.transform.translation, tr.transform.rotation
                M = np.eye(4)
                M[:3, :3] = so3.from_quaternion([q.x, q.y, q.z, q.w])
                M[:3, 3] = a.x, a.y, a.z
                s = tr.header.stamp
                out.append(
                    (conn.topic, tr.header.frame_id, tr.child_frame_id, s.sec + s.nanosec * 1e-9, M)
                )
    return out


@pytest.mark.real_data
def test_tf_chain_dynamic_and_static(data_dir):  # type: ignore[no-untyped-def]
    """odom → base_link = (odom → base_footprint, every /tf message) · (static base_footprint →
    base_link), at the dynamic link's stamps."""
    path = data_dir / "trajectories" / "tf_example"
    msgs = tf_messages(path, get_typestore(Stores.LATEST))
    dyn = sorted((m for m in msgs if m[1:3] == ("odom", "base_footprint")), key=lambda m: m[3])
    (static,) = [m[4] for m in msgs if m[1:3] == ("base_footprint", "base_link")]
    traj = read_trajectory(path, topic="/tf:odom.base_link")
    np.testing.assert_array_equal(traj.stamps, [m[3] for m in dyn])
    np.testing.assert_allclose(traj.matrices, np.array([m[4] @ static for m in dyn]), atol=1e-14)
    inverse = read_trajectory(path, topic="/tf:base_link.odom")
    np.testing.assert_allclose(
        inverse.matrices @ traj.matrices,
        np.broadcast_to(np.eye(4), traj.matrices.shape),
        atol=1e-12,
    )


@pytest.mark.real_data
def test_tf_chain_composes_map_odom_base(data_dir):  # type: ignore[no-untyped-def]
    """map → base_link = (map → odom, interpolated) · (odom → base_link) at odom's stamps."""
    path = data_dir / "trajectories" / "nav2_turtlebot.mcap"
    chain = read_trajectory(path, topic="/tf:map.base_link")
    odom = read_trajectory(path, topic="/tf:odom.base_link")
    mo = read_trajectory(path, topic="/tf:map.odom")
    k = np.searchsorted(odom.stamps, chain.stamps)
    np.testing.assert_array_equal(odom.stamps[k], chain.stamps)
    i = np.searchsorted(mo.stamps, chain.stamps[len(chain) // 2])
    if mo.stamps[i] == chain.stamps[len(chain) // 2]:  # at a shared stamp: no interpolation
        np.testing.assert_allclose(
            chain.matrices[len(chain) // 2],
            mo.matrices[i] @ odom.matrices[k[len(chain) // 2]],
            atol=1e-12,
        )
    assert (chain.frame, chain.child) == ("map", "base_link")


@pytest.mark.real_data
def test_missing_topic_lists_the_topics(data_dir):  # type: ignore[no-untyped-def]
    path = data_dir / "trajectories" / "nav2_turtlebot.mcap"
    with pytest.raises(FileFormatError, match=r"no topic '/pose'.*/amcl_pose.*/odom"):
        read_trajectory(path, topic="/pose")
    with pytest.raises(ParameterError, match="name a topic"):
        read_trajectory(path)
    with pytest.raises(FileFormatError, match="not in the TF tree"):
        read_trajectory(path, topic="/tf:map.nowhere")


# --------------------------------------------------------------------------- written bags
TS = get_typestore(Stores.ROS1_NOETIC)


def _msg(kind, k, t, xyz, q, cov=None):  # type: ignore[no-untyped-def]
    T = TS.types
    header = T["std_msgs/msg/Header"](
        seq=k,
        stamp=T["builtin_interfaces/msg/Time"](sec=int(t), nanosec=round((t % 1) * 1e9)),
        frame_id="map",
    )
    pose = T["geometry_msgs/msg/Pose"](
        position=T["geometry_msgs/msg/Point"](x=xyz[0], y=xyz[1], z=xyz[2]),
        orientation=T["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
    )
    if kind == "geometry_msgs/msg/PoseStamped":
        return T[kind](header=header, pose=pose)
    pwc = T["geometry_msgs/msg/PoseWithCovariance"](
        pose=pose, covariance=np.asarray(cov, dtype=np.float64).reshape(36)
    )
    return T[kind](header=header, pose=pwc)


def write_bag(path: Path, kind: str, rows):  # type: ignore[no-untyped-def]
    with Writer1(path) as w:
        conn = w.add_connection("/pose", kind, typestore=TS)
        for k, row in enumerate(rows):
            msg = _msg(kind, k, *row)
            w.write(conn, (100 + k) * 10**9, TS.serialize_ros1(msg, kind))  # received in order
    return path


def good_rows(n=5, cov=True):  # type: ignore[no-untyped-def]
    C = np.diag([0.1, 0.2, 0.0, 0.0, 0.0, 0.05])
    C[0, 1] = C[1, 0] = 0.01
    return [
        (
            10.0 + 0.5 * k,
            (k, 2.0 * k, 0.0),
            (0.0, 0.0, np.sin(0.1 * k), np.cos(0.1 * k)),
            C if cov else None,
        )
        for k in range(n)
    ]


def test_written_bag_with_covariance_round_trip(tmp_path):  # type: ignore[no-untyped-def]
    rows = good_rows()
    path = write_bag(tmp_path / "a.bag", "geometry_msgs/msg/PoseWithCovarianceStamped", rows)
    traj = read_trajectory(path, topic="/pose")
    assert traj.has_cov
    np.testing.assert_array_equal(traj.cov, np.array([r[3] for r in rows]))
    np.testing.assert_array_equal(traj.stamps, [r[0] for r in rows])


@pytest.mark.parametrize(
    ("change", "match"),
    [
        (
            lambda r: r.__setitem__(2, (r[2][0], (np.nan, 0.0, 0.0), r[2][2], r[2][3])),
            r"message 2: pose is not finite",
        ),
        (
            lambda r: r.__setitem__(3, (r[3][0], r[3][1], (0.0, 0.0, 0.0, 0.0), r[3][3])),
            r"message 3: zero quaternion",
        ),
        (
            lambda r: r.__setitem__(1, (r[1][0], r[1][1], (0.0, 0.0, 0.5, 0.5), r[1][3])),
            r"message 1: quaternion of norm 0.707",
        ),
        (
            lambda r: r.__setitem__(3, (9.0, r[3][1], r[3][2], r[3][3])),
            r"message 3: stamp 9.0 s comes before",
        ),
        (
            lambda r: r.__setitem__(4, (r[4][0], r[4][1], r[4][2], np.full((6, 6), -1.0))),
            r"message 4: covariance unknown",
        ),
        (
            lambda r: r.__setitem__(2, (r[2][0], r[2][1], r[2][2], -np.eye(6))),
            r"message 2: covariance unknown",
        ),
    ],
    ids=[
        "nan",
        "zero-quaternion",
        "non-unit",
        "stamps-back",
        "unknown-cov",
        "unknown-cov-first-entry",
    ],
)
def test_bad_bags(tmp_path, change, match):  # type: ignore[no-untyped-def]
    rows = good_rows()
    change(rows)
    path = write_bag(tmp_path / "bad.bag", "geometry_msgs/msg/PoseWithCovarianceStamped", rows)
    with pytest.raises(FileFormatError, match=match) as info:
        read_trajectory(path, topic="/pose")
    assert str(path) in str(info.value)


def test_all_unknown_covariances_mean_no_covariance(tmp_path):  # type: ignore[no-untyped-def]
    rows = [(r[0], r[1], r[2], np.full((6, 6), -1.0)) for r in good_rows()]
    path = write_bag(tmp_path / "u.bag", "geometry_msgs/msg/PoseWithCovarianceStamped", rows)
    traj = read_trajectory(path, topic="/pose")
    assert not traj.has_cov and traj.cov is None
