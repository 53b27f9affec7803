"""The numba kernels that read large pose-graph files (relmap.io._text_kernels) against
Python's ``float()`` and the general reader (RELMAP_NUMBA=0)."""

from __future__ import annotations

import math
import struct
from pathlib import Path

import numpy as np
import pytest
from hypothesis import example, given
from hypothesis import strategies as st

from relmap import _numba
from relmap.io import posegraph, read_graph

pytestmark = pytest.mark.skipif(
    not _numba.enabled(), reason="numba kernels off (RELMAP_NUMBA=0) or numba missing"
)


def _number(text: str) -> tuple[float, int]:
    from relmap.io import _text_kernels

    buf = np.frombuffer(text.encode("ascii"), dtype=np.uint8)
    return _text_kernels._number(buf, 0, len(buf))


def _bits(x: float) -> bytes:
    return struct.pack("<d", x)


digits = st.text("0123456789", min_size=0, max_size=24)


@st.composite
def decimal_texts(draw: st.DrawFn) -> str:
    sign = draw(st.sampled_from(["", "-", "+"]))
    whole, frac = draw(digits), draw(digits)
    dot = draw(st.booleans())
    mantissa = whole + ("." + frac if dot else "")
    if draw(st.booleans()):
        mantissa += draw(st.sampled_from("eE")) + draw(st.sampled_from(["", "-", "+"]))
        mantissa += str(draw(st.integers(0, 400)))
    return sign + mantissa


@given(decimal_texts())
@example("0.1")
@example("-0.0")
@example("1e22")
@example("1e23")
@example("9007199254740993")  # 2⁵³ + 1: not exact, left to float()
@example("123456789012345678901234")
@example("1e-400")
@example("4.9e-324")
def test_numbers_convert_exactly_as_float_does(text):
    value, status = _number(text)
    try:
        expected = float(text)
    except ValueError:
        assert status == 2
        return
    assert status in (0, 1)
    if status == 0:
        assert _bits(value) == _bits(expected), (text, value, expected)


@given(
    st.floats(allow_nan=False, allow_infinity=False), st.sampled_from(["{!r}", "{:.6g}", "{:e}"])
)
def test_numbers_written_by_python_read_back(x, form):
    text = form.format(x)
    value, status = _number(text)
    assert status in (0, 1)
    if status == 0:
        assert _bits(value) == _bits(float(text))


@pytest.mark.parametrize(
    "text", ["nan", "inf", "-inf", "1_0", "0x10", "1.2.3", "e5", ".", "-", "1e", "1e+"]
)
def test_what_float_would_take_or_is_no_number_is_left_to_the_general_path(text):
    assert _number(text)[1] == 2


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "g.g2o"
    path.write_text(text)
    return path


def _same(a, b) -> None:
    for name in ("vertex_ids", "poses", "edge_from", "edge_to", "information"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    np.testing.assert_array_equal(a.measurements.mean, b.measurements.mean)
    np.testing.assert_array_equal(a.measurements.cov, b.measurements.cov)


def _random_g2o(rng: np.random.Generator, n: int, fmt: str) -> str:
    lines = [
        f"VERTEX_SE2 {k} " + " ".join(fmt.format(v) for v in rng.normal(size=3).tolist())
        for k in range(n)
    ]
    for k in range(n - 1):
        z = rng.normal(size=3).tolist()
        lines.append(
            f"EDGE_SE2 {k} {k + 1} "
            + " ".join(fmt.format(v) for v in z)
            + " "
            + " ".join(fmt.format(v) for v in (2.0, 0.1, 0.0, 3.0, 0.2, 5.0))
        )
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("fmt", ["{!r}", "{:.6f}", "{:.9e}"])
def test_the_kernels_read_what_the_general_path_reads(tmp_path, monkeypatch, fmt):
    path = _write(tmp_path, _random_g2o(np.random.default_rng(3), 50, fmt))
    monkeypatch.setattr(_numba, "LARGE", 0)
    assert posegraph._read_fast(path, path.read_text()) is not None  # the kernels took it
    fast = read_graph(path)
    monkeypatch.setenv("RELMAP_NUMBA", "0")
    _same(read_graph(path), fast)


@pytest.mark.parametrize(
    "extra",
    [
        "FIX 0\n",  # FIX records: the general path
        "# a comment naming a café\n",  # not ASCII
        "VERTEX_SE2 99 nan 0 0\n",  # not a number the kernels take
        "VERTEX_SE2 99 0 0\n",  # a field short
        "VERTEX_SE2 1e2 0 0 0\n",  # not an integer the kernels take
        "".join(f"TAG{k} 1\n" for k in range(17)),  # more distinct tags than the kernels keep
    ],
)
def test_what_the_kernels_do_not_take_goes_to_the_general_path(tmp_path, monkeypatch, extra):
    path = _write(tmp_path, _random_g2o(np.random.default_rng(4), 5, "{!r}") + extra)
    monkeypatch.setattr(_numba, "LARGE", 0)
    text = path.read_text()
    if extra.startswith("TAG"):
        from relmap.io import _text_kernels

        assert _text_kernels.tags(np.frombuffer(text.encode(), dtype=np.uint8))[3] == -1
    else:
        assert posegraph._read_fast(path, text) is None
    fast = _outcome(path)
    monkeypatch.setenv("RELMAP_NUMBA", "0")
    general = _outcome(path)
    if isinstance(general, str):
        assert fast == general
    else:
        _same(general, fast)


def _outcome(path: Path) -> object:
    """The graph read, or the error raised (type and message)."""
    try:
        return read_graph(path)
    except Exception as exc:
        return f"{type(exc).__name__}: {exc}"


def test_real_files_are_read_identically(data_dir, monkeypatch):
    monkeypatch.setattr(_numba, "LARGE", 0)
    for path in sorted((data_dir / "posegraph2d").glob("*.g2o")) + sorted(
        (data_dir / "posegraph3d").glob("*.g2o")
    ):
        text = path.read_text()
        assert posegraph._read_fast(path, text) is not None, path.name
        fast = read_graph(path)
        with monkeypatch.context() as m:
            m.setenv("RELMAP_NUMBA", "0")
            general = read_graph(path)
        _same(general, fast)
        assert math.isfinite(float(np.sum(fast.poses)))
