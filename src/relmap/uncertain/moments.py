"""Beyond first order: exact moments of SE(2) compounding, the unscented alternative, and a
diagnostic that says when the first-order answer of Eqs. (3)-(4) cannot be trusted.

**What is exact.** When the inputs are Gaussian in relmap's chart (each AT's ``(x, y, θ)`` is
``N(mean, cov)``, covariance in the parent frame, heading taken on the real line), the
compounded pose ``c = t₁ + R(θ₁) t₂ + R(θ₁+θ₂) t₃ + …``, ``Θ = θ₁ + θ₂ + …`` is a nonlinear
function of them, and :func:`compound_moments` / :func:`chain_moments` return the **first two
moments of its true distribution** — its mean and covariance, to rounding, with no
linearization and no sampling. The heading's moments are those of the unwrapped sum ``Θ`` on
the real line: mean ``Σ μθ`` (returned wrapped to [-π, π)), variance ``Σ σθ²`` exactly, however
large; its cross-covariances with the position are those of the unwrapped ``Θ`` too. (A Monte
Carlo check must therefore sum sampled headings without wrapping before taking moments.)

**What is not.** The compounded pose is not Gaussian (the paper's crescent, Fig. 5): exact
moments describe it with the right mean and covariance, but probabilities read from the
Gaussian with those moments (ellipses, :mod:`relmap.models.decisions`) remain an approximation;
:meth:`relmap.sim.montecarlo.SampleSet.compare` measures how far from Gaussian a sample is
(Mardia's skewness and kurtosis). Merging afterwards (⊗) is still the linear-Gaussian update
of Eqs. (8)-(10) applied to those moments (a moment-matched Gaussian), not the exact posterior.

**How.** Write positions as complex numbers, ``z = x + iy``, so a rotation is ``e^{iθ}``. For
``θ ~ N(μ, σ²)`` the characteristic function gives ``E[e^{ikθ}] = e^{ikμ - k²σ²/2}``, and for a
jointly Gaussian linear quantity ``u`` (Stein's lemma, or an exponential tilt)
``E[u e^{ikθ}] = E[e^{ikθ}] (E[u] + ik Cov(u, θ))``. A chain link ``(z_k, θ_k)`` is independent
of the heading ``Θ_{k-1}`` that rotates it, so every moment of the chain is a sum of such terms;
they follow from running sums and two first-order complex recursions (a parallel affine scan),
O(n log n) work with a depth of log₂ n vectorized steps, and every prefix at once. The
recursions carry *central* moments (covariances), so nothing cancels catastrophically when the
uncertainty is tiny next to the chain's length.

:func:`unscented_compound` / :func:`unscented_chain` give the unscented transform
(:func:`relmap.uncertain.propagate.unscented`) of the same functions for comparison, and
:func:`linearization_error` predicts the first-order error from the exact moments.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from relmap.errors import ParameterError, ShapeError
from relmap.lie import se2
from relmap.lie.group import SE2 as SE2_GROUP
from relmap.typing import ArrayLike, FloatArray, Option
from relmap.uncertain.gaussian import check_finite, real_array, validate_covariance
from relmap.uncertain.pose import UncertainPose, chain_axis, chain_batch_axis, same_kind
from relmap.uncertain.propagate import EUCLIDEAN, SE2, Chart, Moments, unscented

__all__ = [
    "ChainScheme",
    "Linearization",
    "MomentsMethod",
    "chain_moments",
    "compound_moments",
    "linearization_error",
    "reverse_moments",
    "unscented_chain",
    "unscented_compound",
    "unscented_reverse",
]


class MomentsMethod(Option):
    """How ``compound`` / ``compound_chain`` (and a map's reduction) compute the result's
    moments: Eqs. (1)-(4) (``"first_order"``), the exact mean and covariance for Gaussian inputs
    (``"exact"``: :func:`compound_moments`, :func:`chain_moments`), or the unscented transform
    (``"unscented"``: :func:`unscented_compound`, :func:`unscented_chain`)."""

    FIRST_ORDER = "first_order"
    EXACT = "exact"
    UNSCENTED = "unscented"


class ChainScheme(Option):
    """How :func:`unscented_chain` transforms a chain: one link after the other
    (``"sequential"``) or all links in one transform (``"joint"``)."""

    SEQUENTIAL = "sequential"
    JOINT = "joint"


ComplexArray = np.ndarray


def _poses(mean: ArrayLike, cov: ArrayLike, name: str) -> tuple[FloatArray, FloatArray]:
    m = real_array(mean, f"{name} mean")
    if m.ndim == 0 or m.shape[-1] != 3:
        raise ShapeError(f"{name} mean must have shape (..., 3); got {m.shape}")
    check_finite(m, f"{name} mean")
    C = validate_covariance(cov, dim=3, name=f"{name} cov")
    if C.ndim < 2 or C.shape[-2:] != (3, 3):
        raise ShapeError(f"{name} cov must have shape (..., 3, 3); got {C.shape}")
    return m, C


def _complex(C: FloatArray) -> tuple[FloatArray, ComplexArray, ComplexArray]:
    """A link's covariance in complex form: ``E|z - m|²``, ``E[(z - m)²]``, ``Cov(z, θ)``."""
    p = C[..., 0, 0] + C[..., 1, 1]
    q = C[..., 0, 0] - C[..., 1, 1] + 2j * C[..., 0, 1]
    c_zt = C[..., 0, 2] + 1j * C[..., 1, 2]
    return p, q, c_zt


def _assemble(
    M: ComplexArray,
    mu_theta: FloatArray,
    P: FloatArray,
    Q: ComplexArray,
    R: ComplexArray,
    var_theta: FloatArray,
) -> tuple[FloatArray, FloatArray]:
    """Mean ``(..., 3)`` and covariance ``(..., 3, 3)`` from the complex moments.

    ``P = E|c - M|²``, ``Q = E[(c - M)²]``, ``R = Cov(Θ, c)``: ``Var x = (P + Re Q)/2``,
    ``Var y = (P - Re Q)/2``, ``Cov(x, y) = Im Q / 2``, ``Cov(x, Θ) = Re R``, ``Cov(y, Θ) = Im R``.
    """
    mean = np.stack([M.real, M.imag, se2.wrap_angle(mu_theta)], axis=-1)
    cov = np.empty((*mean.shape, 3))
    cov[..., 0, 0] = 0.5 * (P + Q.real)
    cov[..., 1, 1] = 0.5 * (P - Q.real)
    cov[..., 0, 1] = cov[..., 1, 0] = 0.5 * Q.imag
    cov[..., 0, 2] = cov[..., 2, 0] = R.real
    cov[..., 1, 2] = cov[..., 2, 1] = R.imag
    cov[..., 2, 2] = var_theta
    return mean, cov


def _affine_scan(alpha: ComplexArray, beta: ComplexArray) -> ComplexArray:
    """``x_k = α_k x_{k-1} + β_k`` (``x_0 = 0``) for every k along axis 0, by recursive doubling.

    Each level composes every affine map with the one ``shift`` places before it; all products
    are of the ``α`` themselves (``|α| ≤ 1`` here), never of their inverses, so nothing
    overflows however much the heading's uncertainty damps the phases.
    """
    a = alpha.copy()
    b = beta.copy()
    n = a.shape[0]
    shift = 1
    while shift < n:
        b[shift:] = a[shift:] * b[:-shift] + b[shift:]
        a[shift:] = a[shift:] * a[:-shift]
        shift *= 2
    return b


def _exclusive(x: np.ndarray) -> np.ndarray:
    """``x`` shifted one place along axis 0, with zero first: the value *before* each link."""
    out = np.zeros_like(x)
    out[1:] = x[:-1]
    return out


# ------------------------------------------------------------------------- exact chain
def chain_moments(mean: ArrayLike, cov: ArrayLike, *, axis: int = -1) -> Moments:
    """Exact mean and covariance of every prefix ``A₁ ⊕ … ⊕ A_k`` of a chain of independent
    Gaussian links laid along batch ``axis`` (module docstring: what is exact).

    ``mean (..., 3)``, ``cov (..., 3, 3)``: each link's ``(x, y, θ)`` and covariance in its
    parent frame (any correlation within a link is kept; links are independent). Returns
    :class:`relmap.uncertain.propagate.Moments` of the same batch shape, element k along ``axis``
    the
    pose of frame k in the chain's first frame with its covariance in that frame.

    With ``c_k = Σ_{j≤k} e^{iΘ_{j-1}} z_j``, ``Θ_k = Σ_{j≤k} θ_j``, ``φ_k = E[e^{iΘ_k}]``
    ``= e^{iΣμ - Σσ²/2}``, ``a_k = E[e^{iθ_k}]``, ``C_k = Cov(z_k, θ_k)``, ``q_k = E[(z_k-m_k)²]``,
    ``S_k = Var Θ_k``:

    - ``E[c_k] = Σ_{j≤k} φ_{j-1} m_j``;
    - ``U_k = E[(c_k - E c_k) e^{-iΘ_k}] = ā_k (U_{k-1} + m_k (1 - e^{-S_{k-1}}) - i C_k)``;
    - ``V_k = E[(c_k - E c_k) e^{iΘ_k}] = a_k (V_{k-1} + φ²_{k-1} ((e^{-S_{k-1}} - 1) m_k +
      i e^{-S_{k-1}} C_k))``;
    - ``E|c_k - E c_k|²`` and ``E[(c_k - E c_k)²]`` grow by the new link's own variance plus
      ``2 Re(m̄_k U_{k-1})`` and ``2 m_k V_{k-1}``; ``Cov(Θ_k, c_k)`` grows by
      ``φ_{k-1} (i S_{k-1} m_k + C_k)`` (Stein: ``E[(Θ - μ) e^{iΘ}] = i S φ``).

    Cost: O(n log n) work over the chain, log₂ n vectorized levels, batched over the other
    axes (10 000 links in a few milliseconds).
    """
    m, C, axis = _links(mean, cov, axis, "chain_moments")
    out_mean, out_cov = _chain(np.moveaxis(m, axis, 0), np.moveaxis(C, axis, 0))
    return Moments(np.moveaxis(out_mean, 0, axis), np.moveaxis(out_cov, 0, axis))


def _links(
    mean: ArrayLike, cov: ArrayLike, axis: object, what: str
) -> tuple[FloatArray, FloatArray, int]:
    """A chain's links ``mean (..., 3)`` and ``cov (..., 3, 3)`` broadcast to one batch shape,
    and its ``axis`` checked (:func:`relmap.uncertain.pose.chain_batch_axis`)."""
    m, C = _poses(mean, cov, "chain")
    try:
        batch = np.broadcast_shapes(m.shape[:-1], C.shape[:-2])
    except ValueError:
        raise ShapeError(
            f"mean batch shape {m.shape[:-1]} and cov batch shape {C.shape[:-2]} do not broadcast"
        ) from None
    axis = chain_batch_axis(batch, axis, what, "links")
    return np.broadcast_to(m, (*batch, 3)), np.broadcast_to(C, (*batch, 3, 3)), axis


def _chain(m: FloatArray, C: FloatArray) -> tuple[FloatArray, FloatArray]:
    """:func:`chain_moments` along axis 0 (``m (n, ..., 3)``, ``C (n, ..., 3, 3)``)."""
    z = m[..., 0] + 1j * m[..., 1]
    mu, s = m[..., 2], C[..., 2, 2]
    p, q, c_zt = _complex(C)
    mu_cum, s_cum = np.cumsum(mu, axis=0), np.cumsum(s, axis=0)
    mu_prev, s_prev = _exclusive(mu_cum), _exclusive(s_cum)  # heading before link k
    phi = np.exp(1j * mu_prev - 0.5 * s_prev)  # E[e^{iΘ_{k-1}}]
    shrink = np.expm1(-s_prev)  # e^{-S} - 1 = |φ|² - 1, accurate for tiny S
    damp = np.exp(-s_prev)
    a = np.exp(1j * mu - 0.5 * s)  # E[e^{iθ_k}]
    a_bar = a.conj()

    M = np.cumsum(phi * z, axis=0)
    U = _exclusive(_affine_scan(a_bar, a_bar * (-shrink * z - 1j * c_zt)))
    V = _exclusive(_affine_scan(a, a * phi * phi * (shrink * z + 1j * damp * c_zt)))
    var_step = -shrink * (z * z.conj()).real + p  # Var(e^{iΘ_{k-1}} z_k)
    P = np.cumsum(var_step + 2.0 * (z.conj() * U).real, axis=0)
    Q = np.cumsum(phi * phi * (shrink * z * z + damp * q) + 2.0 * z * V, axis=0)
    R = np.cumsum(phi * (1j * s_prev * z + c_zt), axis=0)
    return _assemble(M, mu_cum, P, Q, R, s_cum)


# -------------------------------------------------------------------------- exact pair
def compound_moments(
    mean_a: ArrayLike,
    cov_a: ArrayLike,
    mean_b: ArrayLike,
    cov_b: ArrayLike,
    *,
    cross_cov: ArrayLike | None = None,
) -> Moments:
    """Exact mean and covariance of ``a ⊕ b`` for Gaussian a and b (module docstring).

    ``mean_a``, ``mean_b`` ``(..., 3)`` and ``cov_a``, ``cov_b`` ``(..., 3, 3)`` in relmap's
    chart (parent frame); ``cross_cov = E[δa δbᵀ]`` ``(..., 3, 3)`` for a dependent pair (the
    6×6 joint covariance ``[[C_a, C_ab], [C_abᵀ, C_b]]``), None for independent inputs.
    Returns :class:`relmap.uncertain.propagate.Moments`, batch axes broadcast. An independent pair
    is
    the two-link chain of :func:`chain_moments`; a dependent one is computed as follows.

    With ``X = (x_a, y_a, θ_a, x_b, y_b, θ_b) ~ N(μ, Σ)``, ``c = z_a + e^{iθ_a} z_b``. Each term
    is ``(A·X) e^{i w·X}`` for a complex coefficient vector A and a real w, and for two terms
    ``E[(A·X)(B·X) e^{i w·X}] = E[e^{i w·X}] ((A·μ̃)(B·μ̃) + A Σ B)``, ``μ̃ = μ + iΣw`` (the
    Gaussian's exponential tilt); the covariance of two terms is written so that no O(1)
    quantities cancel.
    """
    ma, Ca = _poses(mean_a, cov_a, "a")
    mb, Cb = _poses(mean_b, cov_b, "b")
    batch = _broadcast(ma.shape[:-1], Ca.shape[:-2], mb.shape[:-1], Cb.shape[:-2])
    if cross_cov is None:  # independent: the chain recursions, several times faster
        m = np.stack([np.broadcast_to(ma, (*batch, 3)), np.broadcast_to(mb, (*batch, 3))])
        C = np.stack([np.broadcast_to(Ca, (*batch, 3, 3)), np.broadcast_to(Cb, (*batch, 3, 3))])
        mean, cov = _chain(m, C)
        return Moments(mean[1], cov[1])
    return Moments(*_pair(*_joint(ma, Ca, mb, Cb, cross_cov, batch)))


def _joint(
    ma: FloatArray,
    Ca: FloatArray,
    mb: FloatArray,
    Cb: FloatArray,
    cross_cov: ArrayLike | None,
    batch: tuple[int, ...],
) -> tuple[FloatArray, FloatArray]:
    """The 6-D Gaussian of the pair ``(a, b)``: mean (..., 6), covariance (..., 6, 6)."""
    X = None
    if cross_cov is not None:
        X = real_array(cross_cov, "cross_cov")
        if X.ndim < 2 or X.shape[-2:] != (3, 3):
            raise ShapeError(f"cross_cov must have shape (..., 3, 3); got {X.shape}")
        check_finite(X, "cross_cov")
        batch = _broadcast(batch, X.shape[:-2])
    mu = np.concatenate(
        [np.broadcast_to(ma, (*batch, 3)), np.broadcast_to(mb, (*batch, 3))], axis=-1
    )
    S = np.zeros((*batch, 6, 6))
    S[..., :3, :3] = Ca
    S[..., 3:, 3:] = Cb
    if X is not None:
        S[..., :3, 3:] = X
        S[..., 3:, :3] = np.swapaxes(X, -1, -2)
        S = validate_covariance(
            S, name="the joint covariance [[C_a, cross_cov], [cross_covᵀ, C_b]]"
        )
    return mu, S


def _broadcast(*shapes: tuple[int, ...]) -> tuple[int, ...]:
    try:
        return np.broadcast_shapes(*shapes)
    except ValueError:
        raise ShapeError(
            f"batch shapes {' and '.join(map(str, shapes))} do not broadcast"
        ) from None


# Terms of c = z_a + e^{iθ_a} z_b and of Θ = θ_a + θ_b, as (coefficient vector A, frequency w).
_ZA = np.array([1.0, 1j, 0, 0, 0, 0])
_ZB = np.array([0, 0, 0, 1.0, 1j, 0])
_THETA = np.array([0, 0, 1.0, 0, 0, 1.0], dtype=complex)
_W0 = np.zeros(6)
_WA = np.array([0, 0, 1.0, 0, 0, 0])
_C_TERMS = ((_ZA, _W0), (_ZB, _WA))


def _term_moments(
    A: np.ndarray, w: np.ndarray, B: np.ndarray, v: np.ndarray, mu: FloatArray, S: FloatArray
) -> tuple[ComplexArray, ComplexArray, ComplexArray]:
    """``E[(A·X) e^{iw·X}]``, ``E[(B·X) e^{iv·X}]`` and their (bilinear, unconjugated)
    covariance for ``X ~ N(μ, Σ)`` (``(..., 6)``, ``(..., 6, 6)``)."""
    Sw, Sv = S @ w, S @ v
    phi_w = np.exp(1j * (mu @ w) - 0.5 * (Sw @ w))
    phi_v = np.exp(1j * (mu @ v) - 0.5 * (Sv @ v))
    A_mu_w = mu @ A + 1j * (Sw @ A)  # A·μ̃_w
    B_mu_v = mu @ B + 1j * (Sv @ B)
    A_Sv, B_Sw = Sv @ A, Sw @ B  # A·Σv, B·Σw
    wSv = Sw @ v
    ASB = np.einsum("i,...ij,j->...", A, S, B)
    # E[AB e^{i(w+v)X}] = φ_w φ_v e^{-wΣv} ((A·μ̃_w + iA·Σv)(B·μ̃_v + iB·Σw) + AΣB); subtract
    # φ_w φ_v (A·μ̃_w)(B·μ̃_v) with the product expanded, so only small terms remain.
    em1 = np.expm1(-wSv)
    A_full, B_full = A_mu_w + 1j * A_Sv, B_mu_v + 1j * B_Sw
    inner = (
        em1 * A_full * B_full
        + 1j * A_mu_w * B_Sw
        + 1j * A_Sv * B_mu_v
        - A_Sv * B_Sw
        + (em1 + 1.0) * ASB
    )
    return phi_w * A_mu_w, phi_v * B_mu_v, phi_w * phi_v * inner


def _pair(mu: FloatArray, S: FloatArray) -> tuple[FloatArray, FloatArray]:
    zero = np.zeros(mu.shape[:-1], dtype=complex)
    M, P, Q, R = zero, zero, zero, zero
    for A, w in _C_TERMS:
        for B, v in _C_TERMS:
            P = P + _term_moments(A, w, B.conj(), -v, mu, S)[2]  # E[(c - M)(c - M)*]
            Q = Q + _term_moments(A, w, B, v, mu, S)[2]  # E[(c - M)²]
        _, mean_term, cov_theta = _term_moments(_THETA, _W0, A, w, mu, S)
        M = M + mean_term
        R = R + cov_theta  # Cov(Θ, c)
    var_theta = S[..., 2, 2] + S[..., 5, 5] + 2.0 * S[..., 2, 5]
    return _assemble(M, mu[..., 2] + mu[..., 5], np.real(P), Q, R, var_theta)


# ------------------------------------------------------------------------ exact reversal
_REV_A = np.diag([0.0, 0.0, -1.0])  # Aᴿ = (0, 0, -θ) ⊕ (-x, -y, 0): a dependent pair
_REV_B = np.diag([-1.0, -1.0, 0.0])


def reverse_moments(mean: ArrayLike, cov: ArrayLike) -> Moments:
    """Exact mean and covariance of the reversal ``Aᴿ`` of a Gaussian A (Eqs. 5-7 to all
    orders): ``Aᴿ = (0, 0, -θ) ⊕ (-x, -y, 0)``, a dependent pair whose 6×6 joint covariance is
    linear in A's, so :func:`compound_moments` gives it exactly. Batched like it."""
    m, C = _poses(mean, cov, "a")
    CbT = C @ _REV_B.T
    return compound_moments(
        m @ _REV_A.T, _REV_A @ C @ _REV_A.T, m @ _REV_B.T, _REV_B @ CbT, cross_cov=_REV_A @ CbT
    )


# ---------------------------------------------------------------------------- unscented
def unscented_compound(
    mean_a: ArrayLike,
    cov_a: ArrayLike,
    mean_b: ArrayLike,
    cov_b: ArrayLike,
    *,
    cross_cov: ArrayLike | None = None,
) -> Moments:
    """``a ⊕ b`` by the unscented transform of ``se2.compose`` on the 6-D joint input.

    :func:`relmap.uncertain.propagate.unscented` with its defaults (van der Merwe's scaled sigma
    points,
    ``α = 1, β = 2, κ = 0``, so ``λ = 0``): 13 points, the mean and the mean ± ``√6`` times each
    column of the symmetric square root of the 6×6 joint covariance; weights ``Wm₀ = 0``,
    ``Wc₀ = 2``, ``Wᵢ = 1/12``. Input headings are perturbed on the real line; the output is
    averaged in relmap's SE(2) chart (heading wrapped). Exact for functions quadratic in the
    input; for compounding it captures the curvature only partly (compare
    :func:`compound_moments`).
    """
    ma, Ca = _poses(mean_a, cov_a, "a")
    mb, Cb = _poses(mean_b, cov_b, "b")
    batch = _broadcast(ma.shape[:-1], Ca.shape[:-2], mb.shape[:-1], Cb.shape[:-2])
    mu, S = _joint(ma, Ca, mb, Cb, cross_cov, batch)
    return unscented(_compose6, mu, S, chart_in=EUCLIDEAN, chart_out=SE2)


def unscented_reverse(mean: ArrayLike, cov: ArrayLike) -> Moments:
    """``Aᴿ`` by the unscented transform of ``se2.inverse`` (the 3-D input, 7 sigma points at
    ±√3 σ, ``α = 1, β = 2, κ = 0``), averaged in the SE(2) chart."""
    m, C = _poses(mean, cov, "a")
    return unscented(se2.inverse, m, C, chart_in=EUCLIDEAN, chart_out=SE2)


def _compose6(x: FloatArray) -> FloatArray:
    return se2.compose(x[..., :3], x[..., 3:])


def _chain_poses(links: FloatArray) -> FloatArray:
    """Every prefix pose of chains ``(..., n, 3)`` exactly (heading summed, then wrapped)."""
    theta = np.cumsum(links[..., 2], axis=-1)
    before = theta - links[..., 2]
    z = links[..., 0] + 1j * links[..., 1]
    c = np.cumsum(np.exp(1j * before) * z, axis=-1)
    return np.stack([c.real, c.imag, se2.wrap_angle(theta)], axis=-1)


def _flat_chart(n: int) -> Chart:
    """SE(2)'s chart on ``n`` poses flattened to ``(..., 3n)`` vectors."""

    def plus(x: FloatArray, d: FloatArray) -> FloatArray:
        y = se2.plus(x.reshape(*x.shape[:-1], n, 3), d.reshape(*d.shape[:-1], n, 3))
        return y.reshape(*y.shape[:-2], 3 * n)

    def minus(y1: FloatArray, y0: FloatArray) -> FloatArray:
        d = se2.minus(y1.reshape(*y1.shape[:-1], n, 3), y0.reshape(*y0.shape[:-1], n, 3))
        return d.reshape(*d.shape[:-2], 3 * n)

    return Chart(plus, minus)


def unscented_chain(
    mean: ArrayLike,
    cov: ArrayLike,
    *,
    axis: int = -1,
    scheme: ChainScheme | str = ChainScheme.SEQUENTIAL,
) -> Moments:
    """Every prefix of a chain of independent links by the unscented transform.

    ``scheme="sequential"`` (default): prefix k is :func:`unscented_compound` of prefix k-1
    (re-summarized as a Gaussian by its mean and covariance) and link k, exactly what
    compounding one step at a time with ``compound(..., moments="unscented")`` gives; 13 sigma
    points per step (``α = 1, β = 2, κ = 0``, points at ±√6 σ). One batched transform per link
    (a loop over the links, not over the batch), O(n).

    ``scheme="joint"``: one transform of the whole chain, the input the 3n-vector of all links
    (block-diagonal covariance), the output every prefix pose; with the same defaults that is
    6n + 1 sigma points, the means and the means ± ``√(3n)`` times each column of the symmetric
    square root (one link perturbed at a time), ``Wm₀ = 0``, ``Wc₀ = 2``, ``Wᵢ = 1/(6n)``.
    Perturbing one link at a time, it never sees two heading errors together, so it misses
    the cross-link curvature that dominates long chains (docs/studies/moments.py); cost
    O(n³) (the 3n × 3n output covariance).

    Both average the output in the SE(2) chart (heading wrapped). :func:`chain_moments` is
    exact and O(n log n).
    """
    scheme = ChainScheme.parse(scheme, "scheme")
    m, C, axis = _links(mean, cov, axis, "unscented_chain")
    if scheme is ChainScheme.SEQUENTIAL:
        m, C = np.moveaxis(m, axis, 0), np.moveaxis(C, axis, 0)
        out_m, out_C = np.empty_like(m), np.empty_like(C)
        out_m[0], out_C[0] = m[0], C[0]
        for k in range(1, m.shape[0]):
            out_m[k], out_C[k] = unscented_compound(out_m[k - 1], out_C[k - 1], m[k], C[k])
        return Moments(np.moveaxis(out_m, 0, axis), np.moveaxis(out_C, 0, axis))
    m = np.moveaxis(m, axis, -2)  # (..., n, 3)
    C = np.moveaxis(C, axis, -3)  # (..., n, 3, 3)
    n = m.shape[-2]
    rest = m.shape[:-2]
    S = np.zeros((*rest, n, 3, n, 3))
    idx = np.arange(n)
    S[..., idx, :, idx, :] = np.moveaxis(C, -3, 0)
    S = S.reshape(*rest, 3 * n, 3 * n)

    def f(x: FloatArray) -> FloatArray:
        poses = _chain_poses(x.reshape(*x.shape[:-1], n, 3))
        return poses.reshape(*poses.shape[:-2], 3 * n)

    out = unscented(f, m.reshape(*rest, 3 * n), S, chart_in=EUCLIDEAN, chart_out=_flat_chart(n))
    out_mean = out.mean.reshape(*rest, n, 3)
    full = out.cov.reshape(*rest, n, 3, n, 3)
    out_cov = np.moveaxis(full[..., idx, :, idx, :], 0, -3)  # diagonal blocks (..., n, 3, 3)
    return Moments(np.moveaxis(out_mean, -2, axis), np.moveaxis(out_cov, -3, axis))


# -------------------------------------------------------------------------- diagnostic
class Linearization(NamedTuple):
    """How far the first-order answer (Eqs. 3-4) is from the exact moments, per prefix.

    - ``cov_rel_error``: ``‖C_first - C_exact‖_F / ‖C_exact‖_F`` (Frobenius norm).
    - ``mean_error``: ``(..., 3)`` first-order mean ⊟ exact mean (heading wrapped).
    - ``mean_error_sigmas``: the same in units of the exact standard deviations.
    """

    cov_rel_error: FloatArray
    mean_error: FloatArray
    mean_error_sigmas: FloatArray


def linearization_error(steps: UncertainPose, *, axis: int = -1) -> Linearization:
    """Predicted error of first-order compounding of the chain ``steps`` (every prefix).

    Compares :func:`relmap.compound_chain` (Eqs. 3-4) with the exact moments of
    :func:`chain_moments` for Gaussian links: no sampling, O(n log n). A pair ``a ⊕ b`` is the
    chain ``AT.stack([a, b])``. A ``cov_rel_error`` of a few percent says that the first-order
    covariance is off by that much in Frobenius norm; the exact moments (``moments="exact"``)
    are then the better summary. Whether a *Gaussian* with those moments is adequate is a
    different question: sample the chain and read Mardia's skewness from
    :meth:`relmap.sim.montecarlo.SampleSet.compare`.
    """
    if same_kind((steps,)).group is not SE2_GROUP:
        raise ParameterError("linearization_error is available for SE(2) ATs only")
    first = steps._chain(chain_axis(steps, axis, "linearization_error"))  # compound_chain's
    exact_mean, exact_cov = chain_moments(steps.mean, steps.cov, axis=axis)
    norm = np.linalg.norm(exact_cov, axis=(-2, -1))
    diff = np.linalg.norm(first.cov - exact_cov, axis=(-2, -1))
    err = se2.minus(first.mean, exact_mean)
    sig = np.sqrt(np.diagonal(exact_cov, axis1=-2, axis2=-1))
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.where(norm > 0, diff / np.where(norm > 0, norm, 1.0), 0.0)
        in_sigmas = np.where(sig > 0, err / np.where(sig > 0, sig, 1.0), 0.0)
    return Linearization(rel, err, in_sigmas)
