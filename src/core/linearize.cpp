// Accumulation of the pose-graph normal equations (see linearize.hpp).
#include "linearize.hpp"

#include <algorithm>
#include <cmath>
#include <vector>

#include "arrays.hpp"
#include "dense.hpp"

namespace relmap {

namespace {

// The measurements' contributions for B × B blocks (B = 3: the plane; 3-D graphs accumulate in
// linearize3.cpp, using their Jacobians' structure): per measurement W r, W J_i, W J_j, then the
// blocks J_iᵀ W J_i, J_iᵀ W J_j, J_jᵀ W J_j (the (j, i) block written as the transpose of (i, j):
// the matrix is exactly symmetric), each loop running along rows so that it vectorizes.
template <int B>
RELMAP_INLINE double accumulate(int64_t m, const double* r, const double* Ji, const double* Jj,
                                const double* W, const int64_t* slots, const int64_t* g_index,
                                double* data, double* grad) {
    double cost = 0.0;
    for (int64_t k = 0; k < m; ++k) {
        const double* rk = r + k * B;
        const double* Wk = W + k * B * B;
        const double* J[2] = {Ji + k * B * B, Jj + k * B * B};
        double Wr[B], WJ[2][B * B], H[3][B * B];
        for (int a = 0; a < B; ++a) {
            double s = 0.0;
            for (int c = 0; c < B; ++c) s += Wk[a * B + c] * rk[c];
            Wr[a] = s;
            cost += rk[a] * s;
        }
        for (int t = 0; t < 2; ++t) {  // WJ_t[a, :] = Σ_e W[a, e] J_t[e, :]
            for (int q = 0; q < B * B; ++q) WJ[t][q] = 0.0;
            for (int a = 0; a < B; ++a)
                for (int e = 0; e < B; ++e) {
                    const double w = Wk[a * B + e];
                    for (int c = 0; c < B; ++c) WJ[t][a * B + c] += w * J[t][e * B + c];
                }
        }
        const int pair[3][2] = {{0, 0}, {0, 1}, {1, 1}};
        for (int h = 0; h < 3; ++h) {  // H[a, :] = Σ_e J_ta[e, a] WJ_tb[e, :]
            const double* Ja = J[pair[h][0]];
            const double* WJb = WJ[pair[h][1]];
            for (int q = 0; q < B * B; ++q) H[h][q] = 0.0;
            for (int e = 0; e < B; ++e)
                for (int a = 0; a < B; ++a) {
                    const double s = Ja[e * B + a];
                    for (int c = 0; c < B; ++c) H[h][a * B + c] += s * WJb[e * B + c];
                }
        }
        const int64_t* sk = slots + k * 4 * B * B;  // blocks (i,i), (i,j), (j,i), (j,j)
        for (int a = 0; a < B; ++a)
            for (int c = 0; c < B; ++c) {
                data[sk[a * B + c]] += H[0][a * B + c];
                data[sk[B * B + a * B + c]] += H[1][a * B + c];
                data[sk[2 * B * B + a * B + c]] += H[1][c * B + a];
                data[sk[3 * B * B + a * B + c]] += H[2][a * B + c];
            }
        for (int t = 0; t < 2; ++t)
            for (int a = 0; a < B; ++a) {
                double s = 0.0;
                for (int e = 0; e < B; ++e) s += J[t][e * B + a] * Wr[e];
                grad[g_index[(t * B + a) * m + k]] += s;
            }
    }
    return cost;
}

// ---- the planar residuals (SE(2), relmap's chart) ------------------------------------------

constexpr double kPi = 3.14159265358979311600;  // the double nearest π (numpy's np.pi)
constexpr double kTwoPi = 2.0 * kPi;

// An angle wrapped to [-π, π) exactly as relmap.lie.se2.wrap_angle: angles in range are
// returned untouched, others by a floored modulo (numpy's np.mod) shifted by π.
inline double wrap_angle(double t) {
    if (t >= -kPi && t < kPi) return t;
    double m = std::fmod(t + kPi, kTwoPi);
    if (m != 0.0 && m < 0.0) m += kTwoPi;  // the divisor's sign, as np.mod
    double w = m - kPi;
    return w >= kPi ? w - kTwoPi : w;
}

// For the measurement of frame j seen from frame i (poses p_i, p_j = (x, y, θ)), measured z:
// d = p_i⁻¹ ∘ p_j = (R(θ_i)ᵀ (t_j - t_i), wrap(θ_j - θ_i)), r = d ⊟ z (heading wrapped),
// J_i = [[-c, -s, y_d], [s, -c, -x_d], [0, 0, -1]], J_j = blkdiag(R(θ_i)ᵀ, 1) (row-major),
// each then times the frame's ∂p/∂parameters F_i, F_j (row-major 3 × 3) when given (rigid sets).
RELMAP_INLINE void se2_edge(const double* pi, const double* pj, const double* z,
                            const double* Fi, const double* Fj, double* r, double* Ji,
                            double* Jj) {
    const double c = std::cos(pi[2]), s = std::sin(pi[2]);
    const double ex = pj[0] - pi[0], ey = pj[1] - pi[1];
    const double xd = c * ex + s * ey, yd = -s * ex + c * ey;
    r[0] = xd - z[0];
    r[1] = yd - z[1];
    r[2] = wrap_angle(wrap_angle(pj[2] - pi[2]) - z[2]);
    const double A[9] = {-c, -s, yd, s, -c, -xd, 0.0, 0.0, -1.0};
    const double B[9] = {c, s, 0.0, -s, c, 0.0, 0.0, 0.0, 1.0};
    auto times = [](const double* X, const double* F, double* out) {
        for (int a = 0; a < 3; ++a)
            for (int b = 0; b < 3; ++b) {
                double sum = 0.0;
                for (int e = 0; e < 3; ++e) sum += X[a * 3 + e] * F[e * 3 + b];
                out[a * 3 + b] = sum;
            }
    };
    if (Fi) {
        times(A, Fi, Ji);
        times(B, Fj, Jj);
    } else {
        std::copy(A, A + 9, Ji);
        std::copy(B, B + 9, Jj);
    }
}

// The residuals and Jacobians of m measurements (i[k], j[k], z[k]) at poses (n × 3); F (n × 3
// × 3) or null.
RELMAP_INLINE void se2_residuals(int64_t m, const double* poses, const int64_t* i, const int64_t* j,
                                 const double* z, const double* F, double* r, double* Ji,
                                 double* Jj) {
    for (int64_t k = 0; k < m; ++k)
        se2_edge(poses + 3 * i[k], poses + 3 * j[k], z + 3 * k, F ? F + 9 * i[k] : nullptr,
                 F ? F + 9 * j[k] : nullptr, r + 3 * k, Ji + 9 * k, Jj + 9 * k);
}

// The planar residuals and the normal equations in one pass, in chunks (the residuals of a
// chunk stay in cache for their accumulation).
RELMAP_MULTIVERSION
double se2_normal_equations(int64_t m, const double* poses, const int64_t* i, const int64_t* j,
                            const double* z, const double* F, const double* W,
                            const int64_t* slots, const int64_t* g_index, double* data,
                            double* grad) {
    constexpr int64_t chunk = 256;
    double r[3 * chunk], Ji[9 * chunk], Jj[9 * chunk];
    double cost = 0.0;
    std::vector<int64_t> gidx(6 * chunk);
    for (int64_t k0 = 0; k0 < m; k0 += chunk) {
        const int64_t n = std::min(chunk, m - k0);
        se2_residuals(n, poses, i + k0, j + k0, z + 3 * k0, F, r, Ji, Jj);
        for (int64_t t = 0; t < 6; ++t)  // the chunk's gradient indices, component-major
            for (int64_t k = 0; k < n; ++k) gidx[t * n + k] = g_index[t * m + k0 + k];
        cost += accumulate<3>(n, r, Ji, Jj, W + 9 * k0, slots + 36 * k0, gidx.data(), data,
                              grad);
    }
    return cost;
}

}  // namespace

void register_linearize(nb::module_& m) {
    // The planar pose graph: measurements (i[k], j[k], z[k]) at poses (n, 3), with F (n, 3, 3)
    // the frames' ∂pose/∂parameters or (0, 3, 3) for none.
    auto check_edges = [](const Float2& poses, const Index1& i, const Index1& j, const Float2& z,
                          const Float3& F) {
        const int64_t n = static_cast<int64_t>(poses.shape(0));
        const int64_t m = static_cast<int64_t>(i.shape(0));
        if (poses.shape(1) != 3 || static_cast<int64_t>(j.shape(0)) != m ||
            static_cast<int64_t>(z.shape(0)) != m || z.shape(1) != 3)
            throw nb::value_error("poses (n, 3), i and j (m,), z (m, 3) expected");
        if (!(F.shape(0) == 0 || static_cast<int64_t>(F.shape(0)) == n) || F.shape(1) != 3 ||
            F.shape(2) != 3)
            throw nb::value_error("F must be (n, 3, 3) or (0, 3, 3)");
        for (int64_t k = 0; k < m; ++k)
            if (i.data()[k] < 0 || i.data()[k] >= n || j.data()[k] < 0 || j.data()[k] >= n)
                throw nb::value_error("frame index out of range");
        return m;
    };
    m.def(
        "residuals2",
        [check_edges](Float2 poses, Index1 i, Index1 j, Float2 z, Float3 F) {
            const int64_t count = check_edges(poses, i, j, z, F);
            const size_t c = static_cast<size_t>(count);
            auto r = new_array({c, 3});
            auto Ji = new_array({c, 3, 3});
            auto Jj = new_array({c, 3, 3});
            {
                nb::gil_scoped_release unlocked;
                se2_residuals(count, poses.data(), i.data(), j.data(), z.data(),
                              F.shape(0) ? F.data() : nullptr, r.data(), Ji.data(), Jj.data());
            }
            return nb::make_tuple(r, Ji, Jj);
        },
        nb::arg("poses"), nb::arg("i"), nb::arg("j"), nb::arg("z"), nb::arg("F"),
        "(r (m, 3), Ji, Jj (m, 3, 3)): the planar residuals d ⊟ z, d = p_i⁻¹ ∘ p_j, and their "
        "Jacobians with respect to the parameters of frames i and j (times F when given).");
    m.def(
        "normal_equations2",
        [check_edges](Float2 poses, Index1 i, Index1 j, Float2 z, Float3 F, Float3 W,
                      Index2 slots, Index1 g_index, int64_t nnz, int64_t size) {
            const int64_t count = check_edges(poses, i, j, z, F);
            if (static_cast<int64_t>(W.shape(0)) != count || W.shape(1) != 3 || W.shape(2) != 3)
                throw nb::value_error("W (m, 3, 3) expected");
            if (static_cast<int64_t>(slots.shape(0)) != count || slots.shape(1) != 36 ||
                static_cast<int64_t>(g_index.shape(0)) != 6 * count)
                throw nb::value_error("slots (m, 36) and g_index (6 m) expected");
            check_targets(slots.data(), count * 36, g_index.data(), 6 * count, nnz, size);
            auto data = new_array({static_cast<size_t>(nnz + 1)});
            auto grad = new_array({static_cast<size_t>(size + 1)});
            double cost;
            {
                nb::gil_scoped_release unlocked;
                cost = se2_normal_equations(count, poses.data(), i.data(), j.data(), z.data(),
                                            F.shape(0) ? F.data() : nullptr, W.data(),
                                            slots.data(), g_index.data(), data.data(),
                                            grad.data());
            }
            return nb::make_tuple(cost, data, grad);
        },
        nb::arg("poses"), nb::arg("i"), nb::arg("j"), nb::arg("z"), nb::arg("F"), nb::arg("W"),
        nb::arg("slots"), nb::arg("g_index"), nb::arg("nnz"), nb::arg("size"),
        "(cost, data (nnz + 1,), grad (size + 1,)): the planar residuals (residuals2) and the "
        "normal equations in one pass; the last entry of data and grad collects the dropped "
        "contributions (slot nnz, index size).");
}

}  // namespace relmap
