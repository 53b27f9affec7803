"""Every number of every shared g2o/TORO pose graph, as relmap's one reader reads it, against
Python's ``float()`` and ``int()`` of the file's own tokens, bit for bit.

The formats are written out here from the data README (not taken from relmap): the information
entries are stored "exactly as written" (:attr:`relmap.io.PoseGraph.information`), vertex and
edge translations are the file's numbers, ids are the file's integers.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from relmap.io import read_graph

pytestmark = pytest.mark.real_data

UPPER3 = [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)]
TORO2 = [(0, 0), (0, 1), (1, 1), (2, 2), (0, 2), (1, 2)]  # xx xy yy θθ xθ yθ
UPPER6 = [(r, c) for r in range(6) for c in range(r, 6)]
# tag -> (number of ids, translation columns among the values, measurement size, info order)
FORMATS = {
    "VERTEX_SE2": (1, 2, 3, None),
    "VERTEX2": (1, 2, 3, None),
    "VERTEX_SE3:QUAT": (1, 3, 7, None),
    "EDGE_SE2": (2, 2, 3, UPPER3),
    "EDGE2": (2, 2, 3, TORO2),
    "EDGE_SE3:QUAT": (2, 3, 7, UPPER6),
}

FILES = [
    *(f"posegraph2d/{n}" for n in ("intel.g2o", "MIT.g2o", "CSAIL_P_toro.graph")),
    *(f"posegraph2d/{n}" for n in ("FR079_P_toro.graph", "manhattanOlson3500.g2o")),
    *(f"posegraph2d/{n}" for n in ("city10000.g2o", "ring.g2o")),
    *(f"posegraph3d/{n}" for n in ("sphere2500.g2o", "parking-garage.g2o", "torus3D.g2o")),
    *(f"posegraph3d/{n}" for n in ("smallGrid3D.g2o", "tinyGrid3D.g2o")),
]


def _records(path: Path) -> dict[str, list[list[str]]]:
    out: dict[str, list[list[str]]] = {}
    for line in path.read_text().splitlines():
        tokens = line.split()
        if tokens and not tokens[0].startswith("#"):
            out.setdefault(tokens[0], []).append(tokens[1:])
    return out


def _bits(x: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(x, dtype=np.float64).view(np.int64)


@pytest.mark.parametrize("name", FILES)
def test_every_number_is_pythons_float_of_its_token(data_dir, name):
    path = data_dir / name
    g = read_graph(path)
    records = _records(path)
    vertex_tag = next(t for t in records if t.startswith("VERTEX"))
    edge_tag = next(t for t in records if t.startswith("EDGE"))

    n_ids, n_t, _, _ = FORMATS[vertex_tag]
    rows = records[vertex_tag]
    assert g.vertex_ids.tolist() == [int(r[0]) for r in rows]
    want = np.array([[float(tok) for tok in r[n_ids : n_ids + n_t]] for r in rows])
    got = g.poses[:, :n_t] if g.poses.ndim == 2 else g.poses[:, :3, 3]
    assert np.array_equal(_bits(got), _bits(want))

    n_ids, n_t, n_meas, order = FORMATS[edge_tag]
    rows = records[edge_tag]
    assert g.edge_from.tolist() == [int(r[0]) for r in rows]
    assert g.edge_to.tolist() == [int(r[1]) for r in rows]
    numbers = np.array([[float(tok) for tok in r[n_ids:]] for r in rows])
    mean = g.measurements.mean
    got = mean[:, :2] if mean.ndim == 2 else mean[:, :3, 3]  # (x, y) or the translations
    assert np.array_equal(_bits(got), _bits(numbers[:, :n_t]))
    info = numbers[:, n_meas:]
    for k, (r, c) in enumerate(order):
        assert np.array_equal(_bits(g.information[:, r, c]), _bits(info[:, k]))
        assert np.array_equal(_bits(g.information[:, c, r]), _bits(info[:, k]))
