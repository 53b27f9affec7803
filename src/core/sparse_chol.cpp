// Supernodal sparse Cholesky, solves, joint blocks and selected inversion (see sparse_chol.hpp).
#include "sparse_chol.hpp"

#include <algorithm>
#include <cmath>
#include <memory>
#include <stdexcept>
#include <type_traits>

#include "arrays.hpp"
#include "dense.hpp"

namespace relmap {

namespace {

// Calls visit(i) for the entries i < k of column k of P A Pᵀ (the strict upper triangle), read
// straight from A's CSC (both triangles stored) with the ordering perm (new → old) and its
// inverse inv.
template <class Visit>
inline void upper_column(int64_t k, const int64_t* indptr, const int64_t* indices,
                         const int64_t* perm, const int64_t* inv, Visit&& visit) {
    const int64_t c = perm[k];
    for (int64_t e = indptr[c]; e < indptr[c + 1]; ++e) {
        const int64_t i = inv[indices[e]];
        if (i < k) visit(i);
    }
}

// Elimination tree of P A Pᵀ: Liu's algorithm with path compression (Davis 2006, cs_etree).
std::vector<int64_t> elimination_tree(int64_t n, const int64_t* indptr, const int64_t* indices,
                                      const int64_t* perm, const int64_t* inv) {
    std::vector<int64_t> parent(n, -1), ancestor(n, -1);
    for (int64_t k = 0; k < n; ++k)
        upper_column(k, indptr, indices, perm, inv, [&](int64_t i) {
            while (i != -1 && i < k) {
                const int64_t next = ancestor[i];
                ancestor[i] = k;
                if (next == -1) parent[i] = k;
                i = next;
            }
        });
    return parent;
}

// A postorder of the forest (new → old): children before parents, subtrees contiguous
// (Davis 2006, cs_post).
std::vector<int64_t> postorder(const std::vector<int64_t>& parent) {
    int64_t n = static_cast<int64_t>(parent.size());
    std::vector<int64_t> head(n, -1), next(n, -1), post, stack;
    post.reserve(n);
    for (int64_t j = n - 1; j >= 0; --j)
        if (parent[j] != -1) {
            next[j] = head[parent[j]];
            head[parent[j]] = j;
        }
    for (int64_t root = 0; root < n; ++root) {
        if (parent[root] != -1) continue;
        stack.push_back(root);
        while (!stack.empty()) {
            int64_t v = stack.back();
            int64_t child = head[v];
            if (child == -1) {
                stack.pop_back();
                post.push_back(v);
            } else {
                head[v] = next[child];
                stack.push_back(child);
            }
        }
    }
    return post;
}

}  // namespace

SparseCholesky::SparseCholesky(int64_t n, const int64_t* indptr, const int64_t* indices,
                               const int64_t* perm)
    : n_(n), nnz_A_(indptr[n]) {
    // Supervariables: runs of consecutive columns of P A Pᵀ (caller's order) with equal closed
    // patterns (indistinguishable nodes, e.g. a frame's parameters). Each is a chain of the
    // elimination tree inside one fundamental supernode, so the tree, its postorder, the
    // column counts and the row structures are found on the graph of supervariables (a pattern
    // of 3 × 3 blocks has a ninth of the entries), then expanded to columns.
    std::vector<int64_t> inv(n);
    for (int64_t k = 0; k < n; ++k) inv[perm[k]] = k;
    std::vector<int64_t> vfirst, of(n);  // first column of each supervariable; each column's
    {
        std::vector<int64_t> stamp[2] = {std::vector<int64_t>(n, -1), std::vector<int64_t>(n, -1)};
        int64_t size_prev = 0;
        for (int64_t k = 0; k < n; ++k) {
            // stamp k's closed pattern; equal to k-1's if of equal size and all in k-1's
            std::vector<int64_t>& mine = stamp[k & 1];
            const std::vector<int64_t>& prev = stamp[(k + 1) & 1];
            int64_t size = 0;
            bool same = k > 0;
            auto take = [&](int64_t i) {
                if (mine[i] == k) return;
                mine[i] = k;
                ++size;
                same = same && prev[i] == k - 1;
            };
            take(k);
            const int64_t c = perm[k];
            for (int64_t e = indptr[c]; e < indptr[c + 1]; ++e) take(inv[indices[e]]);
            if (!(same && size == size_prev)) vfirst.push_back(k);
            of[k] = static_cast<int64_t>(vfirst.size()) - 1;
            size_prev = size;
        }
        vfirst.push_back(n);
    }
    const int64_t V = static_cast<int64_t>(vfirst.size()) - 1;
    // The graph of supervariables (both triangles, no self-loops), from each one's first column.
    std::vector<int64_t> vptr(V + 1, 0), vidx, vmark(V, -1);
    vidx.reserve(nnz_A_ / 3 + 1);
    for (int64_t v = 0; v < V; ++v) {
        const int64_t c = perm[vfirst[v]];
        vmark[v] = v;
        for (int64_t e = indptr[c]; e < indptr[c + 1]; ++e) {
            const int64_t u = of[inv[indices[e]]];
            if (vmark[u] != v) {
                vmark[u] = v;
                vidx.push_back(u);
            }
        }
        vptr[v + 1] = static_cast<int64_t>(vidx.size());
    }
    std::vector<int64_t> ident(V);
    for (int64_t v = 0; v < V; ++v) ident[v] = v;
    // Its elimination tree, postordered (the same fill); the columns follow, each
    // supervariable's in the caller's order.
    const std::vector<int64_t> vparent0 =
        elimination_tree(V, vptr.data(), vidx.data(), ident.data(), ident.data());
    const std::vector<int64_t> vpost = postorder(vparent0);
    std::vector<int64_t> vrank(V), vinv(V), vparent(V), vsize(V), vstart(V + 1, 0);
    for (int64_t k = 0; k < V; ++k) vrank[vpost[k]] = k;
    for (int64_t k = 0; k < V; ++k) {
        const int64_t v = vpost[k], p0 = vparent0[v];
        vparent[k] = p0 == -1 ? -1 : vrank[p0];
        vsize[k] = vfirst[v + 1] - vfirst[v];
        vstart[k + 1] = vstart[k] + vsize[k];
        vinv[v] = k;
    }
    perm_.resize(n);
    inv_.resize(n);
    for (int64_t k = 0; k < V; ++k)
        for (int64_t t = 0; t < vsize[k]; ++t) perm_[vstart[k] + t] = perm[vfirst[vpost[k]] + t];
    for (int64_t k = 0; k < n; ++k) inv_[perm_[k]] = k;
    // The columns' tree: a chain through each supervariable, whose last column's parent is
    // the first column of the parent supervariable.
    parent_.resize(n);
    for (int64_t k = 0; k < V; ++k) {
        for (int64_t t = vstart[k]; t + 1 < vstart[k + 1]; ++t) parent_[t] = t + 1;
        parent_[vstart[k + 1] - 1] = vparent[k] == -1 ? -1 : vstart[vparent[k]];
    }

    // Row counts by row subtrees of the supervariables' tree: row k of L is the set of nodes
    // met walking up the tree from each i < k of A's row k until one already marked for k
    // (cs_ereach); each node met holds all of k's columns.
    std::vector<int64_t> mark(V, -1), below(V, 0);
    auto each_row_entry = [&](auto&& visit) {
        std::fill(mark.begin(), mark.end(), -1);
        for (int64_t k = 0; k < V; ++k) {
            mark[k] = k;
            upper_column(k, vptr.data(), vidx.data(), vpost.data(), vinv.data(), [&](int64_t i) {
                for (int64_t j = i; j != -1 && mark[j] != k; j = vparent[j]) {
                    mark[j] = k;
                    visit(j, k);
                }
            });
        }
    };
    each_row_entry([&](int64_t j, int64_t k) { below[j] += vsize[k]; });
    std::vector<int64_t> count(n);  // entries of each column of L (diagonal included)
    for (int64_t k = 0; k < V; ++k)
        for (int64_t t = 0; t < vsize[k]; ++t)
            count[vstart[k] + t] = vsize[k] - t + below[k];

    // Fundamental supernodes: column j joins j-1's supernode when j is j-1's parent and
    // struct(j-1) = {j} ∪ struct(j) (so each starts at a supervariable's first column).
    std::vector<int64_t> fund(1, 0);
    for (int64_t j = 1; j < n; ++j)
        if (!(parent_[j - 1] == j && count[j - 1] == count[j] + 1)) fund.push_back(j);
    fund.push_back(n);
    const int64_t F = static_cast<int64_t>(fund.size()) - 1;
    // The row structure of each fundamental supernode's first column, in increasing order:
    // its supervariable's columns, then those of the supervariables below it.
    std::vector<int64_t> fsn(n), fptr(F + 1, 0);
    for (int64_t t = 0; t < F; ++t) {
        for (int64_t j = fund[t]; j < fund[t + 1]; ++j) fsn[j] = t;
        fptr[t + 1] = fptr[t] + count[fund[t]];
    }
    std::vector<int64_t> frows(fptr[F]), filled(F, 0);
    for (int64_t k = 0; k < V; ++k) {
        const int64_t t = fsn[vstart[k]];
        if (fund[t] != vstart[k]) continue;
        for (int64_t c = vstart[k]; c < vstart[k + 1]; ++c) frows[fptr[t] + filled[t]++] = c;
    }
    each_row_entry([&](int64_t j, int64_t k) {
        const int64_t t = fsn[vstart[j]];
        if (fund[t] != vstart[j]) return;
        for (int64_t c = vstart[k]; c < vstart[k + 1]; ++c) frows[fptr[t] + filled[t]++] = c;
    });
    // Relaxed supernodes (amalgamation as in CHOLMOD): a fundamental supernode joins the
    // group before it when its first column is the parent of the group's last and the group
    // stays narrow or almost free of explicit zeros (fewer, wider dense updates).
    std::vector<int64_t> true_count(n + 1, 0);
    for (int64_t j = 0; j < n; ++j) true_count[j + 1] = true_count[j] + count[j];
    first_.assign(1, 0);
    for (int64_t t = 1; t < F; ++t) {
        const int64_t a = first_.back(), b = fund[t], c = fund[t + 1];
        if (parent_[b - 1] == b) {
            const int64_t w = c - a, nr = w + count[c - 1] - 1;
            const double stored = static_cast<double>(w * nr - w * (w - 1) / 2);
            const double zeros = (stored - static_cast<double>(true_count[c] - true_count[a])) / stored;
            if (w <= 4 || (w <= 16 && zeros < 0.8) || (w <= 48 && zeros < 0.1) || zeros < 0.05)
                continue;
        }
        first_.push_back(b);
    }
    first_.push_back(n);
    const int64_t S = supernodes();
    sn_.resize(n);
    rows_ptr_.assign(S + 1, 0);
    panel_ptr_.assign(S + 1, 0);
    for (int64_t s = 0; s < S; ++s) {
        const int64_t f = first_[s], w = first_[s + 1] - f, nr = w + count[first_[s + 1] - 1] - 1;
        for (int64_t j = f; j < f + w; ++j) sn_[j] = s;
        rows_ptr_[s + 1] = rows_ptr_[s] + nr;
        panel_ptr_[s + 1] = panel_ptr_[s] + nr * w;
        max_update_ = std::max(max_update_, (nr - w) * (nr - w));
    }
    // A group's rows: its columns, then the rows below its last fundamental supernode.
    rows_.resize(rows_ptr_[S]);
    for (int64_t s = 0; s < S; ++s) {
        const int64_t f = first_[s], l = first_[s + 1], t = fsn[l - 1];
        int64_t* out = rows_.data() + rows_ptr_[s];
        for (int64_t j = f; j < l; ++j) *out++ = j;
        const int64_t wt = fund[t + 1] - fund[t];
        std::copy(frows.begin() + fptr[t] + wt, frows.begin() + fptr[t + 1], out);
    }
    // A's entries on or below the diagonal (new order) → their slots in the panels, column
    // by column of the new order, each supernode's rows looked up in a map (slot of each row).
    src_.clear();
    dst_.clear();
    src_.reserve(nnz_A_ / 2 + n);
    dst_.reserve(nnz_A_ / 2 + n);
    std::vector<int64_t> slot(n, -1);
    a_ptr_.assign(S + 1, 0);
    for (int64_t k = 0; k < n; ++k) {
        const int64_t s = sn_[k], nr = rows_ptr_[s + 1] - rows_ptr_[s];
        if (k == first_[s])
            for (int64_t p = 0; p < nr; ++p) slot[rows_[rows_ptr_[s] + p]] = p;
        const int64_t c = perm_[k], base = panel_ptr_[s] + (k - first_[s]) * nr;
        for (int64_t e = indptr[c]; e < indptr[c + 1]; ++e) {
            const int64_t i = inv_[indices[e]];
            if (i < k) continue;
            src_.push_back(e);
            dst_.push_back(base + slot[i]);
        }
        a_ptr_[s + 1] = static_cast<int64_t>(src_.size());  // columns come supernode by supernode
    }
    x_size_ = panel_ptr_[S];  // each panel is zeroed by factorize before it is filled
    X_.reset(new double[x_size_ ? x_size_ : 1]);
}

int64_t SparseCholesky::nnz_L() const {
    int64_t total = 0;
    for (int64_t s = 0; s < supernodes(); ++s) {
        int64_t w = first_[s + 1] - first_[s], nr = rows_ptr_[s + 1] - rows_ptr_[s];
        total += w * nr - w * (w - 1) / 2;
    }
    return total;
}

int64_t SparseCholesky::sparent(int64_t s) const {
    int64_t w = first_[s + 1] - first_[s];
    int64_t below = rows_ptr_[s] + w;
    return below < rows_ptr_[s + 1] ? sn_[rows_[below]] : -1;
}

int64_t SparseCholesky::position(int64_t s, int64_t row) const {
    const int64_t* begin = rows_.data() + rows_ptr_[s];
    const int64_t* end = rows_.data() + rows_ptr_[s + 1];
    const int64_t* it = std::lower_bound(begin, end, row);
    return (it != end && *it == row) ? it - begin : -1;
}

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

BlockPattern block_pattern(int64_t nodes, int64_t K, const int64_t* brow, const int64_t* bcol,
                           int64_t b) {
    // The kept blocks sorted by (column, row) by two stable counting sorts (row, then column).
    std::vector<int64_t> count(nodes + 1, 0), by_row, by_col;
    for (int64_t k = 0; k < K; ++k)
        if (brow[k] >= 0 && bcol[k] >= 0) ++count[brow[k] + 1];
    for (int64_t v = 0; v < nodes; ++v) count[v + 1] += count[v];
    by_row.resize(count[nodes]);
    by_col.resize(count[nodes]);
    for (int64_t k = 0; k < K; ++k)
        if (brow[k] >= 0 && bcol[k] >= 0) by_row[count[brow[k]]++] = k;
    std::fill(count.begin(), count.end(), 0);
    for (int64_t k : by_row) ++count[bcol[k] + 1];
    for (int64_t v = 0; v < nodes; ++v) count[v + 1] += count[v];
    for (int64_t k : by_row) by_col[count[bcol[k]]++] = k;
    // Distinct blocks: each block column's in increasing row order; every contribution's block.
    BlockPattern out;
    std::vector<int64_t> unique_of(K, -1), start(nodes + 1, 0);
    std::vector<int64_t>& urow = out.brow;
    std::vector<int64_t>& ucol = out.bcol;
    for (size_t e = 0; e < by_col.size(); ++e) {
        const int64_t k = by_col[e];
        if (e == 0 || brow[k] != urow.back() || bcol[k] != ucol.back()) {
            urow.push_back(brow[k]);
            ucol.push_back(bcol[k]);
            ++start[bcol[k] + 1];
        }
        unique_of[k] = static_cast<int64_t>(urow.size()) - 1;
    }
    for (int64_t v = 0; v < nodes; ++v) start[v + 1] += start[v];
    const int64_t U = static_cast<int64_t>(urow.size()), bb = b * b, nnz = bb * U;
    // Scalar column (J, a) starts at b²·start[J] + a·b·(blocks of column J); in it, block u of
    // rank (u - start[J]) holds rows b·urow[u] … b·urow[u] + b - 1.
    auto column_start = [&](int64_t J, int64_t a) {
        return bb * start[J] + a * b * (start[J + 1] - start[J]);
    };
    out.indptr.resize(b * nodes + 1);
    for (int64_t J = 0; J < nodes; ++J)
        for (int64_t a = 0; a < b; ++a) out.indptr[b * J + a] = column_start(J, a);
    out.indptr[b * nodes] = nnz;
    out.indices.resize(nnz);
    for (int64_t u = 0; u < U; ++u) {
        const int64_t J = ucol[u], rank = u - start[J];
        for (int64_t a = 0; a < b; ++a) {
            int64_t* rows = out.indices.data() + column_start(J, a) + b * rank;
            for (int64_t r = 0; r < b; ++r) rows[r] = b * urow[u] + r;
        }
    }
    out.position.resize(bb * K);
    for (int64_t c = 0; c < b; ++c) {  // entry q = b r + c of block k: row r of column (J, c)
        // the slot of the block's row 0 in column (J, c), per distinct block
        std::vector<int64_t> base(U);
        for (int64_t u = 0; u < U; ++u)
            base[u] = column_start(ucol[u], c) + b * (u - start[ucol[u]]);
        for (int64_t r = 0; r < b; ++r) {
            int64_t* slots = out.position.data() + (b * r + c) * K;
            for (int64_t k = 0; k < K; ++k) {
                const int64_t u = unique_of[k];
                slots[k] = u >= 0 ? base[u] + r : nnz;
            }
        }
    }
    return out;
}

// ---- bindings ------------------------------------------------------------------------------

void register_sparse_chol(nb::module_& m) {
    m.def(
        "block_pattern",
        [](int64_t nodes, Index1 brow, Index1 bcol, int64_t b) {
            const int64_t K = static_cast<int64_t>(brow.shape(0));
            if (nodes < 0 || b < 1 || static_cast<int64_t>(bcol.shape(0)) != K)
                throw nb::value_error("nodes >= 0, b >= 1, and brow and bcol of the same length");
            for (int64_t k = 0; k < K; ++k)
                if (brow.data()[k] >= nodes || bcol.data()[k] >= nodes)
                    throw nb::value_error("block node out of range");
            BlockPattern p;
            {
                nb::gil_scoped_release unlocked;
                p = block_pattern(nodes, K, brow.data(), bcol.data(), b);
            }
            return nb::make_tuple(
                owned_array(std::move(p.indptr)), owned_array(std::move(p.indices)),
                owned_array(std::move(p.position)), owned_array(std::move(p.brow)),
                owned_array(std::move(p.bcol)));
        },
        nb::arg("nodes"), nb::arg("brow"), nb::arg("bcol"), nb::arg("b"),
        "CSC pattern (indptr, indices) of b × b blocks at node pairs (brow, bcol), the slot "
        "of every contribution laid out [entry q][block k], and the distinct blocks' node "
        "pairs (internal: see relmap.network.sparse.SymmetricPattern.from_blocks).");
    nb::class_<SparseCholesky>(m, "SparseCholesky",
                               "Supernodal sparse Cholesky A = L Lᵀ with a fixed pattern "
                               "(internal: see relmap.network.sparse).")
        .def(
            "__init__",
            [](SparseCholesky* self, Index1 indptr, Index1 indices, Index1 perm) {
                const int64_t n = static_cast<int64_t>(perm.shape(0));
                if (static_cast<int64_t>(indptr.shape(0)) != n + 1)
                    throw nb::value_error("indptr must have n + 1 entries");
                if (static_cast<int64_t>(indices.shape(0)) < indptr.data()[n])
                    throw nb::value_error("indices shorter than indptr[-1]");
                new (self) SparseCholesky(n, indptr.data(), indices.data(), perm.data());
            },
            nb::arg("indptr"), nb::arg("indices"), nb::arg("perm"))
        .def_prop_ro("n", &SparseCholesky::n)
        .def_prop_ro("nnz_L", &SparseCholesky::nnz_L)
        .def_prop_ro("supernodes", &SparseCholesky::supernodes)
        .def(
            "ordering", [](const SparseCholesky& f) { return vector_array(f.perm()); },
            "The elimination order (new → old): the caller's ordering, postordered.")
        .def(
            "factorize",
            [](SparseCholesky& f, Float1 data) {
                nb::gil_scoped_release unlocked;
                return f.factorize(data.data());
            },
            nb::arg("data"))
        .def(
            "solve",
            [](const SparseCholesky& f, Float2 b) {
                if (!f.factorized())
                    throw nb::value_error("factorize a positive-definite matrix first");
                if (static_cast<int64_t>(b.shape(0)) != f.n())
                    throw nb::value_error("right-hand side has the wrong number of rows");
                const int64_t m = static_cast<int64_t>(b.shape(1));
                auto out = new_array({static_cast<size_t>(f.n()), static_cast<size_t>(m)});
                {
                    nb::gil_scoped_release unlocked;
                    f.solve(b.data(), out.data(), m);
                }
                return out;
            },
            nb::arg("b"))
        .def(
            "inverse_submatrix",
            [](const SparseCholesky& f, Index1 idx) {
                if (!f.factorized())
                    throw nb::value_error("factorize a positive-definite matrix first");
                const int64_t k = static_cast<int64_t>(idx.shape(0));
                auto out = new_array({static_cast<size_t>(k), static_cast<size_t>(k)});
                f.inverse_submatrix(idx.data(), k, out.data());
                return out;
            },
            nb::arg("idx"))
        .def(
            "selected_inverse_blocks",
            [](const SparseCholesky& f, Index2 groups) {
                if (!f.factorized())
                    throw nb::value_error("factorize a positive-definite matrix first");
                const size_t count = groups.shape(0), b = groups.shape(1);
                auto out = new_array({count, b, b});
                bool ok;
                {
                    nb::gil_scoped_release unlocked;
                    ok = f.selected_inverse_blocks(groups.data(), static_cast<int64_t>(count),
                                                   static_cast<int64_t>(b), out.data());
                }
                if (!ok) throw nb::value_error("a group's entries are not on the factor's pattern");
                return out;
            },
            nb::arg("groups"));
}

}  // namespace relmap
