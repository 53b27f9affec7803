// Biconnected blocks by Tarjan's algorithm (see blocks.hpp).
#include "blocks.hpp"

#include <algorithm>

#include "arrays.hpp"

namespace relmap {

void biconnected_blocks(int64_t n, int64_t m, const int64_t* a, const int64_t* b, int64_t root,
                        std::vector<int64_t>& edges, std::vector<int64_t>& bounds) {
    // Adjacency (CSR): each node's edges in increasing edge number.
    std::vector<int64_t> ptr(n + 1, 0), adj_edge(2 * m), adj_node(2 * m);
    for (int64_t e = 0; e < m; ++e) {
        ++ptr[a[e] + 1];
        ++ptr[b[e] + 1];
    }
    for (int64_t v = 0; v < n; ++v) ptr[v + 1] += ptr[v];
    std::vector<int64_t> fill(ptr.begin(), ptr.end() - 1);
    for (int64_t e = 0; e < m; ++e) {
        adj_edge[fill[a[e]]] = e;
        adj_node[fill[a[e]]++] = b[e];
        adj_edge[fill[b[e]]] = e;
        adj_node[fill[b[e]]++] = a[e];
    }
    std::vector<int64_t> disc(n, -1), low(n, 0), next(n, 0), via(n, -1), stack, edge_stack;
    edges.clear();
    bounds.assign(1, 0);
    int64_t clock = 0;
    disc[root] = low[root] = clock++;
    next[root] = ptr[root];
    stack.push_back(root);
    while (!stack.empty()) {
        const int64_t v = stack.back();
        bool advanced = false;
        while (next[v] < ptr[v + 1]) {
            const int64_t p = next[v]++, e = adj_edge[p], w = adj_node[p];
            if (e == via[v] || w == v) continue;  // the tree edge back, or a self-loop
            if (disc[w] == -1) {                  // a tree edge: descend
                edge_stack.push_back(e);
                disc[w] = low[w] = clock++;
                via[w] = e;
                next[w] = ptr[w];
                stack.push_back(w);
                advanced = true;
                break;
            }
            if (disc[w] < disc[v]) {  // a back edge (or an edge parallel to the tree edge)
                edge_stack.push_back(e);
                low[v] = std::min(low[v], disc[w]);
            }
        }
        if (advanced) continue;
        stack.pop_back();
        if (stack.empty()) break;
        const int64_t u = stack.back();
        low[u] = std::min(low[u], low[v]);
        if (low[v] >= disc[u]) {  // u separates v's subtree: its edges above form a block
            for (;;) {
                const int64_t e = edge_stack.back();
                edge_stack.pop_back();
                edges.push_back(e);
                if (e == via[v]) break;
            }
            bounds.push_back(static_cast<int64_t>(edges.size()));
        }
    }
}

void register_blocks(nb::module_& m) {
    m.def(
        "biconnected_blocks",
        [](int64_t n, Index1 a, Index1 b, int64_t root) {
            const int64_t count = static_cast<int64_t>(a.shape(0));
            if (static_cast<int64_t>(b.shape(0)) != count)
                throw nb::value_error("a and b must have the same length");
            if (root < 0 || root >= n) throw nb::value_error("root out of range");
            for (int64_t e = 0; e < count; ++e)
                if (a.data()[e] < 0 || a.data()[e] >= n || b.data()[e] < 0 || b.data()[e] >= n)
                    throw nb::value_error("edge end out of range");
            std::vector<int64_t> edges, bounds;
            biconnected_blocks(n, count, a.data(), b.data(), root, edges, bounds);
            return nb::make_tuple(vector_array(edges), vector_array(bounds));
        },
        nb::arg("n"), nb::arg("a"), nb::arg("b"), nb::arg("root"),
        "The 2-connected blocks of root's component (Tarjan): (edges, bounds), block k being "
        "edges[bounds[k]:bounds[k + 1]], in the order the depth-first search closes them.");
}

}  // namespace relmap
