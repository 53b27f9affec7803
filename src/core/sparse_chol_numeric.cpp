// Supernodal sparse Cholesky, numerically: the left-looking factorization, the triangular
// solves, joint blocks of the inverse and Takahashi's selected inversion (see
// sparse_chol.hpp; the symbolic analysis they run on is in sparse_chol.cpp).
#include <algorithm>
#include <cmath>
#include <memory>
#include <stdexcept>
#include <type_traits>
#include <vector>

#include "dense.hpp"
#include "sparse_chol.hpp"

namespace relmap {
RELMAP_MULTIVERSION
int64_t SparseCholesky::factorize(const double* data) {
    factorized_ = false;
    int64_t S = supernodes();
    // Left-looking (Ng & Peyton 1993): head[s] links the supernodes d whose next update goes
    // to s; ptr[d] is the first row of d not yet used.
    std::vector<int64_t> head(S, -1), next(S, -1), ptr(S, 0), map(n_), rel(n_);
    std::vector<double> W(max_update_);
    for (int64_t s = 0; s < S; ++s) {
        const int64_t f = first_[s], l = first_[s + 1], w = l - f;
        const int64_t nr = rows_ptr_[s + 1] - rows_ptr_[s];
        const int64_t* R = rows_.data() + rows_ptr_[s];
        double* Xs = X_.get() + panel_ptr_[s];
        // s's panel: A's entries, assembled just before the updates (the panel stays in cache)
        std::fill(Xs, Xs + nr * w, 0.0);
        for (int64_t e = a_ptr_[s]; e < a_ptr_[s + 1]; ++e) X_[dst_[e]] += data[src_[e]];
        for (int64_t i = 0; i < nr; ++i) map[R[i]] = i;  // relative indices of s's rows
        for (int64_t d = head[s]; d != -1;) {
            const int64_t nxt = next[d];
            const int64_t nrd = rows_ptr_[d + 1] - rows_ptr_[d], wd = first_[d + 1] - first_[d];
            const int64_t* Rd = rows_.data() + rows_ptr_[d];
            const double* Xd = X_.get() + panel_ptr_[d];
            const int64_t p = ptr[d], r = nrd - p;
            int64_t q = 0;
            while (p + q < nrd && Rd[p + q] < l) ++q;
            bool consecutive = true;  // d's rows are consecutive rows of s
            for (int64_t ii = 0; ii < r; ++ii) {
                rel[ii] = map[Rd[p + ii]];  // relative indices
                consecutive = consecutive && rel[ii] == rel[0] + ii;
            }
            if (consecutive) {  // the update straight into s's panel: no buffer, no scatter
                dense::lower_product(r, q, wd, -1.0, Xd + p, nrd, Xs + rel[0] * nr + rel[0], nr);
            } else {  // W = L_d[p:, :] L_d[p:p+q, :]ᵀ (r × q, lower part), then scattered
                std::fill(W.begin(), W.begin() + r * q, 0.0);
                dense::lower_product(r, q, wd, 1.0, Xd + p, nrd, W.data(), r);
                for (int64_t jj = 0; jj < q; ++jj) {  // scatter-subtract into s's panel
                    double* Xc = Xs + rel[jj] * nr;    // column Rd[p + jj] - f
                    const double* Wj = W.data() + jj * r;
                    for (int64_t ii = jj; ii < r; ++ii) Xc[rel[ii]] -= Wj[ii];
                }
            }
            ptr[d] = p + q;
            if (p + q < nrd) {
                const int64_t t = sn_[Rd[p + q]];
                next[d] = head[t];
                head[t] = d;
            }
            d = nxt;
        }
        // Dense Cholesky of the panel (its diagonal block and the rows below), right-looking by
        // blocks of 16 columns: each block column by column, then its product into the rest.
        for (int64_t c0 = 0; c0 < w; c0 += 16) {
            const int64_t c1 = std::min<int64_t>(c0 + 16, w);
            for (int64_t c = c0; c < c1; ++c) {
                double* Xc = Xs + c * nr;
                // Xc[c:] -= X[c:, c0:c] X[c, c0:c]ᵀ, eight rows at a time summed in registers
                dense::columns<1, true>(nr - c, c - c0, -1.0, Xs + c0 * nr + c, nr,
                                        Xs + c0 * nr + c, nr, Xc + c, nr);
                const double diag = Xc[c];
                if (!(diag > 0.0) || !std::isfinite(diag)) return f + c;
                const double root = std::sqrt(diag), scale = 1.0 / root;
                Xc[c] = root;
                for (int64_t i = c + 1; i < nr; ++i) Xc[i] *= scale;
            }
            if (c1 < w)
                dense::lower_product(nr - c1, w - c1, c1 - c0, -1.0, Xs + c0 * nr + c1, nr,
                                     Xs + c1 * nr + c1, nr);
        }
        ptr[s] = w;
        if (w < nr) {
            const int64_t t = sn_[R[w]];
            next[s] = head[t];
            head[t] = s;
        }
    }
    factorized_ = true;
    return -1;
}

// Calls body(m) with m a compile-time 1 when m_ is 1 (the solves of one right-hand side: the
// loops over right-hand sides vanish), else with m_ itself; one source for both.
template <class Body>
RELMAP_INLINE void with_columns(int64_t m_, Body&& body) {
    if (m_ == 1)
        body(std::integral_constant<int64_t, 1>{});
    else
        body(m_);
}

RELMAP_MULTIVERSION
void SparseCholesky::forward(double* y, int64_t m_, const std::vector<int64_t>* only) const {
    // Supernode by supernode: L_JJ x_J = y_J, then y_S -= L_SJ x_J (one register-tiled product
    // into a buffer, one scatter).
    const int64_t S = only ? static_cast<int64_t>(only->size()) : supernodes();
    std::vector<double> tmp;
    with_columns(m_, [&](auto m) RELMAP_LAMBDA_INLINE {
        for (int64_t t = 0; t < S; ++t) {
            const int64_t s = only ? (*only)[t] : t;
            const int64_t f = first_[s], w = first_[s + 1] - f;
            const int64_t nr = rows_ptr_[s + 1] - rows_ptr_[s], r = nr - w;
            const int64_t* R = rows_.data() + rows_ptr_[s] + w;
            const double* L = X_.get() + panel_ptr_[s];
            double* x = y + f * m;
            for (int64_t c = 0; c < w; ++c) {
                const double* Lc = L + c * nr;
                const double scale = 1.0 / Lc[c];
                for (int64_t q = 0; q < m; ++q) x[c * m + q] *= scale;
                for (int64_t i = c + 1; i < w; ++i)
                    for (int64_t q = 0; q < m; ++q) x[i * m + q] -= Lc[i] * x[c * m + q];
            }
            tmp.assign(r * m, 0.0);  // L_SJ x_J, column-major (r × m)
            dense::gemm_nt(r, m, w, 1.0, L + w, nr, x, m, tmp.data(), r);
            for (int64_t i = 0; i < r; ++i)
                for (int64_t q = 0; q < m; ++q) y[R[i] * m + q] -= tmp[i + q * r];
        }
    });
}

RELMAP_MULTIVERSION
void SparseCholesky::backward(double* y, int64_t m_) const {
    // Supernodes in reverse: x_J = L_JJ⁻ᵀ (y_J - L_SJᵀ x_S), L_SJᵀ x_S by dot products sharing
    // x_S (gathered into a buffer, column-major r × m).
    std::vector<double> tmp;
    with_columns(m_, [&](auto m) RELMAP_LAMBDA_INLINE {
        for (int64_t s = supernodes() - 1; s >= 0; --s) {
            const int64_t f = first_[s], w = first_[s + 1] - f;
            const int64_t nr = rows_ptr_[s + 1] - rows_ptr_[s], r = nr - w;
            const int64_t* R = rows_.data() + rows_ptr_[s] + w;
            const double* L = X_.get() + panel_ptr_[s];
            double* x = y + f * m;
            tmp.resize(r * m);
            for (int64_t i = 0; i < r; ++i)
                for (int64_t q = 0; q < m; ++q) tmp[i + q * r] = y[R[i] * m + q];
            for (int64_t q = 0; q < m; ++q)  // column q of x_J: stride m
                dense::subtract_dots(w, r, L + w, nr, tmp.data() + q * r, x + q, m);
            for (int64_t c = w - 1; c >= 0; --c) {
                const double* Lc = L + c * nr;
                for (int64_t i = c + 1; i < w; ++i)
                    for (int64_t q = 0; q < m; ++q) x[c * m + q] -= Lc[i] * x[i * m + q];
                const double scale = 1.0 / Lc[c];
                for (int64_t q = 0; q < m; ++q) x[c * m + q] *= scale;
            }
        }
    });
}

RELMAP_MULTIVERSION
void SparseCholesky::solve(const double* b, double* x, int64_t m_) const {
    std::vector<double> y(n_ * m_);
    with_columns(m_, [&](auto m) RELMAP_LAMBDA_INLINE {
        for (int64_t k = 0; k < n_; ++k)
            for (int64_t q = 0; q < m; ++q) y[k * m + q] = b[perm_[k] * m + q];
    });
    forward(y.data(), m_, nullptr);
    backward(y.data(), m_);
    with_columns(m_, [&](auto m) RELMAP_LAMBDA_INLINE {
        for (int64_t k = 0; k < n_; ++k)
            for (int64_t q = 0; q < m; ++q) x[perm_[k] * m + q] = y[k * m + q];
    });
}

void SparseCholesky::inverse_submatrix(const int64_t* idx, int64_t k, double* out) const {
    // The supernodes on the elimination-tree paths of the parameters, in increasing order:
    // L⁻¹ e_p is zero elsewhere.
    const int64_t S = supernodes();
    std::vector<char> on_path(S, 0);
    std::vector<int64_t> path;
    for (int64_t a = 0; a < k; ++a)
        for (int64_t s = sn_[inv_[idx[a]]]; s != -1 && !on_path[s]; s = sparent(s)) {
            on_path[s] = 1;
            path.push_back(s);
        }
    std::sort(path.begin(), path.end());
    std::vector<double> y(n_ * k, 0.0);
    for (int64_t a = 0; a < k; ++a) y[inv_[idx[a]] * k + a] = 1.0;
    forward(y.data(), k, &path);
    std::fill(out, out + k * k, 0.0);
    for (int64_t s : path)
        for (int64_t j = first_[s]; j < first_[s + 1]; ++j) {
            const double* yj = y.data() + j * k;
            for (int64_t a = 0; a < k; ++a)
                for (int64_t c = 0; c < k; ++c) out[a * k + c] += yj[a] * yj[c];
        }
}

RELMAP_MULTIVERSION
bool SparseCholesky::selected_inverse_blocks(const int64_t* groups, int64_t count, int64_t b,
                                             double* out) const {
    // Z = A⁻¹ on L's pattern, in panels like L's, by Takahashi's recurrence from the last
    // supernode (the root) to the first. Every Z_SS a supernode needs is on the pattern of
    // its ancestors (L's pattern is chordal) and already formed. Every entry of Z's panels is
    // written (Z_JJ whole, Z_SJ below it), so Z needs no initialization.
    const int64_t S = supernodes();
    std::unique_ptr<double[]> Zbuf(new double[x_size_ ? x_size_ : 1]);
    double* Z = Zbuf.get();
    std::vector<double> Linv, Lt, Dinv, Zss, ZSJ;
    std::vector<int64_t> at;  // positions of s's rows below in an ancestor's rows
    for (int64_t s = S - 1; s >= 0; --s) {
        const int64_t f = first_[s], w = first_[s + 1] - f;
        const int64_t nr = rows_ptr_[s + 1] - rows_ptr_[s], r = nr - w;
        const int64_t* R = rows_.data() + rows_ptr_[s];
        const double* L = X_.get() + panel_ptr_[s];  // column-major, leading dimension nr
        // L_JJ⁻¹ (column-major, w × w) by forward substitution on the columns of the panel,
        // column j from L x = e_j: contiguous updates along the panel's columns.
        Linv.assign(w * w, 0.0);
        for (int64_t j = 0; j < w; ++j) {
            double* x = Linv.data() + j * w;
            x[j] = 1.0;
            for (int64_t t = j; t < w; ++t) {
                const double* Lt_col = L + t * nr;
                const double xt = x[t] / Lt_col[t];
                x[t] = xt;
                for (int64_t i = t + 1; i < w; ++i) x[i] -= Lt_col[i] * xt;
            }
        }
        Dinv.assign(w * w, 0.0);  // L_JJ⁻ᵀ L_JJ⁻¹
        for (int64_t a = 0; a < w; ++a)
            for (int64_t c = 0; c <= a; ++c) {
                const double sum = dense::dot(w - a, Linv.data() + a * w + a,
                                              Linv.data() + c * w + a);
                Dinv[c * w + a] = Dinv[a * w + c] = sum;
            }
        Lt.assign(r * w, 0.0);  // L̃_SJ = L_SJ L_JJ⁻¹ (r × w, column-major)
        for (int64_t j = 0; j < w; ++j)
            for (int64_t t = j; t < w; ++t) {
                const double a = Linv[j * w + t];
                const double* col = L + t * nr + w;
                double* out_col = Lt.data() + j * r;
                for (int64_t i = 0; i < r; ++i) out_col[i] += col[i] * a;
            }
        // Z_SS gathered from the ancestors' Z panels. The rows below s that are columns of one
        // ancestor t are consecutive in R; for them, the positions of R's later rows in t's
        // rows are found by one merge, the same for each of t's columns.
        Zss.resize(r * r);
        at.resize(r);
        for (int64_t c0 = 0, c1; c0 < r; c0 = c1) {
            const int64_t t = sn_[R[w + c0]], lt = first_[t + 1];
            for (c1 = c0 + 1; c1 < r && R[w + c1] < lt; ++c1) {
            }
            const int64_t nrt = rows_ptr_[t + 1] - rows_ptr_[t];
            const int64_t* Rt = rows_.data() + rows_ptr_[t];
            for (int64_t a = c0, pos = R[w + c0] - first_[t]; a < r; ++a, ++pos) {
                const int64_t ga = R[w + a];
                while (pos < nrt && Rt[pos] != ga) ++pos;
                if (pos == nrt) throw std::logic_error("selected inversion: pattern not chordal");
                at[a] = pos;
            }
            for (int64_t c = c0; c < c1; ++c) {
                const double* Zt = Z + panel_ptr_[t] + (R[w + c] - first_[t]) * nrt;
                double* zc = Zss.data() + c * r;
                for (int64_t a = c; a < r; ++a) zc[a] = Zt[at[a]];
            }
        }
        for (int64_t c0 = 0; c0 < r; c0 += 32)  // the upper triangle, by 32 × 32 tiles
            for (int64_t a0 = c0; a0 < r; a0 += 32)
                for (int64_t c = c0; c < std::min(c0 + 32, r); ++c)
                    for (int64_t a = std::max(a0, c + 1); a < std::min(a0 + 32, r); ++a)
                        Zss[a * r + c] = Zss[c * r + a];
        ZSJ.assign(r * w, 0.0);  // Z_SJ = -Z_SS L̃_SJ
        dense::gemm_nn(r, w, r, -1.0, Zss.data(), r, Lt.data(), r, ZSJ.data(), r);
        double* Zs = Z + panel_ptr_[s];
        for (int64_t j = 0; j < w; ++j) {
            for (int64_t a = 0; a <= j; ++a) {  // Z_JJ = L_JJ⁻ᵀ L_JJ⁻¹ - L̃_SJᵀ Z_SJ
                const double* lt = Lt.data() + a * r;
                const double* zc = ZSJ.data() + j * r;
                Zs[j * nr + a] = Zs[a * nr + j] = Dinv[j * w + a] - dense::dot(r, lt, zc);
            }
            std::copy(ZSJ.data() + j * r, ZSJ.data() + (j + 1) * r, Zs + j * nr + w);
        }
    }
    for (int64_t g = 0; g < count; ++g)
        for (int64_t a = 0; a < b; ++a)
            for (int64_t c = 0; c < b; ++c) {
                const int64_t i = inv_[groups[g * b + a]], j = inv_[groups[g * b + c]];
                const int64_t lo = std::min(i, j), hi = std::max(i, j), t = sn_[lo];
                // a supernode's rows start with its own columns
                const int64_t pos = hi < first_[t + 1] ? hi - first_[t] : position(t, hi);
                if (pos < 0) return false;
                const int64_t nrt = rows_ptr_[t + 1] - rows_ptr_[t];
                out[(g * b + a) * b + c] = Z[panel_ptr_[t] + (lo - first_[t]) * nrt + pos];
            }
    return true;
}

}  // namespace relmap
