"""Trajectory files: TUM, KITTI (+ times file), EuRoC CSV, relmap's own format with covariance,
g2o/TORO vertices, and ROS bags (:mod:`relmap.io.rosbag`) — read, recognised by their content,
and written atomically.

Formats (one pose a line; lines starting with ``#`` and blank lines are skipped):

- ``tum``: ``t x y z qx qy qz qw`` (seconds; quaternion scalar **last**).
- ``kitti``: the 12 numbers of the row-major 3×4 ``[R t]``; no stamps, unless a times file
  (one time in seconds a line) is given.
- ``euroc``: the EuRoC ground-truth CSV ``t[ns], x, y, z, qw, qx, qy, qz, ...`` (time in
  **nanoseconds**, quaternion scalar **first**; further columns ignored).
- ``relmap``: relmap's own, for estimates with covariance. 3-D: ``t x y z qx qy qz qw`` followed
  by the 21 entries of the upper triangle, row by row, of the 6×6 covariance on
  ``(δx, δy, δz, δφx, δφy, δφz)`` — translation in the parent frame, rotation perturbation on
  the left (``R' = Exp(δφ) R``), relmap's chart (29 columns). Planar: ``t x y θ`` followed by
  the 6 entries ``xx xy xθ yy yθ θθ`` of the covariance on ``(x, y, θ)`` in the parent frame
  (10 columns), or ``t x y θ`` alone (4 columns, e.g. MRCLAM ground truth). A header line
  ``# relmap trajectory ... frame=F child=C`` is written and read back for the frame names.
  Without covariance the 3-D form is exactly TUM.
- ``g2o``/``toro``: the vertices of a pose graph (``VERTEX_SE2``, ``VERTEX_SE3:QUAT``,
  ``VERTEX2``) via :func:`relmap.io.read_graph`, in file order, without stamps.
- ROS bags (``.bag``, ``.db3`` and ``.mcap``, or a ROS 2 bag folder): :mod:`relmap.io.rosbag`.

Bad input raises :class:`relmap.errors.FileFormatError` naming the file and line: wrong column
counts (a file mixing planar and 3-D rows included), numbers that are not numbers or not
finite, zero or non-unit quaternions, rotation matrices that are not rotations, stamps that
decrease, covariances that are not symmetric positive semi-definite.
"""

from __future__ import annotations

import io
import os
import re
from pathlib import Path

import numpy as np

from relmap.errors import FileFormatError, ParameterError, RelmapError
from relmap.io.atomic import write_text_atomic
from relmap.io.textfile import read_text
from relmap.lie import so3
from relmap.typing import FloatArray, IntArray
from relmap.uncertain.trajectory import Trajectory, check_increasing, check_rotations

__all__ = ["FORMATS", "read_trajectory", "recognise_trajectory", "write_trajectory"]

FORMATS: tuple[str, ...] = ("tum", "kitti", "euroc", "relmap", "g2o", "bag")
_TRI3 = np.triu_indices(3)
_TRI6 = np.triu_indices(6)
_HEADER = re.compile(r"#\s*relmap trajectory\b(.*)")


# ------------------------------------------------------------------------------- tables
def _rows(text: str) -> tuple[list[str], IntArray]:
    """The data lines (not blank, not ``#``) and their 1-based line numbers."""
    lines = text.splitlines()
    keep = [k for k, s in enumerate(lines) if s.strip() and not s.lstrip().startswith("#")]
    return [lines[k] for k in keep], np.asarray(keep, dtype=np.intp) + 1


def _table(path: Path, rows: list[str], numbers: IntArray, sep: str | None) -> FloatArray:
    """``(n, k)`` floats of the data lines, every line with the same k; errors name the line."""
    tokens = [r.split(sep) if sep else r.split() for r in rows]
    widths = np.fromiter((len(t) for t in tokens), dtype=np.intp, count=len(tokens))
    if not len(widths):
        raise FileFormatError(path, "no poses in the file")
    wrong = np.flatnonzero(widths != widths[0])
    if wrong.size:
        k = int(wrong[0])
        raise FileFormatError(
            path,
            f"{widths[k]} columns where the lines above have {widths[0]} "
            "(a file mixes formats, e.g. planar and 3-D poses)",
            line=int(numbers[k]),
        )
    flat = [s.strip() for t in tokens for s in t]
    try:
        values = np.array(flat, dtype=np.float64).reshape(len(rows), int(widths[0]))
    except ValueError:
        for k, t in enumerate(tokens):
            for s in t:
                try:
                    float(s)
                except ValueError:
                    raise FileFormatError(
                        path, f"{s.strip()!r} is not a number", line=int(numbers[k])
                    ) from None
        raise
    bad = ~np.isfinite(values).all(axis=1)
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        raise FileFormatError(path, "a value is not finite (NaN or infinity)", line=int(numbers[k]))
    return values


def _at_line(path: Path, numbers: IntArray, exc: RelmapError) -> FileFormatError:
    """A validation error of pose/stamp k as an error at k's line."""
    m = re.match(
        r"((?:pose|stamp|quaternion)\s+(\d+):?\s*|[\w ]*?\[(\d+)(?:, \d+)*\]\s*)", str(exc)
    )
    k = None if m is None else int(m.group(2) or m.group(3))
    text = str(exc)[m.end() :] if m and m.group(2) else str(exc)
    line = int(numbers[k]) if k is not None and k < len(numbers) else None
    return FileFormatError(path, text, line=line)


def _quaternions(path: Path, q: FloatArray, numbers: IntArray) -> FloatArray:
    norm = np.linalg.norm(q, axis=1)
    bad = ~(np.abs(norm - 1.0) <= so3.ROTATION_ATOL)
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        what = "zero" if norm[k] == 0 else f"not a unit quaternion (norm {norm[k]:.6g})"
        raise FileFormatError(path, f"quaternion {what}", line=int(numbers[k]))
    return q


def _stamps(path: Path, t: FloatArray, numbers: IntArray) -> FloatArray:
    try:
        check_increasing(t)
    except RelmapError as exc:
        k = int(re.search(r"stamp (\d+)", str(exc)).group(1))  # type: ignore[union-attr]
        raise FileFormatError(
            path,
            f"time stamps must not decrease: {float(t[k])!r} s follows {float(t[k - 1])!r} s",
            line=int(numbers[k]),
        ) from None
    return t


def _unpack(values: FloatArray, tri: tuple[IntArray, IntArray], d: int) -> FloatArray:
    C = np.zeros((len(values), d, d))
    C[:, tri[0], tri[1]] = values
    C[:, tri[1], tri[0]] = values
    return C


def _build(path: Path, numbers: IntArray, make, **names: str) -> Trajectory:  # type: ignore[no-untyped-def]
    try:
        return make(source=str(path), **names)
    except FileFormatError:
        raise
    except RelmapError as exc:
        raise _at_line(path, numbers, exc) from None


def _names(text: str) -> dict[str, str]:
    for line in text.splitlines()[:5]:
        m = _HEADER.match(line.strip())
        if m:
            return dict(re.findall(r"\b(frame|child)=(\S+)", m.group(1)))
    return {}


# ------------------------------------------------------------------------------- readers
def _read_columns(path: Path, text: str, values: FloatArray, numbers: IntArray) -> Trajectory:
    """TUM (8), KITTI (12), relmap 3-D (29), planar (4 or 10): by the number of columns."""
    k = values.shape[1]
    names = _names(text)
    if k in (10, 29):
        unknown = np.flatnonzero(values[:, 8 if k == 29 else 4] == -1.0)
        if unknown.size:
            raise FileFormatError(
                path,
                "covariance marked unknown (first entry −1): write the pose without one",
                line=int(numbers[unknown[0]]),
            )
    if k in (8, 29):
        t = _stamps(path, values[:, 0], numbers)
        q = _quaternions(path, values[:, 4:8], numbers)
        cov = _unpack(values[:, 8:], _TRI6, 6) if k == 29 else None
        return _build(
            path,
            numbers,
            lambda **kw: Trajectory.from_quaternions(values[:, 1:4], q, t, cov, **kw),
            **names,
        )
    if k == 12:
        M = np.zeros((len(values), 4, 4))
        M[:, :3, :] = values.reshape(-1, 3, 4)
        M[:, 3, 3] = 1.0
        try:
            check_rotations(M[:, :3, :3])
        except RelmapError as exc:
            raise _at_line(path, numbers, exc) from None
        return _build(
            path, numbers, lambda **kw: Trajectory.from_matrices(M, None, None, **kw), **names
        )
    if k in (4, 10):
        t = _stamps(path, values[:, 0], numbers)
        cov = _unpack(values[:, 4:], _TRI3, 3) if k == 10 else None
        return _build(
            path, numbers, lambda **kw: Trajectory.planar(values[:, 1:4], t, cov, **kw), **names
        )
    raise FileFormatError(
        path,
        f"{k} columns: not a trajectory format relmap knows (TUM: 8, KITTI: 12, relmap: 29, "
        "planar: 4 or 10)",
        line=int(numbers[0]),
    )


def _read_euroc(path: Path, rows: list[str], numbers: IntArray) -> Trajectory:
    values = _table(path, rows, numbers, ",")
    if values.shape[1] < 8:
        raise FileFormatError(
            path, f"EuRoC CSV needs at least 8 columns; got {values.shape[1]}", line=int(numbers[0])
        )
    t = _stamps(path, values[:, 0] / 1e9, numbers)  # nanoseconds, as evo converts them
    q = _quaternions(path, values[:, [5, 6, 7, 4]], numbers)  # (w, x, y, z) → (x, y, z, w)
    return _build(
        path, numbers, lambda **kw: Trajectory.from_quaternions(values[:, 1:4], q, t, **kw)
    )


def _read_graph_vertices(path: Path) -> Trajectory:
    from relmap.io.posegraph import read_graph

    g = read_graph(path)
    if g.poses.ndim == 2:
        return Trajectory.planar(g.poses, source=str(path))
    return Trajectory.from_matrices(g.poses, source=str(path))


def _read_times(path: Path) -> FloatArray:
    rows, numbers = _rows(read_text(path))
    values = _table(path, rows, numbers, None)
    if values.shape[1] != 1:
        raise FileFormatError(
            path,
            f"a times file has one time a line; got {values.shape[1]} columns",
            line=int(numbers[0]),
        )
    return _stamps(path, values[:, 0], numbers)


def recognise_trajectory(path: str | os.PathLike[str]) -> str:
    """The format of ``path`` from its content: one of :data:`FORMATS` (``"relmap"`` covers
    relmap's own and the planar forms; ``"tum"`` any 8-column table)."""
    p = Path(path)
    if p.is_dir():
        if (p / "metadata.yaml").is_file():
            return "bag"
        raise FileFormatError(p, "a folder that is not a ROS 2 bag (no metadata.yaml)")
    try:
        with open(p, "rb") as fh:
            head = fh.read(4096)
    except FileNotFoundError:
        raise FileFormatError(p, "no such file") from None
    except OSError as exc:
        raise FileFormatError(p, f"cannot read: {exc.strerror}") from None
    if head.startswith((b"#ROSBAG V2.0", b"\x89MCAP", b"SQLite format 3\x00")):
        return "bag"
    text = head.removeprefix(b"\xef\xbb\xbf").decode("utf-8", errors="replace")
    first = next(
        (s.strip() for s in text.splitlines() if s.strip() and not s.lstrip().startswith("#")), ""
    )
    if re.match(r"(VERTEX|EDGE|FIX)\S*\s", first + " "):
        return "g2o"
    if "," in first:
        return "euroc"
    width = len(first.split())
    return {8: "tum", 12: "kitti"}.get(width, "relmap")


def read_trajectory(
    path: str | os.PathLike[str],
    *,
    times: str | os.PathLike[str] | None = None,
    topic: str | None = None,
) -> Trajectory:
    """Read a trajectory, its format recognised from the content (module docstring).

    ``times``: a KITTI times file (one time a line, as many as poses). ``topic``: for a ROS bag,
    the topic (``PoseStamped``, ``PoseWithCovarianceStamped``, ``Odometry``) or a TF chain
    ``/tf:PARENT.CHILD`` (:func:`relmap.io.rosbag.read_bag`).
    """
    p = Path(path)
    fmt = recognise_trajectory(p)
    if fmt == "bag":
        from relmap.io.rosbag import read_bag

        return read_bag(p, topic)
    if topic is not None:
        raise ParameterError(f"--topic is for ROS bags; {p} is a {fmt} file")
    if fmt == "g2o":
        traj = _read_graph_vertices(p)
    else:
        text = read_text(p)
        rows, numbers = _rows(text)
        if fmt == "euroc":
            traj = _read_euroc(p, rows, numbers)
        else:
            traj = _read_columns(p, text, _table(p, rows, numbers, None), numbers)
    if times is not None:
        if traj.stamps is not None:
            raise ParameterError(f"{p} has time stamps of its own; a times file is for KITTI poses")
        t = _read_times(Path(times))
        if len(t) != len(traj):
            raise FileFormatError(times, f"{len(t)} times for the {len(traj)} poses of {p}")
        traj = Trajectory._checked(
            traj.poses,
            t,
            traj.has_cov,
            {"frame": traj.frame, "child": traj.child, "source": traj.source},
        )
    return traj


# ------------------------------------------------------------------------------- writers
def _numbers(a: FloatArray) -> str:
    buf = io.StringIO()
    np.savetxt(buf, a, fmt="%.17g")
    return buf.getvalue()


def write_trajectory(
    path: str | os.PathLike[str], traj: Trajectory, format: str | None = None
) -> str:
    """Write ``traj`` to ``path`` atomically; returns the format written.

    ``format``: ``tum``, ``kitti``, ``euroc`` or ``relmap``; by default ``euroc`` for a ``.csv``
    name, else ``relmap`` when the trajectory is planar or carries a covariance (3-D without
    covariance: ``relmap`` is TUM). Numbers are written with 17 significant digits (they read
    back exactly). TUM, KITTI and EuRoC drop the covariance (and KITTI the stamps); planar
    trajectories are written as 3-D poses in those formats.
    """
    target = Path(path)
    if not target.resolve().parent.is_dir():
        raise ParameterError(f"cannot write {target}: its folder does not exist")
    fmt = format or ("euroc" if target.suffix.lower() == ".csv" else "relmap")
    if fmt not in ("tum", "kitti", "euroc", "relmap"):
        raise ParameterError(
            f"trajectories are written as tum, kitti, euroc or relmap; got {fmt!r}"
        )
    if fmt != "kitti" and traj.stamps is None:
        raise ParameterError(
            f"{fmt} needs time stamps and {traj.source or 'the trajectory'} has none"
        )
    M = traj.matrices
    t = traj.stamps
    names = f" frame={traj.frame}" * bool(traj.frame) + f" child={traj.child}" * bool(traj.child)
    if fmt == "kitti":
        text = _numbers(M[:, :3, :].reshape(-1, 12))
    elif fmt == "euroc":
        q = so3.to_quaternion(M[:, :3, :3])
        stamps_ns = np.round(t * 1e9).astype(np.int64)
        body = _numbers(np.column_stack([M[:, :3, 3], q[:, [3, 0, 1, 2]]])).splitlines()
        text = "#timestamp [ns],p_x [m],p_y [m],p_z [m],q_w [],q_x [],q_y [],q_z []\n" + "".join(
            f"{s},{b.replace(' ', ',')}\n" for s, b in zip(stamps_ns.tolist(), body, strict=True)
        )
    elif traj.is_planar and fmt == "relmap":
        cols = [t[:, None], traj.poses.mean]
        what = "t x y θ"
        if traj.has_cov:
            cols.append(traj.poses.cov[:, _TRI3[0], _TRI3[1]])
            what += " + covariance xx xy xθ yy yθ θθ on (x, y, θ) in the parent frame"
        text = f"# relmap trajectory planar: {what}{names}\n" + _numbers(np.column_stack(cols))
    else:
        q = so3.to_quaternion(M[:, :3, :3])
        cols = [t[:, None], M[:, :3, 3], q]
        what = "t x y z qx qy qz qw"
        if fmt == "relmap" and traj.has_cov:
            cols.append(traj.poses.cov[:, _TRI6[0], _TRI6[1]])
            what += (
                " + covariance upper triangle row by row on (δx δy δz δφx δφy δφz), translation "
                "in the parent frame, rotation on the left"
            )
        head = f"# relmap trajectory 3d: {what}{names}\n" if fmt == "relmap" else ""
        text = head + _numbers(np.column_stack(cols))
    write_text_atomic(target, text)
    return fmt
