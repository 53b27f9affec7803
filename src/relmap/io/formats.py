"""The format registry: every file format relmap reads or writes — relational maps, pose graphs
and trajectories — registered once, with its name, how to recognise it, its reader and its writer.
Every entry point (:func:`relmap.io.load_map`, :func:`relmap.io.read_graph`,
:func:`relmap.io.trajectory.read_trajectory`, ``relmap query``, ``eval`` …) reads through it.

**Recognition never consumes a stream.** An input is read once
(:func:`relmap.io.textfile.read_input`: a pipe front to back; a folder, or a binary file such as a
ROS bag, no further than its first bytes); each format's ``recognise`` looks at its :class:`Head`
only — the first bytes as stored and the first record of the text (the first line that is neither
blank nor a ``#`` comment) — and the same :class:`~relmap.io.textfile.Input` goes on to the
reader. Recognisers do not overlap: an input that two formats claim is an error (a bug of a
registration), so the order of registration never decides. A *fallback* format claims only what
no other format claims (g2o: any file of tagged records, so that its reader names a tag it does
not know, and its line).

**Adding a format**: a reader ``read(source: Input, **options)`` returning what the format
``holds`` (a list of :class:`relmap.io.ATRecord` for ``"map"``, a :class:`relmap.io.PoseGraph` for
``"graph"``, a :class:`relmap.uncertain.trajectory.Trajectory` for ``"trajectory"``), optionally a
writer ``write(path, obj, **options)`` (atomic: :mod:`relmap.io.atomic`), a ``recognise(head)``,
and one call of :func:`register` in the module that defines them (imported by :mod:`relmap.io`).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import Any, NamedTuple

from relmap.errors import FileFormatError, ParameterError
from relmap.io.textfile import Input, read_input
from relmap.typing import Option

__all__ = [
    "Format",
    "Head",
    "Kind",
    "format_of",
    "formats",
    "get",
    "read",
    "recognise",
    "register",
    "writer",
]


class Kind(Option):
    """What a format holds (what its reader returns)."""

    MAP = "map"
    GRAPH = "graph"
    TRAJECTORY = "trajectory"


#: Each kind's name in messages, singular and plural.
_WORDS: dict[Kind, tuple[str, str]] = {
    Kind.MAP: ("map", "maps"),
    Kind.GRAPH: ("pose graph", "pose graphs"),
    Kind.TRAJECTORY: ("trajectory", "trajectories"),
}


class Head(NamedTuple):
    """What a format is recognised from: never more than the start of the input."""

    path: Path
    #: Whether the input is a folder.
    folder: bool
    #: The first bytes as stored (:data:`relmap.io.textfile.HEAD_BYTES` at most; empty for a
    #: folder).
    magic: bytes
    #: The first record: the first line of the text that is neither blank nor a ``#`` comment,
    #: stripped; empty for a folder, binary content or a text without records.
    record: str
    #: The record's 1-based line (0 when there is none).
    line: int


class Format(NamedTuple):
    """One file format (module docstring)."""

    #: Its name (``"g2o"``, ``"tum"`` …): unique, the name ``write_trajectory(format=…)`` and
    #: ``relmap convert --format`` take.
    name: str
    #: What its reader returns.
    holds: Kind
    #: A few words for lists and errors (what the file looks like).
    about: str
    #: ``recognise(head) -> bool``: whether an input is in this format.
    recognise: Callable[[Head], bool]
    #: ``read(source, **options)``: the content of an input (an :class:`Input`).
    read: Callable[..., Any]
    #: ``write(path, obj, **options)``, atomically; None for a format relmap reads only.
    write: Callable[..., None] | None = None
    #: The reader's keyword options beyond the input (a ROS bag's ``topic``).
    options: tuple[str, ...] = ()
    #: Whether it claims an input only when no other format does (module docstring).
    fallback: bool = False


_REGISTRY: dict[str, Format] = {}


def register(fmt: Format) -> Format:
    """Add ``fmt`` to the registry (once per name; :class:`ParameterError` otherwise)."""
    if fmt.name in _REGISTRY:
        raise ParameterError(f"a format named {fmt.name!r} is registered already")
    _REGISTRY[fmt.name] = fmt
    return fmt


def formats(*kinds: Kind, writable: bool = False) -> tuple[Format, ...]:
    """The registered formats that hold one of ``kinds`` (all when none is given), by kind in
    that order, then by name; with ``writable``, only those relmap writes."""
    order = kinds or tuple(_WORDS)
    return tuple(
        sorted(
            (f for f in _REGISTRY.values() if f.holds in order and (f.write or not writable)),
            key=lambda f: (order.index(f.holds), f.name),
        )
    )


def _names(found: tuple[Format, ...]) -> str:
    return ", ".join(f.name for f in found)


def get(name: str, *kinds: Kind, writable: bool = False) -> Format:
    """The format called ``name`` (holding one of ``kinds``, written by relmap if ``writable``);
    :class:`ParameterError` listing the formats that would do."""
    known = formats(*kinds, writable=writable)
    fmt = _REGISTRY.get(name)
    if fmt is not None and fmt in known:
        return fmt
    word = " or ".join(_WORDS[k][1] for k in kinds) or "files"
    verb = "writes" if writable else "reads"
    what = "an unknown format" if fmt is None else f"not a format relmap {verb} {word} as"
    raise ParameterError(f"{name!r} is {what}: relmap {verb} {word} as {_names(known)}")


def writer(name: str, *kinds: Kind) -> Callable[..., None]:
    """The writer of the format called ``name`` (:func:`get` with ``writable``)."""
    write = get(name, *kinds, writable=True).write
    assert write is not None  # get checked it
    return write


def _first_record(text: str | None) -> tuple[str, int]:
    """The first line that is neither blank nor a ``#`` comment, stripped, and its number."""
    if text is None:
        return "", 0
    start, number = 0, 1
    while start <= len(text):
        end = text.find("\n", start)
        end = len(text) if end < 0 else end
        line = text[start:end].strip()
        if line and not line.startswith("#"):
            return line, number
        start, number = end + 1, number + 1
    return "", 0


def _head(source: Input) -> Head:
    record, line = _first_record(source.text)
    return Head(source.path, source.folder, source.head, record, line)


def recognise(source: str | os.PathLike[str] | Input) -> Format | None:
    """The format of an input (a path is read once, :func:`relmap.io.textfile.read_input`), or
    None when no format claims it; :class:`FileFormatError` when two do (two fallbacks, or two
    others)."""
    source = read_input(source)
    head = _head(source)
    claims = [f for f in _REGISTRY.values() if f.recognise(head)]
    found = tuple(f for f in claims if not f.fallback) or tuple(claims)
    if len(found) > 1:
        raise FileFormatError(source.path, f"ambiguous: recognised as {_names(found)}")
    return found[0] if found else None


def _refuse(source: Input, kinds: tuple[Kind, ...]) -> FileFormatError:
    """The error for an input that no format claims: what it is, and what relmap reads."""
    head = _head(source)
    known = f"relmap reads {_WORDS[kinds[0]][1]} from {_names(formats(*kinds))}"
    if source.folder:
        return FileFormatError(source.path, f"cannot read: it is a directory; {known}")
    if source.text is None:
        return FileFormatError(source.path, f"binary content in no format relmap knows; {known}")
    if not head.record:
        return FileFormatError(source.path, f"no records (only blank lines and comments); {known}")
    shown = head.record if len(head.record) <= 40 else head.record[:40] + "…"
    return FileFormatError(
        source.path, f"unknown format (first record {shown!r}); {known}", line=head.line
    )


def format_of(source: str | os.PathLike[str] | Input, kinds: tuple[Kind, ...]) -> Format:
    """The format of an input (a path is read once) that holds one of ``kinds`` (the first is
    what the caller wants, named in errors); :class:`FileFormatError` naming the file (and the
    line of its first record) and listing the formats that would do, for an input of no known
    format or of a format that holds something else."""
    source = read_input(source)
    fmt = recognise(source)
    if fmt is None:
        raise _refuse(source, kinds)
    if fmt.holds not in kinds:
        want, wants = _WORDS[kinds[0]]
        raise FileFormatError(
            source.path,
            f"a {fmt.name} file ({fmt.about}) holds a {_WORDS[fmt.holds][0]}, not a {want}; "
            f"relmap reads {wants} from {_names(formats(*kinds))}",
        )
    return fmt


def read(
    source: str | os.PathLike[str] | Input, kinds: tuple[Kind, ...], **options: Any
) -> tuple[Format, Any]:
    """Read an input (a path is read once) in its format (:func:`format_of`): ``(the format,
    what its reader returns)``. ``options`` go to the reader; one that the format does not take
    is a :class:`ParameterError`."""
    source = read_input(source)
    fmt = format_of(source, kinds)
    unknown = sorted(set(options) - set(fmt.options))
    if unknown:
        takes = _names(tuple(f for f in _REGISTRY.values() if unknown[0] in f.options))
        raise ParameterError(
            f"the option {unknown[0]!r} is for {takes or 'no'} files; {source.path} is a "
            f"{fmt.name} file"
        )
    return fmt, fmt.read(source, **options)
