// The dense kernels' entry points (dense.hpp).
#include "dense.hpp"

namespace relmap::dense {

void gemm_nt(int64_t m, int64_t n, int64_t k, double alpha, const double* A, int64_t lda,
             const double* B, int64_t ldb, double* C, int64_t ldc) {
    gemm_t<true>(m, n, k, alpha, A, lda, B, ldb, C, ldc);
}

void gemm_nn(int64_t m, int64_t n, int64_t k, double alpha, const double* A, int64_t lda,
             const double* B, int64_t ldb, double* C, int64_t ldc) {
    gemm_t<false>(m, n, k, alpha, A, lda, B, ldb, C, ldc);
}

void lower_product(int64_t m, int64_t q, int64_t k, double alpha, const double* A, int64_t lda,
                   double* C, int64_t ldc) {
    for (int64_t j = 0; j < q; j += 4) {
        const int64_t nb = std::min<int64_t>(4, q - j);
        gemm_t<true>(m - j, nb, k, alpha, A + j, lda, A + j, lda, C + j + j * ldc, ldc);
    }
}

}  // namespace relmap::dense
