"""RelationalMap: a network of frames linked by named ATs (the paper's relational map, §5).

Frames are any hashable names. Each AT says where its destination frame is, seen from its
source frame. Parallel ATs between the same frames are allowed, and so are groups of dependent
ATs given with their joint covariance (§3.2: "a compound AT with nonzero covariance
submatrices can be given directly"). :meth:`RelationalMap.query` estimates the AT between any
two frames.

A map holds planar ATs (:class:`relmap.AT`) or 3-D ones (:class:`relmap.AT3`), not both: the
first AT added decides, and everything downstream (reduction, joint estimate, sensing) runs the
same code on that group.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Hashable, Iterable, Iterator, Mapping, Sequence
from types import MappingProxyType
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from relmap.errors import (
    ArgumentTypeError,
    DuplicateNameError,
    ParameterError,
    ShapeError,
    UnknownATError,
    UnknownFrameError,
)
from relmap.lie.group import Group
from relmap.network.parts import Edge, JointGroup
from relmap.typing import ArrayLike, FloatArray
from relmap.uncertain import gaussian
from relmap.uncertain.at import AT
from relmap.uncertain.at3 import AT3
from relmap.uncertain.pose import UncertainPose

if TYPE_CHECKING:
    from relmap.network.losses import LossChoice
    from relmap.network.optimal import Progress, Solution
    from relmap.network.query import Estimate, QueryMethod
    from relmap.network.sensing import SensingDecision, SensingForecast
    from relmap.uncertain.moments import MomentsMethod

__all__ = ["RelationalMap"]

Frame = Hashable


class Record(Protocol):
    """What :meth:`RelationalMap.from_records` reads of each record (e.g. a map file's
    :class:`relmap.io.ATRecord`): the AT's name, its two frames, the AT."""

    name: str
    src: Frame
    dst: Frame
    at: AT | AT3


class Graph(Protocol):
    """What :meth:`RelationalMap.from_posegraph` reads of a pose graph (e.g.
    :class:`relmap.io.PoseGraph`): vertex ids and their initial poses, edge ends by id, the
    batch of measured ATs, and the ids of ``FIX`` vertices."""

    vertex_ids: Any
    poses: Any
    edge_from: Any
    edge_to: Any
    measurements: AT | AT3
    fixed: Any


class RelationalMap:
    """A network of frames linked by named ATs.

    >>> import relmap as rm
    >>> g = rm.RelationalMap()
    >>> g.add("W", "L1", rm.AT.from_sigmas([1.0, 0.0, 0.1], [0.05, 0.05, 0.01]), name="A")
    'A'
    >>> g.add("L1", "L2", rm.AT.from_sigmas([1.0, 0.0, 0.1], [0.05, 0.05, 0.01]), name="B")
    'B'
    >>> g.query("W", "L2").expression
    'A ⊕ B'
    """

    def __init__(self) -> None:
        self._edges: dict[str, Edge] = {}
        self._incident: dict[Frame, dict[str, None]] = {}  # frame -> names (an ordered set)
        self._groups: dict[str, JointGroup] = {}
        self._guesses: dict[Frame, FloatArray] = {}
        self._auto = 0
        self._kind: type[AT] | type[AT3] | None = None  # fixed by the first AT
        self._anchor: Frame | None = None  # the frame a whole-map solve keeps fixed
        self._memo: dict[object, object] = {}  # results kept until the map changes

    def _changed(self) -> None:
        """Forget everything computed from the map (solved factors, block structure)."""
        self._memo.clear()

    def memo(self, key: object, build: Callable[[], Any]) -> Any:
        """The value ``build()`` computed for ``key`` on this map, kept until the map changes
        (an AT or a guess added or removed). Solves use it to keep their factorization."""
        try:
            return self._memo[key]
        except KeyError:
            value = self._memo[key] = build()
            return value

    def memos(self) -> Iterator[tuple[object, Any]]:
        """The kept ``(key, value)`` pairs (see :meth:`memo`)."""
        return iter(list(self._memo.items()))

    def __getstate__(self) -> dict[str, Any]:
        """A map pickles (to a Dask worker, say) without its kept results: a solved factor lives
        in the compiled core and is recomputed where it is needed."""
        state = self.__dict__.copy()
        state["_memo"] = {}
        return state

    @property
    def group(self) -> Group | None:
        """The map's pose group (:data:`relmap.lie.SE2` or :data:`~relmap.lie.SE3`); None while
        the map has never held an AT."""
        return None if self._kind is None else self._kind.group

    @property
    def at_type(self) -> type[AT] | type[AT3]:
        """:class:`relmap.AT` or :class:`relmap.AT3`: the kind the map holds (AT when empty)."""
        return AT if self._kind is None else self._kind

    def _accept(self, at: object) -> None:
        """Check that ``at`` is an AT of the map's kind (fixing the kind on the first one)."""
        if not isinstance(at, UncertainPose):
            raise ArgumentTypeError(f"expected an AT or AT3, got {type(at).__name__}")
        if self._kind is None:
            self._kind = type(at)
        elif type(at) is not self._kind:
            raise ArgumentTypeError(
                f"this map holds {self._kind.group} ATs ({self._kind.__name__}); "
                f"got a {type(at).__name__}"
            )

    # ----------------------------------------------------------------- building
    def add(self, src: Frame, dst: Frame, at: AT | AT3, name: str | None = None) -> str:
        """Add ``at`` (an :class:`AT`, or an :class:`AT3` in a 3-D map), the pose of frame
        ``dst`` seen from frame ``src``; return its name.

        Names are unique; without one, the AT is named ``e<k>``. New frames are created.
        """
        self._accept(at)
        if at.ndim:
            raise ShapeError(f"a map holds single ATs; got batch shape {at.batch_shape}")
        name = self._new_name(name)
        self._insert(Edge(name, src, dst, at))
        return name

    def add_joint(
        self,
        edges: Sequence[tuple[Frame, Frame, ArrayLike]],
        cov: ArrayLike,
        names: Sequence[str] | None = None,
        group: str | None = None,
    ) -> tuple[str, ...]:
        """Add k dependent ATs given as ``(src, dst, mean)`` with their joint covariance.

        Means are ``(x, y, θ)`` (planar, joint ``(3k, 3k)``) or, in a 3-D map, 4×4 matrices or
        ``[x, y, z, qx, qy, qz, qw]`` (joint ``(6k, 6k)``). Each AT's own covariance is its
        diagonal block; the off-diagonal blocks are the cross-covariances ``E[δAᵢ δAⱼᵀ]`` (each
        AT in its own source frame). Returns the names.
        """
        k = len(edges)
        if k < 2:
            raise ShapeError("a joint group needs at least two ATs")
        kind = self._kind or (AT3 if np.shape(edges[0][2]) in ((7,), (4, 4)) else AT)
        dof = kind.group.dof
        joint = gaussian.validate_covariance(cov, dim=dof * k, name="joint cov")
        if names is not None and len(names) != k:
            raise ShapeError(f"{len(names)} names given for {k} ATs")
        group = self._new_group_name(group)
        given = list(names) if names is not None else [None] * k
        new_names = []
        staged = []
        for i, ((src, dst, mean), nm) in enumerate(zip(edges, given, strict=True)):
            block = joint[dof * i : dof * (i + 1), dof * i : dof * (i + 1)]
            at = _make_at(kind, mean, block)
            new_name = self._new_name(nm, reserved=new_names)
            new_names.append(new_name)
            staged.append(Edge(new_name, src, dst, at, group))
        self._accept(staged[0].at)
        for edge in staged:
            self._insert(edge)
        self._groups[group] = JointGroup(group, tuple(new_names), joint)
        return tuple(new_names)

    def remove(self, name: str) -> Edge:
        """Remove the AT called ``name`` (and its whole dependent group, if it has one).

        Returns the removed edge. Frames left without ATs disappear.
        """
        edge = self.edge(name)
        self._changed()
        names = self._groups.pop(edge.group).names if edge.group else (name,)
        for nm in names:
            e = self._edges.pop(nm)
            for frame in (e.src, e.dst):
                inc = self._incident[frame]
                inc.pop(nm, None)
                if not inc:
                    del self._incident[frame]
        return edge

    @classmethod
    def from_records(cls, records: Iterable[Record]) -> RelationalMap:
        """A map from records with ``name, src, dst, at`` (:class:`Record`; e.g. a map file's,
        :func:`relmap.io.read_records`)."""
        g = cls()
        for r in records:
            g.add(r.src, r.dst, r.at, name=r.name)
        return g

    @classmethod
    def from_edges(
        cls,
        src: Sequence[Frame],
        dst: Sequence[Frame],
        ats: AT | AT3,
        names: Sequence[str] | None = None,
    ) -> RelationalMap:
        """A map from parallel sequences of source frames, destination frames and a batch of ATs
        (or AT3s)."""
        m = len(src)
        if len(dst) != m or ats.batch_shape != (m,):
            raise ShapeError(
                f"src ({m}), dst ({len(dst)}) and ats {ats.batch_shape} must have one entry per AT"
            )
        if ats.ndim != 1:
            raise ShapeError(f"ats must be a 1-D batch of ATs; got batch shape {ats.batch_shape}")
        g = cls()
        g._accept(ats)
        if names is None:  # a new map: the automatic names e0 … e(m-1) cannot collide
            names, g._auto = [f"e{k}" for k in range(m)], m
        else:
            names = [str(nm) for nm in names]
            if len(set(names)) < m:
                count = Counter(names)
                dup = next(nm for nm in names if count[nm] > 1)
                raise DuplicateNameError(f"an AT named {dup!r} is already in the map")
        edges = g._edges
        incident = g._incident
        for name, s, d, k in zip(names, src, dst, range(m), strict=True):
            edges[name] = Edge(name, s, d, ats, index=k)
            incident.setdefault(s, {})[name] = None
            incident.setdefault(d, {})[name] = None
        return g

    @classmethod
    def from_posegraph(cls, graph: Graph) -> RelationalMap:
        """A map from a pose graph (:class:`Graph`, e.g. :func:`relmap.io.read_graph`'s):
        vertex ids become frames, edges ATs named ``e0, e1, …`` in file order, the file's poses
        the initial guess of the optimal method, and its first ``FIX`` vertex (else its first
        vertex) the anchor of :meth:`solve`. Vertices without edges are kept as frames with no
        AT (:meth:`solve` names them)."""
        g = cls.from_edges(graph.edge_from.tolist(), graph.edge_to.tolist(), graph.measurements)
        ids = graph.vertex_ids.tolist()
        g._guesses = dict(zip(ids, graph.poses, strict=True))
        for f in ids:
            g._incident.setdefault(f, {})
        fixed = list(graph.fixed)
        g._anchor = int(fixed[0]) if fixed else (ids[0] if ids else None)
        return g

    def _new_name(self, name: str | None, reserved: Sequence[str] = ()) -> str:
        if name is None:
            while f"e{self._auto}" in self._edges or f"e{self._auto}" in reserved:
                self._auto += 1
            name = f"e{self._auto}"
            self._auto += 1
        name = str(name)
        if name in self._edges or name in reserved:
            raise DuplicateNameError(f"an AT named {name!r} is already in the map")
        return name

    def _new_group_name(self, group: str | None) -> str:
        if group is None:
            k = len(self._groups)
            while f"g{k}" in self._groups:
                k += 1
            return f"g{k}"
        if group in self._groups:
            raise DuplicateNameError(f"a group named {group!r} is already in the map")
        return group

    def _insert(self, edge: Edge) -> None:
        for end, frame in (("from", edge.src), ("to", edge.dst)):
            try:
                hash(frame)
            except TypeError:
                raise ParameterError(
                    f"AT {edge.name!r}: frames are hashable names (str, int, ...); its {end!r} "
                    f"frame is a {type(frame).__name__}"
                ) from None
        self._changed()
        self._edges[edge.name] = edge
        for frame in (edge.src, edge.dst):
            self._incident.setdefault(frame, {})[edge.name] = None

    # ---------------------------------------------------------------- inspecting
    @property
    def frames(self) -> list[Frame]:
        """All frames, in the order they first appeared."""
        return list(self._incident)

    @property
    def groups(self) -> list[JointGroup]:
        """The groups of dependent ATs."""
        return list(self._groups.values())

    def edges(self) -> Iterator[Edge]:
        """All ATs, in insertion order."""
        return iter(self._edges.values())

    def edge(self, name: str) -> Edge:
        """The AT called ``name``."""
        try:
            return self._edges[name]
        except KeyError:
            raise UnknownATError(f"no AT named {name!r} in the map") from None

    def incident(self, frame: Frame) -> list[Edge]:
        """The ATs that touch ``frame`` (as source or destination)."""
        self._check_frame(frame)
        return [self._edges[nm] for nm in self._incident[frame]]

    def neighbors(self, frame: Frame) -> list[Frame]:
        """Frames linked to ``frame`` by at least one AT (each once)."""
        out: dict[Frame, None] = {}
        for e in self.incident(frame):
            out[e.dst if e.src == frame else e.src] = None
        return list(out)

    def __len__(self) -> int:
        return len(self._edges)

    def __contains__(self, name: object) -> bool:
        return name in self._edges

    def __iter__(self) -> Iterator[Edge]:
        return self.edges()

    def __repr__(self) -> str:
        return f"RelationalMap({len(self._incident)} frames, {len(self._edges)} ATs)"

    def has_frame(self, frame: Frame) -> bool:
        """Whether ``frame`` is in the map."""
        return frame in self._incident

    def _check_frame(self, frame: Frame) -> None:
        if frame not in self._incident:
            raise UnknownFrameError(f"no frame {frame!r} in the map")

    def submap(self, frames: Iterable[Frame]) -> RelationalMap:
        """The map restricted to ``frames``: the ATs with both ends among them.

        A dependent group is kept only if all its ATs are kept.
        """
        keep = set(frames)
        for f in keep:
            self._check_frame(f)
        sub = RelationalMap()
        sub._auto = self._auto
        sub._kind = self._kind
        for e in self._edges.values():
            if e.src in keep and e.dst in keep:
                group = self._groups.get(e.group) if e.group else None
                if group and not all(
                    self._edges[n].src in keep and self._edges[n].dst in keep for n in group.names
                ):
                    continue
                sub._insert(e)
        for g in self._groups.values():
            if g.names[0] in sub._edges:
                sub._groups[g.name] = g
        return sub

    def copy(self) -> RelationalMap:
        """A shallow copy (ATs are immutable, so nothing is shared that can change)."""
        return self.submap(self.frames) if self._incident else RelationalMap()

    # ------------------------------------------------------- arrays for the solvers
    # The interface the solvers read (relmap.network.parts.MapView): at_type, frames, groups,
    # anchor, has_frame, edge, incidence, ends, order, arrays, guesses, memo, memos.
    def incidence(self) -> Mapping[Frame, Mapping[str, None]]:
        """Frame → the names of its ATs (an ordered set), read-only."""
        return MappingProxyType(self._incident)

    def ends(self) -> dict[str, tuple[Frame, Frame]]:
        """AT name → ``(src, dst)``, in insertion order (kept until the map changes)."""
        return self.memo("ends", lambda: {e.name: (e.src, e.dst) for e in self._edges.values()})

    def order(self) -> dict[str, int]:
        """AT name → its position in insertion order (kept until the map changes)."""
        return self.memo("order", lambda: {name: i for i, name in enumerate(self._edges)})

    @property
    def anchor(self) -> Frame | None:
        """The frame :meth:`solve` keeps fixed by default (a pose graph's first ``FIX``
        vertex, else its first vertex; else the map's first frame)."""
        if self._anchor is not None and self._anchor in self._incident:
            return self._anchor
        return next(iter(self._incident), None)

    def solve(
        self,
        anchor: Frame | None = None,
        *,
        progress: Progress | None = None,
        max_iterations: int = 100,
        rtol: float | None = None,
        loss: LossChoice = None,
    ) -> Solution:
        """The joint estimate of every frame (:func:`relmap.network.optimal.solve_map`);
        ``loss`` (:mod:`relmap.network.losses`, e.g. ``Huber(2.0)``, or ``{AT name: loss}``)
        makes it minimize ``Σ ρ(s²)`` of the ATs' normalized residuals, its weights on
        :attr:`Solution.weights`."""
        from relmap.network.optimal import solve_map

        return solve_map(
            self, anchor, progress=progress, max_iterations=max_iterations, rtol=rtol, loss=loss
        )

    def arrays(self, names: Sequence[str]) -> tuple[FloatArray, FloatArray]:
        """Means ``(k, *point)`` and covariances ``(k, dof, dof)`` of the named ATs, gathered
        per source batch."""
        k = len(names)
        group = self.at_type.group
        edges = [self._edges[nm] for nm in names]
        if k and all(e._source is edges[0]._source and e._index is not None for e in edges):
            rows = np.array([e._index for e in edges], dtype=np.int64)  # one batch (a file)
            source = edges[0]._source
            return np.ascontiguousarray(source.mean[rows]), np.ascontiguousarray(source.cov[rows])
        mean, cov = np.empty((k, *group.point_shape)), np.empty((k, group.dof, group.dof))
        by_source: dict[int, tuple[AT | AT3, list[int], list[int]]] = {}
        for pos, e in enumerate(edges):
            if e._index is None:
                mean[pos], cov[pos] = e._source.mean, e._source.cov
            else:
                entry = by_source.setdefault(id(e._source), (e._source, [], []))
                entry[1].append(pos)
                entry[2].append(e._index)
        for source, positions, rows in by_source.values():
            mean[positions] = source.mean[rows]
            cov[positions] = source.cov[rows]
        return mean, cov

    def guesses(self, frames: Sequence[Frame]) -> FloatArray | None:
        """Initial poses of the frames in one common frame, if the map has one for each."""
        if not self._guesses or any(f not in self._guesses for f in frames):
            return None
        return np.array([self._guesses[f] for f in frames])

    def set_guess(self, frame: Frame, pose: ArrayLike) -> None:
        """Give an initial pose of ``frame`` (in any frame common to all guesses) for the
        optimal method: ``(x, y, θ)``, or in a 3-D map a 4×4 matrix or ``[x, y, z, qx, qy,
        qz, qw]``. Pose-graph files come with one for every frame."""
        self._check_frame(frame)
        arr = np.asarray(pose, dtype=np.float64)
        gaussian.check_finite(arr, "guess")
        if self.at_type.dim == 3:
            if arr.shape == (7,):
                arr = AT3.from_vector(arr).matrix
            elif arr.shape == (4, 4):
                arr = AT3.from_matrix(arr).matrix
            else:
                raise ShapeError(
                    "a 3-D guess is a 4×4 matrix or [x, y, z, qx, qy, qz, qw]; "
                    f"got shape {arr.shape}"
                )
        elif arr.shape != (3,):
            raise ShapeError(f"a guess is one pose (x, y, θ); got shape {arr.shape}")
        self._changed()
        self._guesses[frame] = arr

    # --------------------------------------------------------------- sensing (§6.2)
    def sense(
        self, src: Frame, dst: Frame, reading: AT | AT3, **options: object
    ) -> SensingDecision:
        """Predict, check and test a sensed AT from ``src`` to ``dst``, and add it if it passes
        (:func:`relmap.network.sensing.sense`)."""
        from relmap.network.sensing import sense

        return sense(self, src, dst, reading, **options)  # type: ignore[arg-type]

    def forecast_sensing(
        self,
        sensed: tuple[Frame, Frame],
        sensor_cov: ArrayLike,
        of_interest: tuple[Frame, Frame],
        *,
        method: QueryMethod | str = "auto",
    ) -> SensingForecast:
        """The relation ``of_interest`` before and after a proposed sensing of ``sensed``
        (:func:`relmap.network.sensing.forecast_sensing`); the map is not changed."""
        from relmap.network.sensing import forecast_sensing

        return forecast_sensing(self, sensed, sensor_cov, of_interest, method=method)

    # ------------------------------------------------------------------- query
    def query(
        self,
        src: Frame,
        dst: Frame,
        method: QueryMethod | str = "auto",
        *,
        moments: MomentsMethod | str = "first_order",
        diagnose: bool = False,
        **options: object,
    ) -> Estimate:
        """The AT of frame ``dst`` seen from frame ``src`` (:func:`relmap.network.query.query`).

        ``method`` is a :class:`~relmap.network.query.QueryMethod` (``"auto"``, ``"reduce"``,
        ``"optimal"``); ``moments`` (a :class:`~relmap.uncertain.moments.MomentsMethod`:
        ``"first_order"``, ``"exact"``, ``"unscented"``; SE(2), reduction) sets
        how the reduction compounds; ``diagnose=True`` adds the predicted error of the
        first-order answer as ``Estimate.linearization``.
        """
        from relmap.network.query import query

        return query(
            self,
            src,
            dst,
            method=method,
            moments=moments,
            diagnose=diagnose,
            **options,  # type: ignore[arg-type]
        )

    def query_many(
        self,
        pairs: Iterable[tuple[Frame, Frame]],
        method: QueryMethod | str = "auto",
        **options: object,
    ) -> list[Estimate]:
        """:meth:`query` for each ``(src, dst)`` pair. Joint solves are kept on the map (until
        it changes), so pairs within one solved part of the network cost one solve in all."""
        return [self.query(src, dst, method, **options) for src, dst in pairs]  # type: ignore[arg-type]


def _make_at(kind: type[AT] | type[AT3], mean: ArrayLike, cov: FloatArray) -> AT | AT3:
    """An AT of ``kind`` from a mean as users give it: ``(x, y, θ)``, or for AT3 a 4×4 matrix
    or ``[x, y, z, qx, qy, qz, qw]``."""
    if kind.dim == 2:
        return AT(mean, cov)
    m = np.asarray(mean, dtype=np.float64)
    return AT3.from_matrix(m, cov) if m.shape[-2:] == (4, 4) else AT3.from_vector(m, cov)
