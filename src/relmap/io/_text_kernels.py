"""numba kernels that read the records of a large pose-graph file in one pass over its bytes
(:func:`relmap.io.read_graph`'s fast path; the general path is the reference and the fallback).

They accept a strict subset of what the general path does, and report anything else as a
failure, so the general path then reads the file and names any error: printable ASCII only;
fields separated by spaces, tabs, vertical tabs or form feeds; integers ``[+-]?[0-9]{1,18}``;
decimal numbers ``[+-]?(digits[.digits]|.digits)([eE][+-]?digits)?``. A number whose digits fit
in 2⁵³ and whose decimal exponent is within ±22 is converted exactly as ``float()`` converts it
(Clinger's fast path: one correctly rounded IEEE operation on two exact operands); any other
number is left to ``float()`` (its position is returned).
"""

from __future__ import annotations

import numba
import numpy as np

from relmap.typing import FloatArray, IntArray

__all__ = ["records", "tags"]

_NEWLINE, _HASH = 10, 35
_MAX_TAGS = 16
_POW10 = np.array([10.0**k for k in range(23)])  # exact doubles: 10**k < 2**53·2**k for k ≤ 22
_EXACT = 2**53


@numba.njit(cache=True, inline="always")
def _blank(c: int) -> bool:  # pragma: no cover
    return c == 32 or c == 9 or c == 11 or c == 12  # space, tab, vertical tab, form feed


@numba.njit(cache=True)
def tags(buf: np.ndarray) -> tuple[IntArray, IntArray, IntArray, int]:  # pragma: no cover
    """The distinct record tags in order of first appearance: their byte spans (start, end),
    the 1-based line of their first record, and the number of lines; ``(…, -1)`` when the file
    has a byte the kernels do not take, or more than 16 distinct tags."""
    start = np.empty(_MAX_TAGS, np.int64)
    end = np.empty(_MAX_TAGS, np.int64)
    first = np.empty(_MAX_TAGS, np.int64)
    k = 0
    line = 1
    i = 0
    size = len(buf)
    while i <= size:
        while i < size and _blank(buf[i]):
            i += 1
        if i < size and buf[i] != _NEWLINE and buf[i] != _HASH:
            s = i
            while i < size and buf[i] != _NEWLINE and not _blank(buf[i]):
                if buf[i] < 32 or buf[i] > 126:
                    return start[:k], end[:k], first[:k], -1
                i += 1
            found = False
            for t in range(k):
                if end[t] - start[t] == i - s:
                    same = True
                    for q in range(i - s):
                        if buf[start[t] + q] != buf[s + q]:
                            same = False
                            break
                    if same:
                        found = True
                        break
            if not found:
                if k == _MAX_TAGS:
                    return start[:k], end[:k], first[:k], -1
                start[k], end[k], first[k] = s, i, line
                k += 1
        while i < size and buf[i] != _NEWLINE:  # the rest of the line: only checked here
            c = buf[i]
            if (c < 32 and not _blank(c)) or c > 126:
                return start[:k], end[:k], first[:k], -1
            i += 1
        i += 1
        line += 1
    return start[:k], end[:k], first[:k], line - 1


@numba.njit(cache=True)
def _number(buf: np.ndarray, i: int, j: int) -> tuple[float, int]:  # pragma: no cover
    """The decimal number in ``buf[i:j]``: (value, 0) when converted here, (0, 1) when it is a
    number for ``float()`` to convert, (0, 2) when it is not a number the kernels take."""
    neg = False
    if buf[i] == 43 or buf[i] == 45:  # + -
        neg = buf[i] == 45
        i += 1
    mantissa = 0
    digits = 0  # significant digits kept in the mantissa
    exp10 = 0
    seen = 0  # digits seen in the mantissa's text
    overflow = False
    while i < j and 48 <= buf[i] <= 57:
        d = buf[i] - 48
        if mantissa or d:
            if digits < 18:  # 18 digits fit in an int64
                mantissa = mantissa * 10 + d
                digits += 1
            else:
                overflow = True
                exp10 += 1
        seen += 1
        i += 1
    if i < j and buf[i] == 46:  # .
        i += 1
        while i < j and 48 <= buf[i] <= 57:
            d = buf[i] - 48
            if mantissa or d:
                if digits < 18:
                    mantissa = mantissa * 10 + d
                    digits += 1
                    exp10 -= 1
                else:
                    overflow = True
            else:
                exp10 -= 1
            seen += 1
            i += 1
    if seen == 0:
        return 0.0, 2
    if i < j and (buf[i] == 101 or buf[i] == 69):  # e E
        i += 1
        eneg = False
        if i < j and (buf[i] == 43 or buf[i] == 45):
            eneg = buf[i] == 45
            i += 1
        if i == j:
            return 0.0, 2
        e = 0
        while i < j and 48 <= buf[i] <= 57:
            if e < 100_000:
                e = e * 10 + buf[i] - 48
            i += 1
        exp10 += -e if eneg else e
    if i != j:
        return 0.0, 2
    if mantissa == 0:
        return (-0.0 if neg else 0.0), 0
    if overflow or mantissa >= _EXACT or exp10 > 22 or exp10 < -22:
        return 0.0, 1
    value = float(mantissa)
    value = value * _POW10[exp10] if exp10 >= 0 else value / _POW10[-exp10]
    return (-value if neg else value), 0


@numba.njit(cache=True)
def records(
    buf: np.ndarray, tag: np.ndarray, n_ids: int, n_values: int, n_lines: int
) -> tuple[IntArray, IntArray, FloatArray, IntArray, int]:  # pragma: no cover
    """The records tagged ``tag`` (bytes): their 1-based lines (k,), integer ids (k, n_ids),
    numbers (k, n_values), the numbers left to ``float()`` as rows (record, field, start, end),
    and -1 — or, at the first record the kernels do not take (a field count or a field they do
    not read), its index."""
    lines = np.empty(n_lines, np.int64)
    ids = np.empty((n_lines, n_ids), np.int64)
    values = np.empty((n_lines, n_values))
    slow = np.empty((16, 4), np.int64)
    n_slow = 0
    k = 0
    line = 1
    i = 0
    size = len(buf)
    width = len(tag)
    while i < size:
        while i < size and _blank(buf[i]):
            i += 1
        s = i
        while i < size and buf[i] != _NEWLINE and not _blank(buf[i]):
            i += 1
        match = i - s == width
        if match:
            for q in range(width):
                if buf[s + q] != tag[q]:
                    match = False
                    break
        if match:
            field = 0
            while True:
                while i < size and _blank(buf[i]):
                    i += 1
                if i >= size or buf[i] == _NEWLINE:
                    break
                s = i
                while i < size and buf[i] != _NEWLINE and not _blank(buf[i]):
                    i += 1
                if field >= n_ids + n_values:
                    return lines[:k], ids[:k], values[:k], slow[:n_slow], k
                if field < n_ids:
                    neg = buf[s] == 45
                    p = s + 1 if buf[s] == 43 or buf[s] == 45 else s
                    if p == i or i - p > 18:
                        return lines[:k], ids[:k], values[:k], slow[:n_slow], k
                    v = 0
                    for q in range(p, i):
                        d = buf[q] - 48
                        if d < 0 or d > 9:
                            return lines[:k], ids[:k], values[:k], slow[:n_slow], k
                        v = v * 10 + d
                    ids[k, field] = -v if neg else v
                else:
                    x, status = _number(buf, s, i)
                    if status == 2:
                        return lines[:k], ids[:k], values[:k], slow[:n_slow], k
                    if status == 1:
                        if n_slow == len(slow):
                            grown = np.empty((2 * len(slow), 4), np.int64)
                            grown[:n_slow] = slow
                            slow = grown
                        slow[n_slow, 0], slow[n_slow, 1] = k, field - n_ids
                        slow[n_slow, 2], slow[n_slow, 3] = s, i
                        n_slow += 1
                    values[k, field - n_ids] = x
                field += 1
            if field != n_ids + n_values:
                return lines[:k], ids[:k], values[:k], slow[:n_slow], k
            lines[k] = line
            k += 1
        while i < size and buf[i] != _NEWLINE:
            i += 1
        i += 1
        line += 1
    return lines[:k], ids[:k], values[:k], slow[:n_slow], -1
