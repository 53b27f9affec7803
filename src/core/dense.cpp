// The dense kernels' entry points (dense.hpp), compiled per ISA.
#include "dense.hpp"

namespace relmap::dense {

RELMAP_MULTIVERSION
void gemm_nt(int64_t m, int64_t n, int64_t k, double alpha, const double* A, int64_t lda,
             const double* B, int64_t ldb, double* C, int64_t ldc) {
    gemm_t<true>(m, n, k, alpha, A, lda, B, ldb, C, ldc);
}

RELMAP_MULTIVERSION
void gemm_nn(int64_t m, int64_t n, int64_t k, double alpha, const double* A, int64_t lda,
             const double* B, int64_t ldb, double* C, int64_t ldc) {
    gemm_t<false>(m, n, k, alpha, A, lda, B, ldb, C, ldc);
}

RELMAP_MULTIVERSION
void lower_product(int64_t m, int64_t q, int64_t k, double alpha, const double* A, int64_t lda,
                   double* C, int64_t ldc) {
    lower_product_t(m, q, k, alpha, A, lda, C, ldc);
}

RELMAP_MULTIVERSION
bool all_within(const int64_t* v, int64_t n, int64_t top) {
    int64_t lo = 0, hi = 0;
    for (int64_t e = 0; e < n; ++e) {
        lo = std::min(lo, v[e]);
        hi = std::max(hi, v[e]);
    }
    return lo >= 0 && hi <= top;
}

}  // namespace relmap::dense
