// Small dense kernels for the panels of the sparse Cholesky (column-major storage): a
// register-tiled matrix product (8 × 4 tiles of C held in vector registers over the whole
// inner dimension, so that each loaded entry of A serves four multiply-adds and each of B
// eight; no BLAS is linked). Written once with GCC/Clang vector types; RELMAP_MULTIVERSION
// compiles the entry points (and the loops that call them) twice, for the baseline ISA and
// for x86-64-v3 (AVX2 + FMA), the copy chosen when the module loads (function multiversioning:
// one source, no run-time compilation).
#pragma once

#include <algorithm>
#include <cstdint>
#include <cstring>

#include "multiversion.hpp"  // RELMAP_MULTIVERSION
#if defined(__GNUC__)
#define RELMAP_INLINE inline __attribute__((always_inline))
#define RELMAP_LAMBDA_INLINE __attribute__((always_inline))  // after a lambda's parameters
#else
#define RELMAP_INLINE inline
#define RELMAP_LAMBDA_INLINE
#endif

namespace relmap::dense {

#if defined(__GNUC__)
typedef double v4 __attribute__((vector_size(32)));  // four doubles (one AVX register)
RELMAP_INLINE v4 load4(const double* p) {
    v4 x;
    std::memcpy(&x, p, sizeof x);
    return x;
}
RELMAP_INLINE void store4(double* p, v4 x) { std::memcpy(p, &x, sizeof x); }
RELMAP_INLINE v4 splat4(double a) { return v4{a, a, a, a}; }
#else
struct v4 {  // the same arithmetic without vector extensions (MSVC)
    double x[4];
    v4& operator+=(const v4& o) {
        for (int u = 0; u < 4; ++u) x[u] += o.x[u];
        return *this;
    }
    friend v4 operator*(const v4& a, const v4& b) {
        v4 r;
        for (int u = 0; u < 4; ++u) r.x[u] = a.x[u] * b.x[u];
        return r;
    }
};
inline v4 load4(const double* p) {
    v4 r;
    std::memcpy(r.x, p, sizeof r.x);
    return r;
}
inline void store4(double* p, v4 v) { std::memcpy(p, v.x, sizeof v.x); }
inline v4 splat4(double a) { return v4{{a, a, a, a}}; }
#endif

// C(i, j) += alpha Σ_c A(i, c) B(j, c) for i < m, j < NB; A(i, c) = A[i + c lda],
// B(j, c) = B[j + c ldb] (BT) or B[c + j ldb] (not BT), C(i, j) = C[i + j ldc].
template <int NB, bool BT>
RELMAP_INLINE void columns(int64_t m, int64_t k, double alpha, const double* A, int64_t lda,
                           const double* B, int64_t ldb, double* C, int64_t ldc) {
    auto b = [&](int t, int64_t c) { return BT ? B[t + c * ldb] : B[c + t * ldb]; };
    const v4 va = splat4(alpha);
    int64_t i = 0;
    for (; i + 8 <= m; i += 8) {  // 8 × NB tile: 2 NB accumulators
        v4 lo[NB], hi[NB];
        for (int t = 0; t < NB; ++t) lo[t] = hi[t] = splat4(0.0);
        for (int64_t c = 0; c < k; ++c) {
            const double* a = A + i + c * lda;
            const v4 a0 = load4(a), a1 = load4(a + 4);
            for (int t = 0; t < NB; ++t) {
                const v4 bt = splat4(b(t, c));
                lo[t] += a0 * bt;
                hi[t] += a1 * bt;
            }
        }
        for (int t = 0; t < NB; ++t) {
            double* ct = C + i + t * ldc;
            store4(ct, load4(ct) + va * lo[t]);
            store4(ct + 4, load4(ct + 4) + va * hi[t]);
        }
    }
    if (i + 4 <= m) {  // 4 × NB
        v4 lo[NB];
        for (int t = 0; t < NB; ++t) lo[t] = splat4(0.0);
        for (int64_t c = 0; c < k; ++c) {
            const v4 a0 = load4(A + i + c * lda);
            for (int t = 0; t < NB; ++t) lo[t] += a0 * splat4(b(t, c));
        }
        for (int t = 0; t < NB; ++t) {
            double* ct = C + i + t * ldc;
            store4(ct, load4(ct) + va * lo[t]);
        }
        i += 4;
    }
    for (; i < m; ++i)  // the last rows, one by one
        for (int t = 0; t < NB; ++t) {
            double sum = 0.0;
            for (int64_t c = 0; c < k; ++c) sum += A[i + c * lda] * b(t, c);
            C[i + t * ldc] += alpha * sum;
        }
}

// C += alpha A op(B) for C (m × n): A (m × k); op(B) = Bᵀ with B (n × k) (BT), or B (k × n).
template <bool BT>
RELMAP_INLINE void gemm_t(int64_t m, int64_t n, int64_t k, double alpha, const double* A,
                          int64_t lda, const double* B, int64_t ldb, double* C, int64_t ldc) {
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

// The lower trapezoid of C += alpha A A[:q]ᵀ for C (m × q), A (m × k): column blocks of 4 from
// their diagonal down (a few entries above the diagonal in each block are formed too).
RELMAP_INLINE void lower_product_t(int64_t m, int64_t q, int64_t k, double alpha,
                                   const double* A, int64_t lda, double* C, int64_t ldc) {
    for (int64_t j = 0; j < q; j += 4) {
        const int64_t nb = std::min<int64_t>(4, q - j);
        gemm_t<true>(m - j, nb, k, alpha, A + j, lda, A + j, lda, C + j + j * ldc, ldc);
    }
}

// Σ_i a[i] b[i], in four-wide partial sums (a reordered sum: equal to rounding).
RELMAP_INLINE double dot(int64_t n, const double* a, const double* b) {
    v4 s0 = splat4(0.0), s1 = splat4(0.0);
    int64_t i = 0;
    for (; i + 8 <= n; i += 8) {
        s0 += load4(a + i) * load4(b + i);
        s1 += load4(a + i + 4) * load4(b + i + 4);
    }
    if (i + 4 <= n) {
        s0 += load4(a + i) * load4(b + i);
        i += 4;
    }
    s0 += s1;
    double sum = 0.0;
    for (; i < n; ++i) sum += a[i] * b[i];
#if defined(__GNUC__)
    return sum + ((s0[0] + s0[1]) + (s0[2] + s0[3]));
#else
    return sum + ((s0.x[0] + s0.x[1]) + (s0.x[2] + s0.x[3]));
#endif
}

// y[j incy] -= Σ_i A[i + j lda] x[i] for j < n: n dot products sharing x, four at a time (each
// a reordered sum: equal to rounding).
RELMAP_INLINE void subtract_dots(int64_t n, int64_t k, const double* A, int64_t lda,
                                 const double* x, double* y, int64_t incy) {
    int64_t j = 0;
    for (; j + 4 <= n; j += 4) {
        const double* a = A + j * lda;
        v4 s[4] = {splat4(0.0), splat4(0.0), splat4(0.0), splat4(0.0)};
        int64_t i = 0;
        for (; i + 4 <= k; i += 4) {
            const v4 xi = load4(x + i);
            for (int t = 0; t < 4; ++t) s[t] += load4(a + t * lda + i) * xi;
        }
        for (int t = 0; t < 4; ++t) {
            double sum = 0.0;
            for (int64_t e = i; e < k; ++e) sum += a[t * lda + e] * x[e];
#if defined(__GNUC__)
            y[(j + t) * incy] -= sum + ((s[t][0] + s[t][1]) + (s[t][2] + s[t][3]));
#else
            y[(j + t) * incy] -= sum + ((s[t].x[0] + s[t].x[1]) + (s[t].x[2] + s[t].x[3]));
#endif
        }
    }
    for (; j < n; ++j) y[j * incy] -= dot(k, A + j * lda, x);
}

// The entry points (dense.cpp), each compiled per ISA (RELMAP_MULTIVERSION).
// C (m × n) += alpha A Bᵀ, A (m × k), B (n × k).
void gemm_nt(int64_t m, int64_t n, int64_t k, double alpha, const double* A, int64_t lda,
             const double* B, int64_t ldb, double* C, int64_t ldc);
// C (m × n) += alpha A B, A (m × k), B (k × n).
void gemm_nn(int64_t m, int64_t n, int64_t k, double alpha, const double* A, int64_t lda,
             const double* B, int64_t ldb, double* C, int64_t ldc);
// The lower trapezoid of C += alpha A A[:q]ᵀ (see lower_product_t).
void lower_product(int64_t m, int64_t q, int64_t k, double alpha, const double* A, int64_t lda,
                   double* C, int64_t ldc);
// Whether 0 <= v[e] <= top for every e < n (one pass without early exit: it vectorizes).
bool all_within(const int64_t* v, int64_t n, int64_t top);

}  // namespace relmap::dense
