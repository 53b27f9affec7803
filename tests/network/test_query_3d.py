"""3-D relational maps: the same reduction and joint estimate on AT3s, against GTSAM, the
planar code path, and Monte Carlo."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

import relmap as rm
from relmap.errors import SolverError
from relmap.lie import SE2, SE3, se3
from relmap.network import optimal
from relmap.network.problem import Problem
from tests.helpers import random_covs

FRAMES = "abcde"
BRIDGE = [
    ("a", "b"),
    ("b", "c"),
    ("c", "d"),
    ("d", "e"),
    ("a", "c"),
    ("b", "d"),
    ("c", "e"),
    ("a", "e"),
]


def rng(seed: int) -> np.random.Generator:
    return np.random.default_rng(seed)


def noisy_map(seed: int, edges=BRIDGE, rot_sigma=(0.005, 0.02)) -> tuple[rm.RelationalMap, dict]:
    """A map of AT3s measured (with noise drawn from their covariances) between true poses."""
    g = rng(seed)
    truth = {f: se3.exp(g.normal(size=6)) for f in FRAMES}
    m = rm.RelationalMap()
    for u, v in edges:
        sig = np.r_[g.uniform(0.02, 0.1, 3), g.uniform(*rot_sigma, 3)]
        corr = random_covs(g, (), n=6, scale=1.0)
        d = np.sqrt(np.diag(corr))
        cov = (0.7 * np.eye(6) + 0.3 * corr / np.outer(d, d)) * np.outer(sig, sig)
        z = se3.plus(se3.between(truth[u], truth[v]), g.multivariate_normal(np.zeros(6), cov))
        m.add(u, v, rm.AT3.from_matrix(z, cov), name=u + v)
    return m, truth


def gtsam_relative(m: rm.RelationalMap, src: str, dst: str, guess: dict) -> tuple[rm.AT3, float]:
    """GTSAM's estimate of dst seen from src (src held by a tight prior), and its objective."""
    key = {f: k for k, f in enumerate(m.frames)}
    graph = gtsam.NonlinearFactorGraph()
    for e in m.edges():
        noise = gtsam.noiseModel.Gaussian.Covariance(e.at.to_body())
        graph.add(gtsam.BetweenFactorPose3(key[e.src], key[e.dst], gtsam.Pose3(e.at.matrix), noise))
    values = gtsam.Values()
    for f in m.frames:
        values.insert(key[f], gtsam.Pose3(se3.between(guess[src], guess[f])))
    prior = gtsam.NonlinearFactorGraph(graph)
    prior.add(
        gtsam.PriorFactorPose3(key[src], gtsam.Pose3(), gtsam.noiseModel.Isotropic.Sigma(6, 1e-10))
    )
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(1e-15)
    params.setAbsoluteErrorTol(1e-15)
    result = gtsam.LevenbergMarquardtOptimizer(prior, values, params).optimize()
    cov = gtsam.Marginals(prior, result).marginalCovariance(key[dst])
    return rm.AT3.from_body(result.atPose3(key[dst]).matrix(), cov), 2 * graph.error(result)


# ------------------------------------------------------------------ maps of AT3s
def test_a_map_holds_one_kind_of_at():
    m = rm.RelationalMap()
    assert m.group is None and m.at_type is rm.AT
    m.add("a", "b", rm.AT3.identity())
    assert m.group is SE3 and m.at_type is rm.AT3
    with pytest.raises(TypeError, match="holds SE\\(3\\) ATs"):
        m.add("b", "c", rm.AT([1, 0, 0]))
    p = rm.RelationalMap()
    p.add("a", "b", rm.AT([1, 0, 0]))
    with pytest.raises(TypeError, match="holds SE\\(2\\) ATs"):
        p.add("b", "c", rm.AT3.identity())


def test_chains_and_parallels_reduce_to_compound_and_merge():
    m, _ = noisy_map(1, edges=[("a", "b"), ("b", "c"), ("c", "d")])
    ab, bc, cd = (m.edge(n).at for n in ("ab", "bc", "cd"))
    est = m.query("a", "d")
    assert est.method == "reduce" and est.expression == "ab ⊕ bc ⊕ cd"
    expected = ab @ bc @ cd
    np.testing.assert_allclose(est.at.matrix, expected.matrix, atol=1e-14)
    np.testing.assert_allclose(est.at.cov, expected.cov, atol=1e-16)
    back = m.query("d", "a")
    np.testing.assert_allclose(back.at.matrix, expected.reverse().matrix, atol=1e-13)
    # a parallel measurement is merged
    m.add("a", "d", rm.AT3.from_matrix(expected.matrix, 2 * expected.cov), name="direct")
    merged = m.query("a", "d", method="reduce")
    np.testing.assert_allclose(
        merged.at.cov, rm.merge(expected, m.edge("direct").at).cov, atol=1e-16
    )


def test_optimal_agrees_with_gtsam_on_a_bridge():
    """Same inputs (GTSAM's Pose3 between factors with the converted covariances). GTSAM weighs
    ``Log(z⁻¹d)`` where relmap weighs ``d ⊟ z``: the same to first order, so the optima differ
    at second order in the residuals, and GTSAM's objective at relmap's optimum equals its own
    minimum up to fourth-order terms. Measured at these noise levels: 1.4e-6 relative
    (objective), 0.003 σ (means), 0.2% (covariance)."""
    m, truth = noisy_map(2, rot_sigma=(0.002, 0.005))
    est = m.query("a", "e", method="optimal")
    ref, objective = gtsam_relative(m, "a", "e", truth)
    assert np.abs(se3.minus(est.at.matrix, ref.matrix) / ref.sigmas).max() < 0.01
    np.testing.assert_allclose(est.at.cov, ref.cov, atol=5e-3 * np.abs(ref.cov).max())
    names = [e.name for e in m.edges()]
    problem, index = optimal.problem_from_map(m, names, "a")
    sol = optimal.optimize(problem)
    at_ours = gtsam_objective(m, {f: sol.poses[index[f]] for f in m.frames})
    assert at_ours == pytest.approx(objective, rel=1e-5)
    assert sol.final_error == pytest.approx(objective, rel=1e-2)  # the objectives themselves differ


def gtsam_objective(m: rm.RelationalMap, poses: dict) -> float:
    """GTSAM's Σ rᵀΣ⁻¹r of the map's ATs at the given poses."""
    key = {f: k for k, f in enumerate(m.frames)}
    graph = gtsam.NonlinearFactorGraph()
    for e in m.edges():
        noise = gtsam.noiseModel.Gaussian.Covariance(e.at.to_body())
        graph.add(gtsam.BetweenFactorPose3(key[e.src], key[e.dst], gtsam.Pose3(e.at.matrix), noise))
    values = gtsam.Values()
    for f, T in poses.items():
        values.insert(key[f], gtsam.Pose3(T))
    return 2 * graph.error(values)


def test_delta_y_and_best_deletion_run_in_3d_close_to_optimal():
    m, _ = noisy_map(3)
    red = m.query("a", "e", method="reduce")
    opt = m.query("a", "e", method="optimal")
    assert any(name.startswith("X") for name in red.definitions)
    # an approximation: within a fraction of a σ of the optimum (measured 0.23 σ)
    err = se3.minus(red.at.matrix, opt.at.matrix) / opt.at.sigmas
    assert np.abs(err).max() < 0.5
    # K5 is not reducible by Delta-Y, but by star-mesh elimination (beyond the paper)
    k5, _ = noisy_map(3, edges=[(u, v) for i, u in enumerate(FRAMES) for v in FRAMES[i + 1 :]])
    red5 = k5.query("a", "e", method="reduce")
    assert any(name.startswith("M") for name in red5.definitions)
    err5 = se3.minus(red5.at.matrix, k5.query("a", "e").at.matrix) / red5.at.sigmas
    assert np.abs(err5).max() < 0.5


def test_planar_network_embedded_in_3d_gives_the_planar_answers():
    """One code path: planar ATs lifted to AT3 reduce (Delta-Y included) to the planar results
    exactly, and the joint estimate (z, roll, pitch given a tiny variance) agrees too."""
    g = rng(4)
    planar = rm.RelationalMap()
    lifted = rm.RelationalMap()
    keep = np.array([0, 1, 5])
    for k, (u, v) in enumerate([("w", "t"), ("w", "v"), ("t", "v"), ("t", "u"), ("u", "v")]):
        at = rm.AT(
            [g.uniform(0.5, 2), g.uniform(-1, 1), g.uniform(-0.5, 0.5)],
            random_covs(g, (), scale=0.1),
        )
        planar.add(u, v, at, name="ABCDE"[k])
        lifted.add(u, v, rm.AT3.from_planar(at), name="ABCDE"[k])
    p, s = planar.query("w", "v", method="reduce"), lifted.query("w", "v", method="reduce")
    assert p.expression == s.expression
    np.testing.assert_allclose(s.at.cov[np.ix_(keep, keep)], p.at.cov, atol=1e-14)
    np.testing.assert_allclose(s.at.translation[:2], p.at.mean[:2], atol=1e-14)

    tiny = rm.RelationalMap()
    for e in lifted.edges():
        cov = e.at.cov.copy()
        cov[[2, 3, 4], [2, 3, 4]] = 1e-10
        tiny.add(e.src, e.dst, rm.AT3.from_matrix(e.at.matrix, cov), name=e.name)
    po, so = planar.query("w", "v", method="optimal"), tiny.query("w", "v", method="optimal")
    np.testing.assert_allclose(so.at.cov[np.ix_(keep, keep)], po.at.cov, rtol=1e-6, atol=1e-12)
    np.testing.assert_allclose(so.at.translation[:2], po.at.mean[:2], atol=1e-9)


def test_dependent_ats_in_3d_are_one_joint_residual():
    """Two ATs given with a joint covariance: the optimal estimate matches GTSAM fed with the
    same joint information (as one factor would); here checked by reducing the joint to its
    blocks when the cross term is zero, and by the effect of a nonzero one."""
    g = rng(6)
    truth = {f: se3.exp(g.normal(size=6)) for f in "abc"}
    z_ab, z_bc = se3.between(truth["a"], truth["b"]), se3.between(truth["b"], truth["c"])
    C = random_covs(g, (), n=12, scale=0.05)
    joint = rm.RelationalMap()
    joint.add_joint([("a", "b", z_ab), ("b", "c", z_bc)], C, names=["p", "q"])
    joint.add(
        "a",
        "c",
        rm.AT3.from_matrix(se3.between(truth["a"], truth["c"]), np.eye(6) * 0.01),
        name="r",
    )
    est = joint.query("a", "c", method="optimal")
    # independent version: same blocks, no cross term
    blocks = rm.RelationalMap()
    blocks.add("a", "b", rm.AT3.from_matrix(z_ab, C[:6, :6]), name="p")
    blocks.add("b", "c", rm.AT3.from_matrix(z_bc, C[6:, 6:]), name="q")
    blocks.add("a", "c", joint.edge("r").at, name="r")
    indep = blocks.query("a", "c", method="optimal")
    # with the cross term the chain's information differs: so does the merged covariance
    assert np.abs(est.at.cov - indep.at.cov).max() > 1e-6
    # the joint chain alone equals compound with cross-covariance
    chain = rm.RelationalMap()
    chain.add_joint([("a", "b", z_ab), ("b", "c", z_bc)], C, names=["p", "q"])
    red = chain.query("a", "c", method="reduce")
    expected = rm.compound(
        rm.AT3.from_matrix(z_ab, C[:6, :6]),
        rm.AT3.from_matrix(z_bc, C[6:, 6:]),
        cross_cov=C[:6, 6:],
    )
    np.testing.assert_allclose(red.at.cov, expected.cov, atol=1e-15)


def test_singular_covariances_are_refused_by_the_3d_joint_estimate():
    m, _ = noisy_map(7)
    e = m.edge("ab")
    cov = e.at.cov.copy()
    cov[3, :] = cov[:, 3] = 0.0
    m.remove("ab")
    m.add("a", "b", rm.AT3.from_matrix(e.at.matrix, cov), name="ab")
    with pytest.raises(SolverError, match="'ab' has a singular covariance"):
        m.query("a", "e", method="optimal")


def test_joint_estimate_is_consistent_by_monte_carlo():
    """Measurements drawn around the truth, solved 300 times: the estimates' errors have the
    covariance the solver reports (NEES ≈ 6, mean error ≈ 0)."""
    m, truth = noisy_map(8)
    names = [e.name for e in m.edges()]
    covs = np.stack([m.edge(n).at.cov for n in names])
    problem, _ = optimal.problem_from_map(m, names, "a")
    true_rel = se3.between(truth["a"], truth["e"])
    g = rng(9)
    trials, d2, errors = 300, [], []
    ends = [(u, v) for u, v in BRIDGE]
    true_z = np.stack([se3.between(truth[u], truth[v]) for u, v in ends])
    for _ in range(trials):
        noise = np.einsum("kij,kj->ki", np.linalg.cholesky(covs), g.normal(size=(len(names), 6)))
        z = se3.plus(true_z, noise)
        sol = optimal.optimize(problem._replace(z=z))
        est = sol.relative("a", "e")  # frame ids
        err = se3.minus(est.matrix, true_rel)
        errors.append(err)
        d2.append(err @ np.linalg.solve(est.cov, err))
    d2 = np.array(d2)
    # mean of χ²₆ over 300 trials: σ = √(12/300) = 0.2; 4σ plus 5% for linearization
    assert abs(d2.mean() - 6) < 0.8 + 0.3
    mean_err = np.mean(errors, axis=0) / np.sqrt(np.diag(est.cov))
    assert np.abs(mean_err).max() < 4 / np.sqrt(trials) + 0.05


def test_sensing_in_3d():
    m, _ = noisy_map(10, edges=[("a", "b"), ("b", "c")])
    predicted = m.query("a", "c").at
    ok = rm.AT3.from_matrix(predicted.matrix, np.eye(6) * 1e-4)
    bad = rm.AT3.from_matrix(se3.plus(predicted.matrix, [1, 0, 0, 0, 0, 0]), np.eye(6) * 1e-4)
    from relmap.network.sensing import covariance_after, glitch_test

    assert glitch_test(predicted, ok).accepted and glitch_test(predicted, ok).dof == 6
    assert not glitch_test(predicted, bad).accepted
    after = covariance_after(predicted, np.eye(6) * 1e-4)
    assert np.linalg.eigvalsh(predicted.cov - after).min() > -1e-15
    decision = m.sense("a", "c", bad)
    assert not decision.added and "glitch" in decision.reason
    forecast = m.forecast_sensing(("a", "c"), np.eye(6) * 1e-4, ("a", "c"))
    assert forecast.position_shrink < 1 and forecast.heading_shrink < 1


def test_problem_defaults_to_the_plane():
    assert Problem._field_defaults["group"] is SE2
