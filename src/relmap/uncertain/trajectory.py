"""Trajectories: time-stamped poses, planar or 3-D, with or without a covariance per pose.

A :class:`Trajectory` holds ``n`` poses of one moving frame (``child``) in one fixed frame
(``frame``) as an :class:`relmap.AT` batch ``(n,)`` (planar ``(x, y, θ)``) or an
:class:`relmap.AT3` batch ``(n,)`` (3-D), the time stamps ``(n,)`` in seconds (or ``None`` for a
file without times, such as KITTI poses; such trajectories are paired by index), and whether the
covariances are known. Covariances are in relmap's chart (``DESIGN.md``): planar, on
``(x, y, θ)`` in the parent frame (the paper's); 3-D, 6×6 on ``(δt, δφ)`` with the translation
perturbation in the parent frame and the rotation perturbation on the left,
``R' = Exp(δφ) R``. A trajectory without covariance carries zeros and ``has_cov = False``.

Poses are kept as their source wrote them: a KITTI file's rotation matrices (nine digits) are
not re-orthonormalized, because evaluation tools (evo) use them as written and relmap's
figures must agree with theirs; they are checked to be rotations within
:data:`relmap.lie.so3.ROTATION_ATOL`. Quaternions are normalized.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from relmap._layout import components_outermost
from relmap.errors import NonFiniteError, ParameterError, ShapeError
from relmap.lie import se2, so3
from relmap.lie.so3 import ROTATION_ATOL
from relmap.typing import ArrayLike, FloatArray
from relmap.uncertain import gaussian
from relmap.uncertain.at import AT
from relmap.uncertain.at3 import AT3

__all__ = ["Trajectory", "embed_planar"]


@dataclass(frozen=True)
class Trajectory:
    """Poses of ``child`` in ``frame`` over time (module docstring). Build with
    :meth:`planar`, :meth:`from_matrices` or :meth:`from_quaternions`; they validate."""

    poses: AT | AT3  #: ``(n,)`` batch: AT for planar, AT3 for 3-D trajectories
    stamps: FloatArray | None  #: ``(n,)`` seconds, non-decreasing; None: index only
    has_cov: bool  #: whether ``poses.cov`` is a real covariance (else zeros)
    frame: str = ""  #: the fixed (parent) frame, '' if unknown
    child: str = ""  #: the moving frame, '' if unknown
    source: str = ""  #: where it came from (file, topic), for messages

    # ---------------------------------------------------------------- constructors
    @classmethod
    def planar(
        cls,
        xytheta: ArrayLike,
        stamps: ArrayLike | None = None,
        cov: ArrayLike | None = None,
        **names: str,
    ) -> Trajectory:
        """From planar poses ``(n, 3)`` ``(x, y, θ)`` and optional covariances ``(n, 3, 3)``."""
        x = np.asarray(xytheta, dtype=np.float64)
        if x.ndim != 2 or x.shape[1] != 3:
            raise ShapeError(f"planar poses must have shape (n, 3); got {x.shape}")
        poses = AT(x, None if cov is None else cov)
        return cls._checked(poses, stamps, cov is not None, names)

    @classmethod
    def from_matrices(
        cls,
        T: ArrayLike,
        stamps: ArrayLike | None = None,
        cov: ArrayLike | None = None,
        **names: str,
    ) -> Trajectory:
        """From homogeneous matrices ``(n, 4, 4)`` (rotations checked, kept as given) and
        optional covariances ``(n, 6, 6)`` in relmap's chart."""
        M = np.array(T, dtype=np.float64)
        if M.ndim != 3 or M.shape[1:] != (4, 4):
            raise ShapeError(f"poses must have shape (n, 4, 4); got {M.shape}")
        gaussian.check_finite(M, "poses")
        check_rotations(M[:, :3, :3])
        M[:, 3] = (0.0, 0.0, 0.0, 1.0)
        C = np.zeros((len(M), 6, 6))
        if cov is not None:
            # checked (symmetric and PSD within tolerance) but kept as given, to the last bit:
            # a reader must hand on what the file or message says
            gaussian.validate_covariance(cov, dim=6, name="pose covariance")
            C = np.broadcast_to(np.asarray(cov, dtype=np.float64), (len(M), 6, 6)).copy()
        poses = AT3._trusted(components_outermost(M, 2), components_outermost(C, 2))
        return cls._checked(poses, stamps, cov is not None, names)

    @classmethod
    def from_quaternions(
        cls,
        xyz: ArrayLike,
        quaternions: ArrayLike,
        stamps: ArrayLike | None = None,
        cov: ArrayLike | None = None,
        **names: str,
    ) -> Trajectory:
        """From positions ``(n, 3)`` and quaternions ``(n, 4)`` ``(qx, qy, qz, qw)`` (normalized;
        a norm off 1 by more than :data:`ROTATION_ATOL` raises)."""
        p = np.asarray(xyz, dtype=np.float64)
        q = np.asarray(quaternions, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 3 or q.shape != (len(p), 4):
            raise ShapeError(
                f"need positions (n, 3) and quaternions (n, 4); got {p.shape}, {q.shape}"
            )
        gaussian.check_finite(p, "positions")
        gaussian.check_finite(q, "quaternions")
        M = np.zeros((len(p), 4, 4))
        M[:, :3, :3] = so3.from_quaternion(q)
        M[:, :3, 3] = p
        M[:, 3, 3] = 1.0
        return cls.from_matrices(M, stamps, cov, **names)

    @classmethod
    def _checked(
        cls, poses: AT | AT3, stamps: ArrayLike | None, has_cov: bool, names: dict[str, str]
    ) -> Trajectory:
        n = poses.batch_shape[0]
        if n == 0:
            raise ShapeError("a trajectory needs at least one pose")
        t = None
        if stamps is not None:
            t = np.array(stamps, dtype=np.float64)
            if t.shape != (n,):
                raise ShapeError(f"stamps must have shape ({n},); got {t.shape}")
            gaussian.check_finite(t, "stamps")
            check_increasing(t)
            t.flags.writeable = False
        unknown = set(names) - {"frame", "child", "source"}
        if unknown:
            raise TypeError(f"unknown names {sorted(unknown)}")
        return cls(poses, t, bool(has_cov), **names)

    # ------------------------------------------------------------------- accessors
    @property
    def is_planar(self) -> bool:
        """Whether the poses are planar (AT, SE(2)) rather than 3-D (AT3)."""
        return self.poses.dim == 2

    @property
    def cov(self) -> FloatArray | None:
        """``(n, 3, 3)`` or ``(n, 6, 6)`` in relmap's chart, or None when not known."""
        return self.poses.cov if self.has_cov else None

    @property
    def matrices(self) -> FloatArray:
        """``(n, 4, 4)`` homogeneous poses (planar ones embedded at z = 0, about z)."""
        if self.is_planar:
            return embed_planar(self.poses.mean)
        return self.poses.matrix

    @property
    def positions(self) -> FloatArray:
        """``(n, 3)`` positions (planar: z = 0)."""
        return self.matrices[:, :3, 3]

    def __len__(self) -> int:
        return self.poses.batch_shape[0]

    @property
    def duration(self) -> float:
        """Seconds from the first to the last stamp (0 without stamps)."""
        return 0.0 if self.stamps is None else float(self.stamps[-1] - self.stamps[0])

    @property
    def length(self) -> float:
        """Path length (m): the sum of the distances between consecutive positions."""
        p = self.positions
        return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())

    def select(self, index: ArrayLike) -> Trajectory:
        """The poses at ``index`` (an integer array, may repeat), same frames."""
        i = np.asarray(index, dtype=np.intp)
        stamps = None if self.stamps is None else self.stamps[i]
        return replace(self, poses=self.poses[i], stamps=stamps)

    def with_poses(self, poses: AT | AT3) -> Trajectory:
        """The same stamps and names with other poses of the same count (e.g. aligned)."""
        return replace(self, poses=poses)

    def summary(self) -> dict[str, object]:
        """A JSON-able description: poses, planar or 3-D, span, length, covariance."""
        out: dict[str, object] = {
            "source": self.source,
            "poses": len(self),
            "planar": self.is_planar,
            "stamps": self.stamps is not None,
            "duration": self.duration,
            "length": self.length,
            "covariance": self.has_cov,
            "frame": self.frame,
            "child": self.child,
        }
        if self.stamps is not None:
            out["start"] = float(self.stamps[0])
            out["end"] = float(self.stamps[-1])
        return out


def embed_planar(x: ArrayLike) -> FloatArray:
    """Planar poses ``(..., 3)`` as homogeneous 3-D matrices ``(..., 4, 4)`` (z = 0)."""
    x = np.asarray(x, dtype=np.float64)
    c, s = np.cos(x[..., 2]), np.sin(x[..., 2])
    M = np.zeros((*x.shape[:-1], 4, 4))
    M[..., 0, 0], M[..., 0, 1], M[..., 1, 0], M[..., 1, 1] = c, -s, s, c
    M[..., 2, 2] = M[..., 3, 3] = 1.0
    M[..., 0, 3], M[..., 1, 3] = x[..., 0], x[..., 1]
    return M


def planar_from_matrices(M: ArrayLike) -> FloatArray:
    """``(x, y, θ)`` ``(..., 3)`` of homogeneous poses that rotate about z only."""
    M = np.asarray(M, dtype=np.float64)
    out = np.stack([M[..., 0, 3], M[..., 1, 3], np.arctan2(M[..., 1, 0], M[..., 0, 0])], -1)
    out[..., 2] = se2.wrap_angle(out[..., 2])
    return out


def check_rotations(R: FloatArray, *, atol: float = ROTATION_ATOL) -> None:
    """Raise :class:`ParameterError` at the first ``(n, 3, 3)`` matrix that is not a rotation
    within ``atol`` (|RᵀR - I| and det R = 1); the message names its index."""
    err = np.abs(np.swapaxes(R, -1, -2) @ R - np.eye(3)).max(axis=(-2, -1))
    det = np.linalg.det(R)
    bad = ~(err <= atol) | ~(np.abs(det - 1) <= 3 * atol)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ParameterError(
            f"pose {i}: not a rotation: |RᵀR - I| = {err[i]:.3g}, det = {det[i]:.6g} "
            f"(tolerance {atol:g})"
        )


def check_increasing(t: FloatArray) -> None:
    """Raise :class:`ParameterError` at the first stamp smaller than its predecessor (equal
    stamps are allowed: real files repeat a stamp now and then; association takes the first)."""
    if not np.isfinite(t).all():
        raise NonFiniteError(f"stamp {int(np.flatnonzero(~np.isfinite(t))[0])} is not finite")
    bad = np.flatnonzero(np.diff(t) < 0)
    if bad.size:
        i = int(bad[0]) + 1
        raise ParameterError(
            f"stamps must not decrease: stamp {i} ({float(t[i])!r} s) follows {float(t[i - 1])!r} s"
        )
