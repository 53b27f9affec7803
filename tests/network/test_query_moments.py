"""Map queries beyond first order: ``query(..., moments=...)``, the linearization diagnostic
(``diagnose=True``, ``linearization_check``) and its report in ``relmap validate``."""

from __future__ import annotations

import json

import numpy as np
import pytest

import relmap as rm
from relmap.app.cli import main
from relmap.app.validate import validate_query
from relmap.errors import ParameterError
from relmap.io import save_map
from relmap.lie import se2
from relmap.network.query import linearization_check
from relmap.network.reduce import reduce_network
from relmap.uncertain import moments

TINY = 1e-5  # rad


def chain(steps: rm.AT, names: str = "F") -> rm.RelationalMap:
    g = rm.RelationalMap()
    for i in range(steps.batch_shape[0]):
        g.add(f"{names}{i}", f"{names}{i + 1}", steps[i], name=f"A{i}")
    return g


def links(n: int, deg: float, turn: float = 0.0, sxy: float = 0.05) -> rm.AT:
    return rm.AT.from_sigmas(
        np.tile([1.0, 0.0, np.radians(turn)], (n, 1)),
        np.tile([sxy, sxy, np.radians(deg)], (n, 1)),
    )


def rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


# ------------------------------------------------------------------------ chains
@pytest.mark.parametrize("moments", ["exact", "unscented"])
def test_a_chain_query_is_compound_chain(moments):
    steps = links(12, 8.0, turn=9.0)
    est = chain(steps).query("F0", "F12", moments=moments)
    assert est.method == "reduce" and est.moments == moments and est.linearization is None
    ref = rm.compound_chain(steps, axis=0, moments=moments)[-1]
    np.testing.assert_allclose(est.at.mean, ref.mean, atol=1e-12)
    np.testing.assert_allclose(est.at.cov, ref.cov, rtol=1e-10, atol=1e-12)
    first = chain(steps).query("F0", "F12")
    assert first.moments == "first_order" and rel(first.at.cov, ref.cov) > 0.05


def test_exact_reversal_and_reversed_chain_against_sampling():
    """Querying a chain backwards: each link reversed exactly (moments.reverse_moments),
    the chain's exact moments; agrees with sampling where first order is far off."""
    steps = links(10, 10.0)
    rng = np.random.default_rng(0)
    x = steps.sample(100_000, rng)  # (n, 10, 3)
    z = x[..., 0] + 1j * x[..., 1]
    theta = np.cumsum(x[..., 2], axis=-1)
    end = np.sum(np.exp(1j * (theta - x[..., 2])) * z, axis=-1)
    back = -np.exp(-1j * theta[:, -1]) * end  # the reversal of the chain's end pose
    y = np.stack([back.real, back.imag, -theta[:, -1]], axis=-1)
    mc = np.cov(y.T)
    g = chain(steps)
    exact = g.query("F10", "F0", moments="exact").at
    assert rel(exact.cov, mc) < 0.015  # sampling error ≈ 0.5%
    assert rel(g.query("F10", "F0").at.cov, mc) > 0.2
    one = moments.reverse_moments(steps[0].mean, steps[0].cov)
    assert rel(one.cov, np.cov(se2.inverse(x[:, 0]).T)) < 0.02


# ---------------------------------------------------------------- the diagnostic
def test_diagnostic_is_zero_for_tiny_errors_and_matches_linearization_error():
    tiny = links(20, 1e-4, sxy=1e-3)
    check = chain(tiny).query("F0", "F20", diagnose=True).linearization
    assert check is not None and check.cov_rel_error < 1e-6 and check.mean_error_sigmas < 1e-4

    steps = links(20, 10.0)
    est = chain(steps).query("F0", "F20", diagnose=True)
    check = est.linearization
    ref = moments.linearization_error(steps, axis=0)
    assert check.cov_rel_error > 0.10
    assert check.cov_rel_error == pytest.approx(float(ref.cov_rel_error[-1]), rel=1e-10)
    np.testing.assert_allclose(check.mean_error, ref.mean_error[-1], atol=1e-12)
    # the first-order answer puts the exact mean many of its own σ away
    assert check.mean_error_sigmas > 5
    np.testing.assert_allclose(
        check.exact.cov, chain(steps).query("F0", "F20", moments="exact").at.cov
    )
    # the diagnostic does not change the answer, and is not computed unless asked
    np.testing.assert_array_equal(est.at.cov, chain(steps).query("F0", "F20").at.cov)
    assert chain(steps).query("F0", "F20").linearization is None
    same = linearization_check(chain(steps), "F0", "F20")
    assert same.cov_rel_error == check.cov_rel_error
    assert linearization_check(chain(steps), "F3", "F3").cov_rel_error == 0.0


# ------------------------------------------------------------- bridge with chains
def bridge_with_chains(deg: float, n: int, backwards: bool) -> rm.RelationalMap:
    """Fig. 3's bridge (almost no angular error: Delta-Y is then nearly exact) between two
    serial chains of ``n`` links with σθ = ``deg`` per link; the second chain's ATs point
    towards the source when ``backwards``."""
    g = rm.RelationalMap()
    step = rm.AT.from_sigmas([1.0, 0.0, np.radians(3.0)], [0.05, 0.05, np.radians(deg)])
    for i in range(n):
        g.add(f"S{i}", "w" if i == n - 1 else f"S{i + 1}", step, name=f"P{i}")
    for name, s, t, mean in (
        ("A", "w", "t", [1.0, 1.0, 0.2]),
        ("B", "w", "v", [2.0, 0.0, -0.1]),
        ("C", "t", "v", [1.2, -0.8, -0.3]),
        ("D", "t", "u", [1.1, 0.9, 0.1]),
        ("E", "u", "v", [0.3, -1.9, -0.4]),
    ):
        g.add(s, t, rm.AT.from_sigmas(mean, [0.05, 0.05, TINY]), name=name)
    for i in range(n):
        a, b = ("u" if i == 0 else f"Q{i}"), f"Q{i + 1}"
        g.add(*((b, a) if backwards else (a, b)), step, name=f"Q{i}")
    return g


@pytest.mark.parametrize("backwards", [False, True])
def test_bridge_between_chains_exact_moments_match_monte_carlo(backwards):
    """Large angular errors on the serial parts: the exact-moments reduction agrees with
    Monte Carlo to its sampling error, first order is 20-35% off, and the diagnostic predicts
    first order's sampled error without sampling."""
    g = bridge_with_chains(8.0, 8, backwards)
    v = validate_query(g, "S0", "Q8", method="reduce", n=20_000, seed=3)
    assert "X₁" in v.estimate.expression  # the reduction went through Delta-Y
    mc, se = v.samples.cov, float(v.agreement.cov_rel_standard_error)
    first = g.query("S0", "Q8", method="reduce").at
    exact = g.query("S0", "Q8", method="reduce", moments="exact").at
    assert rel(exact.cov, mc) < 2 * se
    assert rel(first.cov, mc) > 15 * se
    sig = np.sqrt(np.diag(mc))
    assert np.all(np.abs(se2.minus(exact.mean, v.samples.mean)) < 4 * sig / np.sqrt(v.samples.n))
    assert v.linearization is not None
    assert abs(v.linearization.cov_rel_error - float(v.agreement.cov_rel_error)) < 4 * se


def test_batched_exact_reduction_broadcasts_over_a_sample_axis():
    g = bridge_with_chains(8.0, 3, True)
    rng = np.random.default_rng(2)
    draws = {e.name: e.at.sample(3, rng) for e in g.edges()}
    batched = [
        (e.name, e.src, e.dst, rm.AT(draws[e.name], np.broadcast_to(e.at.cov, (3, 3, 3))))
        for e in g.edges()
    ]
    out = reduce_network(batched, "S0", "Q3", moments="exact").at
    for k in range(3):
        one = [(e.name, e.src, e.dst, rm.AT(draws[e.name][k], e.at.cov)) for e in g.edges()]
        ref = reduce_network(one, "S0", "Q3", moments="exact").at
        np.testing.assert_allclose(out.mean[k], ref.mean, atol=1e-12)
        np.testing.assert_allclose(out.cov[k], ref.cov, rtol=1e-9, atol=1e-12)


# ------------------------------------------------------- merging after compounding
def test_merge_after_compounding_fuses_moment_matched_gaussians():
    """What ``moments`` means where a merge follows: the branches' (exact) moments, then the
    Gaussian update of Eqs. (8)-(10) on them."""
    steps = links(10, 6.0, turn=3.0)
    g = chain(steps)
    end = rm.compound_chain(steps, axis=0)[-1]
    direct = rm.AT.from_sigmas(end.mean, [0.5, 0.5, np.radians(10.0)])
    g.add("F0", "F10", direct, name="D")
    est = g.query("F0", "F10", method="reduce", moments="exact")
    # the reduction works on the loop from both ends, (A0 ⊕ … ⊕ A5 ⊕ (A9ᴿ ⊕ … ⊕ A6ᴿ)ᴿ) ⊗ D;
    # with exact moments the reversals cancel and the branch is the exact chain
    assert "A9ᴿ" in est.expression
    ref = rm.merge(rm.compound_chain(steps, axis=0, moments="exact")[-1], direct)
    np.testing.assert_allclose(est.at.mean, ref.mean, atol=1e-12)
    np.testing.assert_allclose(est.at.cov, ref.cov, rtol=1e-10, atol=1e-14)


def test_merge_after_compounding_is_not_the_exact_posterior():
    """The documented limit: fusing the crescent's moment-matched Gaussian with an informative
    direct AT is further from the exact posterior (crescent × Gaussian, by importance
    sampling) than first order, which linearizes where the direct AT cuts the crescent."""
    steps = links(10, 6.0, turn=3.0)
    g = chain(steps)
    end = rm.compound_chain(steps, axis=0)[-1]
    direct = rm.AT.from_sigmas(end.mean, [0.5, 0.5, np.radians(10.0)])
    g.add("F0", "F10", direct, name="D")
    x = steps.sample(200_000, np.random.default_rng(1))
    z = x[..., 0] + 1j * x[..., 1]
    theta = np.cumsum(x[..., 2], axis=-1)
    c = np.sum(np.exp(1j * (theta - x[..., 2])) * z, axis=-1)
    X = np.stack([c.real, c.imag, theta[:, -1]], axis=-1)
    d = X - direct.mean
    w = np.exp(-0.5 * np.einsum("ni,ij,nj->n", d, np.linalg.inv(direct.cov), d))
    w /= w.sum()
    mean = w @ X
    post = ((X - mean) * w[:, None]).T @ (X - mean)
    first = g.query("F0", "F10", method="reduce", diagnose=True)
    exact = g.query("F0", "F10", method="reduce", moments="exact").at
    assert rel(first.at.cov, post) < 0.03
    assert rel(exact.cov, post) > 0.15
    # the diagnostic flags how much the branch summary matters, not the error vs the posterior
    assert first.linearization.cov_rel_error > 0.15


# --------------------------------------------------------------- validate + errors
def test_validate_reports_the_predicted_linearization_error(tmp_path, capsys):
    g = chain(links(20, 10.0))
    path = tmp_path / "chain.json"
    save_map(path, g)
    assert main(["validate", str(path), "F0", "F20", "-n", "4000", "--seed", "1", "--json"]) == 0
    s = json.loads(capsys.readouterr().out)
    lin = s["predicted_linearization"]
    ref = moments.linearization_error(links(20, 10.0), axis=0)
    assert lin["cov_rel_error"] == pytest.approx(float(ref.cov_rel_error[-1]), rel=1e-9)
    assert s["moments"] == "first_order" and lin["mean_error_sigmas"] > 5
    # predicted beside sampled: 43% predicted, sampled within its (4000-sample) error
    assert abs(s["cov_rel_error"] - lin["cov_rel_error"]) < 5 * s["cov_rel_standard_error"]
    assert main(["validate", str(path), "F0", "F20", "-n", "4000", "--moments", "exact"]) == 0
    out = capsys.readouterr().out
    assert "first order vs exact moments (predicted, no sampling)" in out and "exact" in out
    v = validate_query(g, "F0", "F20", method="optimal", n=2)
    assert v.linearization is None and v.summary()["predicted_linearization"] is None


def test_moments_beyond_first_order_need_se2_and_the_reduction():
    g3 = rm.RelationalMap()
    g3.add("a", "b", rm.AT3.from_euler([1, 0, 0, 0, 0, 0.1], np.eye(6) * 1e-3), name="A")
    g3.add("b", "c", rm.AT3.from_euler([1, 0, 0, 0, 0, 0.1], np.eye(6) * 1e-3), name="B")
    with pytest.raises(ParameterError, match="SE\\(2\\)"):
        g3.query("a", "c", moments="exact")
    with pytest.raises(ParameterError, match="SE\\(2\\)"):
        g3.query("a", "c", diagnose=True)
    with pytest.raises(ParameterError, match="SE\\(2\\)"):
        reduce_network([("A", "a", "b", g3.edge("A").at)], "a", "b", moments="unscented")
    g = chain(links(3, 5.0))
    g.add("F0", "F3", rm.AT.from_sigmas([3.0, 0, 0], [0.1, 0.1, 0.1]), name="D")
    with pytest.raises(ParameterError, match="optimal"):
        g.query("F0", "F3", method="optimal", moments="exact")
    with pytest.raises(ParameterError, match="auto"):
        g.query("F0", "F3", moments="exact")  # a loop: auto chooses optimal
    with pytest.raises(ParameterError, match="moments must be"):
        g.query("F0", "F3", method="reduce", moments="second_order")
    assert g.query("F0", "F3", method="reduce", moments="exact").method == "reduce"
