// A fill-reducing ordering: multiple minimum degree (J. W. H. Liu, "Modification of the
// minimum-degree algorithm by multiple elimination", ACM TOMS 11, 1985; surveyed by A. George
// & J. W. H. Liu, "The evolution of the minimum degree ordering algorithm", SIAM Review 31,
// 1989), with indistinguishable nodes merged into supervariables and external degrees.
//
// The graph is eliminated explicitly: a supervariable of least degree (ties: the lowest
// index) is removed and its neighbours become a clique. Explicit fill is affordable for the
// node graphs relmap orders (one node per frame, fill of the order of L's block pattern).
// Supervariables of least degree are kept in degree lists (O(1) moves, no heap), and
// indistinguishable candidates found by sorting their neighbourhood sums (the result does not
// depend on a hash table's order). Measured against SuperLU's MMD (its MMD_AT_PLUS_A
// ordering) on the same node graphs, entries of L (relmap's, supernodes' explicit zeros
// included): city10000 1.287M vs 1.262M, manhattanOlson3500 0.253M vs 0.253M, sphere2500
// 1.405M vs 1.414M.
#pragma once

#include <cstdint>
#include <vector>

#include "core.hpp"

namespace relmap {

// The order (new → old) of the n nodes of the undirected graph with edges (a[e], b[e]).
std::vector<int64_t> minimum_degree(int64_t n, int64_t m, const int64_t* a, const int64_t* b);

// The connected components of the same graph: a label (0, 1, …, in order of each component's
// lowest node) for every node, by union-find (union by size, path halving). With the ordering
// here because both read the frame graph; it spares a process scipy.sparse's import.
std::vector<int64_t> components(int64_t n, int64_t m, const int64_t* a, const int64_t* b);

void register_ordering(nb::module_& m);

}  // namespace relmap
