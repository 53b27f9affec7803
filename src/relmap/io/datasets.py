"""Landmark-localization datasets: UTIAS MRCLAM and CMU Plaza (range-only) logs.

A folder is recognised by the files it holds, never by its name (:func:`recognise`).

**UTIAS MRCLAM** (K. Leung 2009; :func:`read_mrclam`). Plain-text tables, white-space separated,
each starting with ``#`` header lines (any number); times are Unix seconds, metres, radians::

    Barcodes.dat               subject barcode            subjects 1-5 robots, 6-20 landmarks
    Landmark_Groundtruth.dat   subject x y σx σy          surveyed landmark positions
    RobotN_Odometry.dat        t v ω                      forward and angular velocity (m/s, rad/s)
    RobotN_Groundtruth.dat     t x y θ                    Vicon ground truth (~60 Hz)
    RobotN_Measurement.dat     t barcode range bearing    the 2nd column is a BARCODE

for N = 1..5; robot N is subject N. A measurement's barcode is mapped through ``Barcodes.dat`` to
a subject; barcodes of robots, and barcodes in no table, are not landmarks (subject ``-1``).
Repeated timestamps are allowed (several landmarks seen at one instant; the odometry files have
a few repeated times, some with different velocities), but a time that goes backwards is an
error (the real files have none).

**CMU Plaza** (J. Djugash; :func:`read_plaza`), files ``P_DR.txt``, ``P_TD.txt``, ``P_.mat``
with one common prefix ``P`` (``Plaza2``)::

    P_DR.txt   t Δdistance Δheading    dead-reckoning steps (~0.1 s); t is the step's END time
    P_TD.txt   t sender beacon range   range-only measurements to beacons
    P_.mat     GT, DRp: (t, x, y, θ)   ground truth and the dataset's own dead-reckoned path
               TL: (id, x, y)          beacon positions

**Plaza heading convention.** The ``θ`` column of ``GT`` points opposite to the direction of
travel (x and y are fine, and ``DRp``'s heading is the direction of travel: its first pose is
GT's first pose with θ + π exactly). :attr:`Plaza.truth` therefore holds
``wrap(θ_GT + π)``; :attr:`Plaza.truth_raw_heading` keeps the file's column. ``DR``'s
Δdistance is never negative, so the short stretches where ground truth shows the robot backing
up (the last seconds of Plaza 2) are dead-reckoned forwards.

Every heading is wrapped to [-π, π) on reading. Malformed input (a wrong number of columns, a
non-number, a non-finite value, a non-integer id, a negative range, a time going backwards)
raises :class:`relmap.errors.FileFormatError` naming the file and the 1-based line.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import NamedTuple

import numpy as np

from relmap.errors import FileFormatError, NonFiniteError, ParameterError
from relmap.io._parsing import fail_at, frozen, strict_float
from relmap.io.textfile import read_text
from relmap.lie import se2
from relmap.lie.group import SE2
from relmap.typing import ArrayLike, FloatArray, IntArray, Option

__all__ = [
    "DatasetKind",
    "Mrclam",
    "Plaza",
    "RobotLog",
    "read_mrclam",
    "read_plaza",
    "recognise",
]


class DatasetKind(Option):
    """The datasets :func:`recognise` tells apart: UTIAS MRCLAM (:func:`read_mrclam`) and CMU
    Plaza (:func:`read_plaza`)."""

    MRCLAM = "mrclam"
    PLAZA = "plaza"


#: Number of robots (and their subject numbers 1..N) in an MRCLAM folder.
MRCLAM_ROBOTS = 5
_MRCLAM_KINDS = ("Odometry", "Groundtruth", "Measurement")
_MRCLAM_FILES = (
    "Barcodes.dat",
    "Landmark_Groundtruth.dat",
    *(f"Robot{n}_{kind}.dat" for n in range(1, MRCLAM_ROBOTS + 1) for kind in _MRCLAM_KINDS),
)
# Integer columns are read as floats and must hold exact integers below this magnitude.
_INT_LIMIT = 2.0**53


# ------------------------------------------------------------------------------ containers
class RobotLog(NamedTuple):
    """The logs of one MRCLAM robot (immutable: arrays are read-only). Times in Unix seconds."""

    #: Robot number N (also its subject number).
    robot: int
    #: ``(n,)`` odometry times, non-decreasing.
    odometry_t: FloatArray
    #: ``(n,)`` forward velocity (m/s), held from its time until the next record's.
    odometry_v: FloatArray
    #: ``(n,)`` angular velocity (rad/s, counter-clockwise), held likewise.
    odometry_w: FloatArray
    #: ``(k,)`` ground-truth times, non-decreasing.
    truth_t: FloatArray
    #: ``(k, 3)`` ground-truth pose ``(x, y, θ)`` in the world frame, θ wrapped to [-π, π).
    truth: FloatArray
    #: ``(p,)`` measurement times, non-decreasing (several measurements may share one time).
    meas_t: FloatArray
    #: ``(p,)`` int64 barcode read, as written in the file.
    meas_barcode: IntArray
    #: ``(p,)`` int64 landmark subject of each barcode; ``-1`` for robots and unknown barcodes.
    meas_subject: IntArray
    #: ``(p,)`` measured range (m).
    meas_range: FloatArray
    #: ``(p,)`` measured bearing (rad) in the robot frame, wrapped to [-π, π).
    meas_bearing: FloatArray
    #: Number of measurements whose barcode is in no row of ``Barcodes.dat``.
    n_unknown_barcodes: int

    def truth_at(self, t: ArrayLike) -> FloatArray:
        """Ground-truth pose ``(..., 3)`` at times ``t`` (``(...)``, Unix seconds).

        Linear interpolation between the two bracketing ground-truth records: x and y linearly,
        θ along the shorter arc, wrapped to [-π, π). Times must lie within
        ``[truth_t[0], truth_t[-1]]``: a time outside raises
        :class:`relmap.errors.ParameterError` (no extrapolation, no clipping); non-finite times
        raise :class:`relmap.errors.NonFiniteError`.
        """
        return _interpolate_poses(self.truth_t, self.truth, t, f"robot {self.robot} ground truth")


class Mrclam(NamedTuple):
    """An MRCLAM dataset folder (immutable: arrays are read-only)."""

    #: ``(s,)`` int64 subject numbers of ``Barcodes.dat``, in file order.
    subjects: IntArray
    #: ``(s,)`` int64 barcode of each subject.
    barcodes: IntArray
    #: ``(l,)`` int64 landmark subject numbers, in ``Landmark_Groundtruth.dat`` order.
    landmark_ids: IntArray
    #: ``(l, 2)`` surveyed landmark positions ``(x, y)`` (m), world frame.
    landmark_xy: FloatArray
    #: ``(l, 2)`` standard deviations ``(σx, σy)`` (m) of the surveyed positions.
    landmark_sigma: FloatArray
    #: The robots' logs; ``robots[N - 1]`` is robot N.
    robots: tuple[RobotLog, ...]

    def landmark_index(self, subjects: ArrayLike) -> IntArray:
        """Rows into :attr:`landmark_xy` of landmark ``subjects`` (any shape); ``-1`` elsewhere.

        Subjects that are not landmarks (robots, ``-1``, unknown numbers) give ``-1``, so
        ``landmark_index(log.meas_subject)`` selects the measurements of landmarks.
        """
        return _lookup(self.landmark_ids, subjects)


class Plaza(NamedTuple):
    """A CMU Plaza dataset folder (immutable: arrays are read-only). Times in seconds."""

    #: ``(n,)`` end time of each dead-reckoning step (``P_DR.txt``), non-decreasing.
    dr_t: FloatArray
    #: ``(n,)`` distance travelled in each step (m; never negative in Plaza 2).
    dr_distance: FloatArray
    #: ``(n,)`` heading change in each step (rad, counter-clockwise).
    dr_dheading: FloatArray
    #: ``(n + 1,)`` times of :attr:`dr_pose` (``DRp``); ``dr_pose_t[1:] == dr_t`` in Plaza 2.
    dr_pose_t: FloatArray
    #: ``(n + 1, 3)`` the dataset's dead-reckoned path ``(x, y, θ)`` (``DRp``), θ wrapped.
    dr_pose: FloatArray
    #: ``(k,)`` ground-truth times (``GT``).
    truth_t: FloatArray
    #: ``(k, 3)`` ground truth ``(x, y, θ)``, θ = GT's θ + π wrapped: the direction of travel.
    truth: FloatArray
    #: ``(k,)`` GT's θ column as written (wrapped), pointing backwards.
    truth_raw_heading: FloatArray
    #: ``(p,)`` range measurement times (``P_TD.txt``), non-decreasing.
    meas_t: FloatArray
    #: ``(p,)`` int64 id of the sender (the robot's radio).
    meas_sender: IntArray
    #: ``(p,)`` int64 beacon id.
    meas_beacon: IntArray
    #: ``(p,)`` measured range (m).
    meas_range: FloatArray
    #: ``(p,)`` int64 row of each measurement's beacon in :attr:`beacon_ids`, ``-1`` if unknown.
    meas_beacon_index: IntArray
    #: ``(b,)`` int64 beacon ids (``TL``).
    beacon_ids: IntArray
    #: ``(b, 2)`` beacon positions ``(x, y)`` (m).
    beacon_xy: FloatArray
    #: Number of range measurements whose beacon is not in ``TL`` (0 in Plaza 2).
    n_unknown_beacons: int

    def dead_reckoning(self, start: ArrayLike | None = None) -> FloatArray:
        """Integrate the DR steps from ``start`` with the midpoint heading: ``(n + 1, 3)`` poses.

        Step k moves ``dr_distance[k]`` along ``θ_k + dr_dheading[k]/2`` and turns by
        ``dr_dheading[k]``; row 0 is ``start`` (default: ``dr_pose[0]``, which is GT's first
        pose with the heading of travel), row k + 1 the pose at ``dr_t[k]``. Headings wrapped.
        """
        if start is None and not len(self.dr_pose):
            raise ParameterError("no DRp pose to start from: give start")
        x0 = np.asarray(self.dr_pose[0] if start is None else start, dtype=np.float64)
        if x0.shape != (3,):
            raise ParameterError(f"start must be one pose (x, y, θ); got shape {x0.shape}")
        if not np.isfinite(x0).all():
            raise NonFiniteError("start pose must be finite")
        turn = np.concatenate([[0.0], np.cumsum(self.dr_dheading)])
        heading = x0[2] + turn[:-1] + 0.5 * self.dr_dheading
        out = np.empty((len(turn), 3))
        out[:, 0] = x0[0] + np.concatenate([[0.0], np.cumsum(self.dr_distance * np.cos(heading))])
        out[:, 1] = x0[1] + np.concatenate([[0.0], np.cumsum(self.dr_distance * np.sin(heading))])
        out[:, 2] = se2.wrap_angle(x0[2] + turn)
        return out

    def truth_at(self, t: ArrayLike) -> FloatArray:
        """Corrected ground truth ``(..., 3)`` at times ``t``; as :meth:`RobotLog.truth_at`."""
        return _interpolate_poses(self.truth_t, self.truth, t, "Plaza ground truth")


# ----------------------------------------------------------------------------- helpers
def _lookup(table: IntArray, keys: ArrayLike) -> IntArray:
    """Index of each key in ``table`` (unique int64 values), ``-1`` where absent; vectorized."""
    want = np.asarray(keys)
    if want.size and want.dtype.kind not in "iu":
        raise ParameterError(f"ids must be integers; got an array of {want.dtype}")
    want = want.astype(np.int64)
    if not len(table):
        return np.full(want.shape, -1, dtype=np.int64)
    order = np.argsort(table, kind="stable")
    pos = np.minimum(np.searchsorted(table[order], want), len(table) - 1)
    found = table[order][pos] == want
    return np.where(found, order[pos], -1).astype(np.int64)


def _interpolate_poses(times: FloatArray, poses: FloatArray, t: ArrayLike, what: str) -> FloatArray:
    """``poses`` (at ``times``) at times ``t``, after checking ``t`` is finite and inside their
    span (:meth:`relmap.lie.Group.at_times` interpolates)."""
    query = np.asarray(t, dtype=np.float64)
    if not np.isfinite(query).all():
        raise NonFiniteError(f"times for {what} must be finite")
    if not len(times):
        raise ParameterError(f"{what} has no records to interpolate")
    if query.size and (query.min() < times[0] or query.max() > times[-1]):
        outside = (query < times[0]) | (query > times[-1])
        first = float(query[outside].flat[0])
        raise ParameterError(
            f"{int(outside.sum())} time(s) outside the span of {what} "
            f"[{times[0]!r}, {times[-1]!r}] s, e.g. {first!r}; no extrapolation"
        )
    return SE2.at_times(times, poses, query)


# ------------------------------------------------------------------------------ tables
class _Table(NamedTuple):
    path: Path
    columns: tuple[str, ...]
    values: FloatArray  # (n, len(columns))
    lines: IntArray  # (n,) 1-based line of each row

    def fail(self, bad: ArrayLike, message: str) -> None:
        """Raise ``message`` at the line of the first row flagged in ``bad`` (if any)."""
        fail_at(self.path, bad, self.lines, message)

    def column(self, name: str) -> FloatArray:
        return self.values[:, self.columns.index(name)]

    def integers(self, name: str) -> IntArray:
        """Column ``name`` as int64, after checking every value is an exact integer."""
        col = self.column(name)
        bad = (col != np.round(col)) | (np.abs(col) >= _INT_LIMIT)
        if bad.any():
            self.fail(bad, f"{name} must be an integer; got {col[np.flatnonzero(bad)[0]]!r}")
        return col.astype(np.int64)

    def non_negative(self, name: str) -> None:
        col = self.column(name)
        bad = col < 0
        if bad.any():
            self.fail(bad, f"{name} must not be negative; got {col[np.flatnonzero(bad)[0]]!r}")

    def times(self, name: str = "t") -> FloatArray:
        """Column ``name`` after checking it never decreases (equal times are allowed)."""
        t = self.column(name)
        back = np.flatnonzero(t[1:] < t[:-1])
        if back.size:
            k = int(back[0]) + 1
            raise FileFormatError(
                self.path,
                f"time {t[k]!r} goes backwards (the previous record, line "
                f"{int(self.lines[k - 1])}, has {t[k - 1]!r}); records must be in time order",
                line=int(self.lines[k]),
            )
        return t

    def unique(self, ids: IntArray, name: str) -> None:
        order = np.argsort(ids, kind="stable")
        repeats = np.zeros(len(ids), dtype=bool)
        repeats[order[1:][ids[order][1:] == ids[order][:-1]]] = True
        if repeats.any():
            k = int(np.flatnonzero(repeats)[0])
            first = int(np.flatnonzero(ids == ids[k])[0])
            raise FileFormatError(
                self.path,
                f"duplicate {name} {ids[k]} (first on line {int(self.lines[first])})",
                line=int(self.lines[k]),
            )


def _read_table(path: Path, columns: Sequence[str]) -> _Table:
    """Parse a white-space separated table after any leading ``#`` lines, with numpy's C parser.

    Blank lines are skipped. On any failure (or blank lines inside the table) the lines are
    parsed again one by one, to report the offending line or to keep each row's line number.
    Every value must be finite.
    """
    columns = tuple(columns)
    n_cols = len(columns)
    lines = read_text(path).split("\n")
    skip = 0
    while skip < len(lines) and lines[skip].lstrip().startswith("#"):
        skip += 1
    end = len(lines)
    while end > skip and not lines[end - 1].strip():
        end -= 1
    body = lines[skip:end]
    values: FloatArray | None = None
    if not body:
        values = np.empty((0, n_cols))
    else:
        try:
            values = np.loadtxt(body, dtype=np.float64, comments=None, ndmin=2)
        except ValueError:
            values = None
        if values is not None and values.shape != (len(body), n_cols):
            values = None
    if values is not None:
        numbers = np.arange(skip + 1, skip + 1 + len(values), dtype=np.int64)
    else:
        values, numbers = _parse_slowly(path, columns, body, skip)
    table = _Table(path, columns, values, numbers)
    finite = np.isfinite(values)
    if not finite.all():
        row = int(np.flatnonzero(~finite.all(axis=1))[0])
        col = int(np.flatnonzero(~finite[row])[0])
        raise FileFormatError(
            path, f"{columns[col]} is not finite ({values[row, col]!r})", line=int(numbers[row])
        )
    return table


def _parse_slowly(
    path: Path, columns: tuple[str, ...], body: list[str], skip: int
) -> tuple[FloatArray, IntArray]:
    rows: list[list[float]] = []
    numbers: list[int] = []
    for k, raw in enumerate(body):
        line = skip + 1 + k
        tokens = raw.split()
        if not tokens:
            continue
        if len(tokens) != len(columns):
            raise FileFormatError(
                path,
                f"expected {len(columns)} columns ({' '.join(columns)}); got {len(tokens)}",
                line=line,
            )
        row = []
        for name, token in zip(columns, tokens, strict=True):
            try:
                row.append(strict_float(token))
            except ValueError:
                raise FileFormatError(
                    path, f"{name}: {token!r} is not a number", line=line
                ) from None
        rows.append(row)
        numbers.append(line)
    values = np.array(rows, dtype=np.float64).reshape(-1, len(columns))
    return values, np.array(numbers, dtype=np.int64)


# ------------------------------------------------------------------------------ MRCLAM
def _missing(folder: Path, names: Sequence[str]) -> list[str]:
    return [name for name in names if not (folder / name).is_file()]


def _folder(folder: str | os.PathLike[str]) -> Path:
    p = Path(folder)
    if not p.is_dir():
        raise FileFormatError(p, "not a folder")
    return p


def _read_robot(
    folder: Path, n: int, barcode_table: IntArray, barcode_subject: IntArray, landmarks: IntArray
) -> RobotLog:
    odo = _read_table(folder / f"Robot{n}_Odometry.dat", ("t", "v", "ω"))
    odo_t = odo.times()
    gt = _read_table(folder / f"Robot{n}_Groundtruth.dat", ("t", "x", "y", "θ"))
    if not len(gt.values):
        raise FileFormatError(gt.path, "no ground-truth records (t x y θ): the file is empty")
    gt_t = gt.times()
    truth = gt.values[:, 1:].copy()
    truth[:, 2] = se2.wrap_angle(truth[:, 2])
    meas = _read_table(folder / f"Robot{n}_Measurement.dat", ("t", "barcode", "range", "bearing"))
    meas_t = meas.times()
    barcode = meas.integers("barcode")
    meas.non_negative("range")
    row = _lookup(barcode_table, barcode)
    subject = np.where(row >= 0, barcode_subject[row], -1)
    is_landmark = _lookup(landmarks, subject) >= 0
    return RobotLog(
        robot=n,
        odometry_t=frozen(odo_t),
        odometry_v=frozen(odo.values[:, 1]),
        odometry_w=frozen(odo.values[:, 2]),
        truth_t=frozen(gt_t),
        truth=frozen(truth),
        meas_t=frozen(meas_t),
        meas_barcode=frozen(barcode),
        meas_subject=frozen(np.where(is_landmark, subject, -1).astype(np.int64)),
        meas_range=frozen(meas.values[:, 2]),
        meas_bearing=frozen(se2.wrap_angle(meas.values[:, 3])),
        n_unknown_barcodes=int(np.count_nonzero(row < 0)),
    )


def read_mrclam(folder: str | os.PathLike[str]) -> Mrclam:
    """Read a UTIAS MRCLAM dataset folder (``Barcodes.dat``, ``Landmark_Groundtruth.dat`` and the
    odometry, ground-truth and measurement logs of robots 1-5).

    Times are Unix seconds; distances metres; angles radians, wrapped to [-π, π). Measurement
    barcodes are mapped to landmark subjects (``-1`` for robots and unknown barcodes). Raises
    :class:`relmap.errors.FileFormatError` naming the missing files if the folder lacks any of
    them, and naming file and line for malformed content (wrong column count, non-number,
    non-finite value, non-integer subject or barcode, duplicate subject or barcode, negative
    σ or range, a time going backwards, a landmark without a barcode, a robot that is not in
    ``Barcodes.dat`` or is listed as a landmark).
    """
    p = _folder(folder)
    missing = _missing(p, _MRCLAM_FILES)
    if missing:
        raise FileFormatError(p, f"not an MRCLAM folder: missing {', '.join(missing)}")

    bc = _read_table(p / "Barcodes.dat", ("subject", "barcode"))
    subjects, barcodes = bc.integers("subject"), bc.integers("barcode")
    bc.unique(subjects, "subject")
    bc.unique(barcodes, "barcode")
    absent = [n for n in range(1, MRCLAM_ROBOTS + 1) if n not in subjects]
    if absent:
        raise FileFormatError(
            bc.path, f"no barcode for robot subject(s) {', '.join(map(str, absent))}"
        )

    lm = _read_table(p / "Landmark_Groundtruth.dat", ("subject", "x", "y", "σx", "σy"))
    landmark_ids = lm.integers("subject")
    lm.unique(landmark_ids, "subject")
    lm.non_negative("σx")
    lm.non_negative("σy")
    lm.fail(
        (landmark_ids >= 1) & (landmark_ids <= MRCLAM_ROBOTS),
        f"subjects 1-{MRCLAM_ROBOTS} are robots, not landmarks",
    )
    lm.fail(_lookup(subjects, landmark_ids) < 0, "landmark subject has no barcode in Barcodes.dat")

    robots = tuple(
        _read_robot(p, n, barcodes, subjects, landmark_ids) for n in range(1, MRCLAM_ROBOTS + 1)
    )
    return Mrclam(
        subjects=frozen(subjects),
        barcodes=frozen(barcodes),
        landmark_ids=frozen(landmark_ids),
        landmark_xy=frozen(lm.values[:, 1:3]),
        landmark_sigma=frozen(lm.values[:, 3:5]),
        robots=robots,
    )


# ------------------------------------------------------------------------------- Plaza
def _plaza_files(folder: Path) -> tuple[list[Path], list[str]]:
    """``([DR, TD, mat], [])`` for the one complete prefix, or ``([], [what is missing])``."""
    prefixes = sorted(q.name[: -len("_DR.txt")] for q in folder.glob("*_DR.txt") if q.is_file())
    if not prefixes:
        return [], ["a <name>_DR.txt file"]
    complete = [pre for pre in prefixes if not _missing(folder, [f"{pre}_TD.txt", f"{pre}_.mat"])]
    if not complete:
        pre = prefixes[0]
        return [], _missing(folder, [f"{pre}_TD.txt", f"{pre}_.mat"])
    if len(complete) > 1:
        raise FileFormatError(
            folder, f"holds several Plaza datasets ({', '.join(complete)}); expected one"
        )
    pre = complete[0]
    return [folder / f"{pre}_DR.txt", folder / f"{pre}_TD.txt", folder / f"{pre}_.mat"], []


def _mat_array(path: Path, mat: dict[str, object], key: str, n_cols: int) -> FloatArray:
    what = {"GT": "t x y θ", "DRp": "t x y θ", "TL": "id x y"}[key]
    if key not in mat:
        raise FileFormatError(path, f"no variable {key!r} ({what})")
    arr = np.asarray(mat[key])
    if arr.dtype.kind not in "iuf" or arr.ndim != 2 or arr.shape[1] != n_cols:
        raise FileFormatError(
            path,
            f"variable {key!r} must be a numeric (n, {n_cols}) array ({what}); "
            f"got {arr.dtype} {arr.shape}",
        )
    if key == "GT" and not len(arr):
        raise FileFormatError(path, "variable 'GT' (ground truth) has no rows")
    arr = arr.astype(np.float64)
    bad = ~np.isfinite(arr).all(axis=1)
    if bad.any():
        raise FileFormatError(path, f"{key} row {int(np.flatnonzero(bad)[0]) + 1} is not finite")
    if key != "TL":
        back = np.flatnonzero(arr[1:, 0] < arr[:-1, 0])
        if back.size:
            raise FileFormatError(
                path, f"{key} row {int(back[0]) + 2}: time goes backwards; rows must be in order"
            )
    return arr


def read_plaza(folder: str | os.PathLike[str]) -> Plaza:
    """Read a CMU Plaza range-only dataset folder (``P_DR.txt``, ``P_TD.txt``, ``P_.mat``).

    Times are seconds (the dataset's clock), distances metres, angles radians wrapped to
    [-π, π). Ground truth is returned with its heading turned by π (:attr:`Plaza.truth`), to the
    direction of travel; see the module docstring. Beacon ids of ``TD`` are matched to ``TL``
    (unknown ones counted in :attr:`Plaza.n_unknown_beacons`, index ``-1``). Raises
    :class:`relmap.errors.FileFormatError` for missing files and malformed content (file and
    line for the text files, variable and row for the ``.mat`` file).
    """
    p = _folder(folder)
    files, missing = _plaza_files(p)
    if missing:
        raise FileFormatError(p, f"not a CMU Plaza folder: missing {', '.join(missing)}")
    dr_path, td_path, mat_path = files

    dr = _read_table(dr_path, ("t", "Δdistance", "Δheading"))
    dr_t = dr.times()
    td = _read_table(td_path, ("t", "sender", "beacon", "range"))
    td_t = td.times()
    sender, beacon = td.integers("sender"), td.integers("beacon")
    td.non_negative("range")

    import scipy.io  # lazily: keeps `import relmap` light

    try:
        mat = scipy.io.loadmat(str(mat_path))
    except Exception as exc:  # loadmat fails in many ways on a bad file
        raise FileFormatError(mat_path, f"not a readable MATLAB file: {exc}") from None
    gt = _mat_array(mat_path, mat, "GT", 4)
    drp = _mat_array(mat_path, mat, "DRp", 4)
    tl = _mat_array(mat_path, mat, "TL", 3)
    ids = tl[:, 0]
    bad = (ids != np.round(ids)) | (np.abs(ids) >= _INT_LIMIT)
    if bad.any():
        raise FileFormatError(mat_path, f"TL row {int(np.flatnonzero(bad)[0]) + 1}: id not integer")
    beacon_ids = ids.astype(np.int64)
    if len(np.unique(beacon_ids)) != len(beacon_ids):
        raise FileFormatError(mat_path, "TL has duplicate beacon ids")
    index = _lookup(beacon_ids, beacon)

    raw = se2.wrap_angle(gt[:, 3])
    truth = gt[:, 1:].copy()
    truth[:, 2] = se2.wrap_angle(raw + np.pi)
    dr_pose = drp[:, 1:].copy()
    dr_pose[:, 2] = se2.wrap_angle(dr_pose[:, 2])
    return Plaza(
        dr_t=frozen(dr_t),
        dr_distance=frozen(dr.values[:, 1]),
        dr_dheading=frozen(dr.values[:, 2]),
        dr_pose_t=frozen(drp[:, 0]),
        dr_pose=frozen(dr_pose),
        truth_t=frozen(gt[:, 0]),
        truth=frozen(truth),
        truth_raw_heading=frozen(raw),
        meas_t=frozen(td_t),
        meas_sender=frozen(sender),
        meas_beacon=frozen(beacon),
        meas_range=frozen(td.values[:, 3]),
        meas_beacon_index=frozen(index),
        beacon_ids=frozen(beacon_ids),
        beacon_xy=frozen(tl[:, 1:3]),
        n_unknown_beacons=int(np.count_nonzero(index < 0)),
    )


# ------------------------------------------------------------------------------ recognise
def recognise(folder: str | os.PathLike[str]) -> DatasetKind | None:
    """Which dataset ``folder`` holds (a :class:`DatasetKind`), from the files present:
    ``"mrclam"``, ``"plaza"`` or None.

    ``"mrclam"`` needs every MRCLAM file (:func:`read_mrclam`); ``"plaza"`` a ``P_DR.txt``,
    ``P_TD.txt`` and ``P_.mat`` with a common prefix ``P``. None for anything else, including a
    path that is not a folder. Contents are not read. A folder holding the files of both
    datasets is ambiguous, and one holding some MRCLAM files (two or more) but not all is an
    incomplete MRCLAM folder: :class:`relmap.errors.FileFormatError` (naming the missing files).
    """
    p = Path(folder)
    if not p.is_dir():
        return None
    missing = _missing(p, _MRCLAM_FILES)
    if 0 < len(missing) < len(_MRCLAM_FILES) - 1:  # more than one MRCLAM file, not all
        raise FileFormatError(p, f"an incomplete MRCLAM folder: missing {', '.join(missing)}")
    mrclam = not missing
    try:
        plaza = bool(_plaza_files(p)[0])
    except FileFormatError:  # several complete Plaza datasets: still Plaza
        plaza = True
    if mrclam and plaza:
        raise FileFormatError(p, "holds both MRCLAM and CMU Plaza files: which dataset is meant?")
    return DatasetKind.MRCLAM if mrclam else DatasetKind.PLAZA if plaza else None
