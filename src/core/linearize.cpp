// Accumulation of the pose-graph normal equations (see linearize.hpp).
#include "linearize.hpp"

#include <vector>

#include "arrays.hpp"
#include "dense.hpp"

namespace relmap {

namespace {

// The measurements' contributions for b × b blocks (b = 3 in the plane, 6 in 3-D): per
// measurement W r, W J_i, W J_j, then the blocks J_iᵀ W J_i, J_iᵀ W J_j, J_jᵀ W J_j (the
// (j, i) block written as the transpose of (i, j): the matrix is exactly symmetric), each
// loop running along rows so that it vectorizes.
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

// Compiled per ISA (RELMAP_MULTIVERSION, dense.hpp).
RELMAP_MULTIVERSION
double accumulate3(int64_t m, const double* r, const double* Ji, const double* Jj,
                   const double* W, const int64_t* slots, const int64_t* g_index, double* data,
                   double* grad) {
    return accumulate<3>(m, r, Ji, Jj, W, slots, g_index, data, grad);
}

RELMAP_MULTIVERSION
double accumulate6(int64_t m, const double* r, const double* Ji, const double* Jj,
                   const double* W, const int64_t* slots, const int64_t* g_index, double* data,
                   double* grad) {
    return accumulate<6>(m, r, Ji, Jj, W, slots, g_index, data, grad);
}

}  // namespace

void register_linearize(nb::module_& m) {
    m.def(
        "normal_equations",
        [](Float2 r, Float3 Ji, Float3 Jj, Float3 W, Index2 slots, Index1 g_index, int64_t nnz,
           int64_t size) {
            const int64_t count = static_cast<int64_t>(r.shape(0));
            const int64_t b = static_cast<int64_t>(r.shape(1));
            auto square = [&](const Float3& x) {
                return static_cast<int64_t>(x.shape(0)) == count &&
                       static_cast<int64_t>(x.shape(1)) == b &&
                       static_cast<int64_t>(x.shape(2)) == b;
            };
            if ((b != 3 && b != 6) || !square(Ji) || !square(Jj) || !square(W))
                throw nb::value_error("r (m, b), Ji, Jj, W (m, b, b) with b = 3 or 6");
            if (static_cast<int64_t>(slots.shape(0)) != count ||
                static_cast<int64_t>(slots.shape(1)) != 4 * b * b ||
                static_cast<int64_t>(g_index.shape(0)) != 2 * b * count)
                throw nb::value_error("slots (m, 4 b²) and g_index (2 b m) expected");
            for (int64_t e = 0; e < count * 4 * b * b; ++e)
                if (slots.data()[e] < 0 || slots.data()[e] > nnz)
                    throw nb::value_error("slot out of range");
            for (int64_t e = 0; e < 2 * b * count; ++e)
                if (g_index.data()[e] < 0 || g_index.data()[e] > size)
                    throw nb::value_error("gradient index out of range");
            auto data = new_array({static_cast<size_t>(nnz + 1)});
            auto grad = new_array({static_cast<size_t>(size + 1)});
            double cost;
            {
                nb::gil_scoped_release unlocked;
                auto run = b == 3 ? accumulate3 : accumulate6;
                cost = run(count, r.data(), Ji.data(), Jj.data(), W.data(), slots.data(),
                           g_index.data(), data.data(), grad.data());
            }
            return nb::make_tuple(cost, data, grad);
        },
        nb::arg("r"), nb::arg("Ji"), nb::arg("Jj"), nb::arg("W"), nb::arg("slots"),
        nb::arg("g_index"), nb::arg("nnz"), nb::arg("size"),
        "(cost, data (nnz + 1,), grad (size + 1,)) of the normal equations; the last entry of "
        "data and grad collects the dropped contributions (slot nnz, index size).");
}

}  // namespace relmap
