"""Mutation fuzzing of relmap's readers: valid files, mutated at random, must be read or refused
with a :class:`relmap.errors.RelmapError` (a FileFormatError naming the file), never another
exception type. Used by ``tests/io/test_fuzz.py`` (fixed seed; ``RELMAP_FUZZ_COUNT`` sets how
many inputs).
"""

from __future__ import annotations

import gzip
import shutil
import tempfile
import traceback
from collections import Counter
from collections.abc import Callable
from pathlib import Path

import numpy as np

from relmap.errors import RelmapError

G2O_2D = (
    "# a small g2o graph\n"
    "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1.0 0.1 0.05\nVERTEX_SE2 2 2.0 0.2 0.1\n"
    "VERTEX_SE2 3 2.9 1.0 1.5\nFIX 0\n"
    "EDGE_SE2 0 1 1.0 0.1 0.05 500 0 0 500 0 5000\n"
    "EDGE_SE2 1 2 1.0 0.1 0.05 500 10 0 500 0 5000\n"
    "EDGE_SE2 2 3 0.9 0.8 1.4 400 0 1 400 0 4000\n"
    "EDGE_SE2 0 3 2.9 1.0 1.5 100 0 0 100 0 1000\n"
)
TORO_2D = (
    "VERTEX2 0 0 0 0\nVERTEX2 1 1.0 0 0\nVERTEX2 2 2.0 0 0\n"
    "EDGE2 0 1 1.0 0 0 500 0 500 5000 0 0\nEDGE2 1 2 1.0 0 0 500 0 500 5000 0 0\n"
)
_INFO6 = " ".join("100" if r == c else "0" for r in range(6) for c in range(r, 6))
G2O_3D = (
    "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nVERTEX_SE3:QUAT 1 1 0 0 0 0 0.0998 0.995\n"
    "VERTEX_SE3:QUAT 2 2 0.1 0 0 0 0.198 0.980\n"
    f"EDGE_SE3:QUAT 0 1 1 0 0 0 0 0.0998 0.995 {_INFO6}\n"
    f"EDGE_SE3:QUAT 1 2 1 0.1 0 0 0 0.0998 0.995 {_INFO6}\n"
)
TORO_3D = f"VERTEX3 0 0 0 0 0 0 0\nVERTEX3 1 1 0 0 0 0 0.2\nEDGE3 0 1 1 0 0 0 0 0.2 {_INFO6}\n"
MAP_YAML = (
    "relmap: 1\ndescription: fuzz\nangle_unit: deg\nats:\n"
    "  - {name: A, from: W, to: L1, mean: [2.0, 0.5, 60.0], sigma: [0.06, 0.04, 2.0]}\n"
    "  - name: S\n    from: L1\n    to: W\n    mean: [0.52, -1.60, 44.0]\n"
    "    cov: [[9e-4, 0, 0], [0, 9e-4, 0], [0, 0, 1.0]]\n"
)
MAP_JSON = (
    '{"relmap": 1, "angle_unit": "rad", "ats": [\n'
    ' {"name": "A", "from": "W", "to": 1, "mean": [2.0, 0.5, 1.0, 0, 0, 0, 1],'
    ' "sigma": [0.06, 0.04, 0.02, 0.01, 0.01, 0.01]},\n'
    ' {"name": "B", "from": 1, "to": 2, "mean": [1, 0, 0, 0, 0, 0, 1],\n'
    '  "cov": [[1e-2,0,0,0,0,0],[0,1e-2,0,0,0,0],[0,0,1e-2,0,0,0],'
    "[0,0,0,1e-3,0,0],[0,0,0,0,1e-3,0],[0,0,0,0,0,1e-3]]}\n]}\n"
)

# Tokens that readers meet in the wild or that break naive parsers.
_TOKENS = [
    "nan", "NaN", "inf", "-inf", "1e999", "-1e999", "1e308", "1e-320", "0x10", "1_000", "+",
    "-", ".", "e5", "9" * 400, "9" * 5000, "-0", "0", "1", "-1", "2.5", "true", "null", "[]",
    "{}", "[", "]", "{", "}", ":", ",", '"', "'", "#", "&a", "*a", "!!python/object:os.system",
    "<<: *a", "\t", "\r", "\r\n", "\x00", "\ufeff", "\u00e9", "VERTEX_SE2", "EDGE_SE2",
    "VERTEX3", "EDGE_SE3:QUAT", "FIX", "ats:", "mean:", "cov:", "relmap:", "  - ", "\n",
]  # fmt: skip


def mutate(data: bytes, rng: np.random.Generator) -> bytes:
    """One to three random edits of ``data``: byte flips, token insertions or replacements,
    deleted, repeated or swapped lines, truncation, a BOM, CRLF, random bytes, deep nesting."""
    for _ in range(int(rng.integers(1, 4))):
        kind = int(rng.integers(0, 12))
        n = len(data)
        pos = int(rng.integers(0, n + 1)) if n else 0
        if kind == 0 and n:
            b = bytearray(data)
            b[min(pos, n - 1)] = int(rng.integers(0, 256))
            data = bytes(b)
        elif kind in (1, 2):
            tok = _TOKENS[int(rng.integers(len(_TOKENS)))].encode("utf-8")
            sep = b" " if kind == 1 else b""
            data = data[:pos] + sep + tok + sep + data[pos:]
        elif kind == 3:  # replace a whitespace-separated token
            parts = data.split(b" ")
            k = int(rng.integers(len(parts)))
            parts[k] = _TOKENS[int(rng.integers(len(_TOKENS)))].encode("utf-8")
            data = b" ".join(parts)
        elif kind == 4:
            lines = data.split(b"\n")
            del lines[int(rng.integers(len(lines)))]
            data = b"\n".join(lines)
        elif kind == 5:
            lines = data.split(b"\n")
            k = int(rng.integers(len(lines)))
            lines.insert(k, lines[k])
            data = b"\n".join(lines)
        elif kind == 6:
            lines = data.split(b"\n")
            i, j = rng.integers(len(lines), size=2)
            lines[i], lines[j] = lines[j], lines[i]
            data = b"\n".join(lines)
        elif kind == 7:
            data = data[:pos]
        elif kind == 8:
            data = b"\xef\xbb\xbf" + data if rng.random() < 0.5 else data.replace(b"\n", b"\r\n")
        elif kind == 9:
            data = data[:pos] + rng.bytes(int(rng.integers(1, 16))) + data[pos:]
        elif kind == 10:
            depth = int(rng.choice([10, 1000, 20_000]))
            data = data[:pos] + b"[" * depth + b"]" * depth + data[pos:]
        else:
            data = b""
    return data


class Outcome(Counter):  # type: ignore[type-arg]
    """Counts of ``read``, ``refused`` (a RelmapError) and unexpected exception types."""

    def __init__(self) -> None:
        super().__init__()
        self.examples: dict[str, str] = {}

    @property
    def unexpected(self) -> int:
        return sum(v for k, v in self.items() if k not in ("read", "refused"))


def run(read: Callable[[], object], data: bytes, outcome: Outcome) -> None:
    """Call ``read()`` (on a file holding ``data``) and count what happened."""
    try:
        read()
    except RelmapError:
        outcome["refused"] += 1
    except Exception as exc:  # the finding: any other type is a bug
        name = type(exc).__name__
        outcome[name] += 1
        outcome.examples.setdefault(name, f"{data[:300]!r}\n{traceback.format_exc()}")
    else:
        outcome["read"] += 1


def fuzz_text_reader(
    reader: Callable[[Path], object], base: str, suffix: str, count: int, seed: int
) -> Outcome:
    """``count`` mutations of ``base`` read by ``reader`` (some gzip-compressed)."""
    rng = np.random.default_rng(seed)
    outcome = Outcome()
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(count):
            data = mutate(base.encode("utf-8"), rng)
            if k % 10 == 9:
                data = gzip.compress(data)
            path = Path(tmp) / f"f{suffix}"
            path.write_bytes(data)
            run(lambda: reader(path), data, outcome)  # noqa: B023 - called at once
    return outcome


def mrclam_folder(folder: Path) -> Path:
    """A small valid MRCLAM folder (5 robots, 2 landmarks)."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "Barcodes.dat").write_text(
        "# subject barcode\n" + "".join(f"{s} {s + 10}\n" for s in range(1, 8))
    )
    (folder / "Landmark_Groundtruth.dat").write_text(
        "# subject x y σx σy\n6 1.0 1.0 0.01 0.01\n7 2.0 2.0 0.01 0.01\n"
    )
    for n in range(1, 6):
        (folder / f"Robot{n}_Odometry.dat").write_text(
            "# t v w\n0.0 0.1 0.0\n0.5 0.1 0.01\n1.0 0.1 0.0\n"
        )
        (folder / f"Robot{n}_Groundtruth.dat").write_text(
            "# t x y θ\n0.0 0 0 0\n0.5 0.05 0 0.005\n1.0 0.1 0 0.01\n"
        )
        (folder / f"Robot{n}_Measurement.dat").write_text(
            "# t barcode range bearing\n0.25 16 1.4 0.7\n0.75 17 2.7 0.75\n"
        )
    return folder


def plaza_folder(folder: Path) -> Path:
    """A small valid CMU Plaza folder."""
    import scipy.io

    folder.mkdir(parents=True, exist_ok=True)
    (folder / "P_DR.txt").write_text("0.1 0.1 0.0\n0.2 0.1 0.01\n0.3 0.1 0.0\n")
    (folder / "P_TD.txt").write_text("0.1 1 101 5.0\n0.2 1 102 4.0\n")
    gt = np.array([[0.0, 0, 0, 3.1], [0.2, 0.1, 0, 3.1], [0.3, 0.2, 0, 3.1]])
    scipy.io.savemat(
        folder / "P_.mat",
        {"GT": gt, "DRp": gt, "TL": np.array([[101.0, 5, 0], [102.0, 0, 4]])},
    )
    return folder


def fuzz_folder_reader(
    reader: Callable[[Path], object], make: Callable[[Path], Path], count: int, seed: int
) -> Outcome:
    """``count`` folders, each with one of its files mutated (or removed), read by ``reader``."""
    rng = np.random.default_rng(seed)
    outcome = Outcome()
    with tempfile.TemporaryDirectory() as tmp:
        base = make(Path(tmp) / "base")
        names = sorted(p.name for p in base.iterdir())
        for k in range(count):
            folder = Path(tmp) / f"f{k}"
            shutil.copytree(base, folder)
            name = names[int(rng.integers(len(names)))]
            target = folder / name
            if rng.random() < 0.05:
                target.unlink()
                data = b""
            else:
                data = mutate(target.read_bytes(), rng)
                target.write_bytes(data)
            run(lambda: reader(folder), data, outcome)  # noqa: B023 - called at once
            shutil.rmtree(folder)
    return outcome
