"""Pose-graph files, 2-D and 3-D: g2o (``VERTEX_SE2``/``EDGE_SE2``, ``VERTEX_SE3:QUAT``/
``EDGE_SE3:QUAT``, ``FIX``) and TORO (``VERTEX2``/``EDGE2``; the legacy 3-D ``VERTEX3``/``EDGE3``
of TORO, HOG-Man and iSAM, read only).

Formats (one record a line, fields separated by white space; blank lines and lines whose first
field starts with ``#`` are ignored; metres and radians)::

    VERTEX_SE2 id x y θ                                  g2o: initial guess of pose ``id``
    EDGE_SE2 i j dx dy dθ I11 I12 I13 I22 I23 I33        g2o: measurement z and information
    VERTEX_SE3:QUAT id x y z qx qy qz qw                 g2o 3-D: quaternion scalar last
    EDGE_SE3:QUAT i j x y z qx qy qz qw I11 I12 … I66    g2o 3-D: 21 information numbers
    FIX id [id ...]                                      g2o: vertices held fixed
    VERTEX2 id x y θ                                     TORO
    EDGE2 i j dx dy dθ Ixx Ixy Iyy Iθθ Ixθ Iyθ           TORO: note the information order
    VERTEX3 id x y z roll pitch yaw                      TORO/iSAM 3-D (read only)
    EDGE3 i j x y z roll pitch yaw I11 I12 … I66         TORO/iSAM 3-D (read only)

The format — g2o or TORO, 2-D or 3-D — is recognised from the file's content (the tag of its
first record; a leading ``FIX`` leaves the dimension to the first vertex or edge), never its name.
A record of the other dimension in the same file is an error naming its line. An edge's numbers
start with the measured relative pose ``z`` of vertex j in the frame of vertex i
(``z ≈ Tᵢ⁻¹ Tⱼ``); then come the upper triangle of its **information** matrix, row by row (TORO
2-D: in its own order). Each file's information matrices are kept exactly as written
(:attr:`PoseGraph.information`), so writing a graph back reproduces its edges' numbers; relmap's
covariance of each measurement (:attr:`PoseGraph.measurements`) is converted from them as follows.

**2-D** (g2o and TORO). g2o's (and GTSAM's) error ``z⁻¹ (Tᵢ⁻¹ Tⱼ)`` lives in the body frame of
the measurement z (a right perturbation ``z ∘ Exp(ξ)``), so ``Σ_body = I⁻¹``; TORO's information
is read the same way. relmap's covariance is in the parent frame i (Smith & Cheeseman's chart):
``Σ = M Σ_body Mᵀ`` with ``M = blkdiag(R(θ_z), 1)`` (:meth:`relmap.AT.from_body`). Angles are
wrapped to [-π, π) on reading (vertex headings and measured dθ alike); an angle written outside
that range (some files have dθ ≈ ±3π/2) is therefore written back wrapped, an equal rotation.

**3-D g2o.** Quaternions are ``(qx, qy, qz, qw)``; one whose norm differs from 1 by more than
``1e-3`` (:data:`QUATERNION_ATOL`; zero included) is an error: files write 6-7 significant digits
(norms within 1e-6 of 1 in every file of the shared data) and even 4 digits stay within 1e-3,
while anything further is not meant as a unit quaternion. Rotations are computed from the
quaternions normalized. g2o's error of an edge is ``e = (t_Δ, q_Δ,vec)``: the translation and the
vector part of the (``qw ≥ 0``) quaternion of ``Δ = z⁻¹ (Tᵢ⁻¹ Tⱼ)``, and the file's ``I`` is its
information, translation block first. Write ``Tᵢ⁻¹ Tⱼ = z Exp(ξ)`` with a body twist
``ξ = (ρ, ω)`` (:func:`relmap.lie.se3.exp`, translation first): ``Δ = Exp(ξ)``, whose quaternion
is ``(sin(|ω|/2) ω/|ω|, cos(|ω|/2))``, so ``q_Δ,vec = ω/2 + O(|ω|³)`` and ``t_Δ = ρ + O(|ω||ρ|)``:
``e ≈ D ξ`` with ``D = diag(1, 1, 1, ½, ½, ½)`` (``∂q_vec/∂ω = ½ I`` at the identity). Hence the
body covariance is ``Σ_ξ = S I⁻¹ S`` with ``S = D⁻¹ = diag(1, 1, 1, 2, 2, 2)`` — on a rotation
vector the information is a quarter of the file's rotation block and half its cross block. Then
body to relmap's chart: ``z Exp(ρ, ω) = (t_z + R_z J_l(ω) ρ, Exp(R_z ω) R_z)``, so to first order
``δt = R_z ρ`` and ``δφ = R_z ω`` (exactly, for the rotation). Altogether

    ``Σ = K I⁻¹ Kᵀ``,  ``K = blkdiag(R_z, 2 R_z)``,

which is :meth:`relmap.AT3.from_body` (GTSAM's rotation-first body covariance,
:func:`relmap.lie.se3.body_to_chart`) of ``P S I⁻¹ S Pᵀ``, P swapping the two blocks. (GTSAM's
``readG2o`` swaps the blocks but does not rescale: its rotation variances are a quarter of the
true ones.) :func:`file_information` is the inverse conversion, for writing graphs built in
relmap.

**Exact round trips.** A rotation matrix computed from a quaternion does not give that quaternion
back bit for bit (nor does repeating matrix → quaternion → matrix settle), so a 3-D g2o graph
keeps the quaternions as written (:attr:`PoseGraph.vertex_quaternions`,
:attr:`PoseGraph.edge_quaternions`, sign flipped to ``qw ≥ 0``), and :func:`write_graph` writes
each one back wherever it still gives the pose's rotation bit for bit (else the rotation's own
quaternion): reading, writing and reading again gives identical arrays.

**Legacy 3-D** (``EDGE3``/``VERTEX3``, TORO, HOG-Man and iSAM; read only). ``R = Rz(yaw) Ry(pitch)
Rx(roll)`` (:func:`relmap.lie.so3.from_euler`). The 21 numbers are taken as the information of
the error of the pose parameters ``(x, y, z, roll, pitch, yaw)`` of z — the translation in frame
i, the Euler angles as written — which is iSAM's error (predicted minus measured parameter
vectors) and the chart g2o's own conversion of ``EDGE3`` files (``EdgeSE3Euler``) assumes; the
shared ``sphere2500_groundtruth.txt`` against ``sphere2500.g2o`` agrees (the noise whitens in
that chart). relmap's covariance is then :meth:`relmap.AT3.from_euler`'s:
``Σ = J I⁻¹ Jᵀ``, ``J = blkdiag(I₃, E(roll, pitch, yaw))`` with E the Euler-rate matrix (rank 2
at pitch = ±90°: such a covariance cannot describe every rotation error, and stays singular).
A file with ``EDGE3`` lines and no ``VERTEX3`` line at all (iSAM's own files create vertices
from edges) gets the vertices its edges name, in ascending id order, placed by composing the
measurements along a breadth-first spanning tree from the smallest id of each connected part
(at the identity): for a noise-free file such as ``sphere2500_groundtruth.txt`` these are the
true poses in the frame of vertex 0. The format is not written: its information is tied to the
Euler angles as written (their branch, their period, the pole), which a rotation matrix does
not keep. **Trap:** files that came from iSAM (``sphere2500``, city10000, Manhattan) hold
square-root information (1/σ) labelled information; the reader takes them as the format says.

Malformed input raises :class:`relmap.errors.FileFormatError` naming the file and the 1-based line.
"""

from __future__ import annotations

import functools
import os
import re
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import NamedTuple, TypeVar

import numpy as np
import numpy.typing as npt

from relmap import _core
from relmap.errors import (
    FileFormatError,
    ParameterError,
    RelmapError,
    ShapeError,
    UnknownFrameError,
)
from relmap.io import formats
from relmap.io._parsing import fail_at, frozen, strict_float
from relmap.io.atomic import write_text_atomic
from relmap.io.textfile import Input
from relmap.lie import se2, se3, so3
from relmap.lie.group import SE3, Group
from relmap.network.problem import compose_tree
from relmap.typing import ArrayLike, FloatArray, IntArray, Option
from relmap.uncertain import gaussian
from relmap.uncertain.at import AT
from relmap.uncertain.at3 import AT3
from relmap.uncertain.pose import UncertainPose

__all__ = [
    "QUATERNION_ATOL",
    "PoseGraph",
    "as_format",
    "file_information",
    "read_graph",
    "write_graph",
]


class GraphFormat(Option):
    """The text format of a pose graph: g2o (``VERTEX_SE2``/``EDGE_SE2``, ``VERTEX_SE3:QUAT``/
    ``EDGE_SE3:QUAT``, ``FIX``) or TORO (``VERTEX2``/``EDGE2``; the legacy 3-D ``VERTEX3``/
    ``EDGE3``, read only)."""

    G2O = "g2o"
    TORO = "toro"


#: Largest accepted ``| |q| - 1 |`` of a quaternion read from a file (see the module docstring).
QUATERNION_ATOL = 1e-3


class _Spec(NamedTuple):
    format: GraphFormat
    dim: int  # 2 or 3
    vertex: str
    edge: str
    fix: str | None
    pose_size: int  # numbers of a vertex's pose
    measurement_size: int  # numbers of an edge's measurement, before its information
    info_order: tuple[tuple[int, int], ...]  # (row, col) of each information number in the file
    vertex_fields: str
    edge_fields: str

    @property
    def dof(self) -> int:
        return 3 if self.dim == 2 else 6


_UPPER6 = tuple((r, c) for r in range(6) for c in range(r, 6))
_SPECS: dict[tuple[GraphFormat, int], _Spec] = {
    (GraphFormat.G2O, 2): _Spec(
        GraphFormat.G2O, 2, "VERTEX_SE2", "EDGE_SE2", "FIX", 3, 3,
        ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)),
        "id x y θ", "i j dx dy dθ and 6 information numbers",
    ),
    (GraphFormat.TORO, 2): _Spec(
        GraphFormat.TORO, 2, "VERTEX2", "EDGE2", None, 3, 3,
        ((0, 0), (0, 1), (1, 1), (2, 2), (0, 2), (1, 2)),
        "id x y θ", "i j dx dy dθ and 6 information numbers",
    ),
    (GraphFormat.G2O, 3): _Spec(
        GraphFormat.G2O, 3, "VERTEX_SE3:QUAT", "EDGE_SE3:QUAT", "FIX", 7, 7, _UPPER6,
        "id x y z qx qy qz qw", "i j x y z qx qy qz qw and 21 information numbers",
    ),
    (GraphFormat.TORO, 3): _Spec(
        GraphFormat.TORO, 3, "VERTEX3", "EDGE3", None, 6, 6, _UPPER6,
        "id x y z roll pitch yaw", "i j x y z roll pitch yaw and 21 information numbers",
    ),
}  # fmt: skip
#: Each tag's format and dimension (None: either dimension).
_KIND_OF_TAG: dict[str, tuple[GraphFormat, int | None]] = {
    "VERTEX_SE2": (GraphFormat.G2O, 2),
    "EDGE_SE2": (GraphFormat.G2O, 2),
    "FIX": (GraphFormat.G2O, None),
    "VERTEX_SE3:QUAT": (GraphFormat.G2O, 3),
    "EDGE_SE3:QUAT": (GraphFormat.G2O, 3),
    "VERTEX2": (GraphFormat.TORO, 2),
    "EDGE2": (GraphFormat.TORO, 2),
    "VERTEX3": (GraphFormat.TORO, 3),
    "EDGE3": (GraphFormat.TORO, 3),
}
_INT = re.compile(r"[+-]?[0-9]+")
# Rotation matrices handed to write_graph must be orthonormal to this (as relmap.AT3's input).
_ROTATION_ATOL = 1e-6


class PoseGraph(NamedTuple):
    """A 2-D or 3-D pose graph as read from a g2o or TORO file (immutable: arrays are read-only).

    Vertices are rows ``0..n-1`` in file order; edges refer to vertices by **id**, not row
    (:meth:`index_of`, :meth:`edge_indices` map ids to rows). :attr:`group` tells the dimension.
    """

    #: The file's :class:`GraphFormat` (``"g2o"`` or ``"toro"``), used again by
    #: :func:`write_graph` (with :attr:`group`: ``"toro"`` in 3-D is the legacy ``EDGE3``).
    format: GraphFormat
    #: ``(n,)`` int64 vertex ids, in file order.
    vertex_ids: IntArray
    #: Initial guess of each vertex in the world frame: ``(n, 3)`` float64 ``(x, y, θ)`` (θ
    #: wrapped) for 2-D graphs, ``(n, 4, 4)`` float64 homogeneous matrices for 3-D graphs.
    poses: FloatArray
    #: ``(m,)`` int64 id of each edge's vertex i (the measurement's parent frame).
    edge_from: IntArray
    #: ``(m,)`` int64 id of each edge's vertex j.
    edge_to: IntArray
    #: Batch ``(m,)`` :class:`relmap.AT` (2-D) or :class:`relmap.AT3` (3-D): mean = measured pose
    #: of j in frame i, covariance in relmap's chart in frame i (converted, see the module).
    measurements: AT | AT3
    #: ``(m, 3, 3)`` or ``(m, 6, 6)`` float64 information matrices exactly as written, in the
    #: file's own chart (2-D and g2o 3-D: g2o's error in the body frame of z, translation first;
    #: legacy 3-D: the ``(x, y, z, roll, pitch, yaw)`` parameters).
    information: FloatArray
    #: ``(k,)`` int64 ids given by ``FIX`` lines, in file order (always empty for TORO).
    fixed: IntArray
    #: g2o 3-D only (else None): ``(n, 4)`` vertex quaternions ``(qx, qy, qz, qw)`` as written,
    #: sign flipped to ``qw ≥ 0`` (not normalized); :attr:`poses` is computed from them, and
    #: :func:`write_graph` writes them back wherever they still give the pose's rotation exactly.
    vertex_quaternions: FloatArray | None = None
    #: g2o 3-D only (else None): ``(m, 4)`` measurement quaternions, as :attr:`vertex_quaternions`.
    edge_quaternions: FloatArray | None = None

    @property
    def group(self) -> Group:
        """The pose group: :data:`relmap.lie.SE2` for 2-D graphs, :data:`relmap.lie.SE3` for 3-D."""
        group: Group = self.measurements.group
        return group

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


def _group(path: Path, text: str) -> tuple[_Spec, dict[str, _Records]]:
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
    return _classify(path, {tag: group.lines[0] for tag, group in groups.items()}), groups


def _classify(path: Path, first_line: dict[str, int]) -> _Spec:
    """The format named by the first record's tag, given every tag's first line; raises for an
    unknown tag or for 2-D and 3-D records mixed."""
    if not first_line:
        raise FileFormatError(path, "no records: expected a g2o or TORO pose graph")
    first = sorted(first_line, key=first_line.__getitem__)
    kind = _KIND_OF_TAG.get(first[0])
    if kind is None:
        raise FileFormatError(
            path,
            f"unknown record tag {first[0]!r} (expected {', '.join(_KIND_OF_TAG)})",
            line=first_line[first[0]],
        )
    fmt = kind[0]
    # The dimension: that of the first record of this format that has one (2-D if none does).
    sized = [(t, k[1]) for t in first if (k := _KIND_OF_TAG.get(t)) and k[0] == fmt and k[1]]
    dim = sized[0][1] if sized else 2
    spec = _SPECS[(fmt, dim)]
    known = [t for t in (spec.vertex, spec.edge, spec.fix) if t is not None]
    unknown = [tag for tag in first if tag not in known]
    if unknown:
        tag = unknown[0]
        other = _KIND_OF_TAG.get(tag)
        if other is not None and other[0] == fmt:
            message = (
                f"mixed 2-D and 3-D records: {tag} is {other[1]}-D, but the file's first "
                f"{dim}-D record ({sized[0][0]}, line {first_line[sized[0][0]]}) makes it a "
                f"{dim}-D {fmt} pose graph"
            )
        else:
            what = f"3-D {fmt}" if dim == 3 else fmt
            message = f"unknown record tag {tag!r} in a {what} file (expected {', '.join(known)})"
        raise FileFormatError(path, message, line=first_line[tag])
    return spec


class _Table(NamedTuple):
    lines: Sequence[int]  # 1-based line numbers
    ids: IntArray  # (k, n_ids)
    values: FloatArray  # (k, n_values)


def _parse(
    path: Path, tag: str, records: _Records, n_ids: int, n_values: int, fields: str
) -> tuple[IntArray, FloatArray]:
    """``(ids (k, n_ids), values (k, n_values))`` of one tag's records, line by line: the plain
    path of :func:`_records`, which names the first line that does not parse."""
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
    if _INT.fullmatch(token) and len(token) <= 20 and -(2**63) <= int(token) < 2**63:
        return int(token)
    raise FileFormatError(path, f"{tag}: vertex id {token!r} is not a (64-bit) integer", line=line)


def _float(path: Path, tag: str, token: str, line: int) -> float:
    try:
        return strict_float(token)
    except ValueError:
        pass
    raise FileFormatError(path, f"{tag}: {token!r} is not a number", line=line)


def _assemble(values: FloatArray, order: tuple[tuple[int, int], ...], dof: int) -> FloatArray:
    """Symmetric ``(m, dof, dof)`` matrices from upper-triangle entries ``(m, k)`` in ``order``."""
    out = np.empty((len(values), dof, dof))
    for k, (r, c) in enumerate(order):
        out[:, r, c] = out[:, c, r] = values[:, k]
    return out


def _file_covariance(path: Path, tag: str, info: FloatArray, lines: Sequence[int]) -> FloatArray:
    """``I⁻¹`` for every edge (in the file's chart), after checking each ``I`` is positive
    definite (:func:`relmap.uncertain.gaussian.not_positive_definite`)."""
    bad = gaussian.not_positive_definite(info)
    if bad is not None:
        (k,), reason = bad
        raise FileFormatError(
            path, f"{tag} information matrix is not positive definite{reason}", line=lines[k]
        )
    return gaussian.inverse_pd(info)


_T = TypeVar("_T")


def _validated(
    path: Path, tag: str, lines: Sequence[int], build: Callable[[slice | int], _T]
) -> _T:
    """``build(all rows)``; if relmap rejects it, the line of the first row it rejects."""
    try:
        return build(slice(None))
    except RelmapError:
        pass
    for k, line in enumerate(lines):  # only on failure: find the edge to blame
        try:
            build(k)
        except RelmapError as exc:
            raise FileFormatError(
                path, f"{tag} information matrix cannot be inverted accurately: {exc}", line=line
            ) from None
    raise FileFormatError(path, f"{tag} measurements do not form valid ATs")  # pragma: no cover


def _quaternions(path: Path, tag: str, q: FloatArray, lines: Sequence[int]) -> FloatArray:
    """The quaternions ``(k, 4)`` as written, checked to be unit within
    :data:`QUATERNION_ATOL`, sign flipped so that ``qw ≥ 0``."""
    norm = np.linalg.norm(q, axis=-1)
    bad = np.flatnonzero(np.abs(norm - 1.0) > QUATERNION_ATOL)
    if bad.size:
        k = int(bad[0])
        raise FileFormatError(
            path,
            f"{tag} quaternion (qx, qy, qz, qw) has norm {norm[k]:.6g}, not 1 (tolerance "
            f"{QUATERNION_ATOL:g}): not a rotation",
            line=lines[k],
        )
    return np.where(q[:, 3:] < 0.0, -q, q) + 0.0  # + 0.0: no -0.0 (written as "-0.0")


def _rotations(q: FloatArray) -> FloatArray:
    """Rotation matrices of the (checked) quaternions, normalized: one function for reading and
    for :func:`write_graph`'s test that a kept quaternion still gives a rotation exactly."""
    return so3.from_quaternion(q, atol=np.inf)


def _g2o3_chart(R: FloatArray, rotation_scale: float = 2.0) -> FloatArray:
    """``K = blkdiag(R, 2R)`` (..., 6, 6): ``Σ = K I⁻¹ Kᵀ`` maps g2o's 3-D error covariance
    (translation, quaternion vector part; body frame of z) to relmap's chart (module docstring).
    ``_g2o3_chart(Rᵀ, 0.5)`` is its inverse."""
    K = np.zeros((*R.shape[:-2], 6, 6))
    K[..., :3, :3] = R
    K[..., 3:, 3:] = rotation_scale * R
    return K


#: The record tags, their ids and numbers per line (-1: FIX, any positive number of ids).
_TAGS = list(_KIND_OF_TAG)
_SHAPES = {"FIX": (-1, 0)}
for _spec in _SPECS.values():
    _SHAPES[_spec.vertex] = (1, _spec.pose_size)
    _SHAPES[_spec.edge] = (2, _spec.measurement_size + len(_spec.info_order))


def _records(p: Path, text: str) -> tuple[_Spec, _Table, _Table, IntArray, list[int]]:
    """The file's spec, its vertex and edge tables, the FIX ids and their lines.

    Read by relmap's compiled core (``relmap._core.scan_records``: one pass, no Python per
    line); a text it leaves to the plain path (a record that does not parse, whose error needs
    the line's own message, or a non-ASCII or control byte: Python's whitespace is wider) is
    read line by line in Python, which names the offending line."""
    shapes = [_SHAPES[t] for t in _TAGS]
    fast = _core.scan_records(text, _TAGS, [a for a, _ in shapes], [b for _, b in shapes])
    if fast is not None:
        first_line, tables = fast
        spec = _classify(p, first_line)
        table = dict(zip(_TAGS, tables, strict=True))
        vtx, edg = (
            _Table(ln.tolist(), *rest) for ln, *rest in (table[spec.vertex], table[spec.edge])
        )
        if spec.fix is None:  # TORO: no FIX records (_classify refuses them)
            return spec, vtx, edg, np.empty(0, np.int64), []
        fix_lines, fix_ids, _ = table[spec.fix]
        return spec, vtx, edg, fix_ids[:, 0], fix_lines.tolist()
    spec, groups = _group(p, text)
    empty = _Records([], [])
    records = groups.get(spec.vertex, empty)
    vtx = _Table(
        records.lines, *_parse(p, spec.vertex, records, 1, spec.pose_size, spec.vertex_fields)
    )
    records = groups.get(spec.edge, empty)
    n_edge_values = spec.measurement_size + len(spec.info_order)
    edg = _Table(records.lines, *_parse(p, spec.edge, records, 2, n_edge_values, spec.edge_fields))
    fixed: list[int] = []
    fixed_lines: list[int] = []
    for line, rest in zip(*groups.get(spec.fix or "", empty), strict=True):
        if not rest.split():
            raise FileFormatError(p, "FIX needs at least one vertex id", line=line)
        for tok in rest.split():
            fixed.append(_int(p, "FIX", tok, line))
            fixed_lines.append(line)
    return spec, vtx, edg, np.array(fixed, dtype=np.int64), fixed_lines


def read_graph(path: str | os.PathLike[str] | Input) -> PoseGraph:
    """Read a 2-D or 3-D pose graph in g2o or TORO format (recognised from the first record's
    tag).

    Returns a :class:`PoseGraph`: vertex poses in the world frame (``(x, y, θ)`` in 2-D,
    homogeneous matrices in 3-D), and for every edge i → j the measured pose of j in frame i
    with relmap's covariance (frame i; the file's information converted as the module docstring
    derives: ``Σ = M I⁻¹ Mᵀ``, ``M = blkdiag(R(θ_z), 1)`` in 2-D; ``Σ = K I⁻¹ Kᵀ``,
    ``K = blkdiag(R_z, 2 R_z)`` for g2o 3-D; Euler rates for ``EDGE3``). 2-D angles are wrapped to
    [-π, π). Raises :class:`relmap.errors.FileFormatError` (file and line) for an unknown tag,
    2-D and 3-D records mixed, a wrong number of fields, a non-number or non-integer id, a
    non-finite number, a quaternion that is not unit (:data:`QUATERNION_ATOL`), a duplicate
    vertex id, an edge or FIX naming a vertex with no vertex line (``EDGE3`` files without any
    ``VERTEX3`` line excepted, see the module docstring), or an information matrix that is not
    symmetric positive definite. The file is read once (a pipe, gzip, a BOM and CRLF are
    accepted: :func:`relmap.io.textfile.read_input`); a file in another format is refused naming
    it (:func:`relmap.io.formats.read`).
    """
    graph: PoseGraph = formats.read(path, (formats.Kind.GRAPH,))[1]
    return graph


def graph_from_text(p: Path, text: str) -> PoseGraph:
    """:func:`read_graph` of text already read from the file ``p`` (named in errors)."""
    spec, vtx, edg, fixed, fixed_lines = _records(p, text)
    vertex_ids, poses = vtx.ids[:, 0], vtx.values
    edge_ids, edge_values = edg.ids, edg.values

    for tag, values, lines in (
        (spec.vertex, poses, vtx.lines),
        (spec.edge, edge_values, edg.lines),
    ):
        bad = ~np.isfinite(values).all(axis=1)
        fail_at(p, bad, lines, f"non-finite number in a {tag} line (values must be finite)")

    # iSAM's EDGE3 files have no vertex lines: the edges name the vertices.
    implied = spec.edge == "EDGE3" and not len(vtx.lines) and bool(len(edg.lines))
    if implied:
        vertex_ids = np.unique(edge_ids)

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

    information = _assemble(edge_values[:, spec.measurement_size :], spec.info_order, spec.dof)
    cov_file = _file_covariance(p, spec.edge, information, edg.lines)
    z = edge_values[:, : spec.measurement_size].copy()
    measurements: AT | AT3
    vertex_quaternions = edge_quaternions = None
    if spec.dim == 2:
        z[:, 2] = se2.wrap_angle(z[:, 2])  # wrap before M(θ) is built: re-reading gives equal bits
        # AT.from_body without its check of the body covariance: cov_file is already the
        # symmetrized inverse of a checked information matrix (the same bits, one check fewer)
        M = se2.body_to_chart(z)
        cov = gaussian.congruence(M, cov_file)
        measurements = _validated(p, spec.edge, edg.lines, lambda k: AT(z[k], cov[k]))
        poses = poses.copy()
        poses[:, 2] = se2.wrap_angle(poses[:, 2])
    elif spec.format is GraphFormat.G2O:
        vertex_quaternions = _quaternions(p, spec.vertex, poses[:, 3:], vtx.lines)
        edge_quaternions = _quaternions(p, spec.edge, z[:, 3:], edg.lines)
        Rz = _rotations(edge_quaternions)
        Z = se3.from_parts(z[:, :3], Rz)
        cov = gaussian.congruence(_g2o3_chart(Rz), cov_file)
        measurements = _validated(
            p,
            spec.edge,
            edg.lines,
            lambda k: AT3._trusted(
                Z[k], gaussian.validate_covariance(cov[k], dim=6, name="covariance")
            ),
        )
        poses = se3.from_parts(poses[:, :3], _rotations(vertex_quaternions))
    else:  # EDGE3 / VERTEX3: the information is on (x, y, z, roll, pitch, yaw)
        measurements = _validated(
            p, spec.edge, edg.lines, lambda k: AT3.from_euler(z[k], cov_file[k])
        )
        if implied:
            i, j = (
                np.searchsorted(vertex_ids, edge_ids[:, 0]),
                np.searchsorted(vertex_ids, edge_ids[:, 1]),
            )
            poses = compose_tree(len(vertex_ids), i, j, np.asarray(measurements.mean), SE3)
        else:
            poses = se3.from_parts(poses[:, :3], so3.from_euler(poses[:, 3:]))
    return PoseGraph(
        format=spec.format,
        vertex_ids=frozen(vertex_ids),
        poses=frozen(poses),
        edge_from=frozen(edge_ids[:, 0]),
        edge_to=frozen(edge_ids[:, 1]),
        measurements=measurements,
        information=frozen(information),
        fixed=frozen(fixed),
        vertex_quaternions=None if vertex_quaternions is None else frozen(vertex_quaternions),
        edge_quaternions=None if edge_quaternions is None else frozen(edge_quaternions),
    )


# ----------------------------------------------------------------------------------- writing
def _check_rotations(R: FloatArray, name: str) -> None:
    """Rotation matrices ``(n, 3, 3)`` orthonormal to ``_ROTATION_ATOL`` with det +1."""
    if not len(R):
        return
    err = np.abs(np.swapaxes(R, -1, -2) @ R - np.eye(3)).max(axis=(-2, -1))
    det = np.linalg.det(R)
    bad = np.flatnonzero((err > _ROTATION_ATOL) | (det <= 0.0))
    if bad.size:
        k = int(bad[0])
        raise ParameterError(
            f"{name}[{k}] has no rotation matrix in its upper-left 3×3: |RᵀR - I| = "
            f"{err[k]:.3g}, det = {det[k]:.6g} (tolerance {_ROTATION_ATOL:g})"
        )


def _written_quaternions(R: FloatArray, kept: ArrayLike | None) -> FloatArray:
    """Quaternions to write for rotations R ``(k, 3, 3)``: the ones kept from the file where they
    still give R bit for bit, else R's own (``qw ≥ 0``)."""
    q = so3.to_quaternion(R) if len(R) else np.empty((0, 4))
    if kept is None or np.shape(kept) != q.shape or not len(R):
        return q
    kept = np.asarray(kept, dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        same = np.isfinite(kept).all(axis=1) & (_rotations(kept) == R).all(axis=(1, 2))
    return np.where(same[:, None], kept, q)


def write_graph(
    path: str | os.PathLike[str], graph: PoseGraph, poses: ArrayLike | None = None
) -> None:
    """Write ``graph`` in its own format (``graph.format`` and ``graph.group``), atomically.

    Vertices are written at ``poses`` (one per vertex in :attr:`PoseGraph.vertex_ids` order, in
    the world frame: ``(n, 3)`` ``(x, y, θ)`` for 2-D graphs, ``(n, 4, 4)`` homogeneous matrices
    for 3-D ones; default ``graph.poses``), then the g2o ``FIX`` lines, then the edges: each
    measurement mean and the information matrix exactly as stored, in the format's field order.
    3-D rotations are written as quaternions ``qx qy qz qw`` with ``qw ≥ 0``: the ones the graph
    kept from its file where they still give the rotation exactly, else the rotation's own.
    Numbers are written in their shortest round-trip decimal form (relmap's compiled core,
    ``std::to_chars``: ``1`` for 1.0), so reading the file back gives the same arrays bit for
    bit. The legacy 3-D ``EDGE3`` format is not written (:class:`ParameterError`;
    see the module docstring). Nothing is written if anything is invalid. The writer is the
    registered one of the graph's format (:mod:`relmap.io.formats`).
    """
    formats.writer(graph.format, formats.Kind.GRAPH)(path, graph, poses=poses)


def as_format(graph: PoseGraph, format: GraphFormat | None = None) -> PoseGraph:
    """``graph`` as :func:`write_graph` writes it in ``format`` (default: its own, or 3-D g2o
    for a graph read from the legacy ``EDGE3`` format, which is read only).

    2-D g2o and TORO hold the same information matrices (in another field order): only the
    format changes. A legacy 3-D graph written as g2o gets :func:`file_information` of its
    measurements (:class:`ParameterError` at once if a covariance has none) and no kept
    quaternions.
    """
    legacy = graph.group is SE3 and graph.format == GraphFormat.TORO
    target = format or (GraphFormat.G2O if legacy else graph.format)
    if legacy and target == GraphFormat.G2O:
        return graph._replace(
            format=GraphFormat.G2O,
            information=file_information(graph.measurements),
            vertex_quaternions=None,
            edge_quaternions=None,
        )
    return graph._replace(format=target)


def _write_as(
    format: GraphFormat,
    path: str | os.PathLike[str],
    graph: PoseGraph,
    poses: ArrayLike | None = None,
) -> None:
    """The writer registered for ``format``: :func:`write_graph` of :func:`as_format`."""
    _write(path, as_format(graph, format), poses)


def _write(path: str | os.PathLike[str], graph: PoseGraph, poses: ArrayLike | None) -> None:
    group = getattr(graph.measurements, "group", None)
    dim = 3 if group is SE3 else 2
    spec = _SPECS[(GraphFormat.parse(graph.format, "the pose graph's format"), dim)]
    if spec.edge == "EDGE3":
        raise ParameterError(
            "the legacy 3-D EDGE3/VERTEX3 format is read only: its information is tied to the "
            "Euler angles as written, which a rotation matrix does not keep; write 3-D graphs "
            "as g2o (format='g2o', with file_information(measurements) as information)"
        )
    ids = np.asarray(graph.vertex_ids)
    n = len(ids)
    pose_arr = np.asarray(graph.poses if poses is None else poses, dtype=np.float64)
    want_pose = (n, 3) if dim == 2 else (n, 4, 4)
    if pose_arr.shape != want_pose:
        what = "one (x, y, θ) row" if dim == 2 else "one homogeneous matrix"
        raise ShapeError(
            f"poses must have shape {want_pose}, {what} per vertex; got {pose_arr.shape}"
        )
    gaussian.check_finite(pose_arr, "poses")
    m = len(graph.edge_from)
    shapes = {
        "edge_to": (np.shape(graph.edge_to), (m,)),
        "measurements": (graph.measurements.batch_shape, (m,)),
        "information": (np.shape(graph.information), (m, spec.dof, spec.dof)),
    }
    for name, (got, want) in shapes.items():
        if got != want:
            raise ShapeError(f"graph.{name} must have shape {want} for {m} edges; got {got}")
    fixed = np.asarray(graph.fixed, dtype=np.int64).reshape(-1)
    if spec.fix is None and fixed.size:
        raise ParameterError(f"{graph.format} files cannot hold fixed vertices; graph.fixed is set")

    rows, cols = np.array(spec.info_order).T
    info = np.asarray(graph.information, dtype=np.float64)[:, rows, cols]
    mean = np.asarray(graph.measurements.mean, dtype=np.float64)
    if dim == 2:
        vertex_values = pose_arr
        edge_values = np.concatenate([mean, info], axis=1)
    else:
        _check_rotations(pose_arr[:, :3, :3], "poses")
        vq = _written_quaternions(pose_arr[:, :3, :3], graph.vertex_quaternions)
        eq = _written_quaternions(mean[:, :3, :3], graph.edge_quaternions)
        vertex_values = np.concatenate([pose_arr[:, :3, 3], vq], axis=1)
        edge_values = np.concatenate([mean[:, :3, 3], eq, info], axis=1)
    text = "".join(
        [
            _core.format_records(spec.vertex, _ids(ids), _values(vertex_values)),
            _core.format_records(spec.fix or "FIX", _ids(fixed), np.empty((len(fixed), 0))),
            _core.format_records(
                spec.edge,
                _ids(np.column_stack([graph.edge_from, graph.edge_to]), 2),
                _values(edge_values),
            ),
        ]
    )
    write_text_atomic(path, text)


def _ids(ids: ArrayLike, columns: int = 1) -> IntArray:
    arr = np.asarray(ids, dtype=np.int64)
    return np.ascontiguousarray(arr.reshape(len(arr), columns))


def _values(values: FloatArray) -> FloatArray:
    return np.ascontiguousarray(values, dtype=np.float64)


#: A pose group's body-frame chart (:meth:`~relmap.AT.to_body`) to its chart in g2o/TORO files:
#: 2-D ``(x, y, θ)`` as it is; 3-D g2o ``(translation, quaternion vector part)`` from
#: :meth:`relmap.AT3.to_body`'s ``(ω, v)`` (the quaternion's vector part is half the rotation),
#: so that ``body_to_file @ body_to_chartᵀ = blkdiag(R_zᵀ, ½ R_zᵀ) = K⁻¹``.
_BODY_TO_FILE = {
    "SE(2)": np.eye(3),
    "SE(3)": np.block([[np.zeros((3, 3)), np.eye(3)], [0.5 * np.eye(3), np.zeros((3, 3))]]),
}


def file_information(
    measurements: AT | AT3, format: GraphFormat | str = GraphFormat.G2O
) -> FloatArray:
    """The information matrices a file holds for ``measurements`` (batch ``(m,)``, or one):
    the inverse of :func:`read_graph`'s conversion, for writing graphs built in relmap.

    2-D (g2o and TORO alike): ``(M⁻¹ Σ M⁻ᵀ)⁻¹``, ``(..., 3, 3)``. 3-D g2o:
    ``(K⁻¹ Σ K⁻ᵀ)⁻¹`` with ``K = blkdiag(R_z, 2 R_z)``, ``(..., 6, 6)`` (translation block first,
    rotation on the quaternion's vector part). A covariance that is not positive definite has no
    information matrix: :class:`ParameterError` names the first. The legacy 3-D ``EDGE3`` format
    is read only (:class:`ParameterError`).
    """
    if not isinstance(measurements, UncertainPose):
        raise TypeError(f"expected an AT or AT3, got {type(measurements).__name__}")
    format = GraphFormat.parse(format, "format")
    if measurements.dim == 3 and format is not GraphFormat.G2O:
        raise ParameterError(
            f"3-D information can be written for format 'g2o' only; got {format.value!r} (the "
            "legacy EDGE3 format is read only)"
        )
    body_to_file = _BODY_TO_FILE[measurements.group.name]
    cov_file = gaussian.congruence(body_to_file, measurements.to_body())
    if not cov_file.size:
        return cov_file.copy()
    bad = gaussian.not_positive_definite(cov_file)
    if bad is not None:
        where, reason = bad
        raise ParameterError(
            f"measurement{list(where) if where else ''} has no information matrix: "
            f"its covariance is not positive definite{reason}"
        )
    return gaussian.inverse_pd(cov_file)


# ----------------------------------------------------------------------------------- the formats
#: A record's tag, as g2o and TORO write them (upper case, ``:`` inside: ``EDGE_SE3:QUAT``).
_TAG = re.compile(r"[A-Z][A-Z0-9_]*(?::[A-Z0-9_]+)*")
_TORO_TAGS = frozenset(tag for tag, (fmt, _) in _KIND_OF_TAG.items() if fmt is GraphFormat.TORO)


def _first_tag(head: formats.Head) -> str | None:
    tag = head.record.split(None, 1)[0] if head.record else ""
    return tag if _TAG.fullmatch(tag) else None


def _is_toro(head: formats.Head) -> bool:
    """TORO: the first record's tag is TORO's (``VERTEX2``, ``EDGE2``, ``VERTEX3``, ``EDGE3``)."""
    return _first_tag(head) in _TORO_TAGS


def _is_g2o(head: formats.Head) -> bool:
    """g2o, the fallback of tagged records: the first tag is not TORO's (g2o's own; a tag that
    no format claims is refused by the reader, naming it and its line)."""
    tag = _first_tag(head)
    return tag is not None and tag not in _TORO_TAGS


def _read(source: Input) -> PoseGraph:
    assert source.text is not None  # recognised from a text record
    return graph_from_text(source.path, source.text)


formats.register(
    formats.Format(
        GraphFormat.G2O,
        formats.Kind.GRAPH,
        "VERTEX_SE2/EDGE_SE2, VERTEX_SE3:QUAT/EDGE_SE3:QUAT, FIX records",
        _is_g2o,
        _read,
        functools.partial(_write_as, GraphFormat.G2O),
        fallback=True,
    )
)
formats.register(
    formats.Format(
        GraphFormat.TORO,
        formats.Kind.GRAPH,
        "VERTEX2/EDGE2 records; VERTEX3/EDGE3 read only",
        _is_toro,
        _read,
        functools.partial(_write_as, GraphFormat.TORO),
    )
)
