"""Trajectories from ROS bags: ROS 1 ``.bag``, ROS 2 ``.db3`` and ``.mcap`` (files or bag folders),
read with the pure-Python ``rosbags`` library (Apache-2.0; imported only here, when a bag is read).

A topic of ``geometry_msgs/PoseStamped``, ``geometry_msgs/PoseWithCovarianceStamped`` or
``nav_msgs/Odometry`` gives one pose per message, stamped with the header's time
``sec + nanosec·1e-9`` (as evo reads it), in the header's ``frame_id`` (``Odometry``: the child
is ``child_frame_id``). A TF chain ``/tf:PARENT.CHILD`` gives the pose of CHILD in PARENT
composed along the tree of ``/tf`` and ``/tf_static``: at the stamps of the chain's busiest
dynamic transform, within the span every dynamic transform of the chain covers, the others
interpolated there (translation linearly, rotation along the geodesic), as ``tf2`` looks up.

Covariances. ROS's ``PoseWithCovariance`` covariance is row-major 6×6 on
``(x, y, z, rotation about X, Y, Z)`` "in fixed axes": the translation in the header frame and a
small rotation about the header frame's axes, so that ``R' = Exp(δφ) R`` — relmap's chart
exactly (``tf2`` rotates both blocks alike when it transforms a covariance into another frame,
which treats the rotation part as a rotation vector in the parent frame, not as Euler angles).
The conversion is therefore the identity on the 36 numbers (:meth:`relmap.AT3.from_ros`,
:meth:`relmap.AT3.to_ros`). A first entry of −1 marks the covariance unknown (REP 103 / the
message's comment); so does a matrix of zeros, which drivers publish when they have none. A
topic whose messages all say so gives a trajectory without covariance; a topic mixing known and
unknown covariances is an error naming the first message that differs.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from relmap.errors import FileFormatError, ParameterError, RelmapError
from relmap.io import formats
from relmap.io.textfile import Input
from relmap.lie import se3, so3
from relmap.lie.group import SE3
from relmap.typing import FloatArray
from relmap.uncertain.trajectory import Trajectory

__all__ = ["POSE_TYPES", "bag_topics", "read_bag", "read_bag_topics"]

POSE_TYPES = (
    "geometry_msgs/msg/PoseStamped",
    "geometry_msgs/msg/PoseWithCovarianceStamped",
    "nav_msgs/msg/Odometry",
)
_TF_TYPE = "tf2_msgs/msg/TFMessage"


def _open(path: Path):  # type: ignore[no-untyped-def]
    if path.exists() and not (path.is_file() or path.is_dir()):
        raise FileFormatError(path, "a ROS bag is read from its file or folder, not from a pipe")
    try:
        from rosbags.highlevel import AnyReader
    except ImportError:  # pragma: no cover - rosbags is a dependency
        raise ParameterError(
            "reading ROS bags needs the rosbags package (pip install rosbags)"
        ) from None
    try:
        reader = AnyReader([path])
        reader.open()
    except Exception as exc:  # rosbags raises its own (non-relmap) errors on malformed bags
        raise FileFormatError(path, f"not a readable ROS bag: {exc}") from None
    return reader


def bag_topics(path: str | os.PathLike[str]) -> dict[str, tuple[str, int]]:
    """``topic → (message type, message count)`` of a bag."""
    reader = _open(Path(path))
    try:
        return _topics(reader)
    finally:
        reader.close()


def _topics(reader: Any) -> dict[str, tuple[str, int]]:
    out: dict[str, tuple[str, int]] = {}
    for c in reader.connections:
        kind, count = out.get(c.topic, (c.msgtype, 0))
        out[c.topic] = (kind, count + c.msgcount)
    return out


def _listing(topics: dict[str, tuple[str, int]]) -> str:
    return ", ".join(f"{t} ({k}, {n})" for t, (k, n) in sorted(topics.items())) or "none"


def _stamp(header: Any) -> float:
    return header.stamp.sec + header.stamp.nanosec * 1e-9


def read_bag(path: str | os.PathLike[str], topic: str | None) -> Trajectory:
    """The trajectory of ``topic`` (or the TF chain ``/tf:PARENT.CHILD``) in the bag ``path``."""
    if topic is None:
        topics = bag_topics(path)
        raise ParameterError(
            f"{path} is a ROS bag: name a topic (--topic); it has {_listing(topics)}"
        )
    return read_bag_topics(path, [topic])[0]


def read_bag_topics(path: str | os.PathLike[str], topics: list[str]) -> list[Trajectory]:
    """The trajectories of several topics (or TF chains) of one bag, opened once."""
    p = Path(path)
    reader = _open(p)
    try:
        have = _topics(reader)
        for topic in topics:
            if topic.startswith(("/tf:", "tf:")):
                continue
            if topic not in have:
                raise FileFormatError(p, f"no topic {topic!r}; the bag has {_listing(have)}")
            if have[topic][0] not in POSE_TYPES:
                raise FileFormatError(
                    p,
                    f"topic {topic} is {have[topic][0]}; trajectories come from "
                    + ", ".join(POSE_TYPES),
                )
        # one pass per topic: rosbags' merge of several topics' messages is several times
        # slower than reading them one topic after the other (measured on ROS_example.bag)
        return [
            _read_tf(p, reader, t, have)
            if t.startswith(("/tf:", "tf:"))
            else _read_poses(p, reader, [t], have)[t]
            for t in topics
        ]
    finally:
        reader.close()


def _messages(reader: Any, topics: tuple[str, ...]):  # type: ignore[no-untyped-def]
    conns = [c for c in reader.connections if c.topic in topics]
    for conn, _, raw in reader.messages(connections=conns):
        yield conn, reader.deserialize(raw, conn.msgtype)


def _read_poses(
    p: Path, reader: Any, topics: list[str], have: dict[str, tuple[str, int]]
) -> dict[str, Trajectory]:
    records: dict[str, tuple[list[float], list[tuple[float, ...]], list[Any], list[str]]] = {
        t: ([], [], [], []) for t in topics
    }
    for conn, msg in _messages(reader, tuple(topics)):
        stamps, values, covs, names = records[conn.topic]
        with_cov = hasattr(msg.pose, "covariance")
        pose = msg.pose.pose if with_cov else msg.pose
        o, q = pose.position, pose.orientation
        stamps.append(_stamp(msg.header))
        values.append((o.x, o.y, o.z, q.x, q.y, q.z, q.w))
        if with_cov:
            covs.append(msg.pose.covariance)
        if not names:
            names.extend([msg.header.frame_id, getattr(msg, "child_frame_id", "")])
    return {t: _trajectory(p, t, *records[t]) for t in topics}


def _trajectory(
    p: Path, topic: str, stamps: list[float], values: list[Any], covs: list[Any], names: list[str]
) -> Trajectory:
    where = f"topic {topic}"
    v = np.asarray(values, dtype=np.float64).reshape(-1, 7)
    t = np.asarray(stamps, dtype=np.float64)
    _check_messages(p, where, t, v)
    frame, child = names
    cov = None
    if covs:
        C = np.asarray(covs, dtype=np.float64).reshape(-1, 36)
        unknown = (C[:, 0] == -1.0) | ~(C != 0).any(axis=1)
        if unknown.any() and not unknown.all():
            k = int(np.flatnonzero(unknown != unknown[0])[0])
            state = "unknown (first entry −1, or all zeros)" if unknown[k] else "known"
            raise FileFormatError(
                p, f"{where} message {k}: covariance {state}, unlike message 0 before it"
            )
        if not unknown.any():
            cov = C.reshape(-1, 6, 6)
    try:
        return Trajectory.from_quaternions(
            v[:, :3], v[:, 3:], t, cov, frame=frame, child=child, source=f"{p}:{topic}"
        )
    except RelmapError as exc:
        raise FileFormatError(p, f"{where}: {_message_words(exc)}") from None


def _message_words(exc: Exception) -> str:
    import re

    return re.sub(r"^(pose|stamp|quaternion)\s*\[?(\d+)\]?", r"message \2", str(exc))


def _check_messages(p: Path, where: str, t: FloatArray, v: FloatArray) -> None:
    if not len(t):
        raise FileFormatError(p, f"{where} has no messages")
    bad = ~np.isfinite(v).all(axis=1)
    if bad.any():
        raise FileFormatError(
            p,
            f"{where} message {int(np.flatnonzero(bad)[0])}: pose is not finite (NaN or infinity)",
        )
    norm = np.linalg.norm(v[:, 3:], axis=1)
    bad = ~(np.abs(norm - 1) <= so3.ROTATION_ATOL)
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        what = "zero quaternion" if norm[k] == 0 else f"quaternion of norm {norm[k]:.6g}, not 1"
        raise FileFormatError(p, f"{where} message {k}: {what}")
    back = np.flatnonzero(np.diff(t) < 0)
    if back.size:
        k = int(back[0]) + 1
        raise FileFormatError(
            p,
            f"{where} message {k}: stamp {float(t[k])!r} s comes before {float(t[k - 1])!r} s "
            "(stamps must not decrease)",
        )


# ------------------------------------------------------------------------------------- TF
class _Edge:
    """The transforms of one parent → child link: stamps (k,) and poses (k, 4, 4)."""

    def __init__(self, static: bool) -> None:
        self.static = static
        self.t: list[float] = []
        self.v: list[tuple[float, ...]] = []

    def poses(self) -> tuple[FloatArray, FloatArray]:
        t = np.asarray(self.t)
        v = np.asarray(self.v).reshape(-1, 7)
        order = np.argsort(t, kind="stable")
        t, v = t[order], v[order]
        last = np.append(np.diff(t) > 0, True)  # of equal stamps, the last one received
        t, v = t[last], v[last]
        M = se3.from_parts(v[:, :3], so3.from_quaternion(v[:, 3:]))
        return t, M


def _read_tf(p: Path, reader: Any, spec: str, topics: dict[str, tuple[str, int]]) -> Trajectory:
    frames = spec.split(":", 1)[1]
    if "." not in frames:
        raise ParameterError(f"a TF chain is named /tf:PARENT.CHILD; got {spec!r}")
    parent, child = frames.split(".", 1)
    tf_topics = tuple(t for t in ("/tf", "/tf_static") if topics.get(t, ("", 0))[0] == _TF_TYPE)
    if not tf_topics:
        raise FileFormatError(p, f"no /tf or /tf_static topic; the bag has {_listing(topics)}")
    edges: dict[tuple[str, str], _Edge] = {}
    for conn, msg in _messages(reader, tf_topics):
        for tr in msg.transforms:
            key = (tr.header.frame_id, tr.child_frame_id)
            e = edges.setdefault(key, _Edge(conn.topic == "/tf_static"))
            a, q = tr.transform.translation, tr.transform.rotation
            e.t.append(_stamp(tr.header))
            e.v.append((a.x, a.y, a.z, q.x, q.y, q.z, q.w))
    up = {c: par for (par, c) in edges}
    known = set(up) | set(up.values())
    for f in (parent, child):
        if f not in known:
            raise FileFormatError(
                p, f"frame {f!r} is not in the TF tree; its frames are {', '.join(sorted(known))}"
            )

    def ancestors(f: str) -> list[str]:
        out = [f]
        while out[-1] in up and len(out) <= len(up):
            out.append(up[out[-1]])
        return out

    a_p, a_c = ancestors(parent), ancestors(child)
    common = next((f for f in a_c if f in a_p), None)
    if common is None:
        raise FileFormatError(p, f"frames {parent!r} and {child!r} are in different TF trees")
    down = [(up[f], f) for f in a_c[: a_c.index(common)]]  # child → common
    rise = [(up[f], f) for f in a_p[: a_p.index(common)]]  # parent → common
    chain = [edges[k] for k in down + rise]
    dynamic = [e for e in chain if not e.static]
    if not dynamic:
        raise FileFormatError(p, f"{parent} → {child} is static (only /tf_static): no trajectory")
    tables = {id(e): e.poses() for e in chain}
    lo = max(tables[id(e)][0][0] for e in dynamic)
    hi = min(tables[id(e)][0][-1] for e in dynamic)
    base = max(dynamic, key=lambda e: len(tables[id(e)][0]))
    t = tables[id(base)][0]
    t = t[(t >= lo) & (t <= hi)]
    if not len(t):
        raise FileFormatError(
            p, f"the dynamic transforms of {parent} → {child} never overlap in time"
        )

    def at(e: _Edge) -> FloatArray:
        te, M = tables[id(e)]
        if e.static:
            return np.broadcast_to(M[-1], (len(t), 4, 4))
        return SE3.at_times(te, M, t)

    c_in_common = np.broadcast_to(np.eye(4), (len(t), 4, 4))
    for key in reversed(down):  # common → ... → child
        c_in_common = c_in_common @ at(edges[key])
    p_in_common = np.broadcast_to(np.eye(4), (len(t), 4, 4))
    for key in reversed(rise):
        p_in_common = p_in_common @ at(edges[key])
    M = se3.inverse(p_in_common) @ c_in_common
    return Trajectory.from_matrices(M, t, frame=parent, child=child, source=f"{p}:{spec}")


# ----------------------------------------------------------------------------------- the format
#: The first bytes of a ROS 1 bag, an MCAP file and a SQLite database (ROS 2 ``.db3``).
_MAGIC = (b"#ROSBAG V2.0", b"\x89MCAP", b"SQLite format 3\x00")


def _is_bag(head: formats.Head) -> bool:
    """A bag file by its magic number, or a ROS 2 bag folder (it holds ``metadata.yaml``)."""
    if head.folder:
        return (head.path / "metadata.yaml").is_file()
    return head.magic.startswith(_MAGIC)


def _read(source: Input, topic: str | None = None) -> Trajectory:
    """:func:`read_bag` of a bag file or folder: from its path (rosbags seeks in it)."""
    return read_bag(source.path, topic)


formats.register(
    formats.Format(
        "bag",
        formats.Kind.TRAJECTORY,
        "ROS 1 .bag, ROS 2 .db3 or .mcap, or a ROS 2 bag folder with metadata.yaml",
        _is_bag,
        _read,
        options=("topic",),
    )
)
