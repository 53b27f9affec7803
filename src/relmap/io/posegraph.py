"""2-D pose-graph files: g2o (``VERTEX_SE2``, ``EDGE_SE2``, ``FIX``), TORO (``VERTEX2``, ``EDGE2``).

Formats (one record a line, fields separated by white space; blank lines and lines whose first
field starts with ``#`` are ignored; metres and radians)::

    VERTEX_SE2 id x y θ                                  g2o: initial guess of pose ``id``
    EDGE_SE2 i j dx dy dθ I11 I12 I13 I22 I23 I33        g2o: measurement z and information
    FIX id [id ...]                                      g2o: vertices held fixed
    VERTEX2 id x y θ                                     TORO
    EDGE2 i j dx dy dθ Ixx Ixy Iyy Iθθ Ixθ Iyθ           TORO: note the information order

The format is recognised from the file's content (the tag of its first record), never its name.
An edge's ``(dx, dy, dθ)`` is the measured relative pose ``z`` of vertex j in the frame of
vertex i (``z ≈ Tᵢ⁻¹ Tⱼ``); the six numbers after it are the upper triangle of the 3×3
**information** matrix of the measurement error, given row by row in g2o and in TORO's own order.

**Covariance convention.** g2o's (and GTSAM's) error ``z⁻¹ (Tᵢ⁻¹ Tⱼ)`` lives in the body frame of
the measurement z (a right perturbation ``z ∘ Exp(ξ)``), so ``Σ_body = I⁻¹``; TORO's information
is read the same way. relmap's covariance is in the parent frame i (Smith & Cheeseman's chart):
``Σ = M Σ_body Mᵀ`` with ``M = blkdiag(R(θ_z), 1)`` (:meth:`relmap.AT.from_body`). The file's
information matrices are also kept as written (:attr:`PoseGraph.information`), so writing a graph
back reproduces its edges' numbers exactly.

Angles are wrapped to [-π, π) on reading (vertex headings and measured dθ alike); an angle
written outside that range (some files have dθ ≈ ±3π/2) is therefore written back wrapped, an
equal rotation. Malformed input raises :class:`relmap.errors.FileFormatError` naming the file and
the 1-based line.
"""

from __future__ import annotations

import os
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Literal, NamedTuple

import numpy as np
import numpy.typing as npt

from relmap import gaussian
from relmap.at import AT
from relmap.errors import (
    FileFormatError,
    ParameterError,
    RelmapError,
    ShapeError,
    UnknownFrameError,
)
from relmap.gaussian import DEFAULT_RTOL
from relmap.io.atomic import write_text_atomic
from relmap.lie import se2
from relmap.typing import ArrayLike, FloatArray, IntArray

__all__ = ["PoseGraph", "read_graph", "write_graph"]

GraphFormat = Literal["g2o", "toro"]


class _Spec(NamedTuple):
    vertex: str
    edge: str
    fix: str | None
    info_order: tuple[tuple[int, int], ...]  # (row, col) of each information number in the file


_SPECS: dict[str, _Spec] = {
    "g2o": _Spec("VERTEX_SE2", "EDGE_SE2", "FIX", ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))),
    "toro": _Spec("VERTEX2", "EDGE2", None, ((0, 0), (0, 1), (1, 1), (2, 2), (0, 2), (1, 2))),
}
_FORMAT_OF_TAG: dict[str, GraphFormat] = {
    "VERTEX_SE2": "g2o",
    "EDGE_SE2": "g2o",
    "FIX": "g2o",
    "VERTEX2": "toro",
    "EDGE2": "toro",
}
_VERTEX_FIELDS = "id x y θ"
_EDGE_FIELDS = "i j dx dy dθ and 6 information numbers"
# Structured rows for numpy's C text parser: integer ids, then float64 values.
_VERTEX_DTYPE = np.dtype([("ids", np.int64, (1,)), ("values", np.float64, (3,))])
_EDGE_DTYPE = np.dtype([("ids", np.int64, (2,)), ("values", np.float64, (9,))])
_INT = re.compile(r"[+-]?[0-9]+")
# An information matrix is singular when the smallest eigenvalue of its correlation matrix is at
# most this: relmap's rank decision elsewhere (rtol·n, :func:`relmap.gaussian.generalized_inverse`).
_SINGULAR = 3 * DEFAULT_RTOL


class PoseGraph(NamedTuple):
    """A 2-D pose graph as read from a g2o or TORO file (immutable: arrays are read-only).

    Vertices are rows ``0..n-1`` in file order; edges refer to vertices by **id**, not row
    (:meth:`index_of`, :meth:`edge_indices` map ids to rows).
    """

    #: ``"g2o"`` or ``"toro"``: the file's format, used again by :func:`write_graph`.
    format: GraphFormat
    #: ``(n,)`` int64 vertex ids, in file order.
    vertex_ids: IntArray
    #: ``(n, 3)`` float64 initial guess ``(x, y, θ)`` of each vertex in the world frame, θ wrapped.
    poses: FloatArray
    #: ``(m,)`` int64 id of each edge's vertex i (the measurement's parent frame).
    edge_from: IntArray
    #: ``(m,)`` int64 id of each edge's vertex j.
    edge_to: IntArray
    #: Batch ``(m,)`` AT: mean = measured pose of j in frame i, covariance in frame i (relmap's).
    measurements: AT
    #: ``(m, 3, 3)`` float64 information matrices exactly as written (body frame of z, file order).
    information: FloatArray
    #: ``(k,)`` int64 ids given by ``FIX`` lines, in file order (always empty for TORO).
    fixed: IntArray

    def index_of(self, ids: ArrayLike) -> IntArray:
        """Row indices (into :attr:`vertex_ids` and :attr:`poses`) of vertex ``ids``, same shape.

        Vectorized; raises :class:`relmap.errors.UnknownFrameError` naming any id not in the graph.
        """
        want = np.asarray(ids)
        if want.dtype.kind not in "iu" and want.size:
            raise ParameterError(f"vertex ids must be integers; got an array of {want.dtype}")
        want = want.astype(np.int64)
        order = np.argsort(self.vertex_ids, kind="stable")
        ordered = self.vertex_ids[order]
        pos = np.minimum(np.searchsorted(ordered, want), max(len(ordered) - 1, 0))
        found = ordered[pos] == want if len(ordered) else np.zeros(want.shape, dtype=bool)
        if not np.all(found):
            missing = np.unique(want[~found])
            shown = ", ".join(map(str, missing[:10].tolist()))
            more = f" and {len(missing) - 10} more" if len(missing) > 10 else ""
            raise UnknownFrameError(
                f"unknown vertex id(s) {shown}{more}: not among the graph's "
                f"{len(self.vertex_ids)} vertices"
            )
        return order[pos]

    def edge_indices(self) -> tuple[IntArray, IntArray]:
        """Row indices ``(i, j)`` of every edge's two vertices, each ``(m,)``."""
        return self.index_of(self.edge_from), self.index_of(self.edge_to)


# ----------------------------------------------------------------------------------- reading
class _Records(NamedTuple):
    lines: list[int]  # 1-based line numbers
    rests: list[str]  # the text after the tag


def _group(path: Path, text: str) -> tuple[GraphFormat, dict[str, _Records]]:
    """Records grouped by tag, and the format named by the first record's tag."""
    groups: dict[str, _Records] = {}
    for number, head in enumerate([ln.split(None, 1) for ln in text.split("\n")], 1):
        if not head or head[0][0] == "#":
            continue
        group = groups.get(head[0])
        if group is None:
            group = groups[head[0]] = _Records([], [])
        group.lines.append(number)
        group.rests.append(head[1] if len(head) > 1 else "")
    if not groups:
        raise FileFormatError(path, "no records: expected a g2o or TORO 2-D pose graph")
    first_tag = min(groups, key=lambda tag: groups[tag].lines[0])
    fmt = _FORMAT_OF_TAG.get(first_tag)
    known = [t for t, f in _FORMAT_OF_TAG.items() if fmt is None or f == fmt]
    unknown = [tag for tag in groups if tag not in known]
    if unknown:
        tag = min(unknown, key=lambda t: groups[t].lines[0])
        where = f"in a {fmt} file " if fmt else ""
        raise FileFormatError(
            path,
            f"unknown record tag {tag!r} {where}(expected {', '.join(known)})",
            line=groups[tag].lines[0],
        )
    assert fmt is not None  # an unknown first tag was reported above
    return fmt, groups


def _parse(
    path: Path, tag: str, records: _Records, dtype: np.dtype, fields: str
) -> tuple[IntArray, FloatArray]:
    """``(ids (k, n_ids), values (k, n_values))`` of one tag's records, with numpy's C parser.

    On any failure the records are parsed again one by one, to report the offending line.
    """
    n_ids, n_values = dtype["ids"].shape[0], dtype["values"].shape[0]
    if not records.rests:
        return np.empty((0, n_ids), dtype=np.int64), np.empty((0, n_values))
    try:
        rows = np.loadtxt(records.rests, dtype=dtype, comments=None, ndmin=1)
        if rows.shape == (len(records.rests),):
            return rows["ids"], rows["values"]
    except ValueError:
        pass
    ids = np.empty((len(records.rests), n_ids), dtype=np.int64)
    values = np.empty((len(records.rests), n_values))
    for k, (line, rest) in enumerate(zip(records.lines, records.rests, strict=True)):
        tokens = rest.split()
        if len(tokens) != n_ids + n_values:
            raise FileFormatError(
                path,
                f"{tag} needs {n_ids + n_values} fields after the tag ({fields}); "
                f"got {len(tokens)}",
                line=line,
            )
        ids[k] = [_int(path, tag, tok, line) for tok in tokens[:n_ids]]
        values[k] = [_float(path, tag, tok, line) for tok in tokens[n_ids:]]
    return ids, values


def _int(path: Path, tag: str, token: str, line: int) -> int:
    if _INT.fullmatch(token) and -(2**63) <= int(token) < 2**63:
        return int(token)
    raise FileFormatError(path, f"{tag}: vertex id {token!r} is not a (64-bit) integer", line=line)


def _float(path: Path, tag: str, token: str, line: int) -> float:
    try:
        if "_" not in token:
            return float(token)
    except ValueError:
        pass
    raise FileFormatError(path, f"{tag}: {token!r} is not a number", line=line)


def _fail_at(path: Path, bad: ArrayLike, lines: Sequence[int], message: str) -> None:
    """Raise ``message`` at the line of the first row flagged in ``bad`` (if any)."""
    flagged = np.flatnonzero(bad)
    if flagged.size:
        raise FileFormatError(path, message, line=lines[int(flagged[0])])


def _assemble(values: FloatArray, order: tuple[tuple[int, int], ...]) -> FloatArray:
    """Symmetric ``(m, 3, 3)`` matrices from ``(m, 6)`` upper-triangle entries in ``order``."""
    out = np.empty((len(values), 3, 3))
    for k, (r, c) in enumerate(order):
        out[:, r, c] = out[:, c, r] = values[:, k]
    return out


def _body_covariance(path: Path, tag: str, info: FloatArray, lines: Sequence[int]) -> FloatArray:
    """``I⁻¹`` for every edge, after checking each information matrix is positive definite.

    The test is on the correlation matrix ``D^-1/2 I D^-1/2`` (unit-free, as in
    :mod:`relmap.gaussian`): its smallest eigenvalue must exceed ``3·DEFAULT_RTOL``.
    """
    diag = np.diagonal(info, axis1=-2, axis2=-1)
    _fail_at(
        path,
        (diag <= 0.0).any(axis=-1),
        lines,
        f"{tag} information matrix is not positive definite: a diagonal entry is not positive",
    )
    s = np.sqrt(diag)
    corr = info / (s[:, :, None] * s[:, None, :])
    try:
        np.linalg.cholesky(corr - _SINGULAR * np.eye(3))
    except np.linalg.LinAlgError:
        lowest = np.linalg.eigvalsh(corr)[:, 0]
        bad = lowest <= _SINGULAR
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            kind = "indefinite" if lowest[k] < -_SINGULAR else "singular"
            raise FileFormatError(
                path,
                f"{tag} information matrix is not positive definite ({kind}): the smallest "
                f"eigenvalue of its correlation matrix is {lowest[k]:.3g} (must exceed "
                f"{_SINGULAR:g})",
                line=lines[k],
            ) from None
    cov = np.linalg.inv(corr) / (s[:, :, None] * s[:, None, :])
    return 0.5 * (cov + np.swapaxes(cov, -1, -2))


def _measurements(
    path: Path, tag: str, z: FloatArray, cov_body: FloatArray, lines: Sequence[int]
) -> AT:
    try:
        return AT.from_body(z, cov_body)
    except RelmapError:
        pass
    for k, line in enumerate(lines):  # only on failure: find the edge to blame
        try:
            AT.from_body(z[k], cov_body[k])
        except RelmapError as exc:
            raise FileFormatError(
                path, f"{tag} information matrix cannot be inverted accurately: {exc}", line=line
            ) from None
    raise FileFormatError(path, f"{tag} measurements do not form valid ATs")  # pragma: no cover


def _frozen(arr: np.ndarray) -> np.ndarray:
    arr = np.ascontiguousarray(arr)
    arr.flags.writeable = False
    return arr


def read_graph(path: str | os.PathLike[str]) -> PoseGraph:
    """Read a 2-D pose graph in g2o or TORO format (recognised from the first record's tag).

    Returns a :class:`PoseGraph`: vertex poses ``(x, y, θ)`` in the world frame, and for every
    edge i → j the measured pose of j in frame i with relmap's covariance (frame i; the file's
    body-frame information converted by ``Σ = M I⁻¹ Mᵀ``, ``M = blkdiag(R(θ_z), 1)``). Angles are
    wrapped to [-π, π). Raises :class:`relmap.errors.FileFormatError` (file and line) for an
    unknown tag, a wrong number of fields, a non-number or non-integer id, a non-finite number,
    a duplicate vertex id, an edge or FIX naming a vertex with no vertex line, or an information
    matrix that is not symmetric positive definite.
    """
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise FileFormatError(p, f"cannot read: {exc.strerror}") from None
    except UnicodeDecodeError as exc:
        raise FileFormatError(p, f"not a text file (UTF-8): {exc.reason}") from None
    fmt, groups = _group(p, text)
    spec = _SPECS[fmt]
    empty = _Records([], [])

    vtx = groups.get(spec.vertex, empty)
    vertex_ids, poses = _parse(p, spec.vertex, vtx, _VERTEX_DTYPE, _VERTEX_FIELDS)
    vertex_ids = vertex_ids[:, 0]
    edg = groups.get(spec.edge, empty)
    edge_ids, edge_values = _parse(p, spec.edge, edg, _EDGE_DTYPE, _EDGE_FIELDS)
    fixed_list: list[int] = []
    fixed_lines: list[int] = []
    for line, rest in zip(*groups.get(spec.fix or "", empty), strict=True):
        if not rest.split():
            raise FileFormatError(p, "FIX needs at least one vertex id", line=line)
        for tok in rest.split():
            fixed_list.append(_int(p, "FIX", tok, line))
            fixed_lines.append(line)
    fixed = np.array(fixed_list, dtype=np.int64)

    for tag, values, lines in (
        (spec.vertex, poses, vtx.lines),
        (spec.edge, edge_values, edg.lines),
    ):
        bad = ~np.isfinite(values).all(axis=1)
        _fail_at(p, bad, lines, f"non-finite number in a {tag} line (values must be finite)")

    # Duplicate ids: report the earliest line that repeats an id seen before.
    order = np.argsort(vertex_ids, kind="stable")
    ordered = vertex_ids[order]
    repeats = np.zeros(len(vertex_ids), dtype=bool)
    repeats[order[1:][ordered[1:] == ordered[:-1]]] = True
    if repeats.any():
        k = int(np.flatnonzero(repeats)[0])
        first = int(np.flatnonzero(vertex_ids == vertex_ids[k])[0])
        raise FileFormatError(
            p,
            f"duplicate vertex id {vertex_ids[k]} (first defined on line {vtx.lines[first]})",
            line=vtx.lines[k],
        )

    def known(ids: IntArray) -> npt.NDArray[np.bool_]:
        pos = np.minimum(np.searchsorted(ordered, ids), max(len(ordered) - 1, 0))
        return ordered[pos] == ids if len(ordered) else np.zeros(ids.shape, dtype=bool)

    for col, end in ((0, "i"), (1, "j")):
        ok = known(edge_ids[:, col])
        if not ok.all():
            k = int(np.flatnonzero(~ok)[0])
            raise FileFormatError(
                p,
                f"{spec.edge} vertex {end} = {edge_ids[k, col]} has no {spec.vertex} line",
                line=edg.lines[k],
            )
    ok = known(fixed)
    if not ok.all():
        k = int(np.flatnonzero(~ok)[0])
        raise FileFormatError(p, f"FIX vertex {fixed[k]} has no {spec.vertex} line", fixed_lines[k])

    information = _assemble(edge_values[:, 3:], spec.info_order)
    cov_body = _body_covariance(p, spec.edge, information, edg.lines)
    z = edge_values[:, :3].copy()
    z[:, 2] = se2.wrap_angle(z[:, 2])  # wrap before M(θ) is built: re-reading gives equal bits
    measurements = _measurements(p, spec.edge, z, cov_body, edg.lines)
    poses = poses.copy()
    poses[:, 2] = se2.wrap_angle(poses[:, 2])
    return PoseGraph(
        format=fmt,
        vertex_ids=_frozen(vertex_ids),
        poses=_frozen(poses),
        edge_from=_frozen(edge_ids[:, 0]),
        edge_to=_frozen(edge_ids[:, 1]),
        measurements=measurements,
        information=_frozen(information),
        fixed=_frozen(fixed),
    )


# ----------------------------------------------------------------------------------- writing
def write_graph(
    path: str | os.PathLike[str], graph: PoseGraph, poses: ArrayLike | None = None
) -> None:
    """Write ``graph`` in its own format (``graph.format``), atomically.

    Vertices are written at ``poses`` (``(n, 3)``, ``(x, y, θ)`` in the world frame, one row per
    vertex in :attr:`PoseGraph.vertex_ids` order; default ``graph.poses``), then the g2o ``FIX``
    lines, then the edges: each measurement mean and the information matrix exactly as stored,
    in the format's field order. Numbers are written with full precision (``repr``), so reading
    the file back gives the same arrays bit for bit. Nothing is written if anything is invalid.
    """
    spec = _SPECS.get(graph.format)
    if spec is None:
        raise ParameterError(f"unknown pose-graph format {graph.format!r} (expected g2o or toro)")
    ids = np.asarray(graph.vertex_ids)
    n = len(ids)
    xyt = np.asarray(graph.poses if poses is None else poses, dtype=np.float64)
    if xyt.shape != (n, 3):
        raise ShapeError(
            f"poses must have shape ({n}, 3), one (x, y, θ) row per vertex; got {xyt.shape}"
        )
    gaussian.check_finite(xyt, "poses")
    m = len(graph.edge_from)
    shapes = {
        "edge_to": (np.shape(graph.edge_to), (m,)),
        "measurements": (graph.measurements.batch_shape, (m,)),
        "information": (np.shape(graph.information), (m, 3, 3)),
    }
    for name, (got, want) in shapes.items():
        if got != want:
            raise ShapeError(f"graph.{name} must have shape {want} for {m} edges; got {got}")
    fixed = np.asarray(graph.fixed, dtype=np.int64).reshape(-1)
    if spec.fix is None and fixed.size:
        raise ParameterError(f"{graph.format} files cannot hold fixed vertices; graph.fixed is set")

    rows, cols = np.array(spec.info_order).T
    edge_values = np.concatenate(
        [graph.measurements.mean, np.asarray(graph.information)[:, rows, cols]], axis=1
    )
    out = [
        f"{spec.vertex} {i} {x!r} {y!r} {t!r}"
        for i, (x, y, t) in zip(ids.tolist(), xyt.tolist(), strict=True)
    ]
    out += [f"{spec.fix} {i}" for i in fixed.tolist()]
    out += [
        f"{spec.edge} {i} {j} " + " ".join(map(repr, v))
        for i, j, v in zip(
            np.asarray(graph.edge_from).tolist(),
            np.asarray(graph.edge_to).tolist(),
            edge_values.tolist(),
            strict=True,
        )
    ]
    write_text_atomic(path, "\n".join(out) + "\n" if out else "")
