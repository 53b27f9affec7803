"""A pose-graph least-squares problem: frames, relative-pose measurements, and its parameters.

Each measurement (an AT on the edge i → j) contributes the residual
``r = between(p_i, p_j) ⊟ z`` (heading wrapped), weighted by the inverse of its covariance in
the paper's convention (the chart of frame i), so the objective is ``Σ rᵀ Σ⁻¹ r``. Dependent
ATs contribute one joint residual weighted by their joint information.

Exactly known components are not weighted infinitely but built into the parameters:

- an AT with zero covariance ties its two frames rigidly: they share one set of parameters
  (a *rigid set*, with the pose of each member fixed in the set's root frame);
- an AT whose heading is exact (zero heading variance and cross-covariances) ties the headings
  of its frames: they share one heading parameter (a *heading class*) with fixed offsets.

Loops of exact ATs must agree (within ``atol``), or :class:`InconsistentMapError` is raised.
Other singular covariances (e.g. only x known exactly) are not supported: a clear
:class:`SolverError` says so. The anchor frame is fixed at its given pose.

3-D problems (:data:`relmap.lie.SE3`) use the same residual in relmap's SE(3) chart,
``r = between(p_i, p_j) ⊟ z = (t - t_z, Log(R R_zᵀ))``, the negative log-likelihood of the
measurement model ``z = d ⊞ n`` that :class:`relmap.AT3` defines (and samples); every frame but
the anchor owns six parameters, and covariances must be positive definite (exact components are
planar-only).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Sequence
from typing import NamedTuple

import numpy as np

from relmap import _core
from relmap.errors import InconsistentMapError, SolverError
from relmap.lie import se2
from relmap.lie.group import SE2, Group
from relmap.typing import FloatArray, IntArray
from relmap.uncertain.gaussian import max_over_last

__all__ = [
    "Parameterization",
    "Problem",
    "compose_tree",
    "parameterize",
    "standard_parameterization",
]


class Problem(NamedTuple):
    """Arrays of a pose-graph problem over frames ``0 … n-1``.

    ``i, j`` (m,) frame indices of each AT (where j is, seen from i); ``z`` (m, 3) measured
    relative poses (m, 4, 4 in 3-D); ``cov`` (m, dof, dof) their covariances (relmap's chart,
    in frame i); ``groups``: dependent ATs as ``(indices into the m ATs, joint covariance
    (dof·k, dof·k))``; ``guess`` (n, 3) or (n, 4, 4) initial poses in a common frame;
    ``anchor`` the fixed frame; ``names`` (m,) AT names for messages; ``group`` the pose group;
    ``frames`` (n,) the frame id of each index (None: the indices themselves).
    """

    n: int
    i: IntArray
    j: IntArray
    z: FloatArray
    cov: FloatArray
    groups: list[tuple[IntArray, FloatArray]]
    guess: FloatArray
    anchor: int
    names: Sequence[str]
    group: Group = SE2
    frames: list[object] | None = None


class Parameterization(NamedTuple):
    """How frame poses follow from the free parameters.

    Frame f's pose is ``p_r ∘ offset[f]`` with r = ``root[f]`` and
    ``p_r = (x_r, y_r, ϑ_c + phase[r])``, c = ``heading_class[r]``; the state is ``xy``
    (n, 2, used at roots) and ``theta`` (n, used at class roots). ``col`` (n, 3) gives the
    parameter index of (x_r, y_r, ϑ_c) for each frame (-1 where fixed: the anchor's).
    ``soft`` lists the ATs that remain residuals (exact ones hold by construction), ``kind``
    says which are heading-exact (1) or fully uncertain (0).
    """

    root: IntArray
    offset: FloatArray
    heading_class: IntArray
    phase: FloatArray
    col: IntArray
    size: int
    soft: IntArray
    kind: IntArray
    rigid: bool  #: whether any frame is not its own root (offsets are not all identity)

    def poses(self, xy: FloatArray, theta: FloatArray) -> FloatArray:
        """Frame poses (n, 3) from the state."""
        r = self.root
        p_root = np.column_stack([xy[r], theta[self.heading_class[r]] + self.phase[r]])
        if not self.rigid:
            p_root[:, 2] = se2.wrap_angle(p_root[:, 2])
            return p_root
        return se2.compose(p_root, self.offset)

    def initial_state(self, guess: FloatArray, anchor: int) -> tuple[FloatArray, FloatArray]:
        """State from per-frame guesses (roots' guesses are used; the anchor keeps its own)."""
        xy = guess[:, :2].copy()
        theta = guess[:, 2].copy()
        ra = self.root[anchor]
        p_ra = se2.compose(guess[anchor], se2.inverse(self.offset[anchor]))
        xy[ra] = p_ra[:2]
        theta[self.heading_class[ra]] = p_ra[2] - self.phase[ra]
        return xy, theta

    def step(
        self, xy: FloatArray, theta: FloatArray, delta: FloatArray
    ) -> tuple[FloatArray, FloatArray]:
        """The state moved by the parameter step ``delta`` (size,)."""
        return self.stepper()(xy, theta, delta)

    def stepper(
        self,
    ) -> Callable[[FloatArray, FloatArray, FloatArray], tuple[FloatArray, FloatArray]]:
        """:meth:`step` with the index work done once, for repeated steps."""
        free_xy = self.col[:, 0] >= 0
        roots = np.flatnonzero(free_xy & (self.root == np.arange(len(self.root))))
        cx, cy = self.col[roots, 0], self.col[roots, 1]
        heads = np.unique(self.heading_class[self.root])
        heads = heads[self.col_of_class(heads) >= 0]
        ch = self.col_of_class(heads)

        def step(
            xy: FloatArray, theta: FloatArray, delta: FloatArray
        ) -> tuple[FloatArray, FloatArray]:
            xy = xy.copy()
            theta = theta.copy()
            xy[roots, 0] += delta[cx]
            xy[roots, 1] += delta[cy]
            theta[heads] += delta[ch]
            return xy, theta

        return step

    def col_of_class(self, classes: IntArray) -> IntArray:
        """Parameter index of each heading class's ϑ (-1 if fixed)."""
        lookup = np.full(len(self.root), -1, dtype=np.int64)
        frames_col = self.col[:, 2]
        lookup[self.heading_class[self.root]] = frames_col
        return lookup[classes]

    def frame_jacobian(self, poses: FloatArray) -> FloatArray | None:
        """∂p_f/∂(x_r, y_r, ϑ_c) per frame (n, 3, 3), or None when all are identity."""
        if not self.rigid:
            return None
        xr = self._root_xy(poses)
        J = np.zeros((len(self.root), 3, 3))
        J[:, 0, 0] = J[:, 1, 1] = J[:, 2, 2] = 1.0
        J[:, 0, 2] = -(poses[:, 1] - xr[:, 1])
        J[:, 1, 2] = poses[:, 0] - xr[:, 0]
        return J

    def _root_xy(self, poses: FloatArray) -> FloatArray:
        # p_f = p_r ∘ offset_f  ⇒  t_r = t_f - R(θ_r) t_offset
        th_r = se2.angle_difference(poses[:, 2], self.offset[:, 2])
        c, s = np.cos(th_r), np.sin(th_r)
        ox, oy = self.offset[:, 0], self.offset[:, 1]
        return np.column_stack([poses[:, 0] - (c * ox - s * oy), poses[:, 1] - (s * ox + c * oy)])


def _exact_kind(cov: FloatArray, atol: float) -> IntArray:
    """0: fully uncertain, 1: heading exact only, 2: exact. Other singular forms raise."""
    scale = max_over_last(np.abs(cov), 2)
    exact = scale <= atol
    heading_exact = ~exact & (max_over_last(np.abs(cov[:, 2, :]), 1) <= 1e-12 * scale)
    return np.where(exact, 2, np.where(heading_exact, 1, 0))


def standard_parameterization(n: int, anchor: int, dof: int, m: int) -> Parameterization:
    """Every frame but the anchor owns ``dof`` parameters, laid out frame by frame; all ATs soft."""
    col = np.full((n, dof), -1, dtype=np.int64)
    free = np.arange(n) != anchor
    k = np.cumsum(free) - 1
    col[free] = dof * k[free, None] + np.arange(dof)
    frames = np.arange(n)
    return Parameterization(
        frames,
        np.zeros((n, 3)),
        frames,
        np.zeros(n),
        col,
        dof * (n - 1),
        np.arange(m),
        np.zeros(m, dtype=np.int64),
        False,
    )


def parameterize(p: Problem, *, atol: float = 1e-9) -> Parameterization:
    """Rigid sets and heading classes from the exact ATs; parameter indices; consistency checks.

    3-D problems take the standard layout; their covariances must be positive definite."""
    if p.group is not SE2:
        if len(p.cov):
            lam = np.linalg.eigvalsh(p.cov)
            bad = lam[:, 0] <= 1e-12 * lam[:, -1]
            if bad.any():
                raise SolverError(
                    f"AT {p.names[int(np.argmax(bad))]!r} has a singular covariance; the 3-D joint "
                    "estimate needs positive-definite ones (give exactly known components a tiny "
                    "variance, or use method='reduce')"
                )
        return standard_parameterization(p.n, p.anchor, p.group.dof, len(p.i))
    n = p.n
    kind = _exact_kind(p.cov, atol=0.0)
    _check_supported(p, kind)
    # Rigid sets: BFS over exact ATs, poses of members in the root's frame.
    root, offset = _spread(n, p.i, p.j, p.z, kind == 2, p.names, full=True, atol=atol)
    # Heading classes over roots, joined by heading-exact ATs (translated to their roots).
    hmask = kind == 1
    hi, hj = root[p.i[hmask]], root[p.j[hmask]]
    # heading of j's root minus i's root implied by the AT: θ_j - θ_i = z_θ, θ_f = θ_r + off_f
    zt = se2.angle_difference(p.z[hmask, 2] + offset[p.i[hmask], 2], offset[p.j[hmask], 2])
    zh = np.zeros((int(hmask.sum()), 3))
    zh[:, 2] = zt
    names_h = [p.names[k] for k in np.flatnonzero(hmask)]
    heading_class, phase_pose = _spread(
        n, hi, hj, zh, np.ones(len(hi), bool), names_h, full=False, atol=atol
    )
    phase = phase_pose[:, 2]
    roots = np.unique(root)
    classes = np.unique(heading_class[roots])
    anchor_root = root[p.anchor]
    anchor_class = heading_class[anchor_root]
    free_roots = roots[roots != anchor_root]
    free_classes = classes[classes != anchor_class]
    col = np.full((n, 3), -1, dtype=np.int64)
    if len(free_roots) == n - 1 and len(free_classes) == n - 1:
        # no exact ATs: every frame but the anchor owns (x, y, θ), laid out frame by frame
        k = np.cumsum(np.arange(n) != p.anchor) - 1
        free = np.arange(n) != p.anchor
        col[free] = 3 * k[free, None] + np.arange(3)
        size = 3 * (n - 1)
    else:
        xy_of = np.full(n, -1, dtype=np.int64)
        xy_of[free_roots] = 2 * np.arange(len(free_roots))
        th_of = np.full(n, -1, dtype=np.int64)
        th_of[free_classes] = 2 * len(free_roots) + np.arange(len(free_classes))
        has_xy = xy_of[root] >= 0
        col[has_xy, 0] = xy_of[root][has_xy]
        col[has_xy, 1] = xy_of[root][has_xy] + 1
        col[:, 2] = th_of[heading_class[root]]
        size = 2 * len(free_roots) + len(free_classes)
    rigid = bool((root != np.arange(n)).any())
    return Parameterization(
        root, offset, heading_class, phase, col, size, np.flatnonzero(kind < 2), kind, rigid
    )


def _check_supported(p: Problem, kind: IntArray) -> None:
    soft = np.flatnonzero(kind == 0)
    if len(soft):
        lam = np.linalg.eigvalsh(p.cov[soft])
        bad = lam[:, 0] <= 1e-12 * lam[:, -1]
        if bad.any():
            _unsupported(p.names[int(soft[np.argmax(bad)])])
    head = np.flatnonzero(kind == 1)
    if len(head):
        block = p.cov[head, :2, :2]
        lam = np.linalg.eigvalsh(block)
        bad = lam[:, 0] <= 1e-12 * lam[:, -1]
        if bad.any():
            _unsupported(p.names[int(head[np.argmax(bad)])])


def _unsupported(name: str) -> None:
    raise SolverError(
        f"AT {name!r} has a singular covariance that is neither exact (all zero) nor exact in "
        "heading only; the joint estimate supports those two cases (give the other exactly "
        "known components a tiny variance, or use method='reduce')"
    )


def _spread(
    n: int,
    i: IntArray,
    j: IntArray,
    z: FloatArray,
    use: np.ndarray,
    names: Sequence[str],
    *,
    full: bool,
    atol: float,
) -> tuple[IntArray, FloatArray]:
    """Components of the graph of the ``use``d ATs; each frame's pose in its component root.

    With ``full`` the whole pose is tied (rigid sets); otherwise only the heading (the x, y of
    the returned offsets are zero). Loops must agree within ``atol``.
    """
    root = np.arange(n)
    offset = np.zeros((n, 3))
    ks = np.flatnonzero(use)
    if not len(ks):
        return root, offset
    adj: dict[int, list[tuple[int, int, bool]]] = {}
    for k in ks:
        adj.setdefault(int(i[k]), []).append((int(k), int(j[k]), True))
        adj.setdefault(int(j[k]), []).append((int(k), int(i[k]), False))
    seen = np.zeros(n, bool)
    for start in adj:
        if seen[start]:
            continue
        seen[start] = True
        queue = deque([start])
        while queue:
            f = queue.popleft()
            for k, g, forward in adj[f]:
                rel = z[k] if forward else se2.inverse(z[k])
                if not full:
                    rel = np.array([0.0, 0.0, rel[2]])
                implied = se2.compose(offset[f], rel)
                if not full:
                    implied[:2] = 0.0
                if not seen[g]:
                    seen[g] = True
                    root[g] = start
                    offset[g] = implied
                    queue.append(g)
                else:
                    gap = np.abs(se2.minus(implied, offset[g]))
                    if gap.max() > atol:
                        what = "exact ATs" if full else "ATs with exact headings"
                        raise InconsistentMapError(
                            f"{what} contradict each other around a loop through AT "
                            f"{names[k]!r}: they disagree by {gap.max():.3g} (tolerance {atol:g})"
                        )
        root[start] = start
    return root, offset


def compose_tree(n: int, i: IntArray, j: IntArray, z: FloatArray, group: Group = SE2) -> FloatArray:
    """Poses ``(n, *group.point_shape)`` of frames ``0 … n-1`` composed along a spanning tree of
    the measurements ``z`` (z[k]: frame ``j[k]`` seen from ``i[k]``, the tree's links used
    forwards or reversed): breadth first from the lowest frame of each connected part, which is
    placed at the identity. By pointer jumping (each frame composes its ancestor's pose
    ``log₂ n`` times over): O(n log n) vectorized work, no Python loop per frame or level."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import breadth_first_order

    m = len(i)
    i, j = np.asarray(i, dtype=np.int64), np.asarray(j, dtype=np.int64)
    label = _core.components(n, np.ascontiguousarray(i), np.ascontiguousarray(j))
    roots = np.unique(label, return_index=True)[1]
    # one search from a virtual frame n, joined to every part's lowest frame by the identity
    top = n + 1
    rows, cols = np.concatenate([i, j]), np.concatenate([j, i])
    a, b = np.append(rows, np.full(len(roots), n)), np.append(cols, roots)
    adj = sp.csr_matrix((np.ones(len(a)), (a, b)), shape=(top, top))
    _, parent = breadth_first_order(adj, n, directed=False, return_predecessors=True)
    parent[roots] = parent[n] = n
    # each tree link parent → child is one AT between them (stored forwards or reversed)
    child = np.flatnonzero(parent[:n] != n)
    keys = rows * top + cols
    sort = np.argsort(keys, kind="stable")
    hit = sort[np.searchsorted(keys[sort], parent[child] * top + child)]
    edge, forward = hit % m, hit < m
    rel = group.identity((top,))
    flip = np.expand_dims(forward, tuple(range(1, 1 + len(group.point_shape))))
    rel[child] = np.where(flip, z[edge], group.inverse(z[edge]))
    for _ in range(int(np.ceil(np.log2(top)))):
        rel = group.compose(rel[parent], rel)
        parent = parent[parent]
    return rel[:n]
