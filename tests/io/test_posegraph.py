"""relmap.io.posegraph: g2o and TORO 2-D pose graphs, checked against GTSAM, exact round trips."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from relmap.errors import (
    FileFormatError,
    NonFiniteError,
    ParameterError,
    ShapeError,
    UnknownFrameError,
)
from relmap.io import PoseGraph, read_graph, write_graph
from relmap.lie import se2

# Counts from ../shared/data/README.md.
SHARED_2D = [
    ("intel.g2o", "g2o", 1728, 2512),
    ("MIT.g2o", "g2o", 808, 827),
    ("CSAIL_P_toro.graph", "toro", 1045, 1172),
    ("FR079_P_toro.graph", "toro", 989, 1217),
    ("manhattanOlson3500.g2o", "g2o", 3500, 5598),
    ("city10000.g2o", "g2o", 10000, 20687),
    ("ring.g2o", "g2o", 434, 459),
]

# The information matrix whose upper triangle is 1, .1, .2, 2, .3, 3 (row by row).
INFO = np.array([[1.0, 0.1, 0.2], [0.1, 2.0, 0.3], [0.2, 0.3, 3.0]])


def _expected_cov(mean, info):
    """relmap's covariance of a measurement z with body-frame information I: M I⁻¹ Mᵀ."""
    M = se2.body_to_chart(mean)
    return M @ np.linalg.inv(info) @ M.T


def _angles_equal(a, b, atol=1e-12):
    return np.all(np.abs(se2.angle_difference(a, b)) <= atol)


@pytest.mark.parametrize(("name", "fmt", "n", "m"), SHARED_2D)
def test_shared_files_load_with_readme_counts(data_dir, name, fmt, n, m):
    g = read_graph(data_dir / "posegraph2d" / name)
    assert g.format == fmt
    assert g.vertex_ids.shape == (n,) and g.vertex_ids.dtype == np.int64
    assert len(np.unique(g.vertex_ids)) == n
    assert g.poses.shape == (n, 3) and g.poses.dtype == np.float64
    assert g.edge_from.shape == g.edge_to.shape == (m,) and g.edge_from.dtype == np.int64
    assert g.measurements.batch_shape == (m,)
    assert g.information.shape == (m, 3, 3)
    assert g.fixed.shape == (0,)
    assert np.all((g.poses[:, 2] >= -np.pi) & (g.poses[:, 2] < np.pi))
    assert np.all((g.measurements.mean[:, 2] >= -np.pi) & (g.measurements.mean[:, 2] < np.pi))
    np.testing.assert_array_equal(g.information, np.swapaxes(g.information, 1, 2))
    i, j = g.edge_indices()
    np.testing.assert_array_equal(g.vertex_ids[i], g.edge_from)
    np.testing.assert_array_equal(g.vertex_ids[j], g.edge_to)


def test_covariance_conversion_agrees_with_gtsam_noise_model(data_dir):
    path = data_dir / "posegraph2d" / "intel.g2o"
    g = read_graph(path)
    edge_lines = [ln.split() for ln in path.read_text().splitlines() if ln.startswith("EDGE_SE2")]
    for k in (0, 1, 777, 2000, len(edge_lines) - 1):
        i11, i12, i13, i22, i23, i33 = map(float, edge_lines[k][6:12])
        info = np.array([[i11, i12, i13], [i12, i22, i23], [i13, i23, i33]])
        assert np.count_nonzero(info) == 9  # a full matrix: the layout is really tested
        np.testing.assert_array_equal(g.information[k], info)  # kept exactly as written
        cov_body = gtsam.noiseModel.Gaussian.Information(info).covariance()
        M = se2.body_to_chart(g.measurements.mean[k])
        np.testing.assert_allclose(g.measurements.cov[k], M @ cov_body @ M.T, rtol=0, atol=1e-12)


def test_agrees_with_gtsam_readG2o(data_dir):
    path = data_dir / "posegraph2d" / "intel.g2o"
    g = read_graph(path)
    factors, initial = gtsam.readG2o(str(path), False)
    assert initial.size() == len(g.vertex_ids)
    for row, vid in enumerate(g.vertex_ids.tolist()):
        p = initial.atPose2(vid)
        np.testing.assert_allclose(g.poses[row, :2], [p.x(), p.y()], rtol=0, atol=1e-12)
        assert _angles_equal(g.poses[row, 2], p.theta())
    assert factors.size() == len(g.edge_from)
    for k in range(factors.size()):
        f = factors.at(k)
        assert list(f.keys()) == [g.edge_from[k], g.edge_to[k]]
        z = f.measured()
        np.testing.assert_allclose(g.measurements.mean[k, :2], [z.x(), z.y()], rtol=0, atol=1e-12)
        assert _angles_equal(g.measurements.mean[k, 2], z.theta())
        if k % 500 == 0:  # GTSAM's own reading of the information (its body-frame noise model)
            cov_body = f.noiseModel().covariance()
            M = se2.body_to_chart(g.measurements.mean[k])
            np.testing.assert_allclose(g.measurements.cov[k], M @ cov_body @ M.T, atol=1e-12)


def test_toro_information_order(tmp_path):
    p = tmp_path / "tiny.graph"
    p.write_text(
        "VERTEX2 0 0 0 0\nVERTEX2 1 1 0.5 0.7\n"
        "EDGE2 0 1 1.0 0.5 0.7 1 0.1 2 3 0.2 0.3\n"  # xx xy yy θθ xθ yθ
    )
    g = read_graph(p)
    assert g.format == "toro"
    np.testing.assert_array_equal(g.information[0], INFO)
    np.testing.assert_allclose(
        g.measurements.cov[0], _expected_cov([1.0, 0.5, 0.7], INFO), atol=1e-14
    )


def test_g2o_information_order_and_backward_edges(tmp_path):
    p = tmp_path / "tiny.g2o"
    p.write_text(
        "EDGE_SE2 1 0 1.0 0.5 -2.5 1 0.1 0.2 2 0.3 3\n"  # vertices may come after their edges
        "VERTEX_SE2 1 1 0.5 0.7\nVERTEX_SE2 0 0 0 0\n"
    )
    g = read_graph(p)
    assert g.format == "g2o"
    assert (g.edge_from[0], g.edge_to[0]) == (1, 0)
    np.testing.assert_array_equal(g.information[0], INFO)
    np.testing.assert_allclose(
        g.measurements.cov[0], _expected_cov([1.0, 0.5, -2.5], INFO), atol=1e-14
    )
    assert g.index_of(g.edge_from[0]) == 0 and g.index_of(g.edge_to[0]) == 1


def test_format_comes_from_content_not_name(tmp_path):
    g2o = tmp_path / "looks_like_toro.graph"
    g2o.write_text("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n")
    toro = tmp_path / "looks_like_g2o.g2o"
    toro.write_text("VERTEX2 0 0 0 0\nVERTEX2 1 1 0 0\nEDGE2 0 1 1 0 0 1 0 1 1 0 0\n")
    assert read_graph(g2o).format == "g2o"
    assert read_graph(toro).format == "toro"
    write_graph(toro, read_graph(toro))
    assert toro.read_text().startswith("VERTEX2 0 ")


def test_blank_lines_comments_and_crlf_are_ignored(tmp_path):
    p = tmp_path / "c.g2o"
    p.write_bytes(
        b"# header\r\n\r\n   # indented comment\r\nVERTEX_SE2 0 0 0 0\r\n\t\r\n"
        b"VERTEX_SE2 1 1 0 0\r\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\r\nVERTEX_SE2 1 2 0 0\r\n"
    )
    with pytest.raises(FileFormatError, match=r"c\.g2o:8: duplicate vertex id 1 .*line 6"):
        read_graph(p)
    p.write_bytes(p.read_bytes().rsplit(b"VERTEX_SE2 1 2", 1)[0])
    g = read_graph(p)
    assert list(g.vertex_ids) == [0, 1] and len(g.edge_from) == 1


def _random_graph(tmp_path, fmt: str) -> PoseGraph:
    """A graph with non-contiguous ids, full information matrices and awkward numbers."""
    rng = np.random.default_rng(7)
    ids = np.array([10, 3, 7, 42, 0])
    vertex, edge = ("VERTEX_SE2", "EDGE_SE2") if fmt == "g2o" else ("VERTEX2", "EDGE2")
    lines = [
        f"{vertex} {i} {x!r} {y!r} {t!r}"
        for i, (x, y, t) in zip(
            ids.tolist(), (rng.normal(size=(5, 3)) * [10, 10, 3]).tolist(), strict=True
        )
    ]
    for a, b in [(10, 3), (3, 7), (7, 42), (42, 0), (0, 10), (7, 10)]:
        L = rng.normal(size=(3, 3))
        info = L @ L.T + 0.1 * np.eye(3)
        u = info[np.triu_indices(3)]  # g2o order: I11 I12 I13 I22 I23 I33
        nums = (u if fmt == "g2o" else u[[0, 1, 3, 5, 2, 4]]).tolist()
        z = [*rng.normal(size=2).tolist(), float(rng.uniform(-np.pi, np.pi))]
        lines.append(f"{edge} {a} {b} " + " ".join(map(repr, [*z, *nums])))
    if fmt == "g2o":
        lines.append("FIX 3 7")
    p = tmp_path / f"orig.{fmt}"
    p.write_text("\n".join(lines) + "\n")
    return read_graph(p)


def _assert_same_graph(a: PoseGraph, b: PoseGraph) -> None:
    assert a.format == b.format
    for field in ("vertex_ids", "poses", "edge_from", "edge_to", "information", "fixed"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field), err_msg=field)
    np.testing.assert_array_equal(a.measurements.mean, b.measurements.mean)
    np.testing.assert_array_equal(a.measurements.cov, b.measurements.cov)


@pytest.mark.parametrize("fmt", ["g2o", "toro"])
def test_roundtrip_is_exact(tmp_path, fmt):
    g = _random_graph(tmp_path, fmt)
    if fmt == "g2o":
        assert list(g.fixed) == [3, 7]
    out = tmp_path / "out.txt"
    write_graph(out, g)
    back = read_graph(out)
    _assert_same_graph(g, back)
    text = out.read_text()
    write_graph(out, back)
    assert out.read_text() == text
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary left


@pytest.mark.parametrize("name", ["intel.g2o", "manhattanOlson3500.g2o", "CSAIL_P_toro.graph"])
def test_roundtrip_of_real_file_keeps_edges(data_dir, tmp_path, name):
    src = data_dir / "posegraph2d" / name
    g = read_graph(src)
    out = tmp_path / name
    write_graph(out, g)
    _assert_same_graph(g, read_graph(out))
    # The edges' numbers are the file's own: information exact, measurement exact up to the
    # wrapping of dθ (manhattanOlson3500 writes some dθ near ±3π/2).
    orig = [ln.split() for ln in src.read_text().splitlines() if ln.startswith("EDGE")]
    new = [ln.split() for ln in out.read_text().splitlines() if ln.startswith("EDGE")]
    assert len(orig) == len(new)
    o = np.array([[float(v) for v in f[1:]] for f in orig])
    w = np.array([[float(v) for v in f[1:]] for f in new])
    np.testing.assert_array_equal(
        w[:, [0, 1, 2, 3, 5, 6, 7, 8, 9, 10]], o[:, [0, 1, 2, 3, 5, 6, 7, 8, 9, 10]]
    )
    assert _angles_equal(w[:, 4], o[:, 4], atol=1e-14)


def test_write_with_new_poses_changes_only_vertex_lines(data_dir, tmp_path):
    g = read_graph(data_dir / "posegraph2d" / "intel.g2o")
    g = g._replace(fixed=np.array([0]))
    new_poses = g.poses + np.array([1.5, -2.0, 0.25])
    a, b = tmp_path / "a.g2o", tmp_path / "b.g2o"
    write_graph(a, g)
    write_graph(b, g, poses=new_poses)
    la, lb = a.read_text().splitlines(), b.read_text().splitlines()
    assert len(la) == len(lb) == 1728 + 1 + 2512
    changed = [x.split()[0] for x, y in zip(la, lb, strict=True) if x != y]
    assert set(changed) == {"VERTEX_SE2"} and len(changed) == 1728
    back = read_graph(b)
    np.testing.assert_array_equal(back.poses[:, :2], new_poses[:, :2])
    np.testing.assert_array_equal(back.poses[:, 2], se2.wrap_angle(new_poses[:, 2]))
    assert list(back.fixed) == [0]


def test_failed_write_leaves_existing_file_untouched(tmp_path):
    g = _random_graph(tmp_path, "g2o")
    p = tmp_path / "g.g2o"
    write_graph(p, g)
    before = p.read_bytes()
    with pytest.raises(ShapeError, match=r"poses must have shape \(5, 3\).*\(5, 2\)"):
        write_graph(p, g, poses=np.zeros((5, 2)))
    with pytest.raises(ShapeError, match=r"\(5, 3\)"):
        write_graph(p, g, poses=np.zeros((4, 3)))
    bad = np.array(g.poses)
    bad[2, 1] = np.nan
    with pytest.raises(NonFiniteError):
        write_graph(p, g, poses=bad)
    with pytest.raises(ParameterError, match="fixed"):
        write_graph(p, g._replace(format="toro"))
    assert p.read_bytes() == before
    assert not [q for q in tmp_path.iterdir() if q.name.startswith(".")]


def test_index_of(tmp_path):
    g = _random_graph(tmp_path, "g2o")  # ids 10, 3, 7, 42, 0 in file order
    np.testing.assert_array_equal(g.index_of([7, 10, 0]), [2, 0, 4])
    np.testing.assert_array_equal(g.index_of(np.array([[42], [3]])), [[3], [1]])
    assert g.index_of(3) == 1
    assert g.index_of([]).shape == (0,)
    with pytest.raises(UnknownFrameError, match=r"unknown vertex id\(s\) 5, 99"):
        g.index_of([3, 99, 5, 99])
    with pytest.raises(ParameterError, match="integers"):
        g.index_of([3.0])
    i, j = g.edge_indices()
    np.testing.assert_array_equal(g.vertex_ids[i], g.edge_from)
    np.testing.assert_array_equal(g.vertex_ids[j], g.edge_to)


def test_graph_is_immutable(tmp_path):
    g = _random_graph(tmp_path, "g2o")
    with pytest.raises(AttributeError):
        g.poses = np.zeros((5, 3))
    for field in ("vertex_ids", "poses", "edge_from", "edge_to", "information", "fixed"):
        with pytest.raises(ValueError, match="read-only"):
            getattr(g, field)[0] = 1


def test_graph_without_edges(tmp_path):
    p = tmp_path / "v.g2o"
    p.write_text("VERTEX_SE2 5 1 2 3\n")
    g = read_graph(p)
    assert g.measurements.batch_shape == (0,) and g.information.shape == (0, 3, 3)
    write_graph(p, g)
    _assert_same_graph(g, read_graph(p))


GOOD_G2O = (
    "# header comment\n"  # 1
    "VERTEX_SE2 0 0 0 0\n"  # 2
    "VERTEX_SE2 1 1 0 0.5\n"  # 3
    "\n"  # 4
    "VERTEX_SE2 2 2 0 1.0\n"  # 5
    "EDGE_SE2 0 1 1 0 0.5 1 0 0 1 0 1\n"  # 6
    "EDGE_SE2 1 2 1 0 0.5 1 0 0 1 0 1\n"  # 7
)


@pytest.mark.parametrize(
    ("bad_line", "match"),
    [
        ("EDGE_SE2 0 2 1 0 0 1 1 0 1 0 1", r"not positive definite \(singular\)"),
        ("EDGE_SE2 0 2 1 0 0 1 2 0 1 0 1", r"not positive definite \(indefinite\)"),
        ("EDGE_SE2 0 2 1 0 0 1 0 0 1 0 0", "diagonal entry is not positive"),
        ("EDGE_SE2 0 2 1 0 0 -1 0 0 1 0 1", "diagonal entry is not positive"),
        ("EDGE_SE2 0 2 nan 0 0 1 0 0 1 0 1", "non-finite number in a EDGE_SE2 line"),
        ("VERTEX_SE2 3 inf 0 0", "non-finite number in a VERTEX_SE2 line"),
        ("VERTEX_SE2 3 1e999 0 0", "non-finite"),
        ("EDGE_SE2 0 2 1 0 0 1 0 0 1 0", "EDGE_SE2 needs 11 fields after the tag .*got 10"),
        ("EDGE_SE2 0 2 1 0 0 1 0 0 1 0 1 1", "got 12"),
        ("VERTEX_SE2 3 0 0", r"VERTEX_SE2 needs 4 fields after the tag \(id x y θ\); got 3"),
        ("VERTEX_SE2 3 0 0 0 # origin", "got 6"),
        ("VERTEX_SE2", "got 0"),
        ("VERTEX_XY 3 0 0", "unknown record tag 'VERTEX_XY' in a g2o file"),
        ("EDGE2 0 2 1 0 0 1 0 1 1 0 0", "unknown record tag 'EDGE2' in a g2o file"),
        ("EDGE_SE2 0 9 1 0 0 1 0 0 1 0 1", "vertex j = 9 has no VERTEX_SE2 line"),
        ("EDGE_SE2 9 0 1 0 0 1 0 0 1 0 1", "vertex i = 9 has no VERTEX_SE2 line"),
        ("VERTEX_SE2 1 5 5 0", r"duplicate vertex id 1 \(first defined on line 3\)"),
        ("VERTEX_SE2 3.0 0 0 0", r"vertex id '3\.0' is not a \(64-bit\) integer"),
        ("EDGE_SE2 0 1e0 1 0 0 1 0 0 1 0 1", "vertex id '1e0' is not"),
        ("VERTEX_SE2 3 0 0 abc", "'abc' is not a number"),
        ("VERTEX_SE2 3 0 0 1_0", "'1_0' is not a number"),
        ("FIX 7", "FIX vertex 7 has no VERTEX_SE2 line"),
        ("FIX", "FIX needs at least one vertex id"),
        ("FIX 1 x", "FIX: vertex id 'x' is not"),
    ],
)
def test_malformed_g2o_names_file_and_line(tmp_path, bad_line, match):
    p = tmp_path / "bad.g2o"
    p.write_text(GOOD_G2O + bad_line + "\n" + "VERTEX_SE2 8 0 0 0\n")
    with pytest.raises(FileFormatError, match=match) as info:
        read_graph(p)
    assert info.value.line == 8
    assert str(info.value).startswith(f"{p}:8: ")


@pytest.mark.parametrize(
    ("text", "line", "match"),
    [
        ("# only\nHELLO 1 2\nVERTEX_SE2 0 0 0 0\n", 2, "unknown record tag 'HELLO' .*VERTEX2"),
        ("VERTEX2 0 0 0 0\nVERTEX2 1 0 0 0\nFIX 0\n", 3, "'FIX' in a toro file"),
        (
            "VERTEX2 0 0 0 0\nVERTEX2 1 0 0 0\nEDGE2 0 1 1 0 0 1 1 1 1 0 0\n",  # xx=xy=yy=1
            3,
            r"EDGE2 information matrix is not positive definite \(singular\)",
        ),
        ("# nothing\n\n", None, "no records"),
        ("", None, "no records"),
    ],
)
def test_other_malformed_files(tmp_path, text, line, match):
    p = tmp_path / "bad.graph"
    p.write_text(text)
    with pytest.raises(FileFormatError, match=match) as info:
        read_graph(p)
    assert info.value.line == line
    assert str(p) in str(info.value)


def test_unreadable_files(tmp_path):
    with pytest.raises(FileFormatError, match="cannot read"):
        read_graph(tmp_path / "nope.g2o")
    p = tmp_path / "binary.g2o"
    p.write_bytes(b"VERTEX_SE2 0 0 0 \xff\n")
    with pytest.raises(FileFormatError, match="UTF-8"):
        read_graph(p)


def test_written_numbers_read_back_bit_for_bit():
    """The core writes each double in its shortest round-trip form (std::to_chars): reading the
    text with Python's float gives the same bits, for awkward values too."""
    from relmap import _core

    rng = np.random.default_rng(3)
    awkward = [0.1 + 0.2, -0.0, 5e-324, 2.2250738585072014e-308, 1.7976931348623157e308, 1e16,
               123456789012345680.0, 1e-5, -np.pi, 1.0, 2.0 ** 52 + 1]  # fmt: skip
    values = np.concatenate([awkward, rng.normal(size=200) * 10.0 ** rng.integers(-30, 30, 200)])
    ids = np.arange(len(values), dtype=np.int64)[:, None] - 2**62
    text = _core.format_records("X", ids, values[:, None])
    rows = [line.split() for line in text.splitlines()]
    assert [r[0] for r in rows] == ["X"] * len(values)
    assert [int(r[1]) for r in rows] == ids[:, 0].tolist()
    back = np.array([float(r[2]) for r in rows])
    assert back.tobytes() == values.tobytes()
