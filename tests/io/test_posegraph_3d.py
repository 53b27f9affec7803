"""relmap.io.posegraph in 3-D: g2o ``VERTEX_SE3:QUAT``/``EDGE_SE3:QUAT`` and the legacy ``EDGE3``,
on the shared files and synthetic ones; the information conversion checked from first principles
and against GTSAM's ``readG2o``; exact round trips; malformed input."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

import relmap as rm
from relmap.errors import FileFormatError, ParameterError, ShapeError
from relmap.io import PoseGraph, read_graph, write_graph
from relmap.io.posegraph import QUATERNION_ATOL, file_information
from relmap.lie import SE3, se3, so3

# Counts: sphere2500, parking-garage and torus3D from ../shared/data/README.md; the grids counted
# in the files themselves (the README gives none).
SHARED_3D = [
    ("sphere2500.g2o", 2500, 4949),
    ("parking-garage.g2o", 1661, 6275),
    ("torus3D.g2o", 5000, 9048),
    ("smallGrid3D.g2o", 125, 297),
    ("tinyGrid3D.g2o", 9, 11),
]
UPPER = np.triu_indices(6)  # g2o's order of the 21 information numbers: row by row
P = np.block([[np.zeros((3, 3)), np.eye(3)], [np.eye(3), np.zeros((3, 3))]])  # swaps the blocks


def _file_rows(path, tag):
    """The numbers of every ``tag`` line of a file, as floats (ids included)."""
    rows = [ln.split()[1:] for ln in path.read_text().splitlines() if ln.split()[:1] == [tag]]
    return np.array(rows, dtype=np.float64)


def _positive(q):
    return np.where(q[:, 3:] < 0, -q, q) + 0.0


def _g2o_error(delta):
    """g2o's EdgeSE3 error of the relative pose ``delta = z⁻¹ (Tᵢ⁻¹ Tⱼ)``: translation and the
    vector part of its (qw ≥ 0) quaternion (g2o's ``internal::toVectorMQT``)."""
    q = _positive(so3.to_quaternion(delta[..., :3, :3]))
    return np.concatenate([delta[..., :3, 3], q[..., :3]], axis=-1)


def _random_information(rng, m):
    """Full 6×6 information matrices, translation-rotation cross blocks included."""
    L = rng.normal(size=(m, 6, 6))
    return L @ np.swapaxes(L, 1, 2) + 0.5 * np.eye(6)


def _random_file(tmp_path, rng, name="rand.g2o", fixed=True):
    """A 3-D g2o file with non-contiguous ids, quaternions of both signs and norms off 1 by up to
    5e-4 (accepted), full information matrices and awkward numbers."""
    ids = [10, 3, 7, 42, 0, 5]
    lines = []
    for i in ids:
        q = rng.normal(size=4)
        q *= (1 + rng.uniform(-5e-4, 5e-4)) / np.linalg.norm(q)
        lines.append(
            f"VERTEX_SE3:QUAT {i} "
            + " ".join(map(repr, [*(rng.normal(size=3) * 10).tolist(), *q.tolist()]))
        )
    edges = [(10, 3), (3, 7), (7, 42), (42, 0), (0, 10), (7, 10), (5, 42), (3, 5)]
    info = _random_information(rng, len(edges))
    for (a, b), inf in zip(edges, info, strict=True):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        nums = [*rng.normal(size=3).tolist(), *q.tolist(), *inf[UPPER].tolist()]
        lines.append(f"EDGE_SE3:QUAT {a} {b} " + " ".join(map(repr, nums)))
    if fixed:
        lines.append("FIX 3 7")
    p = tmp_path / name
    p.write_text("\n".join(lines) + "\n")
    return p


def _assert_same_graph(a: PoseGraph, b: PoseGraph) -> None:
    assert a.format == b.format and a.group is b.group
    for field in (
        "vertex_ids",
        "poses",
        "edge_from",
        "edge_to",
        "information",
        "fixed",
        "vertex_quaternions",
        "edge_quaternions",
    ):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field), err_msg=field)
    np.testing.assert_array_equal(a.measurements.mean, b.measurements.mean)
    np.testing.assert_array_equal(a.measurements.cov, b.measurements.cov)


# ----------------------------------------------------------------------------- shared files
@pytest.mark.parametrize(("name", "n", "m"), SHARED_3D)
def test_shared_3d_files_load_as_written(data_dir, name, n, m):
    path = data_dir / "posegraph3d" / name
    g = read_graph(path)
    assert g.format == "g2o" and g.group is SE3
    assert isinstance(g.measurements, rm.AT3) and g.measurements.batch_shape == (m,)
    assert g.vertex_ids.shape == (n,) and len(np.unique(g.vertex_ids)) == n
    assert g.poses.shape == (n, 4, 4) and g.information.shape == (m, 6, 6)
    assert g.vertex_quaternions.shape == (n, 4) and g.edge_quaternions.shape == (m, 4)
    assert g.fixed.shape == (0,)
    # vertices: translations and quaternions exactly as written (sign flipped to qw ≥ 0)
    v = _file_rows(path, "VERTEX_SE3:QUAT")
    np.testing.assert_array_equal(g.vertex_ids, v[:, 0])
    np.testing.assert_array_equal(g.poses[:, :3, 3], v[:, 1:4])
    np.testing.assert_array_equal(g.vertex_quaternions, _positive(v[:, 4:8]))
    assert np.all(g.vertex_quaternions[:, 3] >= 0)
    np.testing.assert_array_equal(g.poses[:, 3], np.broadcast_to([0, 0, 0, 1.0], (n, 4)))
    R = g.poses[:, :3, :3]
    np.testing.assert_allclose(
        R @ np.swapaxes(R, 1, 2), np.broadcast_to(np.eye(3), R.shape), atol=1e-15
    )
    # edges: ids, measurement and the 21 information numbers row by row, exactly
    e = _file_rows(path, "EDGE_SE3:QUAT")
    np.testing.assert_array_equal(g.edge_from, e[:, 0])
    np.testing.assert_array_equal(g.edge_to, e[:, 1])
    np.testing.assert_array_equal(g.measurements.translation, e[:, 2:5])
    np.testing.assert_array_equal(g.edge_quaternions, _positive(e[:, 5:9]))
    np.testing.assert_array_equal(g.information[:, UPPER[0], UPPER[1]], e[:, 9:])
    np.testing.assert_array_equal(g.information, np.swapaxes(g.information, 1, 2))
    # rotations are those of the quaternions normalized
    q = g.edge_quaternions / np.linalg.norm(g.edge_quaternions, axis=1, keepdims=True)
    np.testing.assert_allclose(g.measurements.rotation, so3.from_quaternion(q), atol=2e-16 * 8)
    i, j = g.edge_indices()
    np.testing.assert_array_equal(g.vertex_ids[i], g.edge_from)
    np.testing.assert_array_equal(g.vertex_ids[j], g.edge_to)


@pytest.mark.parametrize(("name", "n", "m"), SHARED_3D)
def test_roundtrip_of_real_3d_files_is_exact(data_dir, tmp_path, name, n, m):
    """read → write → read gives identical arrays; the edge and vertex numbers written are the
    file's own (quaternions kept as written, qw ≥ 0); writing again gives the same text."""
    src = data_dir / "posegraph3d" / name
    g = read_graph(src)
    out = tmp_path / name
    write_graph(out, g)
    back = read_graph(out)
    _assert_same_graph(g, back)
    for tag, q in (("VERTEX_SE3:QUAT", slice(4, 8)), ("EDGE_SE3:QUAT", slice(5, 9))):
        orig, new = _file_rows(src, tag), _file_rows(out, tag)
        orig[:, q] = _positive(orig[:, q])
        np.testing.assert_array_equal(new, orig, err_msg=tag)
    text = out.read_text()
    write_graph(out, back)
    assert out.read_text() == text
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary left


def test_agrees_with_gtsam_readG2o(data_dir):
    """Same poses and measurements as GTSAM's readG2o (is3D); its noise model is the file's
    information with the blocks swapped to rotation first and NOT rescaled: against the true
    information on GTSAM's own rotation-first body chart (relmap's covariance converted,
    ``AT3.to_body``) its rotation block is 4×, its cross block 2×, its translation block 1×."""
    path = data_dir / "posegraph3d" / "sphere2500.g2o"
    g = read_graph(path)
    factors, initial = gtsam.readG2o(str(path), True)
    assert initial.size() == len(g.vertex_ids) and factors.size() == len(g.edge_from)
    poses = np.array([initial.atPose3(k).matrix() for k in g.vertex_ids.tolist()])
    np.testing.assert_allclose(poses, g.poses, rtol=0, atol=1e-14)
    z = np.array([factors.at(k).measured().matrix() for k in range(factors.size())])
    np.testing.assert_allclose(z, g.measurements.matrix, rtol=0, atol=1e-14)
    keys = np.array([list(factors.at(k).keys()) for k in range(factors.size())])
    np.testing.assert_array_equal(keys, np.stack([g.edge_from, g.edge_to], axis=1))
    true_info = np.linalg.inv(g.measurements.to_body())  # rotation first, body frame
    for k in range(0, factors.size(), 97):
        theirs = np.linalg.inv(factors.at(k).noiseModel().covariance())
        np.testing.assert_allclose(theirs, P @ g.information[k] @ P, rtol=1e-9, atol=1e-9)
        ours = true_info[k]
        scale = np.abs(theirs).max()
        np.testing.assert_allclose(theirs[:3, :3], 4 * ours[:3, :3], rtol=0, atol=1e-10 * scale)
        np.testing.assert_allclose(theirs[:3, 3:], 2 * ours[:3, 3:], rtol=0, atol=1e-10 * scale)
        np.testing.assert_allclose(theirs[3:, 3:], ours[3:, 3:], rtol=0, atol=1e-10 * scale)


def test_gtsam_block_relation_with_full_information(tmp_path):
    """The same ×4 / ×2 / ×1 relation on a file whose information has translation-rotation cross
    terms (the shared files have none), edges and vertices from readG2o."""
    rng = np.random.default_rng(11)
    path = _random_file(tmp_path, rng, fixed=False)
    g = read_graph(path)
    factors, initial = gtsam.readG2o(str(path), True)
    for row, k in enumerate(g.vertex_ids.tolist()):
        np.testing.assert_allclose(initial.atPose3(k).matrix(), g.poses[row], atol=1e-12)
    true_info = np.linalg.inv(g.measurements.to_body())
    for k in range(factors.size()):
        f = factors.at(k)
        np.testing.assert_allclose(f.measured().matrix(), g.measurements.matrix[k], atol=1e-12)
        theirs = np.linalg.inv(f.noiseModel().covariance())
        scale = np.abs(theirs).max()
        assert np.abs(theirs[:3, 3:]).max() > 0.05 * scale  # cross terms really present
        np.testing.assert_allclose(theirs, P @ g.information[k] @ P, atol=1e-9 * scale)
        S = np.diag([4.0, 4, 4, 1, 1, 1])  # theirs = √S ours √S, rotation first
        np.testing.assert_allclose(
            theirs, np.sqrt(S) @ true_info[k] @ np.sqrt(S), rtol=0, atol=1e-9 * scale
        )


# ----------------------------------------------------------------- the information conversion
def _quadratic_forms(g: PoseGraph, edges, eps, rng, n=400):
    """For body twists ξ of size ~eps at each edge's z: g2o's eᵀ I e of ``z Exp(ξ)`` (e from the
    quaternion of ``z⁻¹ z Exp(ξ)``) and relmap's δᵀ Σ⁻¹ δ of the same pose (δ its chart
    difference from z)."""
    out_g2o, out_relmap = [], []
    for k in edges:
        z = g.measurements.matrix[k]
        xi = rng.normal(size=(n, 6)) * eps
        T = z @ se3.exp(xi)
        e = _g2o_error(se3.between(z, T))
        d = se3.minus(T, z)
        out_g2o.append(np.einsum("ka,ab,kb->k", e, g.information[k], e))
        out_relmap.append(np.einsum("ka,ab,kb->k", d, np.linalg.inv(g.measurements.cov[k]), d))
    return np.concatenate(out_g2o), np.concatenate(out_relmap)


@pytest.mark.parametrize("source", ["sphere2500.g2o", "random"])
def test_information_conversion_is_the_first_order_one(data_dir, tmp_path, source):
    """Σ = K I⁻¹ Kᵀ, K = blkdiag(R_z, 2R_z) is g2o's information converted to first order: the two
    quadratic forms of the same perturbed pose agree, with a relative error that falls as ε²
    (a wrong factor on any block would leave an O(1) error). Measured at ε = 1e-2, 1e-3, 1e-4:
    1.4e-4, 1.3e-6, 1.8e-8 (sphere2500)."""
    rng = np.random.default_rng(3)
    if source == "random":
        g = read_graph(_random_file(tmp_path, rng))
        edges = range(len(g.edge_from))
    else:
        g = read_graph(data_dir / "posegraph3d" / source)
        edges = [0, 100, 2500, 4948]
    errors = []
    for eps in (1e-2, 1e-3, 1e-4):
        a, b = _quadratic_forms(g, edges, eps, rng)
        errors.append(np.abs(a / b - 1).max())
    assert errors[1] < 1e-4 and errors[2] < 1e-6
    assert errors[2] < 0.03 * errors[1] < 0.03**2 * errors[0]  # second order: ×0.01 per decade

    # the conversion without the factor 2 on the rotation is off by O(1)
    k = 0
    R = g.measurements.rotation[k]
    K = np.zeros((6, 6))
    K[:3, :3] = K[3:, 3:] = R
    wrong = rm.AT3.from_matrix(g.measurements.matrix[k], K @ np.linalg.inv(g.information[k]) @ K.T)
    bad = g._replace(
        measurements=rm.AT3.stack([wrong]),
        information=g.information[:1],
    )
    a, b = _quadratic_forms(bad, [0], 1e-4, rng)
    assert np.abs(a / b - 1).max() > 0.5


@pytest.mark.parametrize("name", ["sphere2500.g2o", "parking-garage.g2o"])
def test_file_information_inverts_the_conversion(data_dir, tmp_path, name):
    """Back to the file's numbers to rounding times the matrix's condition number (parking-garage
    has information matrices conditioned 2.6e9: measured 7.6e-11 relative; sphere2500 8.5e-16)."""
    g = read_graph(data_dir / "posegraph3d" / name)
    info = file_information(g.measurements)
    err = np.abs(info - g.information).max(axis=(1, 2)) / np.abs(g.information).max(axis=(1, 2))
    assert np.all(err <= 1e-14 * np.linalg.cond(g.information))
    r = read_graph(_random_file(tmp_path, np.random.default_rng(5)))
    np.testing.assert_allclose(file_information(r.measurements), r.information, rtol=1e-10)
    one = file_information(r.measurements[2])  # one AT, no batch
    np.testing.assert_allclose(one, r.information[2], rtol=1e-10)


def test_graph_built_in_relmap_writes_and_reads_back(tmp_path):
    """A graph of AT3s with no quaternions kept: its file_information written, the covariances
    read back (1e-12 relative), the rotations' own quaternions written (qw ≥ 0)."""
    rng = np.random.default_rng(8)
    m = 6
    mean = se3.exp(rng.normal(size=(m, 6)))
    L = rng.normal(size=(m, 6, 6)) * 0.1
    cov = L @ np.swapaxes(L, 1, 2) + 1e-3 * np.eye(6)
    meas = rm.AT3.from_matrix(mean, cov)
    graph = PoseGraph(
        format="g2o",
        vertex_ids=np.arange(m, dtype=np.int64),
        poses=se3.exp(rng.normal(size=(m, 6))),
        edge_from=np.arange(m, dtype=np.int64),
        edge_to=(np.arange(m, dtype=np.int64) + 1) % m,
        measurements=meas,
        information=file_information(meas),
        fixed=np.array([0], dtype=np.int64),
    )
    out = tmp_path / "built.g2o"
    write_graph(out, graph)
    back = read_graph(out)
    assert list(back.fixed) == [0] and back.group is SE3
    np.testing.assert_allclose(back.poses, graph.poses, atol=1e-15)
    np.testing.assert_allclose(back.measurements.matrix, mean, atol=1e-15)
    np.testing.assert_allclose(back.measurements.cov, cov, rtol=1e-12, atol=1e-15)
    assert np.all(back.vertex_quaternions[:, 3] >= 0) and np.all(back.edge_quaternions[:, 3] >= 0)


# ----------------------------------------------------------------------- synthetic round trips
def test_roundtrip_of_a_random_file_is_exact(tmp_path):
    src = _random_file(tmp_path, np.random.default_rng(2))
    g = read_graph(src)
    assert list(g.fixed) == [3, 7]
    assert list(g.vertex_ids) == [10, 3, 7, 42, 0, 5]
    norms = np.linalg.norm(g.vertex_quaternions, axis=1)
    assert np.abs(norms - 1).max() > 1e-5  # not normalized: kept as written
    out = tmp_path / "out.g2o"
    write_graph(out, g)
    back = read_graph(out)
    _assert_same_graph(g, back)
    assert "-0.0 " not in out.read_text()
    text = out.read_text()
    write_graph(out, back)
    assert out.read_text() == text


def test_write_with_new_poses_changes_only_vertex_lines(data_dir, tmp_path):
    """Solving moves the poses: write_graph takes (n, 4, 4) matrices, writes the rotations' own
    quaternions where the kept ones no longer give them, and leaves every edge line alone."""
    g = read_graph(data_dir / "posegraph3d" / "smallGrid3D.g2o")
    rng = np.random.default_rng(4)
    moved = se3.plus(g.poses, rng.normal(size=(len(g.poses), 6)) * 0.1)
    moved[0] = g.poses[0]  # one vertex kept where it is
    a, b = tmp_path / "a.g2o", tmp_path / "b.g2o"
    write_graph(a, g)
    write_graph(b, g, poses=moved)
    la, lb = a.read_text().splitlines(), b.read_text().splitlines()
    changed = [k for k, (x, y) in enumerate(zip(la, lb, strict=True)) if x != y]
    assert changed == list(range(1, 125))  # every vertex line but the first
    back = read_graph(b)
    np.testing.assert_array_equal(back.poses[:, :3, 3], moved[:, :3, 3])
    np.testing.assert_allclose(back.poses, moved, atol=1e-15)
    np.testing.assert_array_equal(back.vertex_quaternions[0], g.vertex_quaternions[0])
    np.testing.assert_array_equal(back.information, g.information)
    np.testing.assert_array_equal(back.edge_quaternions, g.edge_quaternions)


def test_failed_3d_write_leaves_existing_file_untouched(tmp_path):
    g = read_graph(_random_file(tmp_path, np.random.default_rng(6)))
    p = tmp_path / "g.g2o"
    write_graph(p, g)
    before = p.read_bytes()
    with pytest.raises(ShapeError, match=r"poses must have shape \(6, 4, 4\).*\(6, 3\)"):
        write_graph(p, g, poses=np.zeros((6, 3)))
    skewed = np.array(g.poses)
    skewed[2, 0, 1] += 1e-3
    with pytest.raises(ParameterError, match=r"poses\[2\] has no rotation matrix"):
        write_graph(p, g, poses=skewed)
    mirrored = np.array(g.poses)
    mirrored[4, :3, 0] *= -1
    with pytest.raises(ParameterError, match=r"poses\[4\].*det = -1"):
        write_graph(p, g, poses=mirrored)
    with pytest.raises(ShapeError, match="information"):
        write_graph(p, g._replace(information=g.information[:, :3, :3]))
    assert p.read_bytes() == before
    assert not [q for q in tmp_path.iterdir() if q.name.startswith(".")]


def test_file_information_rejects_what_has_none():
    at = rm.AT3.from_matrix(np.eye(4), np.diag([1.0, 1, 1, 1, 1, 0]))
    with pytest.raises(ParameterError, match="not positive definite"):
        file_information(rm.AT3.stack([rm.AT3.from_matrix(np.eye(4), np.eye(6)), at]))
    with pytest.raises(ParameterError, match="read only"):
        file_information(rm.AT3.from_matrix(np.eye(4), np.eye(6)), format="toro")


# ----------------------------------------------------------------------------- legacy EDGE3
def test_legacy_ground_truth_builds_vertices_from_edges(data_dir, tmp_path):
    """sphere2500_groundtruth.txt: EDGE3 lines only, noise-free. Vertices 0..2499 placed by
    composing along a spanning tree from vertex 0 (identity); every edge then agrees with its
    two poses (to the file's 6 printed digits, accumulated: measured 1.8e-4 m, 4.5e-6 rad), and
    the edges are those of sphere2500.g2o."""
    path = data_dir / "posegraph3d" / "sphere2500_groundtruth.txt"
    gt = read_graph(path)
    assert gt.format == "toro" and gt.group is SE3
    assert gt.vertex_quaternions is None and gt.edge_quaternions is None
    np.testing.assert_array_equal(gt.vertex_ids, np.arange(2500))
    assert gt.measurements.batch_shape == (4949,)
    np.testing.assert_array_equal(gt.poses[0], np.eye(4))
    i, j = gt.edge_indices()
    r = se3.minus(se3.between(gt.poses[i], gt.poses[j]), gt.measurements.matrix)
    assert np.abs(r[:, :3]).max() < 1e-3 and np.abs(r[:, 3:]).max() < 2e-5
    # measurement: x y z roll pitch yaw, R = Rz(yaw) Ry(pitch) Rx(roll); covariance J I⁻¹ Jᵀ
    e = _file_rows(path, "EDGE3")
    np.testing.assert_array_equal(gt.edge_from, e[:, 0])
    np.testing.assert_array_equal(gt.information[:, UPPER[0], UPPER[1]], e[:, 8:])
    for k in (0, 1234, 4948):
        ref = rm.AT3.from_euler(e[k, 2:8], np.linalg.inv(gt.information[k]))
        np.testing.assert_array_equal(gt.measurements.matrix[k], ref.matrix)
        np.testing.assert_allclose(gt.measurements.cov[k], ref.cov, rtol=1e-12, atol=1e-18)
    noisy = read_graph(data_dir / "posegraph3d" / "sphere2500.g2o")
    pairs = set(zip(noisy.edge_from.tolist(), noisy.edge_to.tolist(), strict=True))
    assert pairs == set(zip(gt.edge_from.tolist(), gt.edge_to.tolist(), strict=True))
    with pytest.raises(ParameterError, match="read only"):
        write_graph(tmp_path / "gt.txt", gt)
    assert not list(tmp_path.iterdir())


def test_legacy_vertex3_file_and_disconnected_parts(tmp_path):
    info = " ".join(map(str, np.eye(6)[UPPER]))
    p = tmp_path / "legacy.graph"
    p.write_text(
        "VERTEX3 0 0 0 0 0 0 0\n"
        "VERTEX3 1 1 2 3 0.1 -0.2 0.3\n"
        f"EDGE3 0 1 1 2 3 0.1 -0.2 0.3 {info}\n"
    )
    g = read_graph(p)
    assert g.format == "toro" and g.group is SE3
    np.testing.assert_array_equal(g.poses[1, :3, 3], [1, 2, 3])
    np.testing.assert_allclose(g.poses[1, :3, :3], so3.from_euler([0.1, -0.2, 0.3]), atol=1e-15)
    Rz, Ry, Rx = (so3.exp(a * np.eye(3)[k]) for a, k in ((0.3, 2), (-0.2, 1), (0.1, 0)))
    np.testing.assert_allclose(g.poses[1, :3, :3], Rz @ Ry @ Rx, atol=1e-15)
    np.testing.assert_allclose(g.measurements.matrix[0], g.poses[1], atol=1e-15)
    # an EDGE3 naming a vertex with no VERTEX3 line, when the file has VERTEX3 lines
    p.write_text(p.read_text() + f"EDGE3 1 2 1 0 0 0 0 0 {info}\n")
    with pytest.raises(FileFormatError, match="vertex j = 2 has no VERTEX3 line") as exc:
        read_graph(p)
    assert exc.value.line == 4
    # edges only, two connected parts: each placed from its smallest id, at the identity
    q = tmp_path / "parts.graph"
    q.write_text(
        f"EDGE3 5 6 1 0 0 0 0 0.5 {info}\nEDGE3 2 1 0 1 0 0 0 0 {info}\n"
        f"EDGE3 6 7 1 0 0 0 0 0.5 {info}\n"
    )
    g = read_graph(q)
    np.testing.assert_array_equal(g.vertex_ids, [1, 2, 5, 6, 7])
    np.testing.assert_array_equal(g.poses[0], np.eye(4))
    np.testing.assert_allclose(g.poses[1, :3, 3], [0, -1, 0], atol=1e-15)  # 2 → 1 reversed
    np.testing.assert_array_equal(g.poses[2], np.eye(4))
    np.testing.assert_allclose(g.poses[4, :3, 3], [1 + np.cos(0.5), np.sin(0.5), 0], atol=1e-15)


# ----------------------------------------------------------------------------- bad input
INFO6 = " ".join(map(str, np.eye(6)[UPPER]))
GOOD_3D = (
    "# a 3-D graph\n"  # 1
    "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\n"  # 2
    "VERTEX_SE3:QUAT 1 1 0 0 0 0 0.0998334 0.9950042\n"  # 3
    "\n"  # 4
    "VERTEX_SE3:QUAT 2 2 0 0 0 0 0 1\n"  # 5
    f"EDGE_SE3:QUAT 0 1 1 0 0 0 0 0 1 {INFO6}\n"  # 6
    f"EDGE_SE3:QUAT 1 2 1 0 0 0 0 0 1 {INFO6}\n"  # 7
)


def _info_with(**entries):
    """The identity information with some upper-triangle entries replaced, as the 21 numbers."""
    info = np.eye(6)
    for name, value in entries.items():
        r, c = int(name[1]), int(name[2])
        info[r, c] = info[c, r] = value
    return " ".join(map(repr, info[UPPER].tolist()))


@pytest.mark.parametrize(
    ("bad_line", "match"),
    [
        ("VERTEX_SE3:QUAT 3 0 0 0 0 0 0 1.0011", r"VERTEX_SE3:QUAT quaternion .* norm 1\.0011"),
        ("VERTEX_SE3:QUAT 3 0 0 0 0 0 0.6 0.6", r"norm 0\.848528, not 1 \(tolerance 0\.001\)"),
        ("VERTEX_SE3:QUAT 3 0 0 0 0 0 0 0", "quaternion .* has norm 0, not 1"),
        (f"EDGE_SE3:QUAT 0 2 1 0 0 0 0 0 0 {INFO6}", "EDGE_SE3:QUAT quaternion .* norm 0,"),
        (f"EDGE_SE3:QUAT 0 2 1 0 0 0 0 0 2 {INFO6}", "EDGE_SE3:QUAT quaternion .* norm 2,"),
        (
            "VERTEX_SE3:QUAT 3 0 0 0 0 0 1",
            r"VERTEX_SE3:QUAT needs 8 fields .*\(id x y z qx qy qz qw\); got 7",
        ),
        ("VERTEX_SE3:QUAT 3 0 0 0 0 0 0 1 0", "VERTEX_SE3:QUAT needs 8 fields .*got 9"),
        (f"EDGE_SE3:QUAT 0 2 1 0 0 0 0 0 1 {INFO6} 1", "EDGE_SE3:QUAT needs 30 fields .*got 31"),
        (
            "EDGE_SE3:QUAT 0 2 1 0 0 0 0 0 1 1 0 0 0 0 0",
            "needs 30 fields .*21 information numbers.*got 15",
        ),
        ("EDGE_SE3:QUAT 0 2 1 0 0 0 0 1", "needs 30 fields .*got 8"),
        ("VERTEX_SE2 3 0 0 0", "mixed 2-D and 3-D records: VERTEX_SE2 is 2-D.*line 2.*3-D g2o"),
        ("EDGE_SE2 0 2 1 0 0 1 0 0 1 0 1", "mixed 2-D and 3-D records: EDGE_SE2 is 2-D"),
        ("VERTEX3 3 0 0 0 0 0 0", "unknown record tag 'VERTEX3' in a 3-D g2o file"),
        (
            f"EDGE_SE3:QUAT 0 2 1 0 0 0 0 0 1 {_info_with(i01=2.0)}",
            r"not positive definite \(indefinite\)",
        ),
        (
            f"EDGE_SE3:QUAT 0 2 1 0 0 0 0 0 1 {_info_with(i34=1.0)}",
            r"not positive definite \(singular\)",
        ),
        (
            f"EDGE_SE3:QUAT 0 2 1 0 0 0 0 0 1 {_info_with(i55=-1.0)}",
            "diagonal entry is not positive",
        ),
        (
            f"EDGE_SE3:QUAT 0 2 1 0 0 0 0 0 1 {_info_with(i22=0.0)}",
            "diagonal entry is not positive",
        ),
        (f"EDGE_SE3:QUAT 0 2 1 0 0 0 0 0 1 {_info_with(i05=1.0000001)}", r"\(indefinite\)"),
        ("VERTEX_SE3:QUAT 3 0 0 inf 0 0 0 1", "non-finite number in a VERTEX_SE3:QUAT line"),
        (f"EDGE_SE3:QUAT 0 2 1 0 0 nan 0 0 1 {INFO6}", "non-finite number in a EDGE_SE3:QUAT"),
        (f"EDGE_SE3:QUAT 0 9 1 0 0 0 0 0 1 {INFO6}", "vertex j = 9 has no VERTEX_SE3:QUAT line"),
        ("VERTEX_SE3:QUAT 1 0 0 0 0 0 0 1", r"duplicate vertex id 1 \(first defined on line 3\)"),
        ("VERTEX_SE3:QUAT 3 0 0 0 0 0 0 one", "'one' is not a number"),
        ("FIX 7", "FIX vertex 7 has no VERTEX_SE3:QUAT line"),
    ],
)
def test_malformed_3d_g2o_names_file_and_line(tmp_path, bad_line, match):
    p = tmp_path / "bad.g2o"
    p.write_text(GOOD_3D + bad_line + "\n" + "VERTEX_SE3:QUAT 8 0 0 0 0 0 0 1\n")
    with pytest.raises(FileFormatError, match=match) as info:
        read_graph(p)
    assert info.value.line == 8
    assert str(info.value).startswith(f"{p}:8: ")


def test_good_3d_file_and_quaternion_tolerance(tmp_path):
    p = tmp_path / "good.g2o"
    p.write_text(GOOD_3D)
    g = read_graph(p)
    assert g.group is SE3 and len(g.vertex_ids) == 3
    np.testing.assert_allclose(se3.log(g.poses[1])[3:], [0, 0, 0.2], atol=1e-7)
    # within QUATERNION_ATOL: accepted and normalized (file precision; 4 digits stay within)
    near = 1 + 0.9 * QUATERNION_ATOL
    p.write_text(GOOD_3D + f"VERTEX_SE3:QUAT 3 0 0 0 0 0 0 {near!r}\n")
    g = read_graph(p)
    np.testing.assert_array_equal(g.poses[3], np.eye(4))
    assert g.vertex_quaternions[3, 3] == near  # kept as written
    # qw < 0 is flipped to qw > 0 (the same rotation), and written without "-0.0"
    p.write_text(GOOD_3D + "VERTEX_SE3:QUAT 3 0 0 0 0 0 0 -1\n")
    g = read_graph(p)
    np.testing.assert_array_equal(g.vertex_quaternions[3], [0, 0, 0, 1])
    write_graph(p, g)
    assert "VERTEX_SE3:QUAT 3 0 0 0 0 0 0 1\n" in p.read_text()


@pytest.mark.parametrize(
    ("text", "line", "match"),
    [
        (
            "VERTEX_SE2 0 0 0 0\nVERTEX_SE3:QUAT 1 0 0 0 0 0 0 1\n",
            2,
            "VERTEX_SE3:QUAT is 3-D.*2-D g2o",
        ),
        ("FIX 0\nEDGE_SE3:QUAT 0 1 0 0 0 0 0 0 1 " + INFO6 + "\nVERTEX_SE2 0 0 0 0\n", 3, "mixed"),
        ("EDGE3 0 1 0 0 0 0 0 0 " + INFO6 + "\nEDGE2 0 1 1 0 0 1 0 1 1 0 0\n", 2, "EDGE2 is 2-D"),
        ("EDGE3 0 1 0 0 0 0 0 " + INFO6 + "\n", 1, r"EDGE3 needs 29 fields .*got 28"),
        ("EDGE3 0 1 0 0 0 0 0 0 " + _info_with(i33=0.0) + "\n", 1, "EDGE3 information matrix"),
        (
            "VERTEX3 0 0 0 0 0 0\n",
            1,
            r"VERTEX3 needs 7 fields .*\(id x y z roll pitch yaw\); got 6",
        ),
    ],
)
def test_other_malformed_3d_files(tmp_path, text, line, match):
    p = tmp_path / "bad.graph"
    p.write_text(text)
    with pytest.raises(FileFormatError, match=match) as info:
        read_graph(p)
    assert info.value.line == line
    assert str(info.value).startswith(f"{p}:{line}: ")


def test_text_that_the_core_leaves_to_python_reads_the_same(tmp_path):
    """A non-ASCII comment, Python's wider whitespace (no-break space, \\x1f) and a record the
    core's number syntax refuses ("+-" is not a number, reported at its line) go to the plain
    path of the reader: the same graph, the same errors."""
    ascii_file, wide = tmp_path / "a.g2o", tmp_path / "b.g2o"
    ascii_file.write_text(GOOD_3D + "FIX 0\n")
    wide.write_text(
        GOOD_3D.replace("# a 3-D graph", "# un graphe 3-D, café").replace(
            " 1 1 0", "\u00a01\x1f1 0"
        )
        + "FIX\u00a00\n",
        encoding="utf-8",
    )
    a, b = read_graph(ascii_file), read_graph(wide)
    for field in ("vertex_ids", "poses", "edge_from", "edge_to", "information", "fixed"):
        np.testing.assert_array_equal(getattr(b, field), getattr(a, field))
    np.testing.assert_array_equal(b.measurements.cov, a.measurements.cov)
    bad = tmp_path / "c.g2o"
    bad.write_text(GOOD_3D.replace("VERTEX_SE3:QUAT 2 2 0", "VERTEX_SE3:QUAT 2 +-2 0"))
    with pytest.raises(FileFormatError, match="'\\+-2' is not a number") as info:
        read_graph(bad)
    assert info.value.line == 5
