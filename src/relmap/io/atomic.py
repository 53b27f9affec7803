"""The one writer of every output relmap makes (graphs, map files, PNGs, the report's files).

A regular file is written **atomically**: a temporary file in the same folder, flushed to disk,
then renamed over the target, so a reader never sees a half-written file and a failure leaves
none. What is at the path is respected:

- a new file gets the mode the umask gives any new file (``0o666 & ~umask``);
- an existing regular file keeps its mode, owner and group (copied onto the new inode); one with
  several hard links is written in place instead, so that every link sees the new content;
- a symbolic link is followed: its target is written, the link stays;
- a special file (character or block device, FIFO) is written in place, never replaced;
- a directory, a missing folder, a read-only folder or file system, a name too long: an
  :class:`relmap.errors.OutputError` naming the path and the reason.

:func:`check_writable` makes those checks **before** any work, so that a command fails at once
rather than after minutes of computation; the writers check again as they write.
"""

from __future__ import annotations

import contextlib
import os
import stat
import tempfile
from pathlib import Path

from relmap.errors import OutputError

__all__ = [
    "check_writable",
    "check_writable_folder",
    "make_folder",
    "write_bytes_atomic",
    "write_text_atomic",
]


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _resolve(path: str | os.PathLike[str]) -> Path:
    """The path with every symbolic link followed (a dangling link: the file it names)."""
    try:
        return Path(os.path.realpath(os.fspath(path)))
    except (OSError, ValueError) as exc:  # a loop of links, a NUL byte
        raise OutputError(path, f"cannot write: {getattr(exc, 'strerror', None) or exc}") from None


def _stat(target: Path) -> os.stat_result | None:
    try:
        return target.stat()
    except (FileNotFoundError, NotADirectoryError):  # (a file where a folder should be)
        return None
    except OSError as exc:
        raise OutputError(target, f"cannot write: {exc.strerror}") from None


def _probe_folder(folder: Path, shown: object) -> None:
    """Raise unless a new file can be made in ``folder`` (by making and removing one)."""
    st = _stat(folder)
    if st is None:
        raise OutputError(shown, f"cannot write: the folder {folder} does not exist")
    if not stat.S_ISDIR(st.st_mode):
        raise OutputError(shown, f"cannot write: {folder} is not a folder")
    try:
        fd, tmp = tempfile.mkstemp(dir=folder, prefix=".relmap-probe.", suffix=".tmp")
    except OSError as exc:
        raise OutputError(shown, f"cannot write into the folder {folder}: {exc.strerror}") from None
    os.close(fd)
    with contextlib.suppress(OSError):
        os.unlink(tmp)


def _check_name(path: str | os.PathLike[str]) -> None:
    text = os.fspath(path)
    if not text:
        raise OutputError(path, "cannot write: empty file name")
    if "\0" in text:
        raise OutputError(repr(text), "cannot write: the file name holds a NUL byte")
    try:
        limit = os.pathconf(Path(text).parent if Path(text).parent.is_dir() else ".", "PC_NAME_MAX")
    except (OSError, ValueError):
        limit = 255
    for part in Path(text).parts:
        if len(os.fsencode(part)) > limit:
            raise OutputError(
                path, f"cannot write: file name too long ({len(part)} characters, at most {limit})"
            )


def check_writable(path: str | os.PathLike[str]) -> Path:
    """Check, before any work, that a file can be written at ``path``; return the path written
    (symbolic links followed). Raises :class:`relmap.errors.OutputError` naming ``path`` and the
    reason: a directory, a missing or read-only folder, a read-only special file, a name too long.
    """
    _check_name(path)
    target = _resolve(path)
    st = _stat(target)
    if st is not None and stat.S_ISDIR(st.st_mode):
        raise OutputError(path, "cannot write: it is a directory")
    if st is not None and not stat.S_ISREG(st.st_mode):
        if not os.access(target, os.W_OK):
            raise OutputError(path, "cannot write: permission denied")
        return target
    if st is not None and st.st_nlink > 1:
        if not os.access(target, os.W_OK):
            raise OutputError(path, "cannot write: permission denied")
        return target
    _probe_folder(target.parent, path)
    return target


def check_writable_folder(folder: str | os.PathLike[str]) -> Path:
    """Check, before any work, that files can be written into ``folder`` (created when written,
    with its missing parents); return it resolved. Raises :class:`relmap.errors.OutputError`."""
    _check_name(folder)
    target = _resolve(folder)
    existing = target
    while _stat(existing) is None and existing != existing.parent:
        existing = existing.parent
    st = _stat(existing)
    if st is not None and not stat.S_ISDIR(st.st_mode):
        raise OutputError(folder, f"cannot write a folder there: {existing} is not a folder")
    _probe_folder(existing, folder)
    return target


def make_folder(folder: str | os.PathLike[str]) -> Path:
    """Create ``folder`` (and its parents) if needed, after :func:`check_writable_folder`."""
    target = check_writable_folder(folder)
    try:
        target.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(folder, f"cannot create the folder: {exc.strerror}") from None
    return target


def write_bytes_atomic(path: str | os.PathLike[str], data: bytes) -> None:
    """Write ``data`` to ``path`` as the module docstring says (atomically for a regular file)."""
    target = check_writable(path)
    st = _stat(target)
    try:
        if st is not None and (not stat.S_ISREG(st.st_mode) or st.st_nlink > 1):
            _write_in_place(target, data, truncate=stat.S_ISREG(st.st_mode))
        else:
            _write_replacing(target, data, st)
    except OSError as exc:
        if isinstance(exc, OutputError):
            raise
        raise OutputError(path, f"cannot write: {exc.strerror or exc}") from None


def write_text_atomic(path: str | os.PathLike[str], text: str) -> None:
    """Write ``text`` (UTF-8) to ``path``: :func:`write_bytes_atomic`."""
    write_bytes_atomic(path, text.encode("utf-8"))


def _write_in_place(target: Path, data: bytes, *, truncate: bool) -> None:
    """A device, a FIFO or a multiply linked file: open it and write, never replace it."""
    flags = os.O_WRONLY | (os.O_TRUNC if truncate else 0)
    fd = os.open(target, flags)
    with os.fdopen(fd, "wb") as fh:
        fh.write(data)


def _write_replacing(target: Path, data: bytes, st: os.stat_result | None) -> None:
    fd, tmp = tempfile.mkstemp(dir=target.parent, prefix=f".{target.name[:200]}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
            if st is None:
                os.fchmod(fh.fileno(), 0o666 & ~_umask())
            else:
                if (st.st_uid, st.st_gid) != (os.geteuid(), os.getegid()):
                    with contextlib.suppress(OSError):  # allowed for root, and for a group of ours
                        os.fchown(fh.fileno(), st.st_uid, st.st_gid)
                os.fchmod(fh.fileno(), stat.S_IMODE(st.st_mode))
        os.replace(tmp, target)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
