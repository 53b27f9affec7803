"""The parts of a relational map and the interface its solvers read.

:class:`Edge` (one named AT between two frames) and :class:`JointGroup` (dependent ATs with
their joint covariance) are what a :class:`relmap.RelationalMap` holds. :class:`MapView` is the
small stated interface through which the solvers (:mod:`relmap.network.query`,
:mod:`relmap.network.optimal`, :mod:`relmap.network.sensing`) read a map, and
:class:`EditableMap` adds what sensing needs to change one. The solvers know these protocols
only, never :mod:`relmap.network.graph`: the map sits above its solvers and its methods
(``query``, ``solve``, ``sense``, ``forecast_sensing``) forward to them, so no import circle
joins the two (docs/architecture.md).
"""

from __future__ import annotations

from collections.abc import Callable, Hashable, Iterator, Mapping, Sequence
from typing import Any, NamedTuple, Protocol

from relmap.typing import FloatArray
from relmap.uncertain.at import AT
from relmap.uncertain.at3 import AT3

__all__ = ["Edge", "EditableMap", "JointGroup", "MapView"]

Frame = Hashable


class Edge:
    """One AT of a map: ``at`` is where frame ``dst`` is, seen from frame ``src``.

    ``group`` names the dependent group the AT belongs to, if any. An edge of a map built from
    a batch (a pose-graph file) keeps a reference into the batch and makes its AT on first use.
    """

    __slots__ = ("_at", "_index", "_source", "dst", "group", "name", "src")

    def __init__(
        self,
        name: str,
        src: Frame,
        dst: Frame,
        at: AT | AT3,
        group: str | None = None,
        index: int | None = None,
    ) -> None:
        self.name, self.src, self.dst, self.group = name, src, dst, group
        self._source, self._index = at, index  # index: position in a batched source AT
        self._at: AT | AT3 | None = at if index is None else None

    @property
    def at(self) -> AT | AT3:
        """The AT (a single one)."""
        if self._at is None:
            source = self._source
            self._at = type(source)._trusted(source.mean[self._index], source.cov[self._index])
        return self._at

    def __repr__(self) -> str:
        return f"Edge({self.name!r}: {self.src!r} → {self.dst!r}, {self.at!r})"


class JointGroup(NamedTuple):
    """Dependent ATs with their joint covariance ``(dof·k, dof·k)`` (blocks in ``names`` order)."""

    name: str
    names: tuple[str, ...]
    cov: FloatArray


class MapView(Protocol):
    """What the solvers read of a map (:class:`relmap.RelationalMap` is one)."""

    @property
    def at_type(self) -> type[AT] | type[AT3]:
        """The kind of AT the map holds."""

    @property
    def frames(self) -> list[Frame]:
        """All frames, in the order they first appeared."""

    @property
    def groups(self) -> list[JointGroup]:
        """The groups of dependent ATs."""

    @property
    def anchor(self) -> Frame | None:
        """The frame a whole-map solve keeps fixed by default."""

    def has_frame(self, frame: Frame) -> bool:
        """Whether ``frame`` is in the map."""

    def edge(self, name: str) -> Edge:
        """The AT called ``name``."""

    def incidence(self) -> Mapping[Frame, Mapping[str, None]]:
        """Frame → the names of its ATs (an ordered set)."""

    def ends(self) -> dict[str, tuple[Frame, Frame]]:
        """AT name → ``(src, dst)``, in insertion order."""

    def order(self) -> dict[str, int]:
        """AT name → its position in insertion order."""

    def arrays(self, names: Sequence[str]) -> tuple[FloatArray, FloatArray]:
        """Means ``(k, *point)`` and covariances ``(k, dof, dof)`` of the named ATs."""

    def guesses(self, frames: Sequence[Frame]) -> FloatArray | None:
        """Initial poses of the frames in one common frame, if the map has one for each."""

    def memo(self, key: object, build: Callable[[], Any]) -> Any:
        """``build()``'s value for ``key``, kept until the map changes."""

    def memos(self) -> Iterator[tuple[object, Any]]:
        """The kept ``(key, value)`` pairs."""


class EditableMap(MapView, Protocol):
    """A :class:`MapView` that sensing can copy and add a reading to."""

    def __contains__(self, name: object) -> bool:
        """Whether an AT is called ``name``."""

    def add(self, src: Frame, dst: Frame, at: AT | AT3, name: str | None = None) -> str:
        """Add ``at`` (frame ``dst`` seen from frame ``src``); return its name."""

    def copy(self) -> EditableMap:
        """A copy that can change without changing this map."""
