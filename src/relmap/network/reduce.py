"""The paper's reduction (§5): compounding, merging, Delta-Y (first-order consistent) and Y→Δ.

To estimate the AT from frame s to frame t, mark both, then repeat until one AT links them:
compound the two ATs through any unmarked frame that has exactly two (step 2), and merge
parallel ATs (step 3). Dangling ATs and self-loops are pruned first. Every new AT is oriented
from the frame nearer the source to the frame nearer the destination (hop distances), so the
ATs merged point the query's way: merging does not commute with reversal when there is angular
error, and this fixes one orientation.

When neither step applies (the Wheatstone bridge of Fig. 3), a triangle of ATs (Delta) is
replaced by an equivalent star (Y) around a new frame o (Fig. 4), and when there is no
triangle to use, a star by a triangle (Y→Δ), or more generally an unmarked frame with d ≤
:data:`MESH_MAX_DEGREE` ATs by ATs between every two of its neighbours (star-mesh). Delta-Y is
applied where it lets a series step follow (a corner with three ATs keeps two); Y→Δ and
star-mesh (the fewest ATs first) each remove a frame; so ATs + frames decrease at every
round, and the reduction ends. The candidates for every step are kept up to date through the
frames whose ATs changed (heaps by rank), so a round costs about what it changes.

**The first-order picture** (relmap's derivation; the paper has none). Express every frame f
by a perturbation ξ_f of a common frame (the triangle's or star's first corner w): the chart
perturbation of f's pose p_f is ``δp_f = T(p_f) ξ_f`` with ``T(p) = ∂(a ⊕ p)/∂a`` at the
identity (``[[1, 0, -y], [0, 1, x], [0, 0, 1]]`` in the plane, ``[[I, -[t]×], [0, I]]`` in
3-D). These T commute and compose additively, and an AT e from frame i to j measures, to
first order, ``δz_e = M_e (ξ_j - ξ_i)`` with ``M_e = J_j T(p_j)`` (J_j the Jacobian of
``between(p_i, p_j)`` in p_j). So in ξ coordinates a relational map is a linear network of
matrix-valued "resistances" ``S_e = M_e⁻¹ C_e M_e⁻ᵀ``: compounding adds them, merging is their
parallel combination, and both are exact to first order. Delta-Y and star-mesh are the
resistor-network transforms with matrices:

- **Delta-Y (default, ``delta_y="consistent"``).** Triangle A (w→t), B (w→v), C (t→v), star
  X (w→o), Y (o→v), Z (o→t), o at w. Seen from w, the triangle gives (ξ_t, ξ_v) the joint
  covariance ``P_tt = S_A - S_A Σ⁻¹ S_A``, ``P_vv = S_B - S_B Σ⁻¹ S_B``,
  ``P_tv = S_A Σ⁻¹ S_B`` (Σ = S_A + S_B + S_C, a generalized inverse when singular): 21
  numbers. The star gives ``[[S_X + S_Z, S_X + K], [S_X + Kᵀ, S_X + S_Y]]`` with
  K = E[ξ_z ξ_yᵀ] the cross-covariance of Z and Y. Three independent ATs (K = 0) have only
  18: P_tv is not symmetric unless the S commute (the linear isotropic case, the resistor
  bridge, and isotropic positions with heading error), and such a star was 0.2-3.9% off the
  optimal estimate on the anisotropic bridge. So Y and Z are a dependent pair:
  ``S_X = sym(P_tv)`` kept within ``0 ⪯ S_X ⪯ S_A ∥ S_B = S_A (S_A + S_B)⁻¹ S_B``
  (eigenvalues relative to ``S_A ∥ S_B`` clipped to [0, 1], which is exactly the condition
  for X and the joint of Y and Z to be covariances), ``S_Z = P_tt - S_X``,
  ``S_Y = P_vv - S_X``, ``K = P_tv - S_X``; then ``C_X = S_X``,
  ``C_Y = T(p_v) S_Y T(p_v)ᵀ``, ``C_Z = T(p_t) S_Z T(p_t)ᵀ``, ``E[δZ δYᵀ] = T(p_t) K
  T(p_v)ᵀ``, with the corners' means ``p_t = A ⊗ (B ⊕ Cᴿ)``, ``p_v = B ⊗ (A ⊕ C)`` (the
  paper's A', B'). The star reproduces the triangle's corner covariance exactly, to first
  order. Where the S commute, K = 0 and the star is the independent one.

  **Carrying K** (and the cross-covariances of ATs added with
  :meth:`~relmap.RelationalMap.add_joint`): every AT of the working network keeps *links*,
  the first-order maps D_m from the errors of the dependent ATs m it contains to its own
  (δ = Σ D_m δ_m + independent errors). Reversal and compounding map them by their
  Jacobians (Eq. 7, Eq. 4's J₁, J₂), a merge by its weights; the cross-covariance of two ATs
  is ``Σ D_m E[δ_m δ_nᵀ] D_nᵀ``, and a dependent pair compounds with it (§3.2), dependent
  parallel ATs merge with their joint covariance (§4.2). Compounding through a frame loses
  nothing; a merge of an AT holding Y with one not holding Z, while Z lives on elsewhere,
  would lose the information in their difference, so there (and when a triangle or star-mesh
  step takes Y or Z) the star's K is dropped first: that star becomes the independent one.
  On the bridge Y and Z meet in one merge, so the reduction is the optimal estimate to first
  order; in networks where Y and Z part, that star is the independent approximation. How close
  to the optimal estimate and to Monte Carlo it comes: ``docs/delta_y.md``.
- **Delta-Y as printed (``delta_y="paper"``)**: ``A' = A ⊗ (B ⊕ Cᴿ)``,
  ``B' = B ⊗ (A ⊕ C)``, ``C' = C ⊗ (Aᴿ ⊕ B)``, X: w→o identity mean, Y: o→v mean B',
  Z: o→t mean A', ``C_X = ½(C_A' + C_B' - K C_C' Kᵀ)``, ``C_Y = ½(-C_A' + C_B' + K C_C'
  Kᵀ)``, ``C_Z = ½(C_A' - C_B' + K C_C' Kᵀ)``, K = blkdiag(R(θ_A), 1) (in 3-D the Jacobian
  of ``A ⊕ ·``). The paper prints ``K C_C Kᵀ`` (negative variances even in one dimension)
  and a second, asymmetric form; this uses C_C' and symmetrizes. It ignores how compounding
  carries heading error into position (the T above), so it is exact only without angular
  error, with isotropic positions.
- **Y→Δ and star-mesh**: legs o→a_k (k = 0…d-1), seen from a_0: ``Cov(ξ_k - ξ_0) =
  S_0 + δ_km S_k``; its inverse H is the grounded information of the mesh, so the mesh ATs
  have conductances ``G_km = -sym(H_km)`` and ``G_0k = H_kk - Σ_m G_km``, covariances
  ``M G⁻¹ Mᵀ``. Exact for commuting S (the linear isotropic grid); otherwise only the
  antisymmetric parts of the cross terms are lost. Directions every leg knows exactly stay
  exact; a mesh AT that would not be positive definite, or legs that know different
  directions exactly, make the step unavailable.

The paper's star's (and the mesh's) covariances may be indefinite: they are intermediate
quantities, never validated (the consistent star is a covariance; should an intermediate joint
covariance of a dependent pair still come out indefinite, the step drops that star's K).
**The result is**: its covariance is symmetric PSD (eigenvalues below zero
only by rounding clipped), or :class:`IrreducibleNetworkError` names the approximate steps
that made it indefinite — never an exit status 0 with an impossible answer.

If even these steps cannot reduce the network, :class:`IrreducibleNetworkError` says how big
the rest is; with ``on_irreducible="drop"`` the loop-forming ATs are deleted one at a time,
greedily (each time the one whose deletion lets the rest reduce with the smallest result by
``criterion``; if none does, the one that leaves least), and reported. Best deletion is
refused at once, pointing to ``method='optimal'``, on networks with more than
:data:`DROP_MAX_INPUT_LOOPS` independent loops, or when more than :data:`DROP_MAX_LOOPS`
remain: it would discard most of the information (every real pose graph of the shared data
but ring.g2o is refused within about a second; ring.g2o is answered).

Dependent ATs (:meth:`RelationalMap.add_joint`) are carried by their links (above): a
dependent pair compounds with its cross-covariance (§3.2), dependent parallel ATs merge with
their joint covariance (§4.2, :func:`relmap.merge` with ``joint_cov``), also after other
steps; Delta-Y on a triangle with one of them raises, and star-mesh does not take them.

The reduction runs on batched ATs as well (all ATs with one batch shape), which Monte Carlo
validation uses; best deletion needs single ATs. It runs unchanged on 3-D ATs (:class:`AT3`).

**Beyond first order** (``moments``, SE(2) only; :mod:`relmap.uncertain.moments`). Every compounding
and reversal the reduction performs can use exact or unscented moments instead of Eqs. (1)-(7):

- ``"exact"``: each AT of the working network remembers the chain of Gaussian operands it
  compounds (the given ATs, merged ATs and Delta-Y star ATs, each possibly reversed), and a
  serial chain is evaluated as one :func:`relmap.uncertain.moments.chain_moments` of that whole
  chain,
  with reversed operands by :func:`relmap.uncertain.moments.reverse_moments`. So a chain ``A ⊕ B ⊕
  …``
  gets the exact mean and covariance of its true distribution, exactly as
  ``compound_chain(..., moments="exact")``, not the moments of moments of pairwise steps.
  (Each reversed operand is summarized by its exact moments before entering the chain: exact
  for a chain of forward ATs, to second order in the reversed ones' uncertainty otherwise.)
- ``"unscented"``: each compounding and reversal is the unscented transform of its
  operands, one step at a time in the reduction's own order (which may work along a chain
  from both ends, reversing, so it can differ from ``compound_chain(..., moments="unscented")``
  of the same chain; ``"exact"`` does not depend on the order).
- In both, **merging stays the Gaussian update of Eqs. (8)-(10)** applied to the
  moment-matched inputs: each parallel AT is replaced by the Gaussian with its (exact or
  unscented) mean and covariance and those Gaussians are fused. That is the best linear
  fusion of those moments, not the exact posterior (the crescent-shaped inputs are not
  Gaussian, and the fused estimate is not their Bayesian product); and a merged AT enters
  later chains as one Gaussian operand. **This need not be better than first order**: the
  moment-matched Gaussian of a crescent is broad along the crescent, while the posterior
  keeps only the part of the crescent that the other AT allows, which the tangent
  (first-order) Gaussian at the mean often describes better (10 links at σθ = 6° merged with
  a direct AT, against the exact posterior: first order within 3%, exact moments over 15% off;
  ``tests/network/test_query_moments.py``). Exact moments are the right answer for chains (where
  ``query(method="auto")`` uses the reduction); where merges follow, they are a sensitivity
  check (:class:`relmap.network.query.LinearizationCheck`), not a correction.
- Delta-Y: the three compoundings inside it (``B ⊕ Cᴿ``, ``A ⊕ C``, ``Aᴿ ⊕ B``) use the same
  moments, so long serial branches of a bridge are right; the star construction itself stays
  the linear approximation described above.
"""

from __future__ import annotations

import heapq
from collections import deque
from collections.abc import Callable, Hashable, Sequence
from itertools import count
from typing import NamedTuple

import numpy as np

from relmap.errors import (
    IrreducibleNetworkError,
    NotPositiveSemidefiniteError,
    NumericalError,
    ParameterError,
)
from relmap.lie.group import Group
from relmap.typing import FloatArray, Option
from relmap.uncertain import moments as _moments
from relmap.uncertain.algebra import compound, merge, reverse
from relmap.uncertain.at import AT
from relmap.uncertain.at3 import AT3
from relmap.uncertain.gaussian import congruence, difference_merge_gain, generalized_inverse
from relmap.uncertain.moments import MomentsMethod

__all__ = ["DeltaY", "OnIrreducible", "Reduction", "reduce_network"]

Frame = Hashable


class DeltaY(Option):
    """The star Delta-Y puts in place of a triangle (module docstring): the first-order
    consistent one (``"consistent"``, default) or the paper's formulas (``"paper"``)."""

    CONSISTENT = "consistent"
    PAPER = "paper"


class OnIrreducible(Option):
    """What :func:`reduce_network` does with a network that even Delta-Y cannot reduce:
    ``"raise"`` an :class:`~relmap.errors.IrreducibleNetworkError`, or ``"drop"`` the
    loop-forming ATs one at a time (best deletion)."""

    RAISE = "raise"
    DROP = "drop"


# --------------------------------------------------------------------- expressions
class _Leaf(NamedTuple):
    name: str


class _Rev(NamedTuple):
    inner: object


class _Comp(NamedTuple):
    parts: tuple[object, ...]


class _Merge(NamedTuple):
    parts: tuple[object, ...]


def _render(e: object, inside: str = "") -> str:
    if isinstance(e, _Leaf):
        return e.name
    if isinstance(e, _Rev):
        inner = _render(e.inner, "rev")
        return f"{inner}ᴿ" if isinstance(e.inner, _Leaf) else f"({inner})ᴿ"
    if isinstance(e, _Comp):
        text = " ⊕ ".join(_render(p, "comp") for p in e.parts)
        return f"({text})" if inside in ("merge", "rev") else text
    assert isinstance(e, _Merge)
    text = " ⊗ ".join(_render(p, "merge") for p in e.parts)
    return f"({text})" if inside in ("comp", "rev") else text


def _comp(a: object, b: object) -> _Comp:
    parts = (
        *(a.parts if isinstance(a, _Comp) else (a,)),
        *(b.parts if isinstance(b, _Comp) else (b,)),
    )
    return _Comp(parts)


def _rev(e: object) -> object:
    return e.inner if isinstance(e, _Rev) else _Rev(e)


def _leaves(e: object) -> list[str]:
    if isinstance(e, _Leaf):
        return [e.name]
    if isinstance(e, _Rev):
        return _leaves(e.inner)
    return [n for p in e.parts for n in _leaves(p)]  # type: ignore[attr-defined]


# ---------------------------------------------------------------------- the network
class _Edge(NamedTuple):
    u: Frame
    v: Frame
    at: AT | AT3
    expr: object
    order: float  # for a stable, readable order of merge operands
    # first order, δ(this AT, u → v) = Σ D δ(member) + independent errors, over the members of
    # dependent groups (add_joint ATs, the consistent Delta-Y's Y and Z) this AT contains
    links: tuple[tuple[str, FloatArray], ...]
    # moments="exact": the Gaussian operands this AT compounds, u → v, each (AT, reversed?);
    # None: the AT itself is the one operand
    factors: tuple[tuple[AT, bool], ...] | None = None


class Reduction(NamedTuple):
    """Result of :func:`reduce_network`."""

    at: AT | AT3
    expression: str
    dropped: tuple[str, ...]  #: expressions of ATs deleted by best deletion
    definitions: dict[str, str]  #: what each Delta-Y star AT (X₁, Y₁, Z₁, ...) stands for


class _State:
    """The working network: ATs by id, incidence sets, frame order keys."""

    def __init__(self, edges: dict[int, _Edge], rank: dict[Frame, tuple[float, ...]]):
        self.edges = edges
        self.rank = rank
        self.incident: dict[Frame, set[int]] = {}
        self.touched: list[Frame] = []  # frames whose ATs changed, for the series worklist
        self.linked: set[int] = set()  # the ATs with links
        self.dirty: set[Frame] = set()  # ... and for the Delta-Y and star-mesh candidates:
        self.triangle_at: dict[Frame, tuple[tuple[int, list[tuple[float, ...]]], tuple]] = {}
        self.mesh_at: dict[Frame, tuple[int, tuple[float, ...]]] = {}
        # both also as heaps (key, tick, frame), entries stale once the dict says otherwise
        self.triangle_heap: list[tuple[object, int, Frame]] = []
        self.mesh_heap: list[tuple[object, int, Frame]] = []
        self.tick = count()
        for k, e in edges.items():
            self._link(k, e)

    def _link(self, k: int, e: _Edge) -> None:
        self.incident.setdefault(e.u, set()).add(k)
        self.incident.setdefault(e.v, set()).add(k)
        self.touched += (e.u, e.v)
        self.dirty.update((e.u, e.v))
        if e.links:
            self.linked.add(k)

    def add(self, k: int, e: _Edge) -> None:
        self.edges[k] = e
        self._link(k, e)

    def drop(self, k: int) -> _Edge:
        e = self.edges.pop(k)
        self.linked.discard(k)
        for f in (e.u, e.v):
            self.incident[f].discard(k)
            if not self.incident[f]:
                del self.incident[f]
        self.touched += (e.u, e.v)
        self.dirty.update((e.u, e.v))
        return e

    def between(self, a: Frame, b: Frame) -> list[int]:
        """The ATs linking frames a and b (either way), in insertion order."""
        ks = self.incident.get(a, set()) & self.incident.get(b, set())
        return sorted(k for k in ks if {self.edges[k].u, self.edges[k].v} == {a, b})

    def copy(self) -> _State:
        return _State(dict(self.edges), dict(self.rank))

    def other(self, k: int, f: Frame) -> Frame:
        e = self.edges[k]
        return e.v if e.u == f else e.u


class _Reducer:
    def __init__(
        self,
        s: Frame,
        t: Frame,
        cross: dict[frozenset[str], tuple[str, str, np.ndarray]],
        definitions: dict[str, str],
        moments: MomentsMethod = MomentsMethod.FIRST_ORDER,
        delta_y: DeltaY = DeltaY.CONSISTENT,
    ):
        self.s, self.t = s, t
        self.moments = moments
        self.delta_y_rule = delta_y
        self.cross = cross
        self.star_members: set[str] = set()  # the consistent Delta-Y's correlated Y and Z
        self.partner: dict[str, str] = {}  # Y of a star → its Z, and Z → Y
        self.no_mesh: set[tuple[Frame, frozenset[int]]] = set()  # stars found singular
        self.definitions = definitions
        self.ids = count(1_000_000)
        self.stars = count(1)
        self.meshes = count(1)
        self.progress: Callable[[int, int], None] | None = None

    # -------------------------------------------------------------- orientation
    def oriented(self, st: _State, k: int, a: Frame) -> tuple[AT | AT3, object]:
        """AT k pointing away from frame a, with its expression."""
        e = st.edges[k]
        if e.u == a:
            return e.at, e.expr
        if self.moments is MomentsMethod.FIRST_ORDER:
            return reverse(e.at), _rev(e.expr)
        if self.moments is MomentsMethod.UNSCENTED:
            return AT._trusted(*_moments.unscented_reverse(e.at.mean, e.at.cov)), _rev(e.expr)
        return self.chain(self.factors(st, k, a)), _rev(e.expr)

    # ------------------------------------------------------ beyond first order
    def factors(self, st: _State, k: int, a: Frame) -> tuple[tuple[AT, bool], ...]:
        """The Gaussian operands of AT k, in order from frame a (moments="exact")."""
        e = st.edges[k]
        fs: tuple[tuple[AT, bool], ...] = e.factors or ((e.at, False),)  # type: ignore[assignment]
        return fs if e.u == a else tuple((at, not r) for at, r in reversed(fs))

    def chain(self, fs: Sequence[tuple[AT, bool]]) -> AT:
        """Exact moments of the chain of independent Gaussian operands ``fs``."""
        links = [
            AT._trusted(*_moments.reverse_moments(at.mean, at.cov)) if r else at for at, r in fs
        ]
        if len(links) == 1:
            return links[0]
        means = np.broadcast_arrays(*(x.mean for x in links))
        covs = np.broadcast_arrays(*(x.cov for x in links))
        mean, cov = _moments.chain_moments(np.stack(means), np.stack(covs), axis=0)
        return AT._trusted(mean[-1], cov[-1])

    def series(self, st: _State, legs: Sequence[tuple[int, Frame]]) -> AT | AT3:
        """The ATs ``legs`` (id, frame each leaves from) compounded in order."""
        if self.moments is MomentsMethod.EXACT:
            return self.chain([f for k, a in legs for f in self.factors(st, k, a)])
        ats = [self.oriented(st, k, a)[0] for k, a in legs]
        out = ats[0]
        for x in ats[1:]:
            out = compound(out, x, moments=self.moments)
        return out

    def first(self, st: _State, a: Frame, b: Frame) -> tuple[Frame, Frame]:
        return (a, b) if st.rank[a] <= st.rank[b] else (b, a)

    # ---------------------------------------------------------------- the steps
    def merge_parallel(self, st: _State, frames: Sequence[Frame]) -> None:
        """Merge every group of parallel ATs at ``frames`` (in the order of their ids)."""
        pairs: dict[frozenset[Frame], set[int]] = {}
        for f in frames:
            for k in st.incident.get(f, ()):
                e = st.edges[k]
                pairs.setdefault(frozenset((e.u, e.v)), set()).add(k)
        for ks in sorted((sorted(ks) for ks in pairs.values() if len(ks) >= 2), key=min):
            self.merge_group(st, ks)

    def merge_group(self, st: _State, ks: list[int]) -> int:
        """Merge the parallel ATs ``ks`` into one (oriented first → second by rank); its id.
        Dependent ATs merge with their joint covariance (§4.2)."""
        e0 = st.edges[ks[0]]
        a, b = self.first(st, e0.u, e0.v)
        ks = sorted(ks, key=lambda k: st.edges[k].order)
        # a star's correlation is kept only while no information is lost with it: when its Y
        # and Z are merged with each other (or compounded); merged apart, it is dropped
        inside = {n for k in ks for n, _ in st.edges[k].links}
        apart = {n for n in inside if n in self.partner and self.partner[n] not in inside}
        if apart:
            outside = {n for k in st.linked if k not in ks for n, _ in st.edges[k].links}
            self.decorrelate(st, {n for n in apart if self.partner[n] in outside})
        parts = [self.oriented(st, k, a) for k in ks]
        links = [self.links(st, k, a) for k in ks]
        order = min(st.edges[k].order for k in ks)
        ats = [p[0] for p in parts]
        joint, dependent = self._joint(ats, links)
        try:
            at = merge(*ats, joint_cov=joint) if dependent else merge(*ats)
        except NotPositiveSemidefiniteError:
            if not self.decorrelate(st, {n for li in links for n, _ in li}):
                raise
            return self.merge_group(st, ks)
        out: tuple[tuple[str, FloatArray], ...] = ()
        if any(links):
            W = _merge_weights(joint, ats[0].group.dof, len(ats))
            out = _combine(*(_transform(Wi, Li) for Wi, Li in zip(W, links, strict=True)))
        for k in ks:
            st.drop(k)
        new = next(self.ids)
        st.add(new, _Edge(a, b, at, _Merge(tuple(p[1] for p in parts)), order, out))
        return new

    def links(self, st: _State, k: int, a: Frame) -> tuple[tuple[str, FloatArray], ...]:
        """The links of AT k pointing away from frame a (through Eq. 7's Jacobian)."""
        e = st.edges[k]
        if e.u == a or not e.links:
            return e.links
        return _transform(e.at.group.inverse(e.at.mean, jacobians=True)[1], e.links)

    def cross_cov(
        self, li: tuple[tuple[str, FloatArray], ...], lj: tuple[tuple[str, FloatArray], ...]
    ) -> FloatArray | None:
        """E[δi δjᵀ] of two ATs with links ``li``, ``lj``; None if they are independent."""
        out = None
        for m, Dm in li:
            for n, Dn in lj:
                known = self.cross.get(frozenset((m, n)))
                if known is None:
                    continue
                first, _, X = known
                X = X if first == m else np.swapaxes(X, -1, -2)
                term = Dm @ X @ np.swapaxes(Dn, -1, -2)
                out = term if out is None else out + term
        return out

    def _joint(
        self, ats: Sequence[AT | AT3], links: Sequence[tuple[tuple[str, FloatArray], ...]]
    ) -> tuple[FloatArray, bool]:
        """Joint covariance of the ATs (own covariances on the diagonal, the cross-covariances
        of their links elsewhere), and whether any of them are dependent."""
        b, k = ats[0].group.dof, len(ats)
        shape = np.broadcast_shapes(*(x.batch_shape for x in ats))
        joint = np.zeros((*shape, b * k, b * k))
        dependent = False
        for i, x in enumerate(ats):
            joint[..., b * i : b * i + b, b * i : b * i + b] = x.cov
            for j in range(i + 1, k):
                X = self.cross_cov(links[i], links[j])
                if X is None:
                    continue
                dependent = True
                joint[..., b * i : b * i + b, b * j : b * j + b] = X
                joint[..., b * j : b * j + b, b * i : b * i + b] = np.swapaxes(X, -1, -2)
        return joint, dependent

    def can_compound(self, st: _State, m: Frame) -> bool:
        """Whether frame m is an unmarked frame with exactly two ATs to two other frames."""
        if m in (self.s, self.t) or len(st.incident.get(m, ())) != 2:
            return False
        k1, k2 = st.incident[m]
        return st.other(k1, m) != st.other(k2, m)

    def compound_at(self, st: _State, m: Frame) -> int:
        """Compound the two ATs through frame m (step 2); the new AT's id. A dependent pair
        compounds with its cross-covariance (§3.2)."""
        k1, k2 = sorted(st.incident[m], key=lambda k: st.edges[k].order)
        a, b = st.other(k1, m), st.other(k2, m)
        if st.rank[a] > st.rank[b]:
            (a, k1), (b, k2) = (b, k2), (a, k1)
        ea, eb = st.edges[k1], st.edges[k2]
        e1 = ea.expr if ea.u == m else _rev(ea.expr)  # m → a
        e2 = eb.expr if eb.u == m else _rev(eb.expr)  # m → b
        l1, l2 = self.links(st, k1, a), self.links(st, k2, m)  # a → m, m → b
        cross = self.cross_cov(l1, l2) if l1 and l2 else None
        factors = None
        if cross is not None:
            before, second = self.oriented(st, k1, a)[0], self.oriented(st, k2, m)[0]
            try:
                at = compound(before, second, cross_cov=cross, moments=self.moments)
            except NotPositiveSemidefiniteError:
                if not self.decorrelate(st, {n for n, _ in (*l1, *l2)}):
                    raise
                return self.compound_at(st, m)
        elif self.moments is MomentsMethod.FIRST_ORDER:
            first, second = self.oriented(st, k1, m)[0], self.oriented(st, k2, m)[0]
            at = compound(reverse(first), second)
        elif self.moments is MomentsMethod.EXACT:
            factors = (*self.factors(st, k1, a), *self.factors(st, k2, m))
            at = self.chain(factors)
        else:
            at = self.series(st, [(k1, a), (k2, m)])
        links: tuple[tuple[str, FloatArray], ...] = ()
        if l1 or l2:  # first order: δ(x ⊕ y) = J₁ δx + J₂ δy
            x, y = self.oriented(st, k1, a)[0], self.oriented(st, k2, m)[0]
            _, J1, J2 = x.group.compose(x.mean, y.mean, jacobians=True)
            links = _combine(_transform(J1, l1), _transform(J2, l2))
        order = min(ea.order, eb.order)
        st.drop(k1)
        st.drop(k2)
        new = next(self.ids)
        st.add(new, _Edge(a, b, at, _comp(_rev(e1), e2), order, links, factors))
        return new

    def decorrelate(self, st: _State, among: set[str]) -> bool:
        """Drop the carried correlation of the consistent Delta-Y stars whose Y or Z is
        ``among`` these: each becomes three independent ATs, exact only where the triangle's S
        commute. Done where the correlation would otherwise be lost or cannot be carried (a
        triangle or star-mesh with them, a merge that parts Y from Z, an intermediate joint
        covariance the approximations made indefinite). False if there was none."""
        drop = self.star_members & among
        if not drop:
            return False
        drop |= {self.partner[n] for n in drop}
        changed = False
        for k in list(st.linked):
            e = st.edges[k]
            kept = tuple((n, D) for n, D in e.links if n not in drop)
            if len(kept) != len(e.links):
                st.edges[k] = e._replace(links=kept)
                changed = True
                if not kept:
                    st.linked.discard(k)
        return changed

    # ------------------------------------------------------------------- Delta-Y
    def refresh(self, st: _State) -> None:
        """Bring the Delta-Y and star-mesh candidates up to date with the frames whose ATs
        changed (a triangle through c also changes with the ATs of c's neighbours)."""
        changed, st.dirty = st.dirty, set()
        near = {st.other(k, f) for f in changed for k in st.incident.get(f, ())}
        for c in changed | near:
            entry = self.triangle_through(st, c)
            if entry is None:
                st.triangle_at.pop(c, None)
            elif st.triangle_at.get(c) != entry:
                st.triangle_at[c] = entry
                heapq.heappush(st.triangle_heap, (entry[0], next(st.tick), c))
        for o in changed:
            ks = st.incident.get(o, ())
            st.mesh_at.pop(o, None)
            if o in (self.s, self.t) or not 3 <= len(ks) <= MESH_MAX_DEGREE:
                continue
            others = {st.other(k, o) for k in ks}
            given = {n for k in ks for n, _ in st.edges[k].links} - self.star_members
            if len(others) == len(ks) and not given:
                st.mesh_at[o] = (len(ks), st.rank[o])
                heapq.heappush(st.mesh_heap, (st.mesh_at[o], next(st.tick), o))

    def triangle_through(
        self, st: _State, c: Frame
    ) -> tuple[tuple[int, list[tuple[float, ...]]], tuple[Frame, Frame, Frame]] | None:
        """The first (by :meth:`helping_triangle`'s order) triangle with unmarked corner c of
        three ATs, and its sort key; None if c is marked, has not three ATs, or no two of its
        neighbours are linked."""
        marked = {self.s, self.t}
        ks = st.incident.get(c, ())
        if c in marked or len(ks) != 3:
            return None
        best = None
        near = sorted({st.other(k, c) for k in ks} - {c}, key=lambda f: st.rank[f])
        for i, a in enumerate(near):
            for b in near[i + 1 :]:
                if not st.between(a, b):
                    continue
                tri = tuple(sorted((a, b, c), key=lambda f: st.rank[f]))
                key = (-len(marked & set(tri)), [st.rank[f] for f in tri])
                if best is None or key < best[0]:
                    best = (key, tri)
        return best  # type: ignore[return-value]

    def helping_triangle(self, st: _State) -> tuple[Frame, Frame, Frame] | None:
        """The triangle for Delta-Y, corners ordered by rank: one that lets series-parallel
        steps go on (a corner that is not marked and has three ATs keeps two: its triangle ATs
        become one star AT), the most marked corners first, then by the corners' ranks; None
        if there is none."""
        self.refresh(st)
        heap = st.triangle_heap
        while heap:
            key, _, c = heap[0]
            entry = st.triangle_at.get(c)
            if entry is not None and entry[0] == key:
                return entry[1]
            heapq.heappop(heap)  # stale
        return None

    def delta_y(self, st: _State, tri: tuple[Frame, Frame, Frame]) -> None:
        w, t, v = tri  # ordered by rank: w nearest the source
        kA, kB, kC = (st.between(*p)[-1] for p in ((w, t), (w, v), (t, v)))
        self.decorrelate(st, {n for k in (kA, kB, kC) for n, _ in st.edges[k].links})
        given = sorted({n for k in (kA, kB, kC) for n, _ in st.edges[k].links})
        if given:
            raise IrreducibleNetworkError(
                f"the paper's reduction assumes independent ATs, but {given[0]!r}, an AT of a "
                "dependent group, would be transformed by Delta-Y here; use method='optimal'"
            )
        A, eA = self.oriented(st, kA, w)
        B, eB = self.oriented(st, kB, w)
        C, eC = self.oriented(st, kC, t)
        if self.moments is MomentsMethod.FIRST_ORDER:
            A1 = merge(A, compound(B, reverse(C)))
            B1 = merge(B, compound(A, C))
        else:  # the same compoundings with exact or unscented moments
            A1 = merge(A, self.series(st, [(kB, w), (kC, v)]))
            B1 = merge(B, self.series(st, [(kA, w), (kC, t)]))
        group, kind = A.group, type(A)
        if self.delta_y_rule is DeltaY.PAPER:
            if self.moments is MomentsMethod.FIRST_ORDER:
                C1 = merge(C, compound(reverse(A), B))
            else:
                C1 = merge(C, self.series(st, [(kA, t), (kB, w)]))
            K = group.compose(A.mean, A.mean, jacobians=True)[2]  # ∂(A ⊕ b)/∂b
            KCK = congruence(K, C1.cov)
            covs = (
                0.5 * (A1.cov + B1.cov - KCK),
                0.5 * (-A1.cov + B1.cov + KCK),
                0.5 * (A1.cov - B1.cov + KCK),
            )
        else:
            covs, cross_zy = _consistent_star(group, A.cov, B.cov, C.cov, A1.mean, B1.mean)
        covs = tuple(0.5 * (X + np.swapaxes(X, -1, -2)) for X in covs)
        n = next(self.stars)
        o = ("Δ-Y", n)
        st.rank[o] = (*st.rank[w], 0.5, n)  # after w, before what follows it; unique
        names = [f"X{_sub(n)}", f"Y{_sub(n)}", f"Z{_sub(n)}"]
        triangle = (
            f"the Δ of {_short(_render(eA))} ({w!r}→{t!r}), {_short(_render(eB))} ({w!r}→{v!r}), "
            f"{_short(_render(eC))} ({t!r}→{v!r})"
        )
        o_name = f"o{_sub(n)}"
        rule = "" if self.delta_y_rule is DeltaY.CONSISTENT else " (the paper's formulas)"
        self.definitions[names[0]] = f"Y{rule} of {triangle}: {w!r}→{o_name}, identity mean"
        self.definitions[names[1]] = f"Y of {triangle}: {o_name}→{v!r}, mean of B' = B ⊗ (A ⊕ C)"
        self.definitions[names[2]] = f"Y of {triangle}: {o_name}→{t!r}, mean of A' = A ⊗ (B ⊕ Cᴿ)"
        star_links: list[tuple[tuple[str, FloatArray], ...]] = [(), (), ()]
        if self.delta_y_rule is DeltaY.CONSISTENT:
            self.cross[frozenset(names[1:])] = (names[2], names[1], cross_zy)
            self.star_members.update(names[1:])
            self.partner.update({names[1]: names[2], names[2]: names[1]})
            eye = np.eye(group.dof)
            star_links[1:] = [((names[1], eye),), ((names[2], eye),)]
            self.definitions[names[1]] += f", correlated with {names[2]}"
            self.definitions[names[2]] += f", correlated with {names[1]}"
        order = min(st.edges[k].order for k in (kA, kB, kC))
        for k in (kA, kB, kC):
            st.drop(k)
        means = (group.identity(A.batch_shape), B1.mean, A1.mean)
        ends = ((w, o), (o, v), (o, t))
        for i, ((u, x), mean, cov) in enumerate(zip(ends, means, covs, strict=True)):
            st.add(
                next(self.ids),
                _Edge(
                    u,
                    x,
                    kind._trusted(mean, cov),
                    _Leaf(names[i]),
                    order + i * 1e-3,
                    star_links[i],
                ),
            )

    def stars_to_mesh(self, st: _State) -> bool:
        """Y→Δ, and its generalization star-mesh: replace an unmarked frame o with d ATs to d
        other frames (3 ≤ d ≤ :data:`MESH_MAX_DEGREE`; the fewest first) by ATs between every
        two of them (:func:`_consistent_mesh`); False if there is no such frame (or none whose
        star can be inverted)."""
        self.refresh(st)
        heap = st.mesh_heap  # the fewest ATs first, then by rank
        while heap:
            key, _, o = heapq.heappop(heap)
            if st.mesh_at.get(o) != key:
                continue  # stale
            # (a star found singular below stays off the heap until its ATs change)
            legs = sorted(st.incident[o], key=lambda k: st.rank[st.other(k, o)])
            tried = (o, frozenset(legs))  # AT ids are never reused: the same ATs
            if tried in self.no_mesh:
                continue
            oriented = [self.oriented(st, k, o) for k in legs]
            ends = [st.other(k, o) for k in legs]
            mesh = _consistent_mesh(oriented[0][0].group, [at for at, _ in oriented])
            if mesh is None:
                self.no_mesh.add(tried)
                continue
            n = next(self.meshes)
            order = min(st.edges[k].order for k in legs)
            star = ", ".join(
                f"{_short(_render(e), 40)} ({o!r}→{f!r})"
                for (_, e), f in zip(oriented, ends, strict=True)
            )
            what = "Y→Δ" if len(legs) == 3 else "star-mesh"
            self.decorrelate(st, {n for k in legs for n, _ in st.edges[k].links})
            for k in legs:
                st.drop(k)
            kind = type(oriented[0][0])
            for i, ((p, q), mean, cov) in enumerate(mesh):
                name = f"M{_sub(n)}{_letters(i)}"
                self.definitions[name] = (
                    f"{what} of the star {_short(star, 200)}: {ends[p]!r}→{ends[q]!r}"
                )
                st.add(
                    next(self.ids),
                    _Edge(
                        ends[p],
                        ends[q],
                        kind._trusted(mean, cov),
                        _Leaf(name),
                        order + i * 1e-3,
                        (),
                    ),
                )
            return True
        return False

    # --------------------------------------------------------------------- driver
    def series_parallel(self, st: _State) -> None:
        """Prune, merge parallel ATs and compound serial ones until none is left (steps 2-3).

        A worklist: the frame with the lowest rank that can be compounded next, as a heap of
        the frames whose ATs changed (since the last call: ``st.touched``); O((frames + ATs)
        log frames) the first time, then in the size of what changed."""
        # only frames whose ATs changed since the last call can have anything to do
        frames = list(dict.fromkeys(f for f in st.touched if f in st.incident))
        for k in {k for f in frames for k in st.incident[f] if st.edges[k].u == st.edges[k].v}:
            st.drop(k)
        self.merge_parallel(st, frames)
        heap: list[tuple[tuple[float, ...], int, Frame]] = []
        tick = count()
        st.touched = frames + st.touched
        while True:
            touched, st.touched = st.touched, []
            self.prune_from(st, touched)
            for f in (*touched, *st.touched):
                if f in st.incident:
                    heapq.heappush(heap, (st.rank[f], next(tick), f))
            st.touched = []
            while heap and not self.can_compound(st, heap[0][2]):
                heapq.heappop(heap)
            if not heap:
                return
            m = heapq.heappop(heap)[2]
            new = self.compound_at(st, m)
            e = st.edges[new]
            parallel = st.between(e.u, e.v)
            if len(parallel) > 1:
                self.merge_group(st, parallel)

    def prune_from(self, st: _State, frames: Sequence[Frame]) -> None:
        """Drop dangling ATs (frames with one AT, not marked) reachable from ``frames``."""
        queue = deque(frames)
        while queue:
            f = queue.popleft()
            if f in (self.s, self.t) or f not in st.incident or len(st.incident[f]) != 1:
                continue
            (k,) = st.incident[f]
            other = st.other(k, f)
            st.drop(k)
            queue.append(other)

    def done(self, st: _State) -> bool:
        return len(st.edges) == 1 and {st.edges[k].u for k in st.edges} | {
            st.edges[k].v for k in st.edges
        } == {self.s, self.t}

    def reduce(self, st: _State) -> bool:
        """Series-parallel reductions, with Delta-Y (or else Y→Δ) when stuck; True if one AT
        remains. Every Delta-Y applied lets a series step follow, and every Y→Δ removes a
        frame, so ATs + frames decrease at every round: the loop ends."""
        self.series_parallel(st)
        total = len(st.edges)
        while not self.done(st):
            if self.progress:
                self.progress(total - len(st.edges), total)
            tri = self.helping_triangle(st)
            if tri is not None:
                self.delta_y(st, tri)
            elif not self.stars_to_mesh(st):
                return False
            self.series_parallel(st)
        return True


def _chart_of_origin(group: Group, pose: FloatArray) -> FloatArray:
    """T(p) = ∂(a ⊕ p)/∂a at a = identity: the chart perturbation of pose p (in the common
    frame) caused by a perturbation ξ of the common frame itself, δp = T(p) ξ.

    In the plane T = [[1, 0, -y], [0, 1, x], [0, 0, 1]]; in 3-D [[I, -[t]×], [0, I]]. These
    matrices commute (T(p) T(q) depends only on t_p + t_q), which makes every AT of a map
    a difference ``ξ_j - ξ_i`` of such coordinates to first order (:func:`_consistent_star`).
    """
    eye = group.identity(group.batch_shape(pose))
    return group.compose(eye, pose, jacobians=True)[1]


def _consistent_star(
    group: Group,
    CA: FloatArray,
    CB: FloatArray,
    CC: FloatArray,
    pt: FloatArray,
    pv: FloatArray,
) -> tuple[tuple[FloatArray, FloatArray, FloatArray], FloatArray]:
    """Covariances of the star X (w→o), Y (o→v), Z (o→t), and E[δZ δYᵀ], that reproduce, to
    first order, the triangle A (w→t), B (w→v), C (t→v) seen from its corners (module
    docstring).

    ``pt``, ``pv``: the corners t and v in w's frame (the star's o sits at w)."""
    Tt, Tv = _chart_of_origin(group, pt), _chart_of_origin(group, pv)
    Jv = group.between(pt, pv, jacobians=True)[2]  # ∂ between(t, v) / ∂v
    SA = congruence(np.linalg.inv(Tt), CA)
    SB = congruence(np.linalg.inv(Tv), CB)
    SC = congruence(np.linalg.inv(Jv @ Tv), CC)
    G, _ = generalized_inverse(SA + SB + SC)
    Ptv = SA @ G @ SB
    Ptt = SA - SA @ G @ SA
    Pvv = SB - SB @ G @ SB
    GAB, _ = generalized_inverse(SA + SB)
    R = SA @ GAB @ SB  # S_A ∥ S_B, the most X can carry
    R = 0.5 * (R + np.swapaxes(R, -1, -2))
    SX = _between_zero_and(0.5 * (Ptv + np.swapaxes(Ptv, -1, -2)), R)
    covs = (SX, congruence(Tv, Pvv - SX), congruence(Tt, Ptt - SX))
    return covs, Tt @ (Ptv - SX) @ np.swapaxes(Tv, -1, -2)


def _between_zero_and(M: FloatArray, R: FloatArray, rtol: float = 1e-9) -> FloatArray:
    """M (symmetric) if ``0 ⪯ M ⪯ R`` (within ``rtol``), else the matrix of that interval
    nearest to it in R's metric: M's eigenvalues relative to R clipped to [0, 1]. Where R is
    singular the result vanishes along R's null space."""
    lam, U = np.linalg.eigh(R)
    scale = np.abs(lam).max(axis=-1, keepdims=True)
    keep = lam > rtol * np.where(scale > 0, scale, 1.0)
    root = U * np.where(keep, np.sqrt(np.where(keep, lam, 1.0)), 0.0)[..., None, :]  # R^½
    iroot = U * np.where(keep, 1.0 / np.sqrt(np.where(keep, lam, 1.0)), 0.0)[..., None, :]
    W = congruence(np.swapaxes(iroot, -1, -2), M)  # M relative to R, on R's range
    mu, V = np.linalg.eigh(W)
    inside = congruence(root, W)  # M's part on R's range
    size = np.abs(M).max(axis=(-2, -1)) + np.abs(R).max(axis=(-2, -1))
    ok = (
        (mu.min(axis=-1) >= -rtol)
        & (mu.max(axis=-1) <= 1 + rtol)
        & (np.abs(M - inside).max(axis=(-2, -1)) <= rtol * size)
    )
    clipped = congruence(root, (V * np.clip(mu, 0.0, 1.0)[..., None, :]) @ np.swapaxes(V, -1, -2))
    return np.where(ok[..., None, None], M, clipped)


def _transform(
    M: FloatArray, links: tuple[tuple[str, FloatArray], ...]
) -> tuple[tuple[str, FloatArray], ...]:
    """Links of ``M δ`` for an AT δ with ``links``."""
    return tuple((n, M @ D) for n, D in links)


def _combine(*parts: tuple[tuple[str, FloatArray], ...]) -> tuple[tuple[str, FloatArray], ...]:
    """Links of a sum of ATs' errors (each member appears in one working AT; summed if not)."""
    out: dict[str, FloatArray] = {}
    for links in parts:
        for n, D in links:
            out[n] = out[n] + D if n in out else D
    return tuple(out.items())


def _merge_weights(joint: FloatArray, b: int, k: int) -> list[FloatArray]:
    """First-order weights W_i of the best linear unbiased merge of k ATs with ``joint``
    covariance, ``δx̂ = Σ W_i δ_i`` (:func:`relmap.merge`: x̂ = z₁ - Cov(e₁, d) Cov(d)⁺ d,
    ``d_j = z_j ⊟ z₁``)."""
    K, _, _ = difference_merge_gain(joint, b, k)
    Ks = [K[..., :, b * (j - 1) : b * j] for j in range(1, k)]
    return [np.eye(b) + sum(Ks, np.zeros_like(Ks[0])), *(-Kj for Kj in Ks)]


def _consistent_mesh(
    group: Group, legs: Sequence[AT | AT3]
) -> list[tuple[tuple[int, int], FloatArray, FloatArray]] | None:
    """Star-mesh (Y→Δ for three legs): ATs between every two ends of the star ``legs``
    (o→a₀, …, o→a_{d-1}) that reproduce, to first order, the star seen from its ends (module
    docstring); ``((p, q), mean, cov)`` for the AT a_p → a_q. None when the star or a mesh AT
    is singular (an exactly known direction: no finite mesh)."""
    d, b = len(legs), group.dof
    T = [_chart_of_origin(group, leg.mean) for leg in legs]
    S = [congruence(np.linalg.inv(Ti), leg.cov) for Ti, leg in zip(T, legs, strict=True)]
    # Directions every leg knows exactly (e.g. headings without error) stay exact: the mesh is
    # built on the other directions, U spanning them.
    lam, U = np.linalg.eigh(sum(S))
    keep = lam > 1e-12 * np.abs(lam).max(axis=-1, keepdims=True)
    r = keep.sum(axis=-1)
    if not np.all(r == r.flat[0]) or r.flat[0] == 0:
        return None
    U = U[..., :, b - int(r.flat[0]) :]
    Ut = np.swapaxes(U, -1, -2)
    S = [congruence(Ut, Sk) for Sk in S]
    c = U.shape[-1]
    # ξ_k - ξ_0 (k ≥ 1) seen through the star: Cov = S_0 + δ_km S_k
    P = np.concatenate(
        [
            np.concatenate([S[0] + (S[k] if k == m else 0.0) for m in range(1, d)], axis=-1)
            for k in range(1, d)
        ],
        axis=-2,
    )
    if not np.all(np.linalg.cond(P) < 1e12):
        return None
    H = np.linalg.inv(P)
    H = 0.5 * (H + np.swapaxes(H, -1, -2))

    def block(k: int, m: int) -> FloatArray:
        return H[..., c * (k - 1) : c * k, c * (m - 1) : c * m]

    G: dict[tuple[int, int], FloatArray] = {}
    for k in range(1, d):
        for m in range(k + 1, d):
            Gkm = -block(k, m)
            G[k, m] = 0.5 * (Gkm + np.swapaxes(Gkm, -1, -2))
    for k in range(1, d):
        G[0, k] = block(k, k) - sum((G[min(k, m), max(k, m)] for m in range(1, d) if m != k), 0.0)
    out = []
    for (p, q), Gpq in sorted(G.items()):
        if not np.all(np.linalg.eigvalsh(Gpq) > 1e-12 * np.abs(Gpq).max()):
            return None  # no finite, positive definite AT carries this conductance
        mean, _, Jq = group.between(legs[p].mean, legs[q].mean, jacobians=True)
        Spq = U @ np.linalg.inv(Gpq) @ Ut
        out.append(((p, q), mean, congruence(Jq @ T[q], Spq)))
    return out


def _letters(i: int) -> str:
    """a, b, …, z, aa, ab, …: the i-th name of a star-mesh's ATs."""
    return _LETTERS[i] if i < len(_LETTERS) else _letters(i // 26 - 1) + _LETTERS[i % 26]


def _short(text: str, limit: int = 80) -> str:
    """``text`` cut to ``limit`` characters (with … and the full length)."""
    return text if len(text) <= limit else f"{text[: limit - 20]}… ({len(text)} chars)"


def _sub(n: int) -> str:
    return str(n).translate(str.maketrans("0123456789", "₀₁₂₃₄₅₆₇₈₉"))


def position_trace(at: AT | AT3) -> float:
    """Trace of the position block of the covariance (m²): (x, y), or (x, y, z) in 3-D."""
    return float(np.trace(at.position_cov, axis1=-2, axis2=-1))


#: the most ATs a frame may have for star-mesh elimination when nothing else applies
MESH_MAX_DEGREE = 8
_LETTERS = "abcdefghijklmnopqrstuvwxyz"
#: best deletion tries every AT of what is left; beyond this many independent loops it refuses
DROP_MAX_LOOPS = 8
#: best deletion is refused at once on networks with more independent loops than this
DROP_MAX_INPUT_LOOPS = 100


def reduce_network(
    edges: Sequence[tuple[str, Frame, Frame, AT | AT3]],
    s: Frame,
    t: Frame,
    *,
    on_irreducible: OnIrreducible | str = OnIrreducible.RAISE,
    criterion: Callable[[AT | AT3], float] = position_trace,
    groups: Sequence[tuple[Sequence[str], np.ndarray]] = (),
    moments: MomentsMethod | str = MomentsMethod.FIRST_ORDER,
    delta_y: DeltaY | str = DeltaY.CONSISTENT,
    progress: Callable[[int, int], None] | None = None,
) -> Reduction:
    """Reduce ``edges`` (``(name, src, dst, AT)``) to the AT of frame t seen from frame s.

    ``on_irreducible`` (an :class:`OnIrreducible`) is ``"raise"`` or ``"drop"`` (best
    deletion, judged by ``criterion``, by default the trace of the result's position covariance,
    m²; greedy, one AT at a time, and refused at once, pointing to ``method='optimal'``, when
    more than :data:`DROP_MAX_LOOPS` independent loops are left). ``groups`` lists dependent
    ATs as ``(names, joint covariance)``; ATs containing them compound with their
    cross-covariance (§3.2) and merge with their joint covariance (§4.2); Delta-Y on a
    triangle with one of them raises (module docstring). ``moments`` (a
    :class:`~relmap.uncertain.moments.MomentsMethod`) is ``"first_order"`` (Eqs. 1-7),
    ``"exact"`` or ``"unscented"`` (SE(2) only; module docstring: what they mean where merging
    follows compounding). ``delta_y`` (a :class:`DeltaY`) is ``"consistent"`` (default: the
    first-order-consistent star) or ``"paper"`` (the paper's formulas, to reproduce it).
    ``progress(done, total)`` is called as Delta-Y / Y→Δ rounds go on (ATs reduced of those
    left after series-parallel steps) and during best deletion (deletions tried).

    The result's covariance is symmetric PSD (rounding below 1e-9 of its scale clipped);
    when the approximations of Delta-Y / Y→Δ give an indefinite one,
    :class:`IrreducibleNetworkError` names the steps instead.
    """
    on_irreducible = OnIrreducible.parse(on_irreducible, "on_irreducible")
    s, t = _plain(s), _plain(t)
    edges = [(name, _plain(u), _plain(v), at) for name, u, v, at in edges]
    delta_y = DeltaY.parse(delta_y, "delta_y")
    moments = MomentsMethod.parse(moments, "moments")
    if moments is not MomentsMethod.FIRST_ORDER and any(e[3].dim != 2 for e in edges):
        raise ParameterError(
            f"moments={moments.value!r} is available for SE(2) maps only (3-D ATs compound to "
            "first order); use moments='first_order'"
        )
    group_of: dict[str, tuple[str, ...]] = {}
    cross: dict[frozenset[str], tuple[str, str, np.ndarray]] = {}
    dof = edges[0][3].group.dof if edges else 3
    for gi, (names, joint) in enumerate(groups):
        for i, a in enumerate(names):
            group_of[a] = (f"g{gi}",)
            for j, b in enumerate(names):
                if i < j:
                    cross[frozenset((a, b))] = (
                        a,
                        b,
                        np.asarray(joint)[dof * i : dof * (i + 1), dof * j : dof * (j + 1)],
                    )
    rank = _hop_rank(edges, s, t)
    st = _State(
        {
            i: _Edge(
                u, v, at, _Leaf(name), float(i), ((name, np.eye(dof)),) if name in group_of else ()
            )
            for i, (name, u, v, at) in enumerate(edges)
        },
        rank,
    )
    loops = len(edges) - len({f for e in edges for f in e[1:3]}) + 1
    if on_irreducible is OnIrreducible.DROP and loops > DROP_MAX_INPUT_LOOPS:
        raise IrreducibleNetworkError(
            f"best deletion refused: the network between {s!r} and {t!r} has {len(edges)} ATs "
            f"and {loops} independent loops (more than {DROP_MAX_INPUT_LOOPS}); deleting ATs "
            "until the paper's reduction applies would discard most of its information; use "
            "method='optimal', which uses all of it"
        )
    definitions: dict[str, str] = {}
    reducer = _Reducer(s, t, cross, definitions, moments, delta_y)
    reducer.progress = progress
    with np.errstate(over="ignore", invalid="ignore"):
        try:
            at, expr, dropped = _reduce_or_drop(reducer, st, on_irreducible, criterion, progress)
            finite = bool(np.all(np.isfinite(at.cov)) and np.all(np.isfinite(at.mean)))
        except np.linalg.LinAlgError:
            finite = False
    if not finite:
        raise NumericalError(
            f"the reduction from {s!r} to {t!r} overflowed (inf/NaN): the ATs' means or "
            "covariances are too large for floating point"
        )
    text = _render(expr)
    at = _checked_psd(at, text, definitions)
    return Reduction(at, text, dropped, definitions)


def _plain(frame: Frame) -> Frame:
    """A numpy scalar frame (``np.int64(5)``) as the Python value it equals (``5``): the
    working network compares frames with ``==``, which numpy would broadcast."""
    return frame.item() if isinstance(frame, np.generic) else frame


def _checked_psd(at: AT | AT3, expression: str, definitions: dict[str, str]) -> AT | AT3:
    """``at`` with a symmetric PSD covariance (eigenvalues below zero by rounding, within 1e-9
    of the largest, clipped), or :class:`IrreducibleNetworkError` naming the approximate
    steps that made it indefinite."""
    C = 0.5 * (at.cov + np.swapaxes(at.cov, -1, -2))
    lam, U = np.linalg.eigh(C)
    scale = np.abs(lam).max(axis=-1, keepdims=True)
    worst = (lam / np.where(scale > 0, scale, 1.0)).min()
    if worst < -1e-9:
        steps = [n for n in definitions if n in expression] or ["(none)"]
        shown = ", ".join(steps[:6]) + (f" and {len(steps) - 6} more" if len(steps) > 6 else "")
        raise IrreducibleNetworkError(
            f"the reduction's result is not a covariance (smallest eigenvalue {worst:.3g} of "
            f"its scale) after the approximate Delta-Y / Y→Δ steps {shown}: their first-order "
            "approximation fails here; use method='optimal'",
            (expression,),
        )
    if (lam < 0).any():
        C = (U * np.maximum(lam, 0.0)[..., None, :]) @ np.swapaxes(U, -1, -2)
        C = 0.5 * (C + np.swapaxes(C, -1, -2))
    return type(at)._trusted(at.mean, C)


def _listing(remaining: Sequence[str], limit: int = 6) -> str:
    """A few of the expressions, each cut short, and how many more."""
    shown = ", ".join(_short(r, 60) for r in remaining[:limit])
    return shown + (f" and {len(remaining) - limit} more" if len(remaining) > limit else "")


def _reduce_or_drop(
    reducer: _Reducer,
    st: _State,
    on_irreducible: OnIrreducible,
    criterion: Callable[[AT | AT3], float],
    progress: Callable[[int, int], None] | None = None,
) -> tuple[AT | AT3, object, tuple[str, ...]]:
    dropped_so_far: list[str] = []
    while True:
        if reducer.reduce(st):
            (k,) = st.edges
            at, expr = reducer.oriented(st, k, reducer.s)
            return at, expr, tuple(dropped_so_far)
        remaining = tuple(_render(e.expr) for e in st.edges.values())
        frames = len(st.incident)
        loops = len(st.edges) - frames + 1
        core = f"{len(remaining)} ATs among {frames} frames, {loops} independent loops"
        if on_irreducible is OnIrreducible.RAISE:
            raise IrreducibleNetworkError(
                f"the paper's reduction (with Delta-Y) cannot reduce the network left ({core}: "
                f"{_listing(remaining)}); use method='optimal', or on_irreducible='drop' to "
                "delete ATs (best deletion)",
                remaining,
            )
        if loops > DROP_MAX_LOOPS:
            raise IrreducibleNetworkError(
                f"best deletion refused: the reduction is stuck on {core}, and deleting ATs "
                f"one by one (more than {DROP_MAX_LOOPS} loops) would throw away most of the "
                "information of the network; use method='optimal', which uses all of it",
                remaining,
            )
        if any(e.at.ndim for e in st.edges.values()):
            raise ParameterError("best deletion needs single ATs, not batches")
        best: tuple[float, int, _State, dict[str, str], str] | None = None
        fallback: tuple[int, int, _State, dict[str, str], str] | None = None
        keys = list(st.edges)
        saved = dict(reducer.definitions)
        for done, k in enumerate(keys):
            if progress:
                progress(done, len(keys))
            trial = st.copy()
            name = _render(trial.drop(k).expr)
            if not _connected(trial, reducer.s, reducer.t):
                continue
            reducer.definitions.clear()
            reducer.definitions.update(saved)
            ok = reducer.reduce(trial)
            if ok:
                (only,) = trial.edges
                score = criterion(reducer.oriented(trial, only, reducer.s)[0])
                if best is None or score < best[0]:
                    best = (score, k, trial, dict(reducer.definitions), name)
            elif best is None and (fallback is None or len(trial.edges) < fallback[0]):
                fallback = (len(trial.edges), k, trial, dict(reducer.definitions), name)
        if progress:
            progress(len(keys), len(keys))
        choice = best or fallback
        if choice is None:
            raise IrreducibleNetworkError(
                "no AT can be deleted without disconnecting the frames", remaining
            )
        _, _, st, defs, name = choice
        reducer.definitions.clear()
        reducer.definitions.update(defs)
        dropped_so_far.append(name)


def _connected(st: _State, s: Frame, t: Frame) -> bool:
    seen, queue = {s}, deque([s])
    while queue:
        f = queue.popleft()
        for k in st.incident.get(f, ()):
            g = st.other(k, f)
            if g not in seen:
                seen.add(g)
                queue.append(g)
    return t in seen


def _hop_rank(
    edges: Sequence[tuple[str, Frame, Frame, AT | AT3]], s: Frame, t: Frame
) -> dict[Frame, tuple[float, ...]]:
    """Frames ordered from the source's side to the destination's.

    Key: (hops from s, -hops to t, order of first appearance).
    """
    adj: dict[Frame, list[Frame]] = {}
    seen_order: dict[Frame, int] = {}
    for _, u, v, _ in edges:
        for f in (u, v):
            seen_order.setdefault(f, len(seen_order))
        adj.setdefault(u, []).append(v)
        adj.setdefault(v, []).append(u)

    def hops(root: Frame) -> dict[Frame, int]:
        dist = {root: 0}
        queue = deque([root])
        while queue:
            f = queue.popleft()
            for g in adj.get(f, ()):
                if g not in dist:
                    dist[g] = dist[f] + 1
                    queue.append(g)
        return dist

    ds, dt = hops(s), hops(t)
    big = len(seen_order) + 1
    return {f: (ds.get(f, big), -dt.get(f, big), i) for f, i in seen_order.items()}
