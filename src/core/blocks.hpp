// The 2-connected blocks (biconnected components) of a graph: Tarjan's depth-first search
// (R. E. Tarjan, "Depth-first search and linear graph algorithms", SIAM J. Comput. 1, 1972),
// iterative, with an edge stack; O(nodes + edges).
#pragma once

#include <cstdint>
#include <vector>

#include "core.hpp"

namespace relmap {

// The blocks of root's connected component of the graph with n nodes and edges (a[e], b[e]),
// each node's edges visited in increasing edge number. Blocks come in the order the search
// closes them, each block's edges in the order they leave the edge stack: edges[bounds[k] :
// bounds[k + 1]] is block k. Self-loops belong to no block.
void biconnected_blocks(int64_t n, int64_t m, const int64_t* a, const int64_t* b, int64_t root,
                        std::vector<int64_t>& edges, std::vector<int64_t>& bounds);

void register_blocks(nb::module_& m);

}  // namespace relmap
