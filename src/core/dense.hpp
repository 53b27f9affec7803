// Small dense kernels for the panels of the sparse Cholesky (column-major storage): a matrix
// product with 4 × NB register blocks, so that each loaded entry serves several multiply-adds
// (no BLAS is linked). Compiled for the baseline ISA (SSE2 on x86-64): a build with GCC's
// target_clones for AVX2 + FMA measured no faster on sphere2500's factorization.
#pragma once

#include <algorithm>
#include <cstdint>

namespace relmap::dense {

// C(i, j) += alpha Σ_c A(i, c) B(j, c) for i < m, j < NB; A(i, c) = A[i + c lda],
// B(j, c) = B[j + c ldb] (BT) or B[c + j ldb] (not BT), C(i, j) = C[i + j ldc].
template <int NB, bool BT>
inline void columns(int64_t m, int64_t k, double alpha, const double* A, int64_t lda,
                    const double* B, int64_t ldb, double* C, int64_t ldc) {
    auto b = [&](int t, int64_t c) { return BT ? B[t + c * ldb] : B[c + t * ldb]; };
    int64_t i = 0;
    for (; i + 4 <= m; i += 4) {
        double acc[NB][4] = {};
        for (int64_t c = 0; c < k; ++c) {
            const double* a = A + i + c * lda;
            const double a0 = a[0], a1 = a[1], a2 = a[2], a3 = a[3];
            for (int t = 0; t < NB; ++t) {
                const double bt = b(t, c);
                acc[t][0] += a0 * bt;
                acc[t][1] += a1 * bt;
                acc[t][2] += a2 * bt;
                acc[t][3] += a3 * bt;
            }
        }
        for (int t = 0; t < NB; ++t)
            for (int u = 0; u < 4; ++u) C[i + u + t * ldc] += alpha * acc[t][u];
    }
    for (; i < m; ++i)
        for (int t = 0; t < NB; ++t) {
            double sum = 0.0;
            for (int64_t c = 0; c < k; ++c) sum += A[i + c * lda] * b(t, c);
            C[i + t * ldc] += alpha * sum;
        }
}

// C += alpha A op(B) for C (m × n): A (m × k); op(B) = Bᵀ with B (n × k) (BT), or B (k × n).
template <bool BT>
inline void gemm_t(int64_t m, int64_t n, int64_t k, double alpha, const double* A, int64_t lda,
                 const double* B, int64_t ldb, double* C, int64_t ldc) {
    int64_t j = 0;
    for (; j + 4 <= n; j += 4)
        columns<4, BT>(m, k, alpha, A, lda, BT ? B + j : B + j * ldb, ldb, C + j * ldc, ldc);
    const double* Bj = BT ? B + j : B + j * ldb;
    switch (n - j) {
        case 3: columns<3, BT>(m, k, alpha, A, lda, Bj, ldb, C + j * ldc, ldc); break;
        case 2: columns<2, BT>(m, k, alpha, A, lda, Bj, ldb, C + j * ldc, ldc); break;
        case 1: columns<1, BT>(m, k, alpha, A, lda, Bj, ldb, C + j * ldc, ldc); break;
        default: break;
    }
}

// The entry points (dense.cpp).
// C (m × n) += alpha A Bᵀ, A (m × k), B (n × k).
void gemm_nt(int64_t m, int64_t n, int64_t k, double alpha, const double* A, int64_t lda,
             const double* B, int64_t ldb, double* C, int64_t ldc);
// C (m × n) += alpha A B, A (m × k), B (k × n).
void gemm_nn(int64_t m, int64_t n, int64_t k, double alpha, const double* A, int64_t lda,
             const double* B, int64_t ldb, double* C, int64_t ldc);
// The lower trapezoid of C += alpha A A[:q]ᵀ for C (m × q), A (m × k): column blocks of 4 from
// their diagonal down (a few entries above the diagonal in each block are formed too).
void lower_product(int64_t m, int64_t q, int64_t k, double alpha, const double* A, int64_t lda,
                   double* C, int64_t ldc);

}  // namespace relmap::dense
