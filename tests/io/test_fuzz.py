"""A bounded, fixed-seed fuzz run of every reader (g2o/TORO 2-D and 3-D, map files in YAML and
JSON, MRCLAM and CMU Plaza folders): each mutated input is read or refused with a RelmapError,
never another exception type. ``RELMAP_FUZZ_COUNT=2000 pytest -n 0 tests/io/test_fuzz.py`` runs
it longer."""

from __future__ import annotations

import os

import pytest

from relmap.io import load_map, read_graph
from relmap.io.datasets import read_mrclam, read_plaza
from tests import fuzzing

TEXT_READERS = [
    ("g2o 2-D", read_graph, fuzzing.G2O_2D, ".g2o"),
    ("TORO 2-D", read_graph, fuzzing.TORO_2D, ".graph"),
    ("g2o 3-D", read_graph, fuzzing.G2O_3D, ".g2o"),
    ("TORO 3-D", read_graph, fuzzing.TORO_3D, ".graph"),
    pytest.param(  # YAML's parser is the slowest: in the whole suite, not the quick subset
        "map YAML", load_map, fuzzing.MAP_YAML, ".yaml", marks=pytest.mark.slow, id="map YAML"
    ),
    ("map JSON", load_map, fuzzing.MAP_JSON, ".json"),
    ("load_map of a g2o", load_map, fuzzing.G2O_2D, ".g2o"),
]
#: Mutated inputs per text reader (two fifths of it per dataset folder, each a folder of files).
COUNT = int(os.environ.get("RELMAP_FUZZ_COUNT", "100"))


def _report(outcome: fuzzing.Outcome) -> str:
    return "\n\n".join(f"{k}:\n{v}" for k, v in outcome.examples.items())


@pytest.mark.parametrize(
    ("name", "reader", "base", "suffix"),
    TEXT_READERS,
    ids=[getattr(r, "id", None) or r[0] for r in TEXT_READERS],
)
def test_text_readers_never_raise_an_unexpected_type(name, reader, base, suffix):
    reader(_write_once(base, suffix))  # the base input itself is valid
    outcome = fuzzing.fuzz_text_reader(reader, base, suffix, count=COUNT, seed=16)
    assert outcome.unexpected == 0, _report(outcome)
    assert outcome["refused"] > 0  # the mutations do reach the error paths


def _write_once(text: str, suffix: str):
    import tempfile
    from pathlib import Path

    path = Path(tempfile.mkdtemp()) / f"base{suffix}"
    path.write_text(text)
    return path


@pytest.mark.parametrize(
    ("reader", "make"),
    [(read_mrclam, fuzzing.mrclam_folder), (read_plaza, fuzzing.plaza_folder)],
    ids=["MRCLAM", "Plaza"],
)
def test_dataset_readers_never_raise_an_unexpected_type(tmp_path, reader, make):
    reader(make(tmp_path / "valid"))
    outcome = fuzzing.fuzz_folder_reader(reader, make, count=max(1, COUNT * 2 // 5), seed=16)
    assert outcome.unexpected == 0, _report(outcome)
    assert outcome["refused"] > 0
