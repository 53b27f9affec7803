// Supernodal sparse Cholesky: the symbolic analysis (elimination tree, supernodes, their row
// patterns), `block_pattern`, and the bindings (see sparse_chol.hpp; the numeric factorization,
// solves and selected inversion are in sparse_chol_numeric.cpp).
#include "sparse_chol.hpp"

#include <algorithm>
#include <vector>

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
