// The linearization of 3-D pose graphs (see linearize3.hpp): residuals, chart Jacobians and the
// Gauss-Newton normal equations, one pass over the measurements.
//
// The Jacobians' structure is used rather than 6×6 products: J_j = blkdiag(A, B) with A = R_iᵀ,
// B = J_l(r_φ)⁻¹ R_iᵀ, and J_i = -J_j S with the shear S = [[I, K], [0, I]], K = -[t_j - t_i]×.
// Hence, with H = J_jᵀ W J_j and g = J_jᵀ W r,
//   H_jj = H,  H_ij = J_iᵀ W J_j = -Sᵀ H,  H_ii = Sᵀ H S,  g_j = g,  g_i = -Sᵀ g.
// Log and J_l⁻¹ follow lie/so3.py (the same small-angle series and the same branch near π).
#include "linearize3.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>

#include "arrays.hpp"
#include "dense.hpp"  // RELMAP_MULTIVERSION

namespace relmap {

namespace {

constexpr double kSmall = 1e-4;  // so3._SMALL: below it, the series

using M3 = double[3][3];

// φ = Log(R), |φ| ≤ π (so3.log).
void so3_log(const M3& R, double phi[3]) {
    const double tr = R[0][0] + R[1][1] + R[2][2];
    const double c = std::clamp((tr - 1.0) / 2.0, -1.0, 1.0);
    const double w[3] = {R[2][1] - R[1][2], R[0][2] - R[2][0], R[1][0] - R[0][1]};
    const double wn = std::sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]);
    const double theta = std::atan2(0.5 * wn, c);
    if (theta > M_PI - 1e-3) {
        // sin θ vanishes: n nᵀ from the symmetric part, the largest diagonal's column, the sign
        // of the axis from w
        double nn[3][3];
        for (int a = 0; a < 3; ++a)
            for (int b = 0; b < 3; ++b)
                nn[a][b] = (0.5 * (R[a][b] + R[b][a]) - (a == b ? c : 0.0)) / (1.0 - c);
        int k = 0;
        for (int a = 1; a < 3; ++a)
            if (nn[a][a] > nn[k][k]) k = a;
        const double s = std::sqrt(nn[k][k]);
        double n[3], dot = 0.0;
        for (int a = 0; a < 3; ++a) {
            n[a] = nn[a][k] / s;
            dot += n[a] * w[a];
        }
        const double sign = dot < 0.0 ? -1.0 : 1.0;
        for (int a = 0; a < 3; ++a) phi[a] = sign * theta * n[a];
        return;
    }
    const double t2 = theta * theta;
    const double A = theta < kSmall ? 1.0 - t2 / 6.0 + t2 * t2 / 120.0 : std::sin(theta) / theta;
    for (int a = 0; a < 3; ++a) phi[a] = w[a] / (2.0 * A);
}

// J_l(φ)⁻¹ = I - [φ]×/2 + D [φ]×² (so3.left_jacobian_inverse).
void left_jacobian_inverse(const double phi[3], M3& J) {
    const double t2 = phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2];
    const double t = std::sqrt(t2);
    double D;
    if (t < kSmall) {
        D = 1.0 / 12.0 + t2 / 720.0 + t2 * t2 / 30240.0;
    } else {
        const double h = std::sin(t / 2.0);
        D = (1.0 - t * std::sin(t) / (4.0 * h * h)) / t2;
    }
    const double K[3][3] = {{0.0, -phi[2], phi[1]}, {phi[2], 0.0, -phi[0]}, {-phi[1], phi[0], 0.0}};
    for (int a = 0; a < 3; ++a)
        for (int b = 0; b < 3; ++b) {
            double kk = 0.0;
            for (int e = 0; e < 3; ++e) kk += K[a][e] * K[e][b];
            J[a][b] = (a == b ? 1.0 : 0.0) - 0.5 * K[a][b] + D * kk;
        }
}

// One measurement: the residual r (6), the blocks A = R_iᵀ and B = J_l(r_φ)⁻¹ R_iᵀ of J_j,
// and Δt = t_j - t_i (J_i = -J_j S). Poses are row-major 4×4.
struct Edge {
    double r[6];
    M3 A, B;
    double dt[3];
};

RELMAP_INLINE void edge(const double* Ti, const double* Tj, const double* Tz, Edge& e) {
    M3 Rd, E;
    double td[3];
    for (int a = 0; a < 3; ++a) {
        e.dt[a] = Tj[4 * a + 3] - Ti[4 * a + 3];
        for (int b = 0; b < 3; ++b) e.A[a][b] = Ti[4 * b + a];
    }
    for (int a = 0; a < 3; ++a) {
        td[a] = e.A[a][0] * e.dt[0] + e.A[a][1] * e.dt[1] + e.A[a][2] * e.dt[2];
        for (int b = 0; b < 3; ++b)
            Rd[a][b] = e.A[a][0] * Tj[b] + e.A[a][1] * Tj[4 + b] + e.A[a][2] * Tj[8 + b];
    }
    for (int a = 0; a < 3; ++a)  // E = R_d R_zᵀ
        for (int b = 0; b < 3; ++b)
            E[a][b] = Rd[a][0] * Tz[4 * b] + Rd[a][1] * Tz[4 * b + 1] + Rd[a][2] * Tz[4 * b + 2];
    for (int a = 0; a < 3; ++a) e.r[a] = td[a] - Tz[4 * a + 3];
    so3_log(E, e.r + 3);
    M3 Jinv;
    left_jacobian_inverse(e.r + 3, Jinv);
    for (int a = 0; a < 3; ++a)
        for (int b = 0; b < 3; ++b)
            e.B[a][b] = Jinv[a][0] * e.A[0][b] + Jinv[a][1] * e.A[1][b] + Jinv[a][2] * e.A[2][b];
}

// X = Pᵀ Y Q for 3×3 blocks.
RELMAP_INLINE void congruent(const M3& P, const double* Y, int ld, const M3& Q, M3& X) {
    M3 T;  // Y Q
    for (int a = 0; a < 3; ++a)
        for (int b = 0; b < 3; ++b)
            T[a][b] = Y[a * ld] * Q[0][b] + Y[a * ld + 1] * Q[1][b] + Y[a * ld + 2] * Q[2][b];
    for (int a = 0; a < 3; ++a)
        for (int b = 0; b < 3; ++b) X[a][b] = P[0][a] * T[0][b] + P[1][a] * T[1][b] + P[2][a] * T[2][b];
}

RELMAP_MULTIVERSION
double accumulate(int64_t m, const double* poses, const int64_t* fi, const int64_t* fj,
                  const double* z, const double* W, const int64_t* slots, const int64_t* g_index,
                  double* data, double* grad) {
    double cost = 0.0;
    for (int64_t k = 0; k < m; ++k) {
        Edge e;
        edge(poses + 16 * fi[k], poses + 16 * fj[k], z + 16 * k, e);
        const double* Wk = W + 36 * k;
        double Wr[6];
        for (int a = 0; a < 6; ++a) {
            double s = 0.0;
            for (int c = 0; c < 6; ++c) s += Wk[6 * a + c] * e.r[c];
            Wr[a] = s;
            cost += e.r[a] * s;
        }
        // H = J_jᵀ W J_j by blocks, and g = J_jᵀ W r
        double H[6][6], g[6];
        M3 X;
        congruent(e.A, Wk, 6, e.A, X);
        for (int a = 0; a < 3; ++a)
            for (int b = 0; b < 3; ++b) H[a][b] = X[a][b];
        congruent(e.A, Wk + 3, 6, e.B, X);
        for (int a = 0; a < 3; ++a)
            for (int b = 0; b < 3; ++b) H[a][3 + b] = H[3 + b][a] = X[a][b];
        congruent(e.B, Wk + 21, 6, e.B, X);
        for (int a = 0; a < 3; ++a)
            for (int b = 0; b < 3; ++b) H[3 + a][3 + b] = X[a][b];
        for (int a = 0; a < 3; ++a) {
            g[a] = e.A[0][a] * Wr[0] + e.A[1][a] * Wr[1] + e.A[2][a] * Wr[2];
            g[3 + a] = e.B[0][a] * Wr[3] + e.B[1][a] * Wr[4] + e.B[2][a] * Wr[5];
        }
        // Kᵀ = [Δt]×: rows of Sᵀ H are H's top rows, then Kᵀ H_top + H_bottom
        const double* d = e.dt;
        const double Kt[3][3] = {{0.0, -d[2], d[1]}, {d[2], 0.0, -d[0]}, {-d[1], d[0], 0.0}};
        double SH[6][6];  // Sᵀ H
        for (int b = 0; b < 6; ++b) {
            for (int a = 0; a < 3; ++a) SH[a][b] = H[a][b];
            for (int a = 0; a < 3; ++a)
                SH[3 + a][b] = Kt[a][0] * H[0][b] + Kt[a][1] * H[1][b] + Kt[a][2] * H[2][b] +
                               H[3 + a][b];
        }
        double Hii[6][6];  // Sᵀ H S: columns 0..2 as Sᵀ H; columns 3..5 get (Sᵀ H)_left K + …
        for (int a = 0; a < 6; ++a) {
            for (int b = 0; b < 3; ++b) Hii[a][b] = SH[a][b];
            for (int b = 0; b < 3; ++b)  // K = -Kᵀ... K[c][b] = -Kt[c][b] = Kt[b][c]
                Hii[a][3 + b] = SH[a][0] * Kt[b][0] + SH[a][1] * Kt[b][1] +
                                SH[a][2] * Kt[b][2] + SH[a][3 + b];
        }
        const int64_t* sk = slots + k * 144;  // blocks (i,i), (i,j), (j,i), (j,j)
        for (int a = 0; a < 6; ++a)
            for (int c = 0; c < 6; ++c) {
                // symmetric to rounding: average H_ii with its transpose
                data[sk[6 * a + c]] += 0.5 * (Hii[a][c] + Hii[c][a]);
                data[sk[36 + 6 * a + c]] -= SH[a][c];
                data[sk[72 + 6 * a + c]] -= SH[c][a];
                data[sk[108 + 6 * a + c]] += H[a][c];
            }
        for (int a = 0; a < 3; ++a) {
            grad[g_index[a * m + k]] -= g[a];
            grad[g_index[(3 + a) * m + k]] -=
                Kt[a][0] * g[0] + Kt[a][1] * g[1] + Kt[a][2] * g[2] + g[3 + a];
        }
        for (int a = 0; a < 6; ++a) grad[g_index[(6 + a) * m + k]] += g[a];
    }
    return cost;
}

void check_frames(const Index1& i, const Index1& j, size_t m, int64_t n) {
    if (i.shape(0) != m || j.shape(0) != m)
        throw nb::value_error("i and j need one frame index per measurement");
    for (size_t k = 0; k < m; ++k)
        if (i.data()[k] < 0 || i.data()[k] >= n || j.data()[k] < 0 || j.data()[k] >= n)
            throw nb::value_error("frame index out of range");
}

void check_poses(const Float3& x, const char* what) {
    if (x.shape(1) != 4 || x.shape(2) != 4)
        throw nb::value_error(what);
}

}  // namespace

void register_linearize3(nb::module_& m) {
    m.def(
        "residuals3",
        [](Float3 poses, Index1 i, Index1 j, Float3 z) {
            check_poses(poses, "poses (n, 4, 4) expected");
            check_poses(z, "z (m, 4, 4) expected");
            const size_t count = z.shape(0);
            check_frames(i, j, count, static_cast<int64_t>(poses.shape(0)));
            auto r = new_array({count, 6});
            auto Ji = new_array({count, 6, 6});
            auto Jj = new_array({count, 6, 6});
            {
                nb::gil_scoped_release unlocked;
                for (size_t k = 0; k < count; ++k) {
                    Edge e;
                    edge(poses.data() + 16 * i.data()[k], poses.data() + 16 * j.data()[k],
                         z.data() + 16 * k, e);
                    double* rk = r.data() + 6 * k;
                    double* Jik = Ji.data() + 36 * k;
                    double* Jjk = Jj.data() + 36 * k;
                    const double* d = e.dt;
                    const double Kx[3][3] = {
                        {0.0, -d[2], d[1]}, {d[2], 0.0, -d[0]}, {-d[1], d[0], 0.0}};  // [Δt]×
                    for (int a = 0; a < 6; ++a) rk[a] = e.r[a];
                    for (int a = 0; a < 3; ++a)
                        for (int b = 0; b < 3; ++b) {
                            Jjk[6 * a + b] = e.A[a][b];
                            Jjk[6 * (3 + a) + 3 + b] = e.B[a][b];
                            Jik[6 * a + b] = -e.A[a][b];
                            Jik[6 * (3 + a) + 3 + b] = -e.B[a][b];
                            Jik[6 * a + 3 + b] = e.A[a][0] * Kx[0][b] + e.A[a][1] * Kx[1][b] +
                                                 e.A[a][2] * Kx[2][b];  // A [Δt]×
                        }
                }
            }
            return nb::make_tuple(r, Ji, Jj);
        },
        nb::arg("poses"), nb::arg("i"), nb::arg("j"), nb::arg("z"),
        "(r (m, 6), Ji, Jj (m, 6, 6)): the residuals (t_d - t_z, Log(R_d R_zᵀ)), d = T_i⁻¹ T_j, "
        "and their chart Jacobians with respect to frames i and j.");
    m.def(
        "normal_equations3",
        [](Float3 poses, Index1 i, Index1 j, Float3 z, Float3 W, Index2 slots, Index1 g_index,
           int64_t nnz, int64_t size) {
            check_poses(poses, "poses (n, 4, 4) expected");
            check_poses(z, "z (m, 4, 4) expected");
            const size_t count = z.shape(0);
            check_frames(i, j, count, static_cast<int64_t>(poses.shape(0)));
            if (W.shape(0) != count || W.shape(1) != 6 || W.shape(2) != 6)
                throw nb::value_error("W (m, 6, 6) expected");
            if (slots.shape(0) != count || slots.shape(1) != 144 || g_index.shape(0) != 12 * count)
                throw nb::value_error("slots (m, 144) and g_index (12 m) expected");
            check_targets(slots.data(), static_cast<int64_t>(count * 144), g_index.data(),
                          static_cast<int64_t>(12 * count), nnz, size);
            auto data = new_array({static_cast<size_t>(nnz + 1)});
            auto grad = new_array({static_cast<size_t>(size + 1)});
            double cost;
            {
                nb::gil_scoped_release unlocked;
                cost = accumulate(static_cast<int64_t>(count), poses.data(), i.data(), j.data(),
                                  z.data(), W.data(), slots.data(), g_index.data(), data.data(),
                                  grad.data());
            }
            return nb::make_tuple(cost, data, grad);
        },
        nb::arg("poses"), nb::arg("i"), nb::arg("j"), nb::arg("z"), nb::arg("W"),
        nb::arg("slots"), nb::arg("g_index"), nb::arg("nnz"), nb::arg("size"),
        "(cost, data (nnz + 1,), grad (size + 1,)) of a 3-D pose graph's normal equations at "
        "poses (n, 4, 4): cost Σ rᵀ W r, H = Σ Jᵀ W J, g = Σ Jᵀ W r of residuals3's r, Ji, Jj; the "
        "last entry of data and grad collects the dropped contributions (slot nnz, index size).");
}

}  // namespace relmap
