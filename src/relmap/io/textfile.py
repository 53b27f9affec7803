"""How every relmap reader gets the text of an input file.

One function, :func:`read_text`, used by the pose-graph, map-file and dataset readers, so they
all take the same inputs alike:

- a regular file, or a pipe, FIFO or process substitution (``relmap query <(zcat g.g2o.gz)``),
  read once, front to back;
- gzip-compressed content (recognised by its magic bytes, whatever the name), decompressed;
- UTF-8, with or without a byte-order mark (dropped);
- line ends LF or CRLF (CRLF becomes LF). A line ends at LF only, as for ``grep -n`` and editors,
  so a stray CR never shifts the line numbers of later errors (it is white space inside a line).

Everything else is a :class:`relmap.errors.FileFormatError` naming the file (and, for bytes that
are not UTF-8, the line): a missing file, a directory, no permission, a name too long, corrupt
gzip data.
"""

from __future__ import annotations

import os
from pathlib import Path

from relmap.errors import FileFormatError

__all__ = ["read_text"]

_GZIP_MAGIC = b"\x1f\x8b"
_BOM = b"\xef\xbb\xbf"


def _read_bytes(path: Path) -> bytes:
    try:
        with open(path, "rb") as fh:
            return fh.read()
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


def read_text(path: str | os.PathLike[str]) -> str:
    """The text of ``path`` as the module docstring says (gzip undone, BOM dropped, CRLF → LF).

    Raises :class:`relmap.errors.FileFormatError` naming the file (and the line of the first
    byte that is not UTF-8).
    """
    p = Path(path)
    data = _read_bytes(p)
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
