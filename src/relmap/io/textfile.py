"""How every relmap reader gets the text of an input file.

:func:`read_input` reads an input once for the format registry (:mod:`relmap.io.formats`: maps,
pose graphs, trajectories), :func:`read_text` a file of a known format (dataset tables, a times
file); both take the same inputs alike:

- a regular file, or a pipe, FIFO or process substitution (``relmap query <(zcat g.g2o.gz)``),
  read once, front to back;
- gzip-compressed content (recognised by its magic bytes, whatever the name), decompressed;
- UTF-8, with or without a byte-order mark (dropped);
- line ends LF or CRLF (CRLF becomes LF). A line ends at LF only, as for ``grep -n`` and editors,
  so a stray CR never shifts the line numbers of later errors (it is white space inside a line).

Everything else is a :class:`relmap.errors.FileFormatError` naming the file (and, for bytes that
are not UTF-8, the line): a missing file, a directory (to :func:`read_text`), no permission, a name
too long, corrupt gzip data.

:func:`read_input` also takes a folder, and leaves binary content (a NUL byte among the first
:data:`HEAD_BYTES`, as git and grep tell binary files) unread beyond those first bytes: a folder or
a binary file (a ROS bag) is read by its format's reader, from its path.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import NamedTuple

from relmap.errors import FileFormatError

__all__ = ["HEAD_BYTES", "Input", "read_input", "read_text"]

#: How many first bytes of an input tell binary content and its magic number.
HEAD_BYTES = 4096
_GZIP_MAGIC = b"\x1f\x8b"
_BOM = b"\xef\xbb\xbf"


class Input(NamedTuple):
    """An input read once (:func:`read_input`): what a format is recognised from and read from."""

    #: The path as given (named in errors; a pipe's is ``/dev/fd/N``).
    path: Path
    #: The text (gzip undone, BOM dropped, CRLF → LF); None for a folder or binary content.
    text: str | None
    #: The first :data:`HEAD_BYTES` bytes as stored (gzip not undone); empty for a folder.
    head: bytes
    #: Whether the path is a folder (nothing of it is read).
    folder: bool = False


def _read_bytes(path: Path, *, stop_if_binary: bool = False) -> tuple[bytes, bool]:
    """The bytes of ``path``, and whether they are all of them: with ``stop_if_binary``, only
    the first :data:`HEAD_BYTES` when they hold a NUL byte and no gzip magic."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(HEAD_BYTES)
            if stop_if_binary and head[:2] != _GZIP_MAGIC and b"\0" in head:
                return head, False
            return head + fh.read(), True
    except FileNotFoundError:
        raise FileFormatError(path, "cannot read: no such file") from None
    except IsADirectoryError:
        raise FileFormatError(path, "cannot read: it is a directory, not a file") from None
    except OSError as exc:
        raise FileFormatError(path, f"cannot read: {exc.strerror or exc}") from None
    except ValueError as exc:  # a NUL byte in the name
        raise FileFormatError(repr(str(path)), f"cannot read: {exc}") from None


def _gunzip(path: Path, data: bytes) -> bytes:
    import gzip
    import zlib

    try:
        return gzip.decompress(data)
    except (OSError, EOFError, zlib.error) as exc:
        raise FileFormatError(path, f"corrupt gzip data: {exc}") from None


def read_input(path: str | os.PathLike[str] | Input) -> Input:
    """``path`` read once (an :class:`Input` is returned as it is): a folder is not read, binary
    content is read no further than its first :data:`HEAD_BYTES`, text is read whole and decoded
    as :func:`read_text` does (with its errors)."""
    if isinstance(path, Input):
        return path
    p = Path(path)
    try:
        if p.is_dir():
            return Input(p, None, b"", folder=True)
    except (OSError, ValueError):  # a name too long or holding a NUL byte: said by the read
        pass
    data, whole = _read_bytes(p, stop_if_binary=True)
    head = data[:HEAD_BYTES]
    return Input(p, _decode(p, data) if whole else None, head)


def read_text(path: str | os.PathLike[str]) -> str:
    """The text of ``path`` as the module docstring says (gzip undone, BOM dropped, CRLF → LF).

    Raises :class:`relmap.errors.FileFormatError` naming the file (and the line of the first
    byte that is not UTF-8).
    """
    p = Path(path)
    return _decode(p, _read_bytes(p)[0])


def _decode(p: Path, data: bytes) -> str:
    if data[:2] == _GZIP_MAGIC:
        data = _gunzip(p, data)
    if data.startswith(_BOM):
        data = data[len(_BOM) :]
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        column = exc.start - (data.rfind(b"\n", 0, exc.start) + 1) + 1
        raise FileFormatError(
            p,
            f"not UTF-8 text: byte 0x{data[exc.start]:02x} at column {column} ({exc.reason})",
            line=line,
        ) from None
    if "\r" in text:
        text = text.replace("\r\n", "\n")
    return text
