"""Symmetric 3×3 matrices (covariances on SE(2)'s ``(x, y, θ)``) on their six distinct entries.

``(c00, c01, c02, c11, c12, c22)``, each an array over the batch (or a Python float for one
matrix): the congruences that first-order propagation on SE(2) needs, written out once on these
entries — several times faster than batched 3×3 matmul, and symmetric by construction. The
general N-d congruence ``J C Jᵀ`` is :func:`relmap.uncertain.gaussian.congruence`.
"""

from __future__ import annotations

import numpy as np

from relmap._layout import matrix
from relmap.typing import FloatArray

__all__ = ["Entries", "congruence_3x2", "entries", "rotate", "shear", "to_matrix"]

Value = FloatArray | float
Entries = tuple[Value, Value, Value, Value, Value, Value]

_UPPER = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))


def entries(C: FloatArray) -> Entries:
    """The distinct entries of ``C`` ``(..., 3, 3)`` (Python floats for one matrix: far
    cheaper to combine than numpy scalars)."""
    if C.ndim == 2:
        (c00, c01, c02), (_, c11, c12), (_, _, c22) = C.tolist()
        return c00, c01, c02, c11, c12, c22
    return tuple(C[..., i, j] for i, j in _UPPER)  # type: ignore[return-value]


def to_matrix(e: Entries, shape: tuple[int, ...] | None = None) -> FloatArray:
    """The symmetric ``(*shape, 3, 3)`` matrix with the given distinct entries (broadcast;
    ``shape`` defaults to the entries' broadcast shape)."""
    c00, c01, c02, c11, c12, c22 = e
    if shape is None:
        shapes = {getattr(v, "shape", ()) for v in e}
        shape = shapes.pop() if len(shapes) == 1 else np.broadcast_shapes(*shapes)
    return matrix([[c00, c01, c02], [c01, c11, c12], [c02, c12, c22]], shape)


def rotate(e: Entries, c: Value, s: Value) -> Entries:
    """``K C Kᵀ`` with ``K = blkdiag([[c, -s], [s, c]], 1)`` (Eq. 3's K, a rotation by θ with
    ``c = cos θ``, ``s = sin θ``)."""
    q00, q01, q02, q11, q12, q22 = e
    cc, ss, cs = c * c, s * s, c * s
    cs_q01 = 2.0 * cs * q01
    return (
        cc * q00 - cs_q01 + ss * q11,
        cs * (q00 - q11) + (cc - ss) * q01,
        c * q02 - s * q12,
        ss * q00 + cs_q01 + cc * q11,
        s * q02 + c * q12,
        q22,
    )


def shear(e: Entries, dx: Value, dy: Value) -> Entries:
    """``H C Hᵀ`` with ``H = [[1, 0, -dy], [0, 1, dx], [0, 0, 1]]`` (Eq. 3's H)."""
    p00, p01, p02, p11, p12, p22 = e
    r0 = p02 - dy * p22  # third column of H C
    r1 = p12 + dx * p22
    return (p00 - dy * (p02 + r0), p01 - dy * p12 + dx * r0, r0, p11 + dx * (p12 + r1), r1, p22)


def congruence_3x2(
    a: Value, e: Value, b: Value, f: Value, s00: Value, s01: Value, s11: Value
) -> Entries:
    """``J S Jᵀ`` for ``J = [[a, e], [b, f], [0, 1]]`` and a symmetric 2×2 ``S`` (entries
    ``s00, s01, s11``): a planar step ``(Δx, Δy, Δθ)`` from two inputs (distance, turn)."""
    r00, r01 = a * s00 + e * s01, a * s01 + e * s11  # first row of J S
    r10, r11 = b * s00 + f * s01, b * s01 + f * s11  # second row
    return (a * r00 + e * r01, b * r00 + f * r01, r01, b * r10 + f * r11, r11, s11)
