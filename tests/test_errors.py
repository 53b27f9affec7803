"""Bad input at relmap's edge, one test per root cause: every deliberate error is a RelmapError
naming the argument and what arrived; relmap's own arithmetic never returns inf or NaN; map
files and readers refuse what they cannot read with file and line, and accept a BOM, CRLF,
gzip and pipes alike."""

from __future__ import annotations

import gzip
import os

import numpy as np
import pytest

import relmap as rm
from relmap.errors import (
    ArgumentTypeError,
    CovarianceError,
    FileFormatError,
    NonFiniteError,
    NotNumericError,
    NotPositiveSemidefiniteError,
    NumericalError,
    ParameterError,
    RelmapError,
    ShapeError,
)
from relmap.io import load_map, read_graph
from relmap.io.datasets import read_mrclam, read_plaza, recognise
from relmap.uncertain import gaussian, moments, propagate

I3 = 0.01 * np.eye(3)
NAN = float("nan")


# ------------------------------------------------------------------ conversions of user numbers
@pytest.mark.parametrize(
    ("value", "error", "says"),
    [
        ("0 0 0", NotNumericError, "str"),
        ([1j, 0, 0], NotNumericError, "complex"),
        ({"x": 1, "y": 2, "t": 3}, NotNumericError, "dict"),
        (object(), NotNumericError, "objects"),
        ([object(), 1, 2], NotNumericError, "objects"),
        ([[1, 2, 3], [1, 2]], ShapeError, "differ in length"),
        ([True, False, True], NotNumericError, "booleans"),
        (None, NotNumericError, "None"),
        ([10**400, 0, 0], NotNumericError, "too large"),
    ],
)
def test_at_mean_that_is_not_real_numbers(value, error, says):
    with pytest.raises(error, match="AT mean") as info:
        rm.AT(value)
    assert says in str(info.value)


def test_complex_covariance_is_refused_not_cut_to_its_real_part():
    with pytest.raises(NotNumericError, match=r"AT cov.*complex"):
        rm.AT([0, 0, 0], I3 * (1 + 1e-3j))
    with pytest.raises(NotNumericError, match="complex"):
        rm.AT3([0, 0, 0], [0, 0, 0, 1], np.eye(6) * (1 + 0j))


@pytest.mark.parametrize("bad", ["0 0 0", [1j, 0, 0], {"a": 1}, [[1, 2], [3]]])
def test_at3_inputs_that_are_not_real_numbers(bad):
    with pytest.raises(RelmapError, match="translation"):
        rm.AT3(bad, [0, 0, 0, 1])
    with pytest.raises(RelmapError, match="rotation"):
        rm.AT3([0, 0, 0], bad)


# ------------------------------------------------------------------ tolerances, seeds, counts
@pytest.mark.parametrize("rtol", [NAN, -1.0, float("inf"), "1e-9", None])
def test_rtol_must_be_a_finite_non_negative_number(rtol):
    with pytest.raises(ParameterError, match="rtol"):
        rm.AT([0, 0, 0], -I3, rtol=rtol)  # NaN used to switch the PSD check off


@pytest.mark.parametrize("atol", [NAN, -1.0])
def test_merge_atol(atol):
    exact_a, exact_b = rm.AT([0, 0, 0]), rm.AT([1, 0, 0])
    with pytest.raises(ParameterError, match="atol"):
        rm.merge(exact_a, exact_b, atol=atol)  # NaN used to merge contradictory exact ATs
    with pytest.raises(ParameterError, match="atol"):
        rm.merge(exact_a, exact_a, atol=atol)  # -1 used to say "disagree by 0"
    q = rm.AT3.identity()
    with pytest.raises(ParameterError, match="atol"):
        rm.merge(q, q, atol=atol)


@pytest.mark.parametrize("seed", [-1, "x", 1.5, True, [1, -2], object()])
def test_seeds(seed):
    with pytest.raises(ParameterError, match="seed"):
        rm.AT([0, 0, 0], I3).sample(3, seed=seed)
    with pytest.raises(ParameterError, match="seed"):
        gaussian.sample([0, 0], np.eye(2), 3, seed=seed)


@pytest.mark.parametrize("n", [0, -1, 2.5, 10**20, NAN, "3"])
def test_sample_counts(n):
    with pytest.raises(ParameterError, match="samples"):
        rm.AT([0, 0, 0], I3).sample(n)


# ------------------------------------------------------------------ batches and stacking
def test_compound_and_merge_of_batches_that_do_not_broadcast():
    a4 = rm.AT(np.zeros((4, 3)), np.broadcast_to(I3, (4, 3, 3)))
    a5 = rm.AT(np.zeros((5, 3)), np.broadcast_to(I3, (5, 3, 3)))
    with pytest.raises(ShapeError, match=r"\(4,\).*\(5,\)"):
        a4 @ a5
    with pytest.raises(ShapeError, match=r"\(4,\).*\(5,\)"):
        rm.merge(a4, a5)
    q4 = rm.AT3.identity((4,))
    q5 = rm.AT3.identity((5,))
    with pytest.raises(ShapeError, match="broadcast"):
        rm.merge(q4, q5)
    with pytest.raises(ShapeError, match="broadcast"):
        q4 @ q5


@pytest.mark.parametrize("cls", [rm.AT, rm.AT3])
def test_stack(cls):
    one = cls.identity()
    with pytest.raises(ArgumentTypeError, match="not an AT"):
        cls.stack([1, 2])
    with pytest.raises(ShapeError, match="at least one"):
        cls.stack([])
    with pytest.raises(ShapeError, match="one batch shape"):
        cls.stack([one, cls.identity((2,))])
    with pytest.raises(ShapeError, match="axis"):
        cls.stack([one, one], axis=3)
    with pytest.raises(ArgumentTypeError):
        cls.stack(5)
    assert cls.stack((one, one)).batch_shape == (2,)


def test_mixed_at_and_at3_is_an_argument_type_error():
    with pytest.raises(ArgumentTypeError):
        rm.compound(rm.AT3.identity(), rm.AT.identity())
    with pytest.raises(ArgumentTypeError):
        rm.merge(rm.AT.identity(), rm.AT3.identity())


def test_mahalanobis2_names_the_mismatch():
    with pytest.raises(ShapeError, match="cov"):
        gaussian.mahalanobis2(np.zeros(3), np.zeros(3), np.eye(2))
    with pytest.raises(ShapeError, match="broadcast"):
        gaussian.mahalanobis2(np.zeros((4, 2)), np.zeros((5, 2)), np.eye(2))
    with pytest.raises(NotNumericError, match="x"):
        gaussian.mahalanobis2("0 0", np.zeros(2), np.eye(2))
    with pytest.raises(NotPositiveSemidefiniteError):
        gaussian.mahalanobis2(np.ones(2), np.zeros(2), np.diag([-1.0, 1.0]))
    assert gaussian.mahalanobis2(np.ones(2), np.zeros(2), np.eye(2)) == pytest.approx(2.0)


@pytest.mark.parametrize("cls", [rm.AT, rm.AT3])
def test_compound_chain_of_an_empty_batch(cls):
    with pytest.raises(ShapeError, match="at least one step"):
        rm.compound_chain(cls.identity((0,)))  # used to recurse forever (SE(2))


# ------------------------------------------------------------------ values never validated before
def test_cross_cov_that_makes_the_joint_covariance_indefinite():
    a = rm.AT([1, 0, 0], I3)
    with pytest.raises(NotPositiveSemidefiniteError, match="joint covariance"):
        rm.compound(a, a, cross_cov=0.05 * np.eye(3))  # |C_ab| > C: negative variances
    for method in ("exact", "unscented"):
        with pytest.raises(NotPositiveSemidefiniteError, match="joint covariance"):
            rm.compound(a, a, cross_cov=0.05 * np.eye(3), moments=method)
    q = rm.AT3.from_vector([1, 0, 0, 0, 0, 0, 1], 0.01 * np.eye(6))
    with pytest.raises(NotPositiveSemidefiniteError, match="joint covariance"):
        rm.compound(q, q, cross_cov=0.05 * np.eye(6))
    # a valid dependency still compounds: b = a exactly (cross_cov = C_a) doubles the variance
    c = rm.compound(rm.AT([0, 0, 0], I3), rm.AT([0, 0, 0], I3), cross_cov=I3)
    assert np.allclose(c.cov, 4 * I3)


def test_from_euler_with_nan():
    with pytest.raises(NonFiniteError):
        rm.AT3.from_euler([0, 0, 0, NAN, 0, 0])


BAD_COVS = [
    pytest.param(np.array([[NAN, 0.0], [0.0, 1.0]]), NonFiniteError, id="nan"),
    pytest.param(np.diag([-1.0, 1.0]), NotPositiveSemidefiniteError, id="negative"),
    pytest.param(np.array([[1.0, 2.0], [2.0, 1.0]]), NotPositiveSemidefiniteError, id="indef"),
    pytest.param(np.array([[1.0, 0.5], [0.0, 1.0]]), CovarianceError, id="asymmetric"),
]


@pytest.mark.parametrize(("cov", "error"), BAD_COVS)
def test_gaussian_and_propagate_functions_check_their_covariance(cov, error):
    calls = [
        lambda: gaussian.ellipse([0, 0], cov),
        lambda: gaussian.sample([0, 0], cov, 3),
        lambda: gaussian.sqrt_psd(cov),
        lambda: propagate.propagate(lambda x: 2 * x, [0.0, 0.0], cov),
        lambda: propagate.unscented(lambda x: 2 * x, [0.0, 0.0], cov),
    ]
    for call in calls:
        with pytest.raises(error):
            call()


def test_gaussian_and_propagate_functions_check_their_mean():
    for call in (
        lambda: gaussian.ellipse([NAN, 0], np.eye(2)),
        lambda: gaussian.sample([NAN, 0], np.eye(2), 3),
        lambda: propagate.propagate(lambda x: x, [NAN, 0.0], np.eye(2)),
        lambda: propagate.unscented(lambda x: x, [NAN, 0.0], np.eye(2)),
    ):
        with pytest.raises(NonFiniteError):
            call()


@pytest.mark.parametrize(
    ("cov", "error"),
    [(-I3, NotPositiveSemidefiniteError), (I3 * NAN, NonFiniteError)],
)
def test_moments_functions_check_their_inputs(cov, error):
    m = np.array([1.0, 0.0, 0.1])
    for call in (
        lambda: moments.compound_moments(m, cov, m, I3),
        lambda: moments.compound_moments(m, I3, m, cov),
        lambda: moments.reverse_moments(m, cov),
        lambda: moments.unscented_compound(m, cov, m, I3),
        lambda: moments.unscented_reverse(m, cov),
        lambda: moments.chain_moments(np.stack([m, m]), np.stack([cov, cov]), axis=0),
        lambda: moments.unscented_chain(np.stack([m, m]), np.stack([cov, cov]), axis=0),
    ):
        with pytest.raises(error):
            call()
    with pytest.raises(NonFiniteError):
        moments.reverse_moments([NAN, 0, 0], I3)


# ------------------------------------------------------------------ overflow of relmap's arithmetic
def test_overflow_is_a_numerical_error_naming_the_operation():
    big = rm.AT([1e300, 0.0, 0.0], I3)
    with pytest.raises(NumericalError, match="compound"):
        big @ big  # 1e300² in the covariance
    with pytest.raises(NumericalError, match="reverse"):
        rm.AT([1e200, 1e200, 0.3], I3).reverse()
    with pytest.raises(NumericalError, match="compound_chain"):
        rm.compound_chain(rm.AT(np.tile([1e300, 0.0, 0.0], (4, 1)), np.broadcast_to(I3, (4, 3, 3))))
    q = rm.AT3.from_vector([1e300, 0, 0, 0, 0, 0, 1], 0.01 * np.eye(6))
    with pytest.raises(NumericalError, match="compound"):
        q @ q
    with pytest.raises(NumericalError, match="compound"):
        rm.compound_chain(rm.AT3.stack([q, q, q]))
    with pytest.raises(NumericalError, match="reverse"):
        rm.AT3.from_vector([1e200, 1e200, 0, 0, 0, 0.3, 0.95], 0.01 * np.eye(6), atol=0.1).reverse()


def test_dead_reckoning_with_1e300_steps_is_a_numerical_error():
    from relmap.models import odometry as motion

    noise = motion.DistanceNoise(k_s=0.01, k_theta=0.01, k_theta_s=0.001)
    steps = np.tile([1e300, 0.1], (5, 1))
    with pytest.raises(NumericalError, match=r"dead reckoning|compound_chain"):
        motion.dead_reckon(steps, noise)
    with pytest.raises(NumericalError, match="increments_from_velocities"):
        motion.increments_from_velocities([0.0, 1e10, 2e10], [1e300, 1e300, 1e300], [0, 0, 0])
    ok = motion.dead_reckon(np.tile([1.0, 0.1], (5, 1)), noise)
    assert np.isfinite(ok.cov).all()


# ------------------------------------------------------------------ map files
def _write(tmp_path, name: str, data: bytes | str):
    p = tmp_path / name
    p.write_bytes(data if isinstance(data, bytes) else data.encode())
    return p


@pytest.mark.parametrize(
    ("name", "text", "message"),
    [
        ("dup.json", '{"ats": [{"from": "a", "to": "b", "mean": [1, 2, 3], "mean": [1, 2, 4]}]}',
         "duplicate key 'mean'"),
        ("dup.yaml", "ats:\n  - from: a\n    to: b\n    mean: [1, 2, 3]\n    mean: [1, 2, 4]\n",
         ":5: invalid YAML: duplicate key 'mean'"),
        ("dup_top.yaml", "ats: []\nats: []\n", "duplicate key 'ats'"),
        ("bool.yaml", "ats:\n  - {from: a, to: b, mean: [true, false, true]}\n", "bool"),
        ("bool.json", '{"ats": [{"from": "a", "to": "b", "mean": [1, 2, 3], '
         '"sigma": [true, 1, 1]}]}', "bool"),
        ("version.json", '{"relmap": true, "ats": []}', "version True"),
        ("version.yaml", "relmap: 1.0\nats: []\n", "version 1.0"),
        ("int400.json", '{"ats": [{"from": "a", "to": "b", "mean": [1, 2, ' + "9" * 400 + "]}]}",
         "too large"),
        ("int5000.json", '{"ats": [{"from": "a", "to": "b", "mean": [1, 2, ' + "9" * 5000 + "]}]}",
         "digits"),
        ("int5000.yaml", "ats:\n  - {from: a, to: b, mean: [1, 2, " + "9" * 5000 + "]}\n",
         "digits"),
        ("deep.json", "[" * 100_000 + "]" * 100_000, "nested too deeply"),
        ("deep4.json", "[" * 10_000 + "]" * 10_000, "nested too deeply"),
        ("deep.yaml", "[" * 100_000 + "]" * 100_000, "nested too deeply"),
        ("deep4.yaml", "a:\n" + "".join(" " * k + "a:\n" for k in range(1, 10_000)), "deeply"),
        ("name.yaml", "ats:\n  - {name: [1], from: a, to: b, mean: [1, 2, 3]}\n", "'name'"),
    ],
)  # fmt: skip
def test_map_files_refuse_with_file_name(tmp_path, name, text, message):
    p = _write(tmp_path, name, text)
    with pytest.raises(FileFormatError) as info:
        load_map(p)
    assert message in str(info.value)
    assert str(info.value).startswith(str(p))


@pytest.mark.parametrize(
    "text",
    ["[" * 100_000 + "]" * 100_000, "a:\n" + "".join(" " * k + "a:\n" for k in range(1, 3000))],
)
def test_deep_yaml_without_libyaml_is_refused(tmp_path, monkeypatch, text):
    """PyYAML without its C parser (no libyaml on the platform): the pure-Python composer
    recurses, and the RecursionError is said as the nesting, naming the file."""
    import yaml

    monkeypatch.delattr(yaml, "CSafeLoader", raising=False)
    p = _write(tmp_path, "deep.yaml", text)
    with pytest.raises(FileFormatError, match="nested too deeply") as info:
        load_map(p)
    assert str(info.value).startswith(str(p))


def test_non_utf8_bytes_name_file_and_line(tmp_path):
    p = _write(tmp_path, "m.yaml", b"ats:\n  - {from: a, to: b\xff, mean: [1, 2, 3]}\n")
    with pytest.raises(FileFormatError, match=r"m\.yaml:2: not UTF-8"):
        load_map(p)
    p = _write(tmp_path, "m.json", b'{"ats": [\n{"from": "\xc3"}]}')
    with pytest.raises(FileFormatError, match=r"m\.json:2: not UTF-8"):
        load_map(p)


def test_a_directory_given_as_a_map_file(tmp_path):
    with pytest.raises(FileFormatError, match="directory"):
        load_map(tmp_path)
    with pytest.raises(FileFormatError, match="no such file"):
        load_map(tmp_path / "nope.json")


MAP_JSON = '{"ats": [{"name": "A", "from": "W", "to": "L", "mean": [1, 2, 0.5]}]}\n'
MAP_YAML = "ats:\n  - {name: A, from: W, to: L, mean: [1, 2, 0.5], sigma: [0.1, 0.1, 0.01]}\n"
G2O = "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0 100 0 0 100 0 1000\n"


def _variants(text: str) -> dict[str, bytes]:
    raw = text.encode()
    return {
        "plain": raw,
        "bom": b"\xef\xbb\xbf" + raw,
        "crlf": raw.replace(b"\n", b"\r\n"),
        "bom+crlf": b"\xef\xbb\xbf" + raw.replace(b"\n", b"\r\n"),
        "gzip": gzip.compress(raw),
        "gzip+bom+crlf": gzip.compress(b"\xef\xbb\xbf" + raw.replace(b"\n", b"\r\n")),
    }


@pytest.mark.parametrize("variant", list(_variants("")))
@pytest.mark.parametrize(
    ("suffix", "text"), [(".json", MAP_JSON), (".yaml", MAP_YAML), (".g2o", G2O)]
)
def test_readers_take_bom_crlf_and_gzip_alike(tmp_path, variant, suffix, text):
    plain = _write(tmp_path, "plain" + suffix, text)
    name = "v" + suffix + (".gz" if "gzip" in variant else "")
    other = _write(tmp_path, name, _variants(text)[variant])
    a, b = load_map(plain), load_map(other)
    assert a.frames == b.frames
    for e, f in zip(a.edges(), b.edges(), strict=True):
        assert np.array_equal(e.at.mean, f.at.mean) and np.array_equal(e.at.cov, f.at.cov)
    if suffix == ".g2o":
        assert np.array_equal(read_graph(other).poses, read_graph(plain).poses)


@pytest.mark.parametrize(
    ("suffix", "text"), [(".json", MAP_JSON), (".yaml", MAP_YAML), (".g2o", G2O)]
)
def test_load_map_reads_a_pipe(tmp_path, suffix, text):
    r, w = os.pipe()
    os.write(w, text.encode())
    os.close(w)
    try:
        g = load_map(f"/dev/fd/{r}" if suffix != ".json" else _fifo_json(tmp_path, text))
    finally:
        os.close(r)
    assert len(g.frames) == 2


def _fifo_json(tmp_path, text: str) -> str:
    """A FIFO named *.json (a pipe's name has no suffix; JSON is told by the name)."""
    import threading

    fifo = tmp_path / "m.json"
    os.mkfifo(fifo)
    threading.Thread(target=lambda: fifo.write_text(text), daemon=True).start()
    return str(fifo)


def test_line_numbers_after_a_stray_cr(tmp_path):
    # a CR alone is not a line end (grep -n, editors): the error is on line 3
    p = _write(tmp_path, "g.g2o", b"VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1\r0 0\nEDGE_SE2 0 1 x\n")
    with pytest.raises(FileFormatError, match=r"g\.g2o:3:"):
        read_graph(p)
    p = _write(tmp_path, "m.yaml", b"# a\r comment\nats:\n  - {from: a, to: b, mean: [1, 2, x]}\n")
    with pytest.raises(FileFormatError, match=r"m\.yaml"):
        load_map(p)
    p = _write(tmp_path, "m2.yaml", b"ats: []\r\nats: []\n")
    with pytest.raises(FileFormatError, match=r"m2\.yaml:2: invalid YAML: duplicate key"):
        load_map(p)
    p = _write(tmp_path, "m.json", b'{"ats":\r [\n\n  1,]}')
    with pytest.raises(FileFormatError, match=r"m\.json:3:"):
        load_map(p)


def test_corrupt_gzip(tmp_path):
    p = _write(tmp_path, "g.g2o.gz", gzip.compress(G2O.encode())[:-8])
    with pytest.raises(FileFormatError, match="gzip"):
        read_graph(p)


# ------------------------------------------------------------------ datasets
def _mrclam(folder, *, empty: str | None = None, missing: str | None = None):
    folder.mkdir()
    (folder / "Barcodes.dat").write_text(
        "# subject barcode\n" + "".join(f"{s} {s + 10}\n" for s in range(1, 8))
    )
    (folder / "Landmark_Groundtruth.dat").write_text("# s x y sx sy\n6 1 1 0 0\n7 2 2 0 0\n")
    for n in range(1, 6):
        (folder / f"Robot{n}_Odometry.dat").write_text("# t v w\n0 0.1 0\n1 0.1 0\n")
        (folder / f"Robot{n}_Groundtruth.dat").write_text("# t x y θ\n0 0 0 0\n1 0.1 0 0\n")
        (folder / f"Robot{n}_Measurement.dat").write_text("# t b r b\n0.5 16 1.0 0.1\n")
    if empty:
        (folder / empty).write_text("# header only\n")
    if missing:
        (folder / missing).unlink()
    return folder


def test_mrclam_reads_a_bom_and_crlf(tmp_path):
    folder = _mrclam(tmp_path / "m")
    ref = read_mrclam(folder)
    for p in folder.iterdir():
        p.write_bytes(b"\xef\xbb\xbf" + p.read_bytes().replace(b"\n", b"\r\n"))
    got = read_mrclam(folder)
    assert np.array_equal(got.robots[0].truth, ref.robots[0].truth)
    assert np.array_equal(got.landmark_xy, ref.landmark_xy)


def test_mrclam_empty_ground_truth_names_the_file(tmp_path):
    folder = _mrclam(tmp_path / "m", empty="Robot2_Groundtruth.dat")
    with pytest.raises(FileFormatError, match=r"Robot2_Groundtruth\.dat: no ground-truth"):
        read_mrclam(folder)


def test_a_folder_missing_one_mrclam_file_names_it(tmp_path):
    folder = _mrclam(tmp_path / "m", missing="Robot3_Measurement.dat")
    with pytest.raises(FileFormatError, match=r"missing Robot3_Measurement\.dat"):
        recognise(folder)
    with pytest.raises(FileFormatError, match=r"missing Robot3_Measurement\.dat"):
        read_mrclam(folder)


def test_plaza_empty_ground_truth(tmp_path):
    import scipy.io

    folder = tmp_path / "p"
    folder.mkdir()
    (folder / "P_DR.txt").write_text("0.1 0.1 0.0\n0.2 0.1 0.0\n")
    (folder / "P_TD.txt").write_text("0.1 1 101 5.0\n")
    scipy.io.savemat(
        folder / "P_.mat",
        {"GT": np.zeros((0, 4)), "DRp": np.zeros((2, 4)), "TL": np.array([[101.0, 1, 1]])},
    )
    with pytest.raises(FileFormatError, match=r"P_\.mat.*'GT'.*no rows"):
        read_plaza(folder)


@pytest.mark.parametrize("variance", [1e200, 1e300])
def test_decisions_with_a_huge_covariance_fail_cleanly(variance):
    from relmap.models import decisions

    a = rm.AT([1.0, 0.0, 0.0], variance * np.eye(3))
    with pytest.raises(NumericalError, match="in_view"):
        decisions.in_view(a, 0.5, 5.0)  # used to end in LinAlgError, or run out of memory
    with pytest.raises(NumericalError, match="through_door"):
        decisions.through_door(a, 1.0, 0.5)  # used to be "negative dimensions"
    wide = rm.AT([1.0, 0.0, 0.0], np.diag([1e100, 1e100, 1e-2]))
    assert decisions.through_door(wide, 1.0, 0.5).probability == pytest.approx(0.0, abs=1e-12)


def test_montecarlo_validates_its_inputs():
    from relmap.lie import se2
    from relmap.sim import montecarlo

    a = rm.AT([1.0, 0.0, 0.1], I3)
    with pytest.raises(ParameterError, match="seed"):
        montecarlo.simulate(se2.compose, a, a, n=10, seed=-1)
    with pytest.raises(ArgumentTypeError):
        montecarlo.simulate(se2.compose, a, "b", n=10)
    with pytest.raises(NonFiniteError):
        montecarlo.sample_moments(np.full((4, 3), NAN))
    with pytest.raises(NotNumericError):
        montecarlo.sample_moments("samples")


def test_map_names_and_frames_are_checked_with_relmap_errors():
    """A duplicate AT name is a DuplicateNameError, an unhashable frame a ParameterError naming
    the AT and the end (both RelmapErrors; before, a plain ValueError and a bare TypeError)."""
    from relmap.errors import DuplicateNameError, ParameterError, RelmapError

    g = rm.RelationalMap()
    at = rm.AT([1.0, 0.0, 0.0], np.eye(3) * 1e-2)
    g.add("W", "A", at, name="x")
    with pytest.raises(DuplicateNameError, match="'x' is already in the map"):
        g.add("A", "B", at, name="x")
    with pytest.raises(ParameterError, match="'to' frame is a list") as info:
        g.add("W", ["B"], at, name="y")
    assert isinstance(info.value, RelmapError)
    assert [e.name for e in g.edges()] == ["x"]  # nothing half-added


# ------------------------------------------------------------------------------------- options
def _options_cases():  # type: ignore[no-untyped-def]
    """(call with a bad option, the argument's name, the choices' values): one per option."""
    from relmap.evaluate import metrics
    from relmap.evaluate.alignment import AlignMode, align
    from relmap.io.posegraph import GraphFormat, file_information
    from relmap.network.query import QueryMethod
    from relmap.network.reduce import DeltaY, OnIrreducible
    from relmap.sim import study
    from relmap.uncertain.trajectory import Trajectory

    a = rm.AT([1.0, 0.0, 0.1], I3)
    g = rm.RelationalMap()
    g.add("w", "t", a, name="A")
    steps = rm.AT.stack([a, a])
    P = np.broadcast_to(np.eye(4), (3, 4, 4))
    traj = Trajectory.from_matrices(P, np.arange(3.0))
    return [
        (lambda: rm.compound(a, a, moments="second"), "moments", moments.MomentsMethod),
        (lambda: rm.compound_chain(steps, moments="2nd"), "moments", moments.MomentsMethod),
        (
            lambda: moments.unscented_chain(steps.mean, steps.cov, axis=0, scheme="parallel"),
            "scheme",
            moments.ChainScheme,
        ),
        (lambda: g.query("w", "t", method="best"), "method", QueryMethod),
        (lambda: g.query("w", "t", method="reduce", delta_y="both"), "delta_y", DeltaY),
        (
            lambda: g.query("w", "t", method="reduce", on_irreducible="x"),
            "on_irreducible",
            OnIrreducible,
        ),
        (lambda: metrics.ape(P, P, "angle"), "pose relation", metrics.Relation),
        (lambda: metrics.rpe(P, P, unit="km"), "delta unit", metrics.DeltaUnit),
        (lambda: align(traj, traj, "affine"), "alignment", AlignMode),
        (lambda: file_information(a, format="g3o"), "format", GraphFormat),
        (lambda: study.run(abs, [{"x": 1}], on_error="ignore"), "on_error", study.OnError),
    ]


def test_a_bad_option_names_the_argument_and_lists_the_choices():
    """Every option (a relmap.typing.Option) refuses a value that is none of its choices with a
    ParameterError naming the argument and listing the choices."""
    for call, name, options in _options_cases():
        with pytest.raises(ParameterError) as info:
            call()
        message = str(info.value)
        assert message.startswith(f"{name} must be one of "), message
        assert all(repr(v) in message for v in options.choices()), message


def test_an_option_takes_its_string_or_its_member():
    """Callers pass strings or members alike (a str enum), and get the same answer."""
    from relmap.network.query import QueryMethod
    from relmap.uncertain.moments import MomentsMethod

    a = rm.AT([1.0, 0.0, 0.1], I3)
    by_name = rm.compound(a, a, moments="exact")
    by_member = rm.compound(a, a, moments=MomentsMethod.EXACT)
    np.testing.assert_array_equal(by_name.cov, by_member.cov)
    g = rm.RelationalMap()
    g.add("w", "t", a, name="A")
    est = g.query("w", "t", method=QueryMethod.REDUCE)
    assert est.method is QueryMethod.REDUCE and est.method == "reduce"
    assert QueryMethod.parse("optimal", "method") is QueryMethod.OPTIMAL
