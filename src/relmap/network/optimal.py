"""The optimal (joint) estimate: sparse nonlinear least squares over a pose graph.

The paper's "general method ... recursive state estimation", done as it is done today: every
frame of the network estimated jointly relative to one anchor frame by Gauss-Newton with
Levenberg-Marquardt damping on the sparse normal equations, then any relative AT read off the
joint covariance (the inverse of the normal matrix at the optimum), by solving for the few
columns needed from the one sparse factorization. Exact in the linear case (no angular error),
where one step reaches the optimum.

The residuals, their chart Jacobians and the normal equations, accumulated straight into the
sparse matrix's slots, are one pass of relmap's compiled core over the ATs
(``relmap._core.normal_equations2`` in the plane, ``src/core/linearize.cpp``;
``relmap._core.normal_equations3`` and :func:`residuals3` in 3-D, ``src/core/linearize3.cpp``).
The matrix is factorized by the core's sparse Cholesky (:mod:`relmap.network.sparse`); one
Levenberg-Marquardt loop drives the planar (:class:`_System`: frames tied into rigid sets and
exact headings) and the 3-D (:class:`_LieSystem`) problems.

A loss (:mod:`relmap.network.losses`, e.g. Huber's) makes the cost ``Σ ρ(s²)`` of the ATs'
normalized residuals: each AT's information is weighted by ``ρ'(s²)`` at every linearization
(iteratively reweighted least squares); :attr:`Solution.weights` are those at the optimum.
Residuals, weights and exact components: see :mod:`relmap.network.problem`.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable, Mapping, Sequence
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from relmap import _core
from relmap.errors import (
    NumericalError,
    ParameterError,
    SolverError,
    UnknownATError,
    UnknownFrameError,
)
from relmap.lie.group import SE2, Group
from relmap.network.losses import L2, Loss, LossChoice, restrict
from relmap.network.problem import Parameterization, Problem, compose_tree, parameterize
from relmap.network.sparse import SymmetricFactor, SymmetricPattern, selected_inverse_blocks
from relmap.typing import FloatArray, IntArray
from relmap.uncertain.at import AT
from relmap.uncertain.at3 import AT3
from relmap.uncertain.gaussian import congruence, inverse_pd

if TYPE_CHECKING:
    from relmap.network.parts import MapView

__all__ = [
    "Solution",
    "Solved",
    "optimize",
    "problem_from_map",
    "solve_frames",
    "solve_map",
    "solve_relative",
]

Frame = Hashable
Progress = Callable[[int, float], None]


class Solved(NamedTuple):
    """An AT from a joint solve and the iterations it took."""

    at: AT | AT3
    iterations: int


class _Linearized(NamedTuple):
    """A linearization of the cost at some poses."""

    cost: float  #: Σ ρ(s²) (Σ rᵀ Σ⁻¹ r under least squares)
    poses: FloatArray  #: the frames' poses
    data: FloatArray  #: the normal matrix Σ w Jᵀ Σ⁻¹ J (the pattern's CSC data)
    grad: FloatArray  #: the gradient Σ w Jᵀ Σ⁻¹ r
    weights: FloatArray | None  #: every AT's w = ρ'(s²) (None: least squares)


class _Weights(NamedTuple):
    """Information W = Σ⁻¹ of the soft ATs; square-root information L (LᵀL = Σ⁻¹) of the
    dependent groups."""

    edges: IntArray  #: soft ATs not in a group
    W: FloatArray  #: (k, dof, dof)
    groups: list[tuple[IntArray, FloatArray]]  #: (AT indices, L of the joint (dof·k, dof·k))


class Solution:
    """A solved pose graph: poses, the factorized normal matrix, covariance queries.

    Poses are named by **frame id** (:attr:`frames`, the map's or file's names; a pose-graph
    vertex id, not its row): :meth:`relative`, :meth:`joint_cov` and :meth:`pose` take ids, and
    an unknown id is a :class:`relmap.errors.FrameError` naming it. Rows (the order of
    :attr:`poses` and :meth:`marginals`) are :meth:`row` of an id.
    """

    def __init__(
        self,
        problem: Problem,
        param: Parameterization,
        poses: FloatArray,
        factor: SymmetricFactor | None,
        iterations: int,
        initial_error: float,
        final_error: float,
        data: FloatArray | None = None,
        converged: bool = True,
        stale: bool = False,
        weights: FloatArray | None = None,
        loss: LossChoice = None,
    ) -> None:
        self.problem = problem
        self.param = param
        self.poses = poses  #: (n, 3) or (n, 4, 4) optimized frame poses (anchor at its given pose)
        self.group: Group = problem.group
        self._factor = factor
        # whether _factor holds another matrix than _data (factorized on first use: a caller
        # that wants only the poses never pays for it)
        self._stale = stale and factor is not None and data is not None
        self.iterations = iterations
        self.initial_error = initial_error  #: the cost Σ ρ(rᵀ Σ⁻¹ r) at the initial guess
        self.final_error = final_error  #: the same at the optimum
        self.loss = loss  #: the loss(es) minimized (None: least squares)
        self._weights = weights
        self._data = data  # the normal matrix at the optimum (pattern's CSC data)
        #: whether the stopping rule was met (False: stopped at max_iterations)
        self.converged = converged
        #: the frame id of each row of :attr:`poses`
        self.frames: list[object] = (
            list(problem.frames) if problem.frames is not None else list(range(problem.n))
        )
        self._row = dict(zip(self.frames, range(len(self.frames)), strict=True))

    @property
    def weights(self) -> FloatArray:
        """The weight ``ρ'(s²)`` of each AT at the optimum, ``(m,)`` in the order of
        ``problem.names`` (a pose graph's edges in file order, a map's ATs as added): the factor
        on its information in the normal matrix, so in the covariances. 1 under least squares;
        a dependent group's ATs share their group's; exact ATs (held by construction) 1."""
        if self._weights is None:
            return np.ones(len(self.problem.i))
        return self._weights

    @property
    def factor(self) -> SymmetricFactor | None:
        """The sparse Cholesky factorization of the normal matrix at the optimum (None when
        nothing is free)."""
        if self._stale:
            assert self._factor is not None and self._data is not None
            self._factor.factorize(self._data)
            self._stale = False
        return self._factor

    def row(self, frame: object) -> int:
        """The row of frame ``frame`` (an id) in :attr:`poses` and :meth:`marginals`."""
        try:
            return self._row[frame]
        except (KeyError, TypeError):
            raise UnknownFrameError(f"no frame {frame!r} in the solution") from None

    def has_frame(self, frame: object) -> bool:
        """Whether ``frame`` (an id) is one of the solved frames."""
        try:
            return frame in self._row
        except TypeError:
            return False

    def _rows(self, frames: Sequence[object]) -> list[int]:
        return [self.row(f) for f in frames]

    def pose(self, frame: object) -> FloatArray:
        """The optimized pose of frame ``frame`` (an id) in the anchor's frame."""
        return self.poses[self.row(frame)]

    def _frame_blocks(self, frames: Sequence[int]) -> tuple[IntArray, FloatArray]:
        """Parameter columns of the frames and ∂pose/∂parameters, (k, dof) and (k, dof, dof)."""
        frames = np.asarray(frames, dtype=np.int64)
        dof = self.group.dof
        J = self.param.frame_jacobian(self.poses) if self.group is SE2 else None
        Jf = np.broadcast_to(np.eye(dof), (len(frames), dof, dof)) if J is None else J[frames]
        return self.param.col[frames], Jf

    def joint_cov(self, frames: Sequence[object]) -> FloatArray:
        """Joint covariance (dof·k, dof·k) of the poses of ``frames`` (ids; relmap's chart, in
        the anchor's frame), from the one factorization."""
        return self._joint_cov_rows(self._rows(frames))

    def _joint_cov_rows(self, frames: Sequence[int]) -> FloatArray:
        cols, Jf = self._frame_blocks(frames)
        k, b = len(cols), self.group.dof
        flat = cols.reshape(-1)
        free = flat >= 0
        P_params = np.zeros((b * k, b * k))
        if free.any() and self.factor is not None:
            P_params[np.ix_(free, free)] = self.factor.inverse_submatrix(flat[free])
        J = np.zeros((b * k, b * k))
        for a in range(k):
            J[b * a : b * a + b, b * a : b * a + b] = Jf[a]
        return congruence(J, P_params)

    def marginals(self) -> FloatArray:
        """The marginal covariance of every frame's pose (relmap's chart), ``(n, dof, dof)``.

        By selected inversion (Takahashi) of the normal matrix at the optimum: only the blocks
        of the inverse on the factor's pattern are formed, never the dense inverse. The anchor
        (fixed) has zero covariance. Without exact ATs; with them, frame by frame solves.
        """
        n, b = len(self.poses), self.group.dof
        out = np.zeros((n, b, b))
        free = np.flatnonzero(self.param.col[:, 0] >= 0)
        standard = self.param.size == b * (n - 1) and not self.param.kind.any()
        if standard and self.factor is not None and len(free):
            blocks = selected_inverse_blocks(
                self.factor.pattern, self._data, block=b, factor=self.factor
            )
            out[free] = blocks[self.param.col[free, 0] // b]
            return out
        for f in range(n):
            out[f] = self._joint_cov_rows([f])
        return out

    def relative(self, a: object, b: object) -> AT | AT3:
        """The AT (AT3 in 3-D) of frame ``b`` seen from frame ``a`` (frame ids), with its
        first-order covariance."""
        return self._relative_rows(self.row(a), self.row(b))

    def _relative_rows(self, a: int, b: int) -> AT | AT3:
        d, Ja, Jb = self.group.between(self.poses[a], self.poses[b], jacobians=True)
        if a == self.problem.anchor:  # the anchor is exact: only b's covariance matters
            cov = self._joint_cov_rows([b])
            J = Jb
        else:
            cov = self._joint_cov_rows([a, b])
            J = np.hstack([Ja, Jb])
        out = congruence(J, cov)
        if not (np.all(np.isfinite(out)) and np.all(np.isfinite(d))):
            raise NumericalError(
                f"the AT of frame {self.frames[b]!r} seen from {self.frames[a]!r} overflowed "
                "(inf/NaN): the measurements are too large for floating point"
            )
        kind = AT if self.group is SE2 else AT3
        return kind._trusted(d, out)


def _information(cov: FloatArray, kind: IntArray) -> FloatArray:
    """W = Σ⁻¹ (k, dof, dof), symmetrized; heading-exact ATs weight their position only.

    One batched inverse (:func:`relmap.uncertain.gaussian.inverse_pd`: the covariances were checked
    positive definite when parameterized)."""
    W = np.zeros_like(cov)
    full = kind == 0
    if full.all():
        W = inverse_pd(cov)
    elif full.any():
        W[full] = inverse_pd(cov[full])
    head = kind == 1
    if head.any():
        block = np.zeros((int(head.sum()), 3, 3))
        block[:, :2, :2] = inverse_pd(cov[head][:, :2, :2])
        W[head] = block
    return np.ascontiguousarray(W)


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
    return _Weights(edges, _information(p.cov[edges], param.kind[edges]), groups)


class _Losses(NamedTuple):
    """Which loss each soft AT takes, for the systems: per distinct loss, the rows of the plain
    soft ATs (:attr:`_Weights.edges`) it applies to (the others keep least squares), and each
    dependent group's loss (None: least squares)."""

    parts: list[tuple[Loss, IntArray]]
    groups: list[Loss | None]
    edges: IntArray  #: the plain soft ATs (indices into the problem's ATs)
    members: list[IntArray]  #: each group's ATs
    m: int  #: the problem's number of ATs

    def weigh(self, W: FloatArray, r: FloatArray) -> tuple[FloatArray, FloatArray, float]:
        """At residuals ``r`` (k, b) of the plain ATs with information ``W`` (k, b, b): ``W``
        times the weights ``ρ'(s²)``, the weights, and ``Σ (ρ(s²) - ρ'(s²) s²)``, what the cost
        has beyond the weighted squares the normal equations sum (0 under least squares,
        exactly: a loss of huge scale reproduces least squares bit for bit)."""
        s2 = np.einsum("ka,kab,kb->k", r, W, r)
        w = np.ones_like(s2)
        extra = 0.0
        for loss, rows in self.parts:
            part = s2[rows]
            w[rows] = weight = loss.weight(part)
            extra += float(np.sum(loss.value(part) - weight * part))
        return W * w[:, None, None], w, extra

    def every(self, plain: FloatArray | None, groups: Sequence[float]) -> FloatArray:
        """The weights of all the problem's ATs (m,) from the plain ATs' (:meth:`weigh`'s) and
        the groups'."""
        assert plain is not None
        out = np.ones(self.m)
        out[self.edges] = plain
        for members, weight in zip(self.members, groups, strict=True):
            out[members] = weight
        return out


def _losses(p: Problem, w: _Weights, loss: LossChoice) -> _Losses | None:
    """Each soft AT's loss from ``loss`` (one for all, or by AT name); None when every AT is
    least squares (the plain path, unchanged)."""
    if loss is None or isinstance(loss, L2):
        return None
    m = len(p.i)
    kinds: list[Loss] = []
    which = np.full(m, -1, dtype=np.int64)  # index into kinds; -1: least squares

    def kind(value: object) -> int:
        if not isinstance(value, Loss):
            raise ParameterError(
                f"a loss must have value(s2) and weight(s2) (relmap.network.losses); got {value!r}"
            )
        if isinstance(value, L2):
            return -1
        for k, known in enumerate(kinds):
            if known is value or known == value:
                return k
        kinds.append(value)
        return len(kinds) - 1

    if isinstance(loss, Mapping):
        index = {name: k for k, name in enumerate(p.names)}
        for name, value in loss.items():
            if name not in index:
                raise UnknownATError(f"no AT named {name!r} to take a loss")
            which[index[name]] = kind(value)
    else:
        which[:] = kind(loss)
    if not kinds:
        return None
    plain = which[w.edges]
    parts = [(value, np.flatnonzero(plain == k)) for k, value in enumerate(kinds)]
    group_losses: list[Loss | None] = []
    for members, _ in w.groups:
        chosen = np.unique(which[members])
        if len(chosen) > 1:
            names = ", ".join(repr(p.names[k]) for k in members)
            raise ParameterError(f"the dependent ATs {names} are one residual: give them one loss")
        group_losses.append(kinds[chosen[0]] if chosen[0] >= 0 else None)
    group_members = [np.asarray(members) for members, _ in w.groups]
    kept = [part for part in parts if len(part[1])]
    return _Losses(kept, group_losses, w.edges, group_members, m)


def _group_weight(loss: Loss | None, e: FloatArray) -> tuple[float, float]:
    """(weight ``ρ'(s²)``, cost ``ρ(s²)``) of a dependent group's whitened joint residual ``e``,
    ``s² = |e|²``; (1, s²) under least squares."""
    s2 = float(e @ e)
    if loss is None:
        return 1.0, s2
    at = np.array([s2])
    return float(loss.weight(at)[0]), float(loss.value(at)[0])


def _slots(position: IntArray) -> IntArray:
    """The CSC slots of every plain AT's four blocks, (m, 4·b²) contiguous int64."""
    m, b2 = position.shape[0], int(np.prod(position.shape[1:]))
    return np.ascontiguousarray(position.reshape(m, b2), dtype=np.int64)


_NO_FRAME_JACOBIAN = np.zeros((0, 3, 3))  # every frame its own root: ∂pose/∂parameters = I


def _residuals2(
    poses: FloatArray, i: IntArray, j: IntArray, z: FloatArray, Jf: FloatArray | None
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The planar residuals ``r = p_i⁻¹ ∘ p_j ⊟ z`` (m, 3) and their Jacobians ``Ji, Jj``
    (m, 3, 3) with respect to the parameters of frames i and j (through ``Jf``, each frame's
    ∂pose/∂parameters, for rigid sets): relmap's compiled core (``relmap._core.residuals2``,
    the closed forms of :func:`relmap.lie.se2.between` with its Jacobians)."""
    c = np.ascontiguousarray
    return _core.residuals2(  # type: ignore[no-any-return]
        c(poses, dtype=np.float64),
        c(i, dtype=np.int64),
        c(j, dtype=np.int64),
        c(z, dtype=np.float64),
        _NO_FRAME_JACOBIAN if Jf is None else c(Jf, dtype=np.float64),
    )


class _System:
    """Residuals, Jacobians and the normal equations, assembled with a fixed pattern.

    The pattern's contributions are laid out component-major: for each of the four 3×3 blocks
    (i,i), (i,j), (j,i), (j,j) and each of its 9 entries, one slot per AT (then the dependent
    groups' blocks); entries of fixed parameters go to a discarded slot. The core fills the
    plain ATs' slots in one pass with their residuals and Jacobians (:func:`_residuals2`);
    under a loss, a first pass of residuals gives the weights.
    """

    def __init__(
        self, p: Problem, param: Parameterization, w: _Weights, losses: _Losses | None = None
    ):
        self.p, self.param, self.w, self.losses = p, param, w, losses
        i = np.ascontiguousarray(p.i[w.edges], dtype=np.int64)
        j = np.ascontiguousarray(p.j[w.edges], dtype=np.int64)
        self.i, self.j = i, j
        self.group_frames = [
            np.unique(np.concatenate([p.i[members], p.j[members]])) for members, _ in w.groups
        ]
        standard = not w.groups and param.size == 3 * (len(param.root) - 1) and not param.kind.any()
        if standard:
            # every free frame owns the parameter block 3k..3k+2: assemble by blocks
            node_of = np.where(param.col[:, 0] >= 0, param.col[:, 0] // 3, -1)
            ni, nj = node_of[i], node_of[j]
            brow = np.concatenate([ni, ni, nj, nj])
            bcol = np.concatenate([ni, nj, ni, nj])
            pattern = SymmetricPattern.from_blocks(param.size // 3, brow, bcol)
            # contributions come as [type t][entry q][k]; from_blocks lays them out [q][t, k]
            m = len(i)
            pattern.position = pattern.position.reshape(9, 4, m).transpose(1, 0, 2).reshape(-1)
            self.pattern = pattern
        else:
            self.pattern = self._scalar_pattern(p, param, w, i, j)
        # gradient scatter: parameters of frames i then j, component-major; fixed → a spare slot
        g_index = np.concatenate([param.col[i].T.reshape(-1), param.col[j].T.reshape(-1)])
        self.g_index = np.ascontiguousarray(np.where(g_index >= 0, g_index, param.size))
        self.W = np.ascontiguousarray(w.W, dtype=np.float64)  # information Σ⁻¹ of each soft AT
        self._z = np.ascontiguousarray(p.z[w.edges], dtype=np.float64)
        m = len(i)  # the plain ATs' contribution slots, AT by AT: (m, [block t][entry q])
        self._slots = _slots(self.pattern.position[: 36 * m].reshape(4, 9, m).transpose(2, 0, 1))

    def _scalar_pattern(
        self, p: Problem, param: Parameterization, w: _Weights, i: IntArray, j: IntArray
    ) -> SymmetricPattern:
        rows, cols = [], []
        for a, b in ((i, i), (i, j), (j, i), (j, j)):
            for r in range(3):
                for c in range(3):
                    rows.append(param.col[a, r])
                    cols.append(param.col[b, c])
        for members, _ in w.groups:
            frames = np.unique(np.concatenate([p.i[members], p.j[members]]))
            for fa in frames:
                for fb in frames:
                    rows.append(np.repeat(param.col[fa], 3))
                    cols.append(np.tile(param.col[fb], 3))
        r = np.concatenate(rows) if rows else np.zeros(0, np.int64)
        c = np.concatenate(cols) if cols else np.zeros(0, np.int64)
        # the node of each parameter: its frame's root for x, y; its heading class for θ
        node = np.empty(param.size, dtype=np.int64)
        free = param.col >= 0
        n = len(param.root)
        node[param.col[:, 0][free[:, 0]]] = param.root[free[:, 0]]
        node[param.col[:, 1][free[:, 1]]] = param.root[free[:, 1]]
        heading_node = param.heading_class[param.root] + n
        node[param.col[:, 2][free[:, 2]]] = heading_node[free[:, 2]]
        return SymmetricPattern(param.size, r, c, node)

    def linearize(self, xy: FloatArray, theta: FloatArray) -> _Linearized:
        """The cost, poses, normal equations and weights at the state ``(xy, theta)``."""
        param, w, losses = self.param, self.w, self.losses
        poses = np.ascontiguousarray(param.poses(xy, theta), dtype=np.float64)
        Jf = param.frame_jacobian(poses)
        F = _NO_FRAME_JACOBIAN if Jf is None else np.ascontiguousarray(Jf)
        nnz = self.pattern.nnz
        W, plain, beyond = self.W, None, 0.0
        if losses is not None:
            r = _residuals2(poses, self.i, self.j, self._z, None)[0]
            W, plain, beyond = losses.weigh(self.W, r)
        cost, data, grad = _core.normal_equations2(
            poses, self.i, self.j, self._z, F, W, self._slots, self.g_index, nnz, param.size
        )
        cost, data, grad = float(cost) + beyond, data[:nnz], grad[: param.size]
        values, group_weights = [], []
        group_losses = losses.groups if losses is not None else [None] * len(w.groups)
        for (members, Lg), frames, loss in zip(
            w.groups, self.group_frames, group_losses, strict=True
        ):
            gcost, gvals, ggrad, gweight = self._group(poses, Jf, members, Lg, frames, loss)
            cost += gcost
            values.extend(gvals)
            grad += ggrad
            group_weights.append(gweight)
        if values:
            extra = self.pattern.position[36 * len(self.i) :]
            data = data + np.bincount(extra, np.concatenate(values), self.pattern.nnz + 1)[:-1]
        weights = None if losses is None else losses.every(plain, group_weights)
        return _Linearized(cost, poses, data, grad, weights)

    def _group(
        self,
        poses: FloatArray,
        Jf: FloatArray | None,
        members: IntArray,
        Lg: FloatArray,
        frames: IntArray,
        loss: Loss | None,
    ) -> tuple[float, list[FloatArray], FloatArray, float]:
        p, param = self.p, self.param
        k = len(members)
        where = {int(f): a for a, f in enumerate(frames)}
        J = np.zeros((3 * k, 3 * len(frames)))
        r = np.zeros(3 * k)
        rk, Jik, Jjk = _residuals2(poses, p.i[members], p.j[members], p.z[members], Jf)
        for row, m in enumerate(members):
            fi, fj = int(p.i[m]), int(p.j[m])
            r[3 * row : 3 * row + 3] = rk[row]
            J[3 * row : 3 * row + 3, 3 * where[fi] : 3 * where[fi] + 3] += Jik[row]
            J[3 * row : 3 * row + 3, 3 * where[fj] : 3 * where[fj] + 3] += Jjk[row]
        e, LJ = Lg @ r, Lg @ J
        weight, cost = _group_weight(loss, e)
        H = weight * (LJ.T @ LJ)
        g = weight * (LJ.T @ e)
        vals = [
            H[3 * a : 3 * a + 3, 3 * b : 3 * b + 3].reshape(-1)
            for a in range(len(frames))
            for b in range(len(frames))
        ]
        grad = np.zeros(param.size)
        cols = param.col[frames].reshape(-1)
        ok = cols >= 0
        np.add.at(grad, cols[ok], g[ok])
        return cost, vals, grad, weight


def residuals3(
    poses: FloatArray, i: IntArray, j: IntArray, z: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The SE(3) residuals ``r = d ⊟ z = (t_d - t_z, Log(R_d R_zᵀ))`` (m, 6) of the predicted
    relative poses ``d = T_i⁻¹ T_j`` against measured z (m, 4, 4), and their chart Jacobians
    ``Ji, Jj`` (m, 6, 6) with respect to frames i and j (relmap's chart on both sides): relmap's
    compiled core (``relmap._core.residuals3``, ``src/core/linearize3.cpp``).

    The residual is exactly the noise of relmap's measurement model ``z = d ⊞ n``,
    ``n ~ N(0, Σ)`` (up to sign), so ``Σ rᵀ Σ⁻¹ r`` is its negative log-likelihood, and in the
    plane it is the planar residual. A left perturbation δφ of R_d moves the rotation part by
    ``J_l(r_φ)⁻¹ δφ``, so ``Jj = blkdiag(I, J_l⁻¹) blkdiag(R_iᵀ, R_iᵀ)`` and
    ``Ji = -Jj [[I, -[t_j - t_i]×], [0, I]]``. GTSAM's between factor weighs ``Log(z⁻¹ d)``
    instead, which agrees to first order; the optima differ at second order in the residuals.
    """
    c = np.ascontiguousarray
    return _core.residuals3(  # type: ignore[no-any-return]
        c(poses, dtype=np.float64),
        c(i, dtype=np.int64),
        c(j, dtype=np.int64),
        c(z, dtype=np.float64),
    )


class _LieSystem:
    """Residuals, Jacobians and normal equations of 3-D pose graphs (:data:`relmap.lie.SE3`).

    The standard layout only: every frame but the anchor owns one 6-parameter block and a
    step moves it in the chart, ``p_f ← p_f ⊞ δ_f``. The residuals (:func:`residuals3`) and the
    normal equations of the plain ATs are one pass of relmap's compiled core
    (``relmap._core.normal_equations3``). The block contributions are laid out
    ``[entry q][block k]`` for :meth:`SymmetricPattern.from_blocks`: the four blocks
    (i,i), (i,j), (j,i), (j,j) of every AT, then every block pair of each dependent group.
    Under a loss, a first pass of residuals gives the weights.
    """

    def __init__(
        self, p: Problem, param: Parameterization, w: _Weights, losses: _Losses | None = None
    ):
        self.p, self.param, self.w, self.losses = p, param, w, losses
        self.group, self.dof = p.group, p.group.dof
        b = self.dof
        self.i = np.ascontiguousarray(p.i[w.edges], dtype=np.int64)
        self.j = np.ascontiguousarray(p.j[w.edges], dtype=np.int64)
        node_of = np.where(param.col[:, 0] >= 0, param.col[:, 0] // b, -1)
        ni, nj = node_of[self.i], node_of[self.j]
        brow, bcol = [ni, ni, nj, nj], [ni, nj, ni, nj]
        self.group_frames = []
        for members, _ in w.groups:
            frames = np.unique(np.concatenate([p.i[members], p.j[members]]))
            self.group_frames.append(frames)
            brow.append(np.repeat(node_of[frames], len(frames)))
            bcol.append(np.tile(node_of[frames], len(frames)))
        self.pattern = SymmetricPattern.from_blocks(
            param.size // b, np.concatenate(brow), np.concatenate(bcol), block=b
        )
        g_index = np.concatenate([param.col[self.i].T.reshape(-1), param.col[self.j].T.reshape(-1)])
        self.g_index = np.ascontiguousarray(np.where(g_index >= 0, g_index, param.size))
        self.W = np.ascontiguousarray(w.W, dtype=np.float64)
        self._z = np.ascontiguousarray(p.z[w.edges])
        m = len(self.i)  # the plain ATs' contribution slots, AT by AT: (m, [block t][entry q])
        position = self.pattern.position.reshape(b * b, -1)  # [entry q][block k]
        self._slots = _slots(position[:, : 4 * m].reshape(b * b, 4, m).transpose(2, 1, 0))
        self._group_position = position[:, 4 * m :]

    def linearize(self, poses: FloatArray) -> _Linearized:
        """The cost, poses, normal equations and weights at ``poses``."""
        b, nnz, size, losses = self.dof, self.pattern.nnz, self.param.size, self.losses
        poses = np.ascontiguousarray(poses, dtype=np.float64)
        W, plain, beyond = self.W, None, 0.0
        if losses is not None:
            r = residuals3(poses, self.i, self.j, self._z)[0]
            W, plain, beyond = losses.weigh(self.W, r)
        cost, data, grad = _core.normal_equations3(
            poses, self.i, self.j, self._z, W, self._slots, self.g_index, nnz, size
        )
        cost, data, grad = float(cost) + beyond, data[:nnz], grad[:size]
        blocks, group_weights = [], []
        group_losses = losses.groups if losses is not None else [None] * len(self.w.groups)
        for (members, Lg), frames, loss in zip(
            self.w.groups, self.group_frames, group_losses, strict=True
        ):
            gcost, H, ggrad, gweight = self._group(poses, members, Lg, frames, loss)
            cost += gcost
            blocks.append(H)
            grad += ggrad
            group_weights.append(gweight)
        if blocks:  # laid out [entry q][block k], as the pattern's positions
            values = np.concatenate([B.reshape(-1, b * b) for B in blocks]).T
            slots = self._group_position.reshape(-1)
            data = data + np.bincount(slots, values.reshape(-1), self.pattern.nnz + 1)[:-1]
        weights = None if losses is None else losses.every(plain, group_weights)
        return _Linearized(cost, poses, data, grad, weights)

    def _group(
        self,
        poses: FloatArray,
        members: IntArray,
        Lg: FloatArray,
        frames: IntArray,
        loss: Loss | None,
    ) -> tuple[float, FloatArray, FloatArray, float]:
        """One dependent group: cost, its Hessian blocks (f², b, b) in (frame, frame) order,
        its gradient and its weight."""
        p, b = self.p, self.dof
        k, nf = len(members), len(frames)
        where = np.searchsorted(frames, np.stack([p.i[members], p.j[members]]))
        r, Ji, Jj = residuals3(poses, p.i[members], p.j[members], p.z[members])
        J = np.zeros((k, b, nf, b))
        rows = np.arange(k)
        np.add.at(J, (rows, slice(None), where[0]), Ji)  # J[k, :, f, :] += ∂r_k/∂p_f
        np.add.at(J, (rows, slice(None), where[1]), Jj)
        J = J.reshape(k * b, nf * b)
        e, LJ = Lg @ r.reshape(-1), Lg @ J
        weight, cost = _group_weight(loss, e)
        H = weight * (LJ.T @ LJ).reshape(nf, b, nf, b).transpose(0, 2, 1, 3).reshape(nf * nf, b, b)
        g = weight * (LJ.T @ e)
        grad = np.zeros(self.param.size)
        cols = self.param.col[frames].reshape(-1)
        ok = cols >= 0
        np.add.at(grad, cols[ok], g[ok])
        return cost, H, grad, weight

    def step(self, poses: FloatArray, delta: FloatArray) -> FloatArray:
        """The poses moved by the parameter step ``delta`` (size,), anchor fixed."""
        D = np.zeros((len(poses), self.dof))
        free = self.param.col[:, 0] >= 0
        D[free] = delta[self.param.col[free]]
        return self.group.plus(poses, D)


def optimize(
    p: Problem,
    *,
    max_iterations: int = 100,
    rtol: float = 1e-10,
    atol: float = 1e-9,
    xtol: float = 1e-13,
    progress: Progress | None = None,
    loss: LossChoice = None,
) -> Solution:
    """Minimize ``Σ rᵀ Σ⁻¹ r`` over the frame poses, the anchor fixed, from ``p.guess``; with
    ``loss``, ``Σ ρ(rᵀ Σ⁻¹ r)`` (:mod:`relmap.network.losses`: one loss for every AT, or a
    mapping from AT names, in ``p.names``, to losses, the others least squares).

    **Stopping rule** (on the decrease, then on the step): the iterations end when the
    undamped (Gauss-Newton) step at the current poses predicts a decrease below ``rtol``
    relatively, or the last accepted step lowered the objective only by rounding. Gauss-Newton
    converges only linearly when the residuals are not zero, so the poses are then polished
    with the factorization at hand (chord steps ``δ = -H⁻¹ g`` with the gradient recomputed,
    no new factorization, at most 8, while they shrink) until the step is negligible,
    ``max|δ| ≤ xtol·(1 + max|t|)`` (t the poses' translations, m; δ in m and rad) or stops
    lowering the objective. One further Gauss-Newton step then moves the poses by less than
    about 1e-12 relatively. If the polish moved the poses, the normal matrix is factorized
    once more at the polished poses (when :attr:`Solution.factor` is first used: a caller that
    wants only the poses does not pay for it), so the covariances are those at the returned
    poses (the last Gauss-Newton iterate's differed by O(polish): 9e-8 relatively on the bridge).
    ``Solution.converged`` is False when ``max_iterations`` ended the loop instead. An
    objective that overflows raises :class:`relmap.errors.NumericalError`.

    Levenberg-Marquardt on the Gauss-Newton normal equations: damping ``λ·diag(H)`` with
    Nielsen's update from the gain ratio, starting undamped (λ = 0, Gauss-Newton) and
    returning to it once λ is negligible. Converged when the Gauss-Newton
    step predicts a decrease of the objective below ``rtol`` relatively (so the factorization
    that proved it is the one at the optimum, kept for covariances), or when steps stop
    lowering the objective beyond rounding. Gauss-Newton converges quadratically near the
    optimum, so the default (1e-10, against GTSAM's 1e-5 on the achieved decrease) leaves the
    objective within about 1e-10 relative of its minimum and the poses within a small
    fraction of their σ (1e-6 m on FR079); ``rtol=1e-14`` reaches the optimum to rounding, at
    the price of about one more factorization.

    Under a loss every linearization weights each AT's information by ``ρ'(s²)`` at the
    current poses (iteratively reweighted least squares), "objective" above is the robust cost
    ``Σ ρ(s²)`` (the gain ratio and the acceptance of a step use it), and the covariances are
    those of the weighted normal matrix at the optimum (:attr:`Solution.weights`).
    """
    param = parameterize(p, atol=atol)
    w = _weights(p, param)
    losses = _losses(p, w, loss)
    if p.group is SE2:
        planar = _System(p, param, w, losses)
        state: object = param.initial_state(p.guess, p.anchor)
        pattern = planar.pattern

        def linearize(x: object) -> _Linearized:
            return planar.linearize(*x)  # type: ignore[misc]

        move = param.stepper()

        def step(x: object, delta: FloatArray) -> object:
            return move(*x, delta)  # type: ignore[misc]
    else:
        system = _LieSystem(p, param, w, losses)
        state, pattern = np.array(p.guess, dtype=np.float64), system.pattern
        linearize, step = system.linearize, system.step  # type: ignore[assignment]
    cost, poses, data, grad, weights = linearize(state)
    _check_cost(cost, "at the initial guess")
    initial = cost
    if param.size == 0:
        return Solution(p, param, poses, None, 0, initial, cost, weights=weights, loss=loss)
    scale = 1.0 + float(np.abs(_translations(p.group, poses)).max(initial=0.0))
    stalled = False  # the last accepted step lowered the objective by rounding only
    converged = True
    factor = SymmetricFactor(pattern)
    lam, nu = 0.0, 2.0  # plain Gauss-Newton first; damping only once a step fails
    iterations = 0
    undamped_at_current = False  # whether the factor holds the undamped matrix at the state
    if progress:
        progress(0, cost)
    while True:
        diag = pattern.diagonal(data)
        if not np.all(diag > 0):
            k = int(np.argmin(diag))
            raise SolverError(
                f"parameter {k} of the network is not constrained by any AT (a frame with no "
                "informative measurement)"
            )
        factor.factorize(pattern.with_diagonal(data, diag * lam) if lam else data)
        undamped_at_current = lam == 0.0
        delta = -factor.solve(grad)
        # The model predicts the decrease -gᵀδ + λ δᵀDδ (objective Σ‖e‖², g = J̃ᵀe).
        # (einsum, not BLAS: a multithreaded dot product on a busy machine cost 20 ms a call)
        predicted = -float(np.einsum("i,i->", grad, delta))
        if lam:
            predicted += lam * float(np.einsum("i,i,i->", delta, diag, delta))
        if lam == 0.0 and (predicted <= rtol * max(cost, 1e-300) or stalled):
            # Converged in the objective. Polish the poses to rounding with the factorization
            # at hand (chord steps: no new factorization); if they moved the poses, the
            # normal matrix is factorized once more at the polished poses, for covariances.
            size = float(np.abs(delta).max(initial=0.0))
            for _ in range(_POLISH_STEPS):
                if size <= xtol * scale:
                    break
                moved = step(state, delta)
                moved_at = linearize(moved)
                if not moved_at.cost <= cost * (1.0 + 1e-13) + 1e-300:
                    break
                state = moved
                cost, poses, data, grad, weights = moved_at
                undamped_at_current = False
                delta = -factor.solve(grad)
                smaller = float(np.abs(delta).max(initial=0.0))
                if smaller > 0.5 * size:
                    break  # no longer shrinking: rounding
                size = smaller
            break
        if iterations >= max_iterations:
            converged = False
            break
        iterations += 1
        state_new = step(state, delta)
        moved_at = linearize(state_new)  # usually accepted: linearize right away
        new_cost = moved_at.cost
        _check_cost(new_cost, f"at iteration {iterations}")
        if new_cost <= cost:
            stalled = cost - new_cost <= 1e-13 * max(cost, 1e-300)
            rho = (cost - new_cost) / max(predicted, 1e-300)  # gain ratio (Nielsen's update)
            state = state_new
            cost, poses, data, grad, weights = moved_at
            undamped_at_current = False
            lam *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
            nu = 2.0
            if lam < 1e-9:
                lam = 0.0
            if progress:
                progress(iterations, cost)
            if lam > 1e12:  # steps accepted only for lowering nothing (a kink or a jump in
                break  # the cost, e.g. a heading residual wrapping at ±π): as below
        elif new_cost - cost <= max(rtol, 1e-12) * max(cost, 1e-300):
            break  # no further decrease beyond rounding: the current point is the optimum
        else:
            lam = 1e-6 if lam == 0.0 else lam * nu
            nu *= 2.0
            if lam > 1e12:
                break  # no descent possible: the current point is a minimum to rounding
    # the undamped normal matrix at the optimum, for covariances: factorized when first needed
    stale = not undamped_at_current
    return Solution(
        p, param, poses, factor, iterations, initial, cost, data, converged, stale, weights, loss
    )


#: chord steps (with the last factorization) that polish a converged solution to rounding
_POLISH_STEPS = 8


def _translations(group: Group, poses: FloatArray) -> FloatArray:
    return poses[..., :2] if group is SE2 else poses[..., :3, 3]


def _check_cost(cost: float, where: str) -> None:
    if not np.isfinite(cost):
        raise NumericalError(
            f"the least-squares objective overflowed ({cost}) {where}: the measurements or "
            "their information are too large for floating point"
        )


def problem_from_map(
    g: MapView,
    names: Sequence[str],
    anchor: Frame,
    *,
    keep_guess: bool = False,
    frames: Sequence[Frame] | None = None,
) -> tuple[Problem, dict[Frame, int]]:
    """The problem formed by the named ATs of a map, anchored at frame ``anchor``.

    Initial guess: the map's own guesses where it has them for every frame (pose-graph files),
    re-expressed relative to the anchor (``keep_guess``: as given, the anchor at its own
    guess); otherwise poses compounded along a spanning tree, the anchor at the identity.
    ``frames``: the order of the problem's frames (default: the anchor, then as the ATs name
    them). Reads the map through :class:`~relmap.network.parts.MapView` only (``ends``,
    ``arrays``, ``guesses``, ``groups``, ``at_type``).
    """
    ends = g.ends()
    index: dict[Frame, int] = (
        {anchor: 0} if frames is None else {f: k for k, f in enumerate(frames)}
    )
    src = [ends[n][0] for n in names]
    dst = [ends[n][1] for n in names]
    for f in (*src, *dst):
        if f not in index:
            index[f] = len(index)
    n = len(index)
    i = np.fromiter((index[f] for f in src), dtype=np.int64, count=len(src))
    j = np.fromiter((index[f] for f in dst), dtype=np.int64, count=len(dst))
    z, cov = g.arrays(names)
    group = g.at_type.group
    b = group.dof
    position = {nm: k for k, nm in enumerate(names)}
    groups = []
    for grp in g.groups:
        members = [nm for nm in grp.names if nm in position]
        if len(members) < 2:
            continue
        sel = np.array([grp.names.index(nm) for nm in members])
        rows = (b * sel[:, None] + np.arange(b)).reshape(-1)
        groups.append((np.array([position[nm] for nm in members]), grp.cov[np.ix_(rows, rows)]))
    order = list(index)
    a = index[anchor]
    guess = g.guesses(order)
    if guess is None:
        guess = compose_tree(n, i, j, z, group)
        if a:
            guess = group.between(guess[a], guess)
    elif not keep_guess:
        guess = group.between(guess[a], guess)
    return Problem(n, i, j, z, cov, groups, guess, a, list(names), group, order), index


def solve_map(
    g: MapView,
    anchor: Frame | None = None,
    *,
    progress: Progress | None = None,
    max_iterations: int = 100,
    rtol: float | None = None,
    loss: LossChoice = None,
) -> Solution:
    """Optimize every frame of a map jointly (the optimal method over the whole network).

    ``anchor`` (default :attr:`RelationalMap.anchor`: a pose graph's first ``FIX`` vertex,
    else its first vertex) stays at its guess (the map's guesses, e.g. a pose graph's; else
    the identity, the others compounded along a spanning tree). Poses come in
    :attr:`Solution.frames` order (:attr:`RelationalMap.frames`). ``loss``: see
    :func:`optimize` (AT names are the map's). See :func:`solve_frames`.
    """
    if anchor is None:
        anchor = g.anchor
    if anchor is None or not g.has_frame(anchor):
        raise UnknownFrameError(f"no frame {anchor!r} in the map to anchor the solve")
    frames = g.frames
    names = list(g.ends())
    index = {f: k for k, f in enumerate(frames)}
    _check_connected(frames, *_rows(g, names, index), index[anchor])
    problem, _ = problem_from_map(g, names, anchor, keep_guess=True, frames=frames)
    options = {} if rtol is None else {"rtol": rtol}
    return optimize(problem, progress=progress, max_iterations=max_iterations, loss=loss, **options)


def solve_frames(
    frames: Sequence[Frame],
    i: IntArray,
    j: IntArray,
    ats: AT | AT3,
    guess: FloatArray,
    anchor: int,
    *,
    progress: Progress | None = None,
    max_iterations: int = 100,
    rtol: float | None = None,
    loss: LossChoice = None,
) -> Solution:
    """Optimize frames ``frames`` linked by the batch ``ats`` (AT k: frame ``j[k]`` seen from
    ``i[k]``, rows into ``frames``) from the poses ``guess``, the frame at row ``anchor``
    fixed. Frames not linked to the anchor (a second component, frames without an AT) are
    refused with a :class:`SolverError` naming them: nothing would fix their poses. This is
    the array form a pose-graph file gives (:func:`relmap.io.solve_graph`). ``loss``: see
    :func:`optimize`; AT k is named ``e{k}``."""
    _check_connected(frames, i, j, anchor)
    m = len(i)
    problem = Problem(
        len(frames),
        np.asarray(i, dtype=np.int64),
        np.asarray(j, dtype=np.int64),
        ats.mean,
        ats.cov,
        [],
        np.array(guess),
        anchor,
        _Numbered(m),
        ats.group,
        list(frames),
    )
    options = {} if rtol is None else {"rtol": rtol}
    return optimize(problem, progress=progress, max_iterations=max_iterations, loss=loss, **options)


class _Numbered(Sequence[str]):
    """The names ``e0 … e{m-1}`` of m ATs, each formed only when asked for (in a message)."""

    def __init__(self, m: int) -> None:
        self._m = m

    def __len__(self) -> int:
        return self._m

    def __getitem__(self, k):  # type: ignore[no-untyped-def, override]
        if isinstance(k, slice):
            return [f"e{i}" for i in range(self._m)[k]]
        return f"e{range(self._m)[k]}"


def _rows(g: MapView, names: Sequence[str], index: dict[Frame, int]) -> tuple[IntArray, IntArray]:
    ends = g.ends()
    i = np.fromiter((index[ends[n][0]] for n in names), dtype=np.int64, count=len(names))
    j = np.fromiter((index[ends[n][1]] for n in names), dtype=np.int64, count=len(names))
    return i, j


def _check_connected(frames: Sequence[Frame], i: IntArray, j: IntArray, anchor: int) -> None:
    """Raise :class:`SolverError` naming the frames that no chain of ATs links to the anchor
    (one union-find pass of relmap's compiled core)."""
    n = len(frames)
    c = np.ascontiguousarray
    label = _core.components(n, c(i, dtype=np.int64), c(j, dtype=np.int64))
    count = int(label.max(initial=-1)) + 1
    if count <= 1:
        return
    degree = np.bincount(np.concatenate([i, j]), minlength=n)
    alone = [frames[k] for k in np.flatnonzero(degree == 0)]
    others = [
        [frames[k] for k in np.flatnonzero(label == c)]
        for c in range(count)
        if c != label[anchor] and degree[label == c].any()
    ]

    def few(part: Sequence[Frame]) -> str:
        shown = ", ".join(map(repr, part[:5]))
        return f"{len(part)} frames ({shown}{', …' if len(part) > 5 else ''})"

    what = []
    if others:
        what.append(
            f"{len(others)} more connected component(s) with no anchor: "
            + "; ".join(few(c) for c in others[:3])
        )
    if alone:
        what.append(f"{few(alone)} without any AT")
    reached = int((label == label[anchor]).sum())
    raise SolverError(
        f"the map is not connected: the anchor {frames[anchor]!r} reaches {reached} frames, "
        "but " + " and ".join(what) + "; solve each component separately "
        "(RelationalMap.submap) or query frames within one"
    )


def solve_relative(g: MapView, names: Sequence[str], entry: Frame, exit: Frame) -> Solved:
    """The AT of ``exit`` seen from ``entry``, from the joint estimate over the named ATs."""
    sol = solve_part(g, names, entry)
    return Solved(sol.relative(entry, exit), sol.iterations)


def solve_part(
    g: MapView, names: Sequence[str], anchor: Frame, loss: LossChoice = None
) -> Solution:
    """The joint estimate over the named ATs, anchored at ``anchor`` (under ``loss``, a
    mapping's names outside ``names`` ignored); kept on the map (:meth:`RelationalMap.memo`,
    with its loss, which must then be hashable) until it changes, so that further queries in
    the same part reuse its factorization."""
    part_loss = restrict(loss, frozenset(names))

    def build() -> Solution:
        problem, _ = problem_from_map(g, names, anchor)
        return optimize(problem, loss=part_loss)

    key: tuple[object, ...] = ("solved", frozenset(names))
    if part_loss is not None:
        key += (frozenset(part_loss.items()) if isinstance(part_loss, Mapping) else part_loss,)
    return g.memo(key, build)  # type: ignore[no-any-return]
