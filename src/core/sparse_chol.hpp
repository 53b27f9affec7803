// Sparse Cholesky A = L Lᵀ of a symmetric positive-definite matrix with a fixed pattern:
// symbolic analysis once, numerical factorization every iteration, solves, the joint blocks of
// a few parameters, and selected inversion (the entries of A⁻¹ on L's pattern).
//
// Algorithms (as in T. A. Davis, "Direct Methods for Sparse Linear Systems", SIAM 2006, and
// E. Ng & B. Peyton, "Block sparse Cholesky algorithms on advanced uniprocessor computers",
// SIAM J. Sci. Comput. 14, 1993):
// - the fill-reducing ordering comes from the caller (relmap orders the frame graph);
// - elimination tree by Liu's algorithm with path compression, then postordered;
// - L's row structure by row subtrees of the elimination tree (cs_ereach);
// - fundamental supernodes (chains of columns with nested structures) stored as dense
//   column-major panels, factorized by the left-looking supernodal Cholesky of Ng & Peyton
//   (each supernode's panel is assembled from A just before it gathers the updates of its
//   descendants, linked lists, relative indices; an update whose rows are consecutive rows of
//   the target is formed straight in the target's panel, others in a buffer then scattered);
// - selected inversion by Takahashi's recurrence (K. Takahashi, J. Fagan, M.-S. Chen, 1973;
//   supernodal form as in Y. Lin et al., ACM TOMS 37, 2011): with L̃_SJ = L_SJ L_JJ⁻¹,
//   Z_SJ = -Z_SS L̃_SJ, Z_JJ = L_JJ⁻ᵀ L_JJ⁻¹ - L̃_SJᵀ Z_SJ, supernodes from last to first; Z_SS
//   is gathered from each ancestor's panel with one merge of row lists per ancestor;
// - the joint block of A⁻¹ of a few parameters from forward solves along their
//   elimination-tree paths only: (A⁻¹)_pq = (L⁻¹ e_p)ᵀ (L⁻¹ e_q).
#pragma once

#include <cstdint>
#include <memory>
#include <vector>

#include "core.hpp"

namespace relmap {

class SparseCholesky {
public:
    // Pattern of A in CSC (n + 1 pointers, row indices; both triangles), and the
    // fill-reducing ordering perm (new → old). The ordering is postordered here.
    SparseCholesky(int64_t n, const int64_t* indptr, const int64_t* indices, const int64_t* perm);

    // Numerical factorization from the CSC data (the pattern's order; entries of the lower
    // triangle in the new order are read, so the data must be symmetric). Returns -1, or the
    // (new) column at which the matrix was found not positive definite.
    int64_t factorize(const double* data);

    // x = A⁻¹ b for m right-hand sides, row-major (n, m), in the original order.
    void solve(const double* b, double* x, int64_t m) const;

    // (A⁻¹)[idx][:, idx] (k, k), row-major, for original parameter indices idx (k,).
    void inverse_submatrix(const int64_t* idx, int64_t k, double* out) const;

    // Selected inversion; then the blocks (A⁻¹)[g][:, g] of groups of b original parameter
    // indices (count, b), every pair of a group on L's pattern (e.g. one frame's parameters).
    // Returns false if some pair is not on the pattern.
    bool selected_inverse_blocks(const int64_t* groups, int64_t count, int64_t b,
                                 double* out) const;

    int64_t n() const { return n_; }
    bool factorized() const { return factorized_; }  // the last factorize succeeded
    int64_t nnz_L() const;  // entries of L (one triangle, diagonal included)
    int64_t supernodes() const { return static_cast<int64_t>(first_.size()) - 1; }
    const std::vector<int64_t>& perm() const { return perm_; }

private:
    int64_t n_;
    int64_t nnz_A_;
    std::vector<int64_t> perm_, inv_;          // new → old, old → new
    std::vector<int64_t> parent_;              // elimination tree (new order)
    std::vector<int64_t> first_;               // first column of each supernode, then n
    std::vector<int64_t> sn_;                  // supernode of each column
    std::vector<int64_t> rows_ptr_, rows_;     // row structure of each supernode (sorted)
    std::vector<int64_t> panel_ptr_;           // offset of each supernode's panel
    std::vector<int64_t> src_, dst_;           // A's lower entries → panel slots
    std::vector<int64_t> a_ptr_;               // the entries of each supernode in src_, dst_
    std::unique_ptr<double[]> X_;              // the panels of L, column-major
    int64_t x_size_ = 0;                       // their entries
    bool factorized_ = false;
    int64_t max_update_ = 0;                   // workspace for the largest update

    int64_t sparent(int64_t s) const;                        // parent supernode, or -1
    int64_t position(int64_t s, int64_t row) const;          // row's slot in s, or -1
    void forward(double* y, int64_t m, const std::vector<int64_t>* only) const;
    void backward(double* y, int64_t m) const;
};

// The CSC pattern (both triangles, rows sorted) of a symmetric matrix of dense b × b blocks at
// the node pairs (brow[k], bcol[k]), k < K (duplicates allowed; a negative node drops the
// block), and the slot of every contribution: position[q K + k] for entry q = b r + c of block
// k (K·b² contributions, [entry q][block k]; a dropped block's go to the spare slot nnz). The
// blocks of one block column are stored row-block by row-block in each of its b columns.
// brow, bcol: the distinct blocks' node pairs, in (column, row) order.
struct BlockPattern {
    std::vector<int64_t> indptr, indices, position, brow, bcol;
};
BlockPattern block_pattern(int64_t nodes, int64_t K, const int64_t* brow, const int64_t* bcol,
                           int64_t b);

void register_sparse_chol(nb::module_& m);

}  // namespace relmap
