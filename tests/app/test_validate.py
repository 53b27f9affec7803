"""`relmap validate`: Monte Carlo check of a map query, vectorized over samples."""

from __future__ import annotations

import json

import numpy as np
import pytest

import relmap as rm
from relmap.app.cli import main
from relmap.app.validate import validate_query
from relmap.errors import ParameterError
from relmap.io import save_map
from relmap.sim import montecarlo
from tests.helpers import fig3_bridge

TINY = 1e-5  # rad: angular errors this small make every operation linear to ~1e-10


def chain_map() -> rm.RelationalMap:
    g = rm.RelationalMap()
    g.add("W", "L1", rm.AT([1.0, 0.0, 0.0], np.diag([0.04, 0.01, TINY**2])), name="A")
    g.add("L1", "L2", rm.AT([2.0, 0.0, 0.0], np.diag([0.01, 0.09, TINY**2])), name="B")
    g.add("L2", "X", rm.AT.from_sigmas([1.0, 1.0, 0.3], [0.1, 0.1, 0.1]), name="dangling")
    return g


def bridge_map(angular: float) -> rm.RelationalMap:
    """The shipped Fig. 3 bridge with heading σ ``angular`` (rad)."""
    return fig3_bridge((0.05, 0.05, angular))


def _agrees(v, k=4.0):
    a = v.agreement
    assert a.cov_rel_error < k * a.cov_rel_standard_error, (a.cov_rel_error, a)
    assert np.all(np.abs(a.mean_error) <= k * a.mean_standard_error + 1e-12)


def test_linear_chain_matches_the_analytic_result():
    """Headings 0 and (almost) no angular error: W→L2 is A + B, covariance C_A + C_B plus
    the terms of A's tiny heading error swinging B (y = y_A + y_B + x_B θ_A)."""
    g = chain_map()
    v = validate_query(g, "W", "L2", n=40_000, seed=1)
    assert v.estimate.method == "reduce" and v.estimate.expression == "A ⊕ B"
    assert v.names == ("A", "B")  # the dangling AT cannot matter and is not sampled
    s2 = TINY**2
    analytic = np.array([[0.05, 0.0, 0.0], [0.0, 0.10 + 4 * s2, 2 * s2], [0.0, 2 * s2, 2 * s2]])
    np.testing.assert_allclose(v.estimate.at.cov, analytic, rtol=1e-6, atol=1e-16)
    np.testing.assert_allclose(v.estimate.at.mean, [3.0, 0.0, 0.0], atol=1e-15)
    _agrees(v)
    np.testing.assert_allclose(v.samples.cov[:2, :2], analytic[:2, :2], rtol=0.03, atol=1e-3)
    a = v.agreement
    assert abs(float(a.nees) - 3.0) < 0.1
    assert abs(float(a.coverage) - 0.9) < 0.01
    assert abs(float(a.skewness)) < 0.01 and abs(float(a.excess_kurtosis)) < 0.1


@pytest.mark.parametrize("method", ["reduce", "optimal"])
def test_linear_isotropic_bridge_agrees(method):
    """Linear and isotropic: Delta-Y is exact, so both methods' spreads match their
    prediction (Gauss-Markov)."""
    g = bridge_map(TINY)
    n = 20_000 if method == "reduce" else 300
    v = validate_query(g, "w", "u", method=method, n=n, seed=2)
    assert v.estimate.method == method
    _agrees(v)


def test_the_batched_reduction_equals_one_query_per_sample():
    """The reduction evaluated once on a batch of sampled maps gives, sample by sample, what
    querying each sampled map gives."""
    g = bridge_map(np.radians(2.0))
    n, seed = 6, 5
    v = validate_query(g, "w", "u", method="reduce", n=n, seed=seed)
    rng = montecarlo.block_rng(seed, 0)  # n < one block: every sample is in block 0
    draws = [g.edge(name).at.sample(n, rng) for name in v.names]
    for k in range(n):
        h = rm.RelationalMap()
        for name, d in zip(v.names, draws, strict=True):
            e = g.edge(name)
            h.add(e.src, e.dst, rm.AT(d[k], e.at.cov), name=name)
        one = h.query("w", "u", method="reduce").at.mean
        np.testing.assert_allclose(v.samples.samples[k], one, atol=1e-12)


def test_delta_y_with_angular_error_agrees_with_monte_carlo():
    """With heading errors the (default, first-order-consistent) Delta-Y agrees with the
    sampled spread within a few percent (the paper's formulas were 16% off at 1°)."""
    v = validate_query(bridge_map(np.radians(1.0)), "w", "u", method="reduce", n=20_000)
    a = v.agreement
    assert a.cov_rel_error < 4 * a.cov_rel_standard_error + 0.02


def test_bad_requests():
    g = chain_map()
    with pytest.raises(ParameterError):
        validate_query(g, "W", "W")
    with pytest.raises(ParameterError):
        validate_query(g, "W", "L2", n=1)
    with pytest.raises(rm.errors.UnknownFrameError):
        validate_query(g, "W", "nowhere")


def test_cli_json_and_text(tmp_path, capsys):
    path = tmp_path / "chain.yaml"
    save_map(path, chain_map())
    assert main(["validate", str(path), "W", "L2", "-n", "5000", "--seed", "4", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["from"] == "W" and out["to"] == "L2" and out["method"] == "reduce"
    assert out["expression"] == "A ⊕ B" and out["n"] == 5000 and out["seed"] == 4
    assert out["sampled"] == ["A", "B"] and out["nees_expected"] == 3
    np.testing.assert_allclose(out["predicted"]["mean"], [3.0, 0.0, 0.0], atol=1e-12)
    for key in ("cov_rel_error", "cov_rel_standard_error", "nees", "coverage",
                "mardia_skewness", "mardia_excess_kurtosis", "mean_error"):  # fmt: skip
        assert key in out
    assert out["cov_rel_error"] < 4 * out["cov_rel_standard_error"]
    assert main(["validate", str(path), "W", "L2", "-n", "500", "--method", "optimal"]) == 0
    text = capsys.readouterr().out
    assert "optimal" in text and "NEES" in text and "Mardia" in text
    assert main(["validate", str(path), "W", "nowhere"]) == 2
    assert "no frame" in capsys.readouterr().err


def test_cli_says_the_method_why_and_how_long(tmp_path, capsys, monkeypatch):
    path = tmp_path / "chain.yaml"
    save_map(path, chain_map())
    assert main(["validate", str(path), "W", "L2", "-n", "100"]) == 0
    captured = capsys.readouterr()
    assert "relmap validate: reduce (auto chose reduce: no loop" in captured.err
    assert "samples in this process, about" in captured.err
    assert "method: auto chose reduce" in captured.out

    from relmap.app import validate

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(validate, "run", interrupted)
    assert main(["validate", str(path), "W", "L2"]) == 130
    assert "interrupted" in capsys.readouterr().err
