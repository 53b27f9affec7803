"""Trajectory files: TUM, KITTI (+ times file), EuRoC CSV, relmap's own format with covariance,
g2o/TORO vertices, and ROS bags (:mod:`relmap.io.rosbag`) — read, recognised by their content,
and written atomically. The four text formats are registered here (:mod:`relmap.io.formats`,
recognised by the first record: commas, or how many numbers it holds), and
:func:`read_trajectory`, :func:`recognise_trajectory` and :func:`write_trajectory` go through
the registry for every format.

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
  ``VERTEX2``, ``VERTEX3``) as :func:`relmap.io.read_graph` reads them, in file order, without
  stamps.
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
from relmap.io import formats
from relmap.io._parsing import is_number
from relmap.io.atomic import write_text_atomic
from relmap.io.posegraph import PoseGraph
from relmap.io.textfile import Input, read_input, read_text
from relmap.lie import so3
from relmap.typing import FloatArray, IntArray
from relmap.uncertain.trajectory import Trajectory, check_increasing, check_rotations

__all__ = ["read_trajectory", "recognise_trajectory", "write_trajectory"]

_TRI3 = np.triu_indices(3)
_TRI6 = np.triu_indices(6)
_HEADER = re.compile(r"#\s*relmap trajectory\b(.*)")


# ------------------------------------------------------------------------------- tables
def _rows(text: str) -> tuple[list[str], IntArray]:
    """The data lines (not blank, not ``#``) and their 1-based line numbers (a line ends at LF
    only: :mod:`relmap.io.textfile`)."""
    lines = text.split("\n")
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
    for line in text.split("\n", 5)[:5]:
        m = _HEADER.match(line.strip())
        if m:
            return dict(re.findall(r"\b(frame|child)=(\S+)", m.group(1)))
    return {}


# ------------------------------------------------------------------------------- readers
def _numbers(source: Input, sep: str | None = None) -> tuple[Path, FloatArray, IntArray]:
    """The input's table of numbers (:func:`_table`) and each row's line."""
    assert source.text is not None  # recognised from a text record
    rows, numbers = _rows(source.text)
    return source.path, _table(source.path, rows, numbers, sep), numbers


def _with_quaternions(
    source: Input, path: Path, values: FloatArray, numbers: IntArray, cov: FloatArray | None
) -> Trajectory:
    """``t x y z qx qy qz qw`` rows (TUM; relmap 3-D with the covariance ``cov``)."""
    t = _stamps(path, values[:, 0], numbers)
    q = _quaternions(path, values[:, 4:8], numbers)
    return _build(
        path,
        numbers,
        lambda **kw: Trajectory.from_quaternions(values[:, 1:4], q, t, cov, **kw),
        **_names(source.text or ""),
    )


def _read_tum(source: Input) -> Trajectory:
    """TUM: ``t x y z qx qy qz qw`` (relmap 3-D without covariance is the same)."""
    return _with_quaternions(source, *_numbers(source), None)


def _read_relmap(source: Input) -> Trajectory:
    """relmap's own: 3-D with covariance (29 columns), planar with (10) or without it (4)."""
    path, values, numbers = _numbers(source)
    k = values.shape[1]
    if k in (10, 29):
        unknown = np.flatnonzero(values[:, 8 if k == 29 else 4] == -1.0)
        if unknown.size:
            raise FileFormatError(
                path,
                "covariance marked unknown (first entry −1): write the pose without one",
                line=int(numbers[unknown[0]]),
            )
    if k == 29:
        return _with_quaternions(source, path, values, numbers, _unpack(values[:, 8:], _TRI6, 6))
    t = _stamps(path, values[:, 0], numbers)
    cov = _unpack(values[:, 4:], _TRI3, 3) if k == 10 else None
    return _build(
        path,
        numbers,
        lambda **kw: Trajectory.planar(values[:, 1:4], t, cov, **kw),
        **_names(source.text or ""),
    )


def _read_kitti(source: Input) -> Trajectory:
    """KITTI: the 12 numbers of the row-major 3×4 ``[R t]`` a line, no stamps."""
    path, values, numbers = _numbers(source)
    M = np.zeros((len(values), 4, 4))
    M[:, :3, :] = values.reshape(-1, 3, 4)
    M[:, 3, 3] = 1.0
    try:
        check_rotations(M[:, :3, :3])
    except RelmapError as exc:
        raise _at_line(path, numbers, exc) from None
    return _build(
        path,
        numbers,
        lambda **kw: Trajectory.from_matrices(M, None, None, **kw),
        **_names(source.text or ""),
    )


def _read_euroc(source: Input) -> Trajectory:
    """EuRoC's ground-truth CSV: ``t[ns], x, y, z, qw, qx, qy, qz, ...``."""
    path, values, numbers = _numbers(source, ",")
    if values.shape[1] < 8:
        raise FileFormatError(
            path, f"EuRoC CSV needs at least 8 columns; got {values.shape[1]}", line=int(numbers[0])
        )
    t = _stamps(path, values[:, 0] / 1e9, numbers)  # nanoseconds, as evo converts them
    q = _quaternions(path, values[:, [5, 6, 7, 4]], numbers)  # (w, x, y, z) → (x, y, z, w)
    return _build(
        path, numbers, lambda **kw: Trajectory.from_quaternions(values[:, 1:4], q, t, **kw)
    )


def _vertices(path: Path, graph: PoseGraph) -> Trajectory:
    """The vertices of a pose graph, in file order, without stamps."""
    if graph.poses.ndim == 2:
        return Trajectory.planar(graph.poses, source=str(path))
    return Trajectory.from_matrices(graph.poses, source=str(path))


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


#: What a trajectory is read from: a trajectory format, or the vertices of a pose graph.
_KINDS = (formats.Kind.TRAJECTORY, formats.Kind.GRAPH)


def recognise_trajectory(path: str | os.PathLike[str] | Input) -> str:
    """The name of the format of ``path`` (:mod:`relmap.io.formats`), recognised from its
    content: ``tum``, ``kitti``, ``euroc``, ``relmap``, ``bag`` or a pose graph's (``g2o``,
    ``toro``). A path is read (:func:`relmap.io.textfile.read_input`; a pipe cannot be read
    again: give :func:`read_trajectory` the :class:`~relmap.io.textfile.Input` read here)."""
    return formats.format_of(read_input(path), _KINDS).name


def read_trajectory(
    path: str | os.PathLike[str] | Input,
    *,
    times: str | os.PathLike[str] | None = None,
    topic: str | None = None,
) -> Trajectory:
    """Read a trajectory, its format recognised from the content (module docstring); the input
    is read once (:func:`relmap.io.textfile.read_input`: a pipe, gzip, a BOM and CRLF are
    accepted).

    ``times``: a KITTI times file (one time a line, as many as poses). ``topic``: for a ROS bag,
    the topic (``PoseStamped``, ``PoseWithCovarianceStamped``, ``Odometry``) or a TF chain
    ``/tf:PARENT.CHILD`` (:func:`relmap.io.rosbag.read_bag`).
    """
    source = read_input(path)
    p = source.path
    fmt, traj = formats.read(source, _KINDS, **({} if topic is None else {"topic": topic}))
    if fmt.holds is formats.Kind.GRAPH:
        traj = _vertices(p, traj)
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
def _text(a: FloatArray) -> str:
    buf = io.StringIO()
    np.savetxt(buf, a, fmt="%.17g")
    return buf.getvalue()


def _stamped(traj: Trajectory, fmt: str) -> FloatArray:
    """The stamps a format needs, or the error that ``traj`` has none."""
    if traj.stamps is None:
        raise ParameterError(
            f"{fmt} needs time stamps and {traj.source or 'the trajectory'} has none"
        )
    return traj.stamps


def _frame_names(traj: Trajectory) -> str:
    return f" frame={traj.frame}" * bool(traj.frame) + f" child={traj.child}" * bool(traj.child)


def _quaternion_columns(traj: Trajectory, fmt: str) -> list[FloatArray]:
    """``t``, ``x y z``, ``qx qy qz qw`` of every pose."""
    M = traj.matrices
    return [_stamped(traj, fmt)[:, None], M[:, :3, 3], so3.to_quaternion(M[:, :3, :3])]


def _write_tum(path: Path, traj: Trajectory) -> None:
    write_text_atomic(path, _text(np.column_stack(_quaternion_columns(traj, "tum"))))


def _write_kitti(path: Path, traj: Trajectory) -> None:
    write_text_atomic(path, _text(traj.matrices[:, :3, :].reshape(-1, 12)))


def _write_euroc(path: Path, traj: Trajectory) -> None:
    M = traj.matrices
    q = so3.to_quaternion(M[:, :3, :3])
    stamps_ns = np.round(_stamped(traj, "euroc") * 1e9).astype(np.int64)
    body = _text(np.column_stack([M[:, :3, 3], q[:, [3, 0, 1, 2]]])).splitlines()
    text = "#timestamp [ns],p_x [m],p_y [m],p_z [m],q_w [],q_x [],q_y [],q_z []\n" + "".join(
        f"{s},{b.replace(' ', ',')}\n" for s, b in zip(stamps_ns.tolist(), body, strict=True)
    )
    write_text_atomic(path, text)


def _write_relmap(path: Path, traj: Trajectory) -> None:
    if traj.is_planar:
        cols = [_stamped(traj, "relmap")[:, None], traj.poses.mean]
        what = "planar: t x y θ"
        if traj.has_cov:
            cols.append(traj.poses.cov[:, _TRI3[0], _TRI3[1]])
            what += " + covariance xx xy xθ yy yθ θθ on (x, y, θ) in the parent frame"
    else:
        cols = _quaternion_columns(traj, "relmap")
        what = "3d: t x y z qx qy qz qw"
        if traj.has_cov:
            cols.append(traj.poses.cov[:, _TRI6[0], _TRI6[1]])
            what += (
                " + covariance upper triangle row by row on (δx δy δz δφx δφy δφz), translation "
                "in the parent frame, rotation on the left"
            )
    header = f"# relmap trajectory {what}{_frame_names(traj)}\n"
    write_text_atomic(path, header + _text(np.column_stack(cols)))


def write_trajectory(
    path: str | os.PathLike[str], traj: Trajectory, format: str | None = None
) -> str:
    """Write ``traj`` to ``path`` atomically; returns the format written.

    ``format``: a trajectory format relmap writes (``tum``, ``kitti``, ``euroc`` or ``relmap``:
    :func:`relmap.io.formats.formats`); by default ``euroc`` for a ``.csv`` name, else
    ``relmap`` (3-D without covariance: ``relmap`` is TUM with a header line). Numbers are
    written with 17 significant digits (they read back exactly). TUM, KITTI and EuRoC drop the
    covariance (and KITTI the stamps); planar trajectories are written as 3-D poses in those
    formats.
    """
    target = Path(path)
    if not target.resolve().parent.is_dir():
        raise ParameterError(f"cannot write {target}: its folder does not exist")
    name = format or ("euroc" if target.suffix.lower() == ".csv" else "relmap")
    formats.writer(name, formats.Kind.TRAJECTORY)(target, traj)
    return name


# ------------------------------------------------------------------------------- the formats
def _columns(head: formats.Head) -> int:
    """How many numbers the first record holds when it is a white-space separated row of
    numbers (its first field a decimal number), else 0."""
    fields = head.record.split()
    return len(fields) if fields and "," not in head.record and is_number(fields[0]) else 0


def _is_tum(head: formats.Head) -> bool:
    return _columns(head) == 8


def _is_kitti(head: formats.Head) -> bool:
    return _columns(head) == 12


def _is_relmap(head: formats.Head) -> bool:
    return _columns(head) in (4, 10, 29)


def _is_euroc(head: formats.Head) -> bool:
    """Comma-separated, its first field a number (the time in nanoseconds)."""
    return "," in head.record and is_number(head.record.split(",", 1)[0].strip())


_TUM = "t x y z qx qy qz qw"
_TRAJECTORY = formats.Kind.TRAJECTORY
formats.register(formats.Format("tum", _TRAJECTORY, _TUM, _is_tum, _read_tum, _write_tum))
formats.register(
    formats.Format(
        "kitti", _TRAJECTORY, "3×4 [R t], 12 numbers", _is_kitti, _read_kitti, _write_kitti
    )
)
formats.register(
    formats.Format(
        "euroc", _TRAJECTORY, "CSV t[ns],x,y,z,qw,qx,qy,qz", _is_euroc, _read_euroc, _write_euroc
    )
)
formats.register(
    formats.Format(
        "relmap",
        _TRAJECTORY,
        "t x y θ [+ 6 cov.], or TUM + 21 cov.",
        _is_relmap,
        _read_relmap,
        _write_relmap,
    )
)
