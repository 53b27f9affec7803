"""The optimal (joint) estimate: sparse nonlinear least squares over a pose graph.

The paper's "general method ... recursive state estimation", done as it is done today: every
frame of the network estimated jointly relative to one anchor frame by Gauss-Newton with
Levenberg-Marquardt damping on the sparse normal equations, then any relative AT read off the
joint covariance (the inverse of the normal matrix at the optimum), by solving for the few
columns needed from the one sparse factorization. Exact in the linear case (no angular error),
where one step reaches the optimum.

Residuals, weights and exact components: see :mod:`relmap.network.problem`.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable, Sequence
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from relmap.at import AT
from relmap.errors import SolverError
from relmap.lie import se2
from relmap.network.problem import Parameterization, Problem, parameterize
from relmap.network.sparse import SymmetricFactor, SymmetricPattern
from relmap.typing import FloatArray, IntArray

if TYPE_CHECKING:
    from relmap.network.graph import RelationalMap

__all__ = ["Solution", "Solved", "optimize", "problem_from_map", "solve_relative"]

Frame = Hashable
Progress = Callable[[int, float], None]


class Solved(NamedTuple):
    """An AT from a joint solve and the iterations it took."""

    at: AT
    iterations: int


class _Weights(NamedTuple):
    """Square-root information L (LᵀL = Σ⁻¹) of the soft ATs and of the dependent groups."""

    edges: IntArray  #: soft ATs not in a group
    L: FloatArray  #: (k, 3, 3)
    groups: list[tuple[IntArray, FloatArray]]  #: (AT indices, L of the joint (3k, 3k))


class Solution:
    """A solved pose graph: poses, the factorized normal matrix, covariance queries."""

    def __init__(
        self,
        problem: Problem,
        param: Parameterization,
        poses: FloatArray,
        factor: SymmetricFactor | None,
        iterations: int,
        initial_error: float,
        final_error: float,
    ) -> None:
        self.problem = problem
        self.param = param
        self.poses = poses  #: (n, 3) optimized frame poses (anchor at its given pose)
        self.factor = factor
        self.iterations = iterations
        self.initial_error = initial_error  #: Σ rᵀ Σ⁻¹ r at the initial guess
        self.final_error = final_error  #: the same at the optimum

    def _frame_blocks(self, frames: Sequence[int]) -> tuple[IntArray, FloatArray]:
        """Parameter columns of the frames and ∂pose/∂parameters, (k, 3) and (k, 3, 3)."""
        frames = np.asarray(frames, dtype=np.int64)
        J = self.param.frame_jacobian(self.poses)
        Jf = np.broadcast_to(np.eye(3), (len(frames), 3, 3)) if J is None else J[frames]
        return self.param.col[frames], Jf

    def joint_cov(self, frames: Sequence[int]) -> FloatArray:
        """Joint covariance (3k, 3k) of the frames' poses (paper's chart), from one solve."""
        cols, Jf = self._frame_blocks(frames)
        k = len(cols)
        flat = cols.reshape(-1)
        free = flat >= 0
        P_params = np.zeros((3 * k, 3 * k))
        if free.any() and self.factor is not None:
            idx = flat[free]
            E = np.zeros((self.param.size, len(idx)))
            E[idx, np.arange(len(idx))] = 1.0
            X = self.factor.solve(E)
            sub = X[idx, :]
            P_params[np.ix_(free, free)] = 0.5 * (sub + sub.T)
        J = np.zeros((3 * k, 3 * k))
        for a in range(k):
            J[3 * a : 3 * a + 3, 3 * a : 3 * a + 3] = Jf[a]
        return J @ P_params @ J.T

    def relative(self, a: int, b: int) -> AT:
        """The AT of frame b seen from frame a, with its first-order covariance."""
        d, Ja, Jb = se2.between(self.poses[a], self.poses[b], jacobians=True)
        if a == self.problem.anchor and Ja is not None:
            cov = self.joint_cov([b])
            J = Jb
        else:
            cov = self.joint_cov([a, b])
            J = np.hstack([Ja, Jb])
        out = J @ cov @ J.T
        return AT._trusted(d, 0.5 * (out + out.T))


def _sqrt_information(cov: FloatArray, kind: IntArray) -> FloatArray:
    """L with LᵀL = Σ⁻¹ (k, 3, 3); heading-exact ATs weight their position only."""
    L = np.zeros_like(cov)
    full = kind == 0
    if full.any():
        C = np.linalg.cholesky(cov[full])
        L[full] = np.linalg.inv(C)
    head = kind == 1
    if head.any():
        block = np.zeros((int(head.sum()), 3, 3))
        block[:, :2, :2] = np.linalg.inv(np.linalg.cholesky(cov[head][:, :2, :2]))
        L[head] = block
    return L


def _weights(p: Problem, param: Parameterization) -> _Weights:
    in_group = np.zeros(len(p.i), bool)
    groups = []
    for members, joint in p.groups:
        in_group[members] = True
        keep = np.isin(members, param.soft)
        if not keep.all():
            raise SolverError("a dependent group with exactly known ATs is not supported")
        C = np.linalg.cholesky(joint)
        groups.append((np.asarray(members), np.linalg.inv(C)))
    edges = param.soft[~in_group[param.soft]]
    return _Weights(edges, _sqrt_information(p.cov[edges], param.kind[edges]), groups)


class _System:
    """Residuals, Jacobians and the normal equations, assembled with a fixed pattern."""

    def __init__(self, p: Problem, param: Parameterization, w: _Weights):
        self.p, self.param, self.w = p, param, w
        i, j = p.i[w.edges], p.j[w.edges]
        # 3×3 blocks (i,i), (i,j), (j,i), (j,j) of every AT, and the groups' blocks.
        rows, cols = [], []
        for a, b in ((i, i), (i, j), (j, i), (j, j)):
            rows.append(np.repeat(param.col[a], 3, axis=1).reshape(-1))
            cols.append(np.tile(param.col[b], (1, 3)).reshape(-1))
        self.group_frames = []
        for members, _ in w.groups:
            frames = np.unique(np.concatenate([p.i[members], p.j[members]]))
            self.group_frames.append(frames)
            for fa in frames:
                for fb in frames:
                    rows.append(np.repeat(param.col[fa], 3))
                    cols.append(np.tile(param.col[fb], 3))
        r = np.concatenate(rows) if rows else np.zeros(0, np.int64)
        c = np.concatenate(cols) if cols else np.zeros(0, np.int64)
        self.keep = (r >= 0) & (c >= 0)
        self.pattern = SymmetricPattern(param.size, r[self.keep], c[self.keep])

    def linearize(
        self, xy: FloatArray, theta: FloatArray
    ) -> tuple[float, FloatArray, FloatArray, FloatArray]:
        """(cost, poses, normal-matrix entries in pattern order, gradient)."""
        p, param, w = self.p, self.param, self.w
        poses = param.poses(xy, theta)
        Jf = param.frame_jacobian(poses)
        i, j = p.i[w.edges], p.j[w.edges]
        d, Ji, Jj = se2.between(poses[i], poses[j], jacobians=True)
        r = se2.minus(d, p.z[w.edges])
        if Jf is not None:
            Ji, Jj = Ji @ Jf[i], Jj @ Jf[j]
        e = np.einsum("kab,kb->ka", w.L, r)
        Li, Lj = w.L @ Ji, w.L @ Jj
        cost = float(np.einsum("ka,ka->", e, e))
        LiT, LjT = np.swapaxes(Li, -1, -2), np.swapaxes(Lj, -1, -2)
        blocks = [LiT @ Li, LiT @ Lj, LjT @ Li, LjT @ Lj]
        values = [b.reshape(-1) for b in blocks]
        grad = np.zeros(param.size)
        gi = np.einsum("kba,kb->ka", Li, e)
        gj = np.einsum("kba,kb->ka", Lj, e)
        for g_, f in ((gi, i), (gj, j)):
            c = param.col[f].reshape(-1)
            ok = c >= 0
            np.add.at(grad, c[ok], g_.reshape(-1)[ok])
        for (members, Lg), frames in zip(w.groups, self.group_frames, strict=True):
            gcost, gvals, ggrad = self._group(poses, Jf, members, Lg, frames)
            cost += gcost
            values.extend(gvals)
            grad += ggrad
        data = self.pattern.assemble(np.concatenate(values)[self.keep])
        return cost, poses, data, grad

    def _group(
        self,
        poses: FloatArray,
        Jf: FloatArray | None,
        members: IntArray,
        Lg: FloatArray,
        frames: IntArray,
    ) -> tuple[float, list[FloatArray], FloatArray]:
        p, param = self.p, self.param
        k = len(members)
        where = {int(f): a for a, f in enumerate(frames)}
        J = np.zeros((3 * k, 3 * len(frames)))
        r = np.zeros(3 * k)
        for row, m in enumerate(members):
            fi, fj = int(p.i[m]), int(p.j[m])
            d, Ji, Jj = se2.between(poses[fi], poses[fj], jacobians=True)
            if Jf is not None:
                Ji, Jj = Ji @ Jf[fi], Jj @ Jf[fj]
            r[3 * row : 3 * row + 3] = se2.minus(d, p.z[m])
            J[3 * row : 3 * row + 3, 3 * where[fi] : 3 * where[fi] + 3] += Ji
            J[3 * row : 3 * row + 3, 3 * where[fj] : 3 * where[fj] + 3] += Jj
        e, LJ = Lg @ r, Lg @ J
        H = LJ.T @ LJ
        g = LJ.T @ e
        vals = [
            H[3 * a : 3 * a + 3, 3 * b : 3 * b + 3].reshape(-1)
            for a in range(len(frames))
            for b in range(len(frames))
        ]
        grad = np.zeros(param.size)
        cols = param.col[frames].reshape(-1)
        ok = cols >= 0
        np.add.at(grad, cols[ok], g[ok])
        return float(e @ e), vals, grad

    def cost(self, xy: FloatArray, theta: FloatArray) -> float:
        p, param, w = self.p, self.param, self.w
        poses = param.poses(xy, theta)
        i, j = p.i[w.edges], p.j[w.edges]
        r = se2.minus(se2.between(poses[i], poses[j]), p.z[w.edges])
        e = np.einsum("kab,kb->ka", w.L, r)
        total = float(np.einsum("ka,ka->", e, e))
        for members, Lg in w.groups:
            rg = se2.minus(se2.between(poses[p.i[members]], poses[p.j[members]]), p.z[members])
            eg = Lg @ rg.reshape(-1)
            total += float(eg @ eg)
        return total


def optimize(
    p: Problem,
    *,
    max_iterations: int = 100,
    rtol: float = 1e-10,
    atol: float = 1e-9,
    progress: Progress | None = None,
) -> Solution:
    """Minimize ``Σ rᵀ Σ⁻¹ r`` over the frame poses, the anchor fixed, from ``p.guess``.

    Levenberg-Marquardt on the Gauss-Newton normal equations (damping ``λ·diag(H)``, λ shrunk
    after a successful step and grown after a failed one). Stops when a step lowers the
    objective by less than ``rtol`` relatively (or the step itself is below rounding). The
    returned :class:`Solution` keeps the factorization of the normal matrix at the optimum.
    """
    param = parameterize(p, atol=atol)
    w = _weights(p, param)
    system = _System(p, param, w)
    xy, theta = param.initial_state(p.guess, p.anchor)
    cost, poses, data, grad = system.linearize(xy, theta)
    initial = cost
    if param.size == 0:
        return Solution(p, param, poses, None, 0, initial, cost)
    factor = SymmetricFactor(system.pattern)
    lam = 0.0  # plain Gauss-Newton first; damping only after a failed step
    iterations = 0
    if progress:
        progress(0, cost)
    while iterations < max_iterations:
        iterations += 1
        diag = system.pattern.diagonal(data)
        if not np.all(diag > 0):
            k = int(np.argmin(diag))
            raise SolverError(
                f"parameter {k} of the network is not constrained by any AT (a frame with no "
                "informative measurement)"
            )
        factor.factorize(system.pattern.with_diagonal(data, diag * lam) if lam else data)
        delta = -factor.solve(grad)
        xy_new, theta_new = param.step(xy, theta, delta)
        new_cost = system.cost(xy_new, theta_new)
        if new_cost <= cost:
            small_step = np.abs(delta).max() <= 1e-14 * (
                1.0 + np.abs(np.concatenate([xy.ravel(), theta])).max()
            )
            decrease = cost - new_cost
            xy, theta = xy_new, theta_new
            converged = decrease <= rtol * max(cost, 1e-300) or small_step
            cost, poses, data, grad = system.linearize(xy, theta)
            lam = lam / 10.0 if lam > 1e-9 else 0.0
            if progress:
                progress(iterations, cost)
            if converged:
                break
        elif new_cost - cost <= rtol * max(cost, 1e-300):
            break  # no further decrease beyond rounding: the current point is the optimum
        else:
            lam = 1e-4 if lam == 0.0 else lam * 10.0
            if lam > 1e12:
                break  # no descent possible: the current point is a minimum to rounding
    factor.factorize(data)  # the undamped normal matrix at the optimum, for covariances
    return Solution(p, param, poses, factor, iterations, initial, cost)


def problem_from_map(
    g: RelationalMap, names: Sequence[str], anchor: Frame
) -> tuple[Problem, dict[Frame, int]]:
    """The problem formed by the named ATs of a map, anchored at frame ``anchor`` (identity).

    Initial guess: the map's own guesses where it has them for every frame (pose-graph files),
    re-expressed relative to the anchor; otherwise poses compounded along a spanning tree.
    """
    edges = [g._edges[n] for n in names]
    index: dict[Frame, int] = {anchor: 0}
    for e in edges:
        for f in (e.src, e.dst):
            if f not in index:
                index[f] = len(index)
    n = len(index)
    i = np.array([index[e.src] for e in edges], dtype=np.int64)
    j = np.array([index[e.dst] for e in edges], dtype=np.int64)
    z, cov = g._gather(names)
    position = {nm: k for k, nm in enumerate(names)}
    groups = []
    for grp in g.groups:
        members = [nm for nm in grp.names if nm in position]
        if len(members) < 2:
            continue
        sel = np.array([grp.names.index(nm) for nm in members])
        rows = (3 * sel[:, None] + np.arange(3)).reshape(-1)
        groups.append((np.array([position[nm] for nm in members]), grp.cov[np.ix_(rows, rows)]))
    guess = g._guess([f for f in index])
    if guess is None:
        guess = _tree_guess(n, i, j, z)
    else:
        guess = se2.between(guess[0], guess)
    return Problem(n, i, j, z, cov, groups, guess, 0, list(names)), index


def _tree_guess(n: int, i: IntArray, j: IntArray, z: FloatArray) -> FloatArray:
    """Poses along a spanning tree (BFS from frame 0), composed by pointer jumping:
    O(n log depth) vectorized work, no Python loop per frame."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import breadth_first_order

    m = len(i)
    rows, cols = np.concatenate([i, j]), np.concatenate([j, i])
    adj = sp.csr_matrix((np.ones(2 * m), (rows, cols)), shape=(n, n))
    order, parent = breadth_first_order(adj, 0, directed=False, return_predecessors=True)
    if len(order) < n:
        raise SolverError("the network is not connected")
    # For each tree link parent → child, one AT between them (forward or reversed).
    keys = rows * n + cols
    sort = np.argsort(keys, kind="stable")
    child = np.arange(1, n) if order[0] == 0 else np.arange(n)
    child = child[child != 0]
    hit = sort[np.searchsorted(keys[sort], parent[child] * n + child)]
    edge = hit % m
    forward = hit < m  # stored as (i, j): the AT points parent → child
    rel = np.zeros((n, 3))
    rel[child] = np.where(forward[:, None], z[edge], se2.inverse(z[edge]))
    anc = parent.copy()
    anc[0] = 0
    for _ in range(int(np.ceil(np.log2(max(n, 2))))):
        rel = se2.compose(rel[anc], rel)
        rel[0] = 0.0
        anc = anc[anc]
    return rel


def solve_relative(g: RelationalMap, names: Sequence[str], entry: Frame, exit: Frame) -> Solved:
    """The AT of ``exit`` seen from ``entry``, from the joint estimate over the named ATs."""
    problem, index = problem_from_map(g, names, entry)
    sol = optimize(problem)
    return Solved(sol.relative(index[entry], index[exit]), sol.iterations)
