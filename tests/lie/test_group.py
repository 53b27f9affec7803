"""relmap.lie.group: pose interpolation (:meth:`Group.interpolate`, :meth:`Group.at_times`)
against the plain mathematics: lerp of positions, the shorter arc of headings, quaternion slerp
written out, numpy's own linear interpolation, and scipy's Slerp as a peer."""

from __future__ import annotations

import numpy as np
import pytest

from relmap.lie import SE2, SE3, so3

RNG = np.random.default_rng(20260731)


def _rotation(axis, angle):  # type: ignore[no-untyped-def]
    """Rodrigues' formula written out: rotation by ``angle`` about the unit ``axis``."""
    n = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    K = np.array([[0, -n[2], n[1]], [n[2], 0, -n[0]], [-n[1], n[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def _pose3(t, R):  # type: ignore[no-untyped-def]
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


def _random_pose3(shape=()):  # type: ignore[no-untyped-def]
    q = RNG.normal(size=(*shape, 4))
    R = so3.from_quaternion(q / np.linalg.norm(q, axis=-1, keepdims=True))
    out = np.zeros((*shape, 4, 4))
    out[..., :3, :3], out[..., :3, 3], out[..., 3, 3] = R, RNG.normal(size=(*shape, 3)), 1.0
    return out


def _slerp(q0, q1, f):  # type: ignore[no-untyped-def]
    """Shoemake's slerp, the shorter arc: sin((1-f)Ω)/sin Ω q0 + sin(fΩ)/sin Ω q1."""
    q1 = q1 if np.dot(q0, q1) >= 0 else -q1
    omega = np.arccos(np.clip(np.dot(q0, q1), -1.0, 1.0))
    return (np.sin((1 - f) * omega) * q0 + np.sin(f * omega) * q1) / np.sin(omega)


def test_endpoints_are_the_two_poses():
    a = np.column_stack([RNG.normal(size=(5, 2)), RNG.uniform(-np.pi, np.pi, 5)])
    b = np.column_stack([RNG.normal(size=(5, 2)), RNG.uniform(-np.pi, np.pi, 5)])
    np.testing.assert_array_equal(SE2.interpolate(a, b, 0.0), a)
    np.testing.assert_allclose(SE2.interpolate(a, b, 1.0), b, atol=1e-15)
    A, B = _random_pose3((5,)), _random_pose3((5,))
    np.testing.assert_allclose(SE3.interpolate(A, B, 0.0), A, atol=1e-15)
    np.testing.assert_allclose(SE3.interpolate(A, B, 1.0), B, atol=1e-12)


def test_the_midpoint_of_a_known_motion():
    """From the origin to (2, 4, 6) turned 90° about (1, 1, 1): half way is (1, 2, 3) turned 45°
    about the same axis (not the screw motion's midpoint)."""
    axis = [1.0, 1.0, 1.0]
    mid = SE3.interpolate(np.eye(4), _pose3([2, 4, 6], _rotation(axis, np.pi / 2)), 0.5)
    np.testing.assert_allclose(mid, _pose3([1, 2, 3], _rotation(axis, np.pi / 4)), atol=1e-15)
    planar = SE2.interpolate(np.array([0.0, 0.0, 0.0]), np.array([2.0, 4.0, np.pi / 2]), 0.5)
    np.testing.assert_allclose(planar, [1.0, 2.0, np.pi / 4], atol=1e-15)


def test_the_heading_takes_the_shorter_arc_across_pi():
    a, b = np.array([0.0, 0.0, 3.0]), np.array([1.0, 0.0, -3.0])  # 2π - 6 ≈ 0.283 rad apart
    gap = 2 * np.pi - 6.0
    for f in (0.25, 0.5, 0.75):
        heading = 3.0 + f * gap  # through +π, never through 0
        expected = heading - 2 * np.pi if heading >= np.pi else heading
        out = SE2.interpolate(a, b, f)
        assert out[2] == pytest.approx(expected, abs=1e-15) and -np.pi <= out[2] < np.pi
        assert out[0] == pytest.approx(f)
    # and in 3-D: 170° to -170° about z passes through 180°
    A = _pose3([0, 0, 0], _rotation([0, 0, 1], np.radians(170)))
    B = _pose3([0, 0, 0], _rotation([0, 0, 1], np.radians(-170)))
    np.testing.assert_allclose(
        SE3.interpolate(A, B, 0.5)[:3, :3], _rotation([0, 0, 1], np.pi), atol=1e-15
    )


def test_rotations_follow_slerp():
    """At random fractions, the rotation is Shoemake's slerp of the two quaternions."""
    A, B = _random_pose3((50,)), _random_pose3((50,))
    f = RNG.uniform(0, 1, 50)
    out = SE3.interpolate(A, B, f)
    qa, qb = so3.to_quaternion(A[:, :3, :3]), so3.to_quaternion(B[:, :3, :3])
    want = np.array([so3.from_quaternion(_slerp(qa[k], qb[k], f[k])) for k in range(50)])
    np.testing.assert_allclose(out[:, :3, :3], want, atol=1e-12)
    np.testing.assert_allclose(
        out[:, :3, 3], A[:, :3, 3] + f[:, None] * (B[:, :3, 3] - A[:, :3, 3]), atol=1e-15
    )


def test_against_scipy_slerp():
    Rotation = pytest.importorskip("scipy.spatial.transform").Rotation
    Slerp = pytest.importorskip("scipy.spatial.transform").Slerp
    times = np.sort(RNG.uniform(0, 10, 12))
    M = _random_pose3((12,))
    t = RNG.uniform(times[0], times[-1], 40)
    theirs = Slerp(times, Rotation.from_matrix(M[:, :3, :3]))(t).as_matrix()
    np.testing.assert_allclose(SE3.at_times(times, M, t)[:, :3, :3], theirs, atol=1e-12)


@pytest.mark.parametrize(
    ("shape_a", "shape_b", "shape_f", "batch"),
    [((), (), (), ()), ((4, 1), (5,), (4, 5), (4, 5)), ((3,), (), (2, 1), (2, 3))],
)
def test_batch_shapes_broadcast(shape_a, shape_b, shape_f, batch):
    a = np.concatenate([RNG.normal(size=(*shape_a, 2)), RNG.uniform(-3, 3, (*shape_a, 1))], -1)
    b = np.concatenate([RNG.normal(size=(*shape_b, 2)), RNG.uniform(-3, 3, (*shape_b, 1))], -1)
    f = RNG.uniform(0, 1, shape_f)
    out = SE2.interpolate(a, b, f)
    assert out.shape == (*batch, 3)
    A, B = _random_pose3(shape_a), _random_pose3(shape_b)
    out3 = SE3.interpolate(A, B, f)
    assert out3.shape == (*batch, 4, 4)
    # each element is the interpolation of its own pair
    index = (0,) * len(batch)
    pick_a = a[(0,) * len(shape_a)] if shape_a else a
    pick_b = b[(0,) * len(shape_b)] if shape_b else b
    one = SE2.interpolate(pick_a, pick_b, f[(0,) * len(shape_f)] if shape_f else f)
    np.testing.assert_array_equal(out[index], one)


def test_a_sampled_path_at_times_is_numpys_linear_interpolation():
    """Positions and (unwrapped) headings interpolated by np.interp, the heading wrapped."""
    times = np.array([0.0, 1.0, 1.0, 2.5, 4.0])  # a repeated time
    x = RNG.normal(size=5)
    y = RNG.normal(size=5)
    heading = np.cumsum(RNG.uniform(-1.0, 1.0, 5))  # steps under π: the shorter arc is this one
    poses = np.column_stack([x, y, (heading + np.pi) % (2 * np.pi) - np.pi])
    t = np.array([[0.0, 0.3, 1.0], [1.7, 2.5, 4.0]])  # any shape
    out = SE2.at_times(times, poses, t)
    assert out.shape == (2, 3, 3)
    np.testing.assert_allclose(out[..., 0], np.interp(t, times, x), atol=1e-15)
    np.testing.assert_allclose(out[..., 1], np.interp(t, times, y), atol=1e-15)
    wrapped = (np.interp(t, times, heading) + np.pi) % (2 * np.pi) - np.pi
    np.testing.assert_allclose(np.cos(out[..., 2] - wrapped), 1.0, atol=1e-15)
    np.testing.assert_array_equal(SE2.at_times(times, poses, 1.0), poses[2])  # the last of equals
    np.testing.assert_array_equal(SE2.at_times([3.0], poses[:1], [3.0, 3.0]), poses[[0, 0]])
    M = _random_pose3((5,))
    np.testing.assert_allclose(SE3.at_times(times, M, times), M[[0, 2, 2, 3, 4]], atol=1e-12)
