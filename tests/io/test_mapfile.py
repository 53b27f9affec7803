"""relmap.io.mapfile: JSON and YAML map files, exact round trips, errors naming file and entry."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import relmap as rm
from relmap.errors import FileFormatError
from relmap.io import ATRecord, read_records, write_records

FIG1 = Path(rm.__file__).parent / "data" / "fig1.json"


def test_reads_the_shipped_fig1():
    recs = read_records(FIG1)
    assert [r.name for r in recs] == ["A", "B", "C", "D", "S"]
    assert (recs[0].src, recs[0].dst) == ("W", "L1")
    assert recs[0].at.mean[2] == pytest.approx(np.deg2rad(60.0))
    assert recs[0].at.sigmas[2] == pytest.approx(np.deg2rad(2.0))


@pytest.mark.parametrize("suffix", [".json", ".yaml"])
def test_roundtrip_is_exact(tmp_path, suffix):
    rng = np.random.default_rng(0)
    L = rng.normal(size=(3, 3, 3)) * 0.1
    recs = [
        ATRecord(f"e{i}", f"f{i}", i + 1, rm.AT(rng.normal(size=3), L[i] @ L[i].T))
        for i in range(3)
    ]
    path = tmp_path / f"map{suffix}"
    write_records(path, recs, description="round trip")
    back = read_records(path)
    for r, b in zip(recs, back, strict=True):
        assert (r.name, r.src, r.dst) == (b.name, b.src, b.dst)
        np.testing.assert_array_equal(r.at.mean, b.at.mean)
        np.testing.assert_array_equal(r.at.cov, b.at.cov)
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary left


def test_degrees_apply_to_cov(tmp_path):
    p = tmp_path / "m.yaml"
    p.write_text(
        "angle_unit: deg\nats:\n"
        "  - {from: a, to: b, mean: [1, 2, 90], cov: [[1, 0, 0], [0, 1, 0], [0, 0, 4]]}\n"
    )
    (r,) = read_records(p)
    assert r.at.mean[2] == pytest.approx(np.pi / 2)
    assert r.at.cov[2, 2] == pytest.approx(4 * (np.pi / 180) ** 2)
    assert r.name == "e0"


@pytest.mark.parametrize(
    ("doc", "match"),
    [
        (
            {"ats": [{"from": "a", "to": "b", "mean": [0, 0, 0], "sigmaa": [1, 1, 1]}]},
            r"ats\[0\].*unknown key",
        ),
        ({"ats": [{"from": "a", "mean": [0, 0, 0]}]}, "missing 'to'"),
        ({"ats": [{"from": "a", "to": "b", "mean": [0, 0]}]}, r"mean must have shape \(3,\)"),
        (
            {
                "ats": [
                    {
                        "from": "a",
                        "to": "b",
                        "mean": [0, 0, 0],
                        "cov": [[1, 2, 0], [2, 1, 0], [0, 0, 1]],
                    }
                ]
            },
            "positive semi-definite",
        ),
        (
            {"ats": [{"from": "a", "to": "b", "mean": [0, 0, "x"]}]},
            "could not convert|must be numbers|must hold numbers",
        ),
        (
            {
                "ats": [
                    {"name": "A", "from": "a", "to": "b", "mean": [0, 0, 0]},
                    {"name": "A", "from": "b", "to": "c", "mean": [0, 0, 0]},
                ]
            },
            "duplicate",
        ),
        (
            {
                "ats": [
                    {
                        "from": "a",
                        "to": "b",
                        "mean": [0, 0, 0],
                        "sigma": [1, 1, 1],
                        "cov": np.eye(3).tolist(),
                    }
                ]
            },
            "not both",
        ),
        ({"ats": [{"from": ["a"], "to": "b", "mean": [0, 0, 0]}]}, "frame name"),
        ({"ats": {}}, "must be a list"),
        ({"relmap": 2, "ats": []}, "version"),
        ({"angle_unit": "grad", "ats": []}, "angle_unit"),
        ({"atss": []}, "unknown top-level"),
    ],
)
def test_errors_name_file_and_entry(tmp_path, doc, match):
    p = tmp_path / "bad.json"
    p.write_text(json.dumps(doc))
    with pytest.raises(FileFormatError, match=match) as info:
        read_records(p)
    assert str(p) in str(info.value)


def test_syntax_errors_give_line_numbers(tmp_path):
    p = tmp_path / "bad.json"
    p.write_text('{\n  "ats": [\n    {"from": "a",,}\n  ]\n}\n')
    with pytest.raises(FileFormatError, match=r"bad.json:3"):
        read_records(p)
    y = tmp_path / "bad.yaml"
    y.write_text("ats:\n  - {from: a, to: b\n  - x\n")
    with pytest.raises(FileFormatError, match=r"bad.yaml:\d+: invalid YAML"):
        read_records(y)


def test_yaml_is_loaded_safely(tmp_path):
    p = tmp_path / "evil.yaml"
    p.write_text("ats: !!python/object/apply:os.system ['echo pwned']\n")
    with pytest.raises(FileFormatError, match="invalid YAML"):
        read_records(p)


def test_missing_file(tmp_path):
    with pytest.raises(FileFormatError, match="cannot read"):
        read_records(tmp_path / "nope.yaml")


def test_failed_write_leaves_previous_file_intact(tmp_path):
    p = tmp_path / "m.json"
    write_records(p, [ATRecord("A", "a", "b", rm.AT([1.0, 0.0, 0.0]))])
    before = p.read_text()
    batch = rm.AT(np.zeros((2, 3)))
    with pytest.raises(ValueError, match="batch shape"):
        write_records(p, [ATRecord("B", "a", "b", batch)])
    assert p.read_text() == before


@pytest.mark.parametrize("suffix", [".json", ".yaml"])
def test_3d_maps_round_trip_and_query(tmp_path, suffix):
    """AT3 entries: mean [x, y, z, qx, qy, qz, qw], 6×6 cov; the rotation is kept to rounding
    (the quaternion is re-normalized on reading) and the covariance exactly."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(1)
    L = rng.normal(size=(2, 6, 6)) * 0.1
    q = Rotation.random(2, random_state=1).as_quat()
    recs = [
        ATRecord(f"e{i}", f"f{i}", f"f{i + 1}", rm.AT3(rng.normal(size=3), q[i], L[i] @ L[i].T))
        for i in range(2)
    ]
    path = tmp_path / f"map3{suffix}"
    write_records(path, recs)
    back = read_records(path)
    for r, b in zip(recs, back, strict=True):
        assert isinstance(b.at, rm.AT3)
        np.testing.assert_allclose(b.at.matrix, r.at.matrix, atol=1e-15)
        np.testing.assert_array_equal(b.at.cov, r.at.cov)
    g = rm.io.load_map(path)
    assert g.group is rm.lie.SE3
    est = g.query("f0", "f2")
    np.testing.assert_allclose(est.at.cov, (recs[0].at @ recs[1].at).cov, atol=1e-15)


def test_3d_sigma_in_degrees_and_mixed_files(tmp_path):
    p = tmp_path / "m.yaml"
    p.write_text(
        "angle_unit: deg\nats:\n"
        "  - {from: a, to: b, mean: [1, 2, 3, 0, 0, 0, 1], sigma: [1, 1, 1, 2, 2, 2]}\n"
    )
    (r,) = read_records(p)
    np.testing.assert_allclose(r.at.sigmas, [1, 1, 1, *np.deg2rad([2, 2, 2])])
    p.write_text(
        "ats:\n  - {from: a, to: b, mean: [1, 2, 3, 0, 0, 0, 1]}\n"
        "  - {from: b, to: c, mean: [1, 2, 0.3]}\n"
    )
    with pytest.raises(FileFormatError, match=r"ats\[1\].*SE\(2\) AT in a file of SE\(3\) ATs"):
        read_records(p)
    p.write_text("ats:\n  - {from: a, to: b, mean: [1, 2, 3, 0, 0, 0.5, 1]}\n")
    with pytest.raises(FileFormatError, match=r"ats\[0\].*norm"):
        read_records(p)


def test_query_command_on_a_3d_map(tmp_path, capsys):
    from relmap.app.cli import main

    p = tmp_path / "m3.yaml"
    p.write_text(
        "ats:\n"
        "  - {name: A, from: W, to: L1, mean: [1, 0, 0.2, 0, 0, 0.0998, 0.995],"
        " sigma: [0.05, 0.05, 0.02, 0.01, 0.01, 0.02]}\n"
        "  - {name: B, from: L1, to: L2, mean: [1, 0.2, 0, 0.0998, 0, 0, 0.995],"
        " sigma: [0.05, 0.05, 0.02, 0.01, 0.01, 0.02]}\n"
    )
    assert main(["query", str(p), "W", "L2", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    g = rm.io.load_map(p)
    expected = g.edge("A").at @ g.edge("B").at
    assert out["expression"] == "A ⊕ B" and len(out["mean"]) == 7
    np.testing.assert_allclose(out["mean"], expected.vector, atol=1e-15)
    np.testing.assert_allclose(out["cov"], expected.cov, atol=1e-18)
    assert main(["query", str(p), "W", "L2"]) == 0
    text = capsys.readouterr().out
    assert "quaternion" not in text and "(qx qy qz qw)" in text and "roll" in text
    assert "90% position ellipsoid" in text
