// Multiple minimum degree ordering on the explicit elimination graph (see ordering.hpp).
#include "ordering.hpp"

#include <algorithm>
#include <utility>

#include "arrays.hpp"

namespace relmap {

std::vector<int64_t> minimum_degree(int64_t n, int64_t m, const int64_t* a, const int64_t* b) {
    // Adjacency of supervariables (sets of indistinguishable nodes, named by a representative)
    // as sorted vectors without duplicates or self-loops.
    std::vector<std::vector<int64_t>> adj(n), members(n);
    for (int64_t e = 0; e < m; ++e)
        if (a[e] != b[e]) {
            adj[a[e]].push_back(b[e]);
            adj[b[e]].push_back(a[e]);
        }
    for (int64_t v = 0; v < n; ++v) {
        std::sort(adj[v].begin(), adj[v].end());
        adj[v].erase(std::unique(adj[v].begin(), adj[v].end()), adj[v].end());
        members[v].assign(1, v);
    }
    std::vector<int64_t> weight(n, 1), degree(n, 0);
    // external degree: the number of nodes adjacent to the supervariable
    auto external = [&](int64_t v) {
        int64_t d = 0;
        for (int64_t u : adj[v]) d += weight[u];
        return d;
    };
    // Degree lists (doubly linked, O(1) moves): head[d] is a supervariable of degree d.
    std::vector<int64_t> head(n + 1, -1), next(n, -1), prev(n, -1);
    int64_t least = n, alive = n;
    auto insert = [&](int64_t v, int64_t d) {
        degree[v] = d;
        prev[v] = -1;
        next[v] = head[d];
        if (head[d] >= 0) prev[head[d]] = v;
        head[d] = v;
        least = std::min(least, d);
    };
    auto remove = [&](int64_t v) {
        if (prev[v] >= 0)
            next[prev[v]] = next[v];
        else
            head[degree[v]] = next[v];
        if (next[v] >= 0) prev[next[v]] = prev[v];
    };
    for (int64_t v = n - 1; v >= 0; --v) insert(v, external(v));  // lowest index first
    std::vector<char> done(n, 0);
    std::vector<int64_t> order, merged, changed, touched(n, -1);
    std::vector<std::pair<int64_t, int64_t>> keyed;  // (neighbourhood sum, supervariable)
    order.reserve(n);
    // Multiple elimination (J. W. H. Liu, ACM TOMS 11, 1985): each round eliminates
    // supervariables of the round's least degree that are not neighbours of one eliminated in
    // the same round; then indistinguishable neighbours merge and degrees are updated.
    for (int64_t round = 0; alive > 0; ++round) {
        while (head[least] < 0) ++least;
        changed.clear();
        for (int64_t v = head[least], after; v != -1; v = after) {
            after = next[v];  // elimination below moves no other supervariable between lists
            if (touched[v] == round) continue;  // a neighbour of this round's: degree changes
            remove(v);
            --alive;
            done[v] = 1;
            order.insert(order.end(), members[v].begin(), members[v].end());
            const std::vector<int64_t> clique = std::move(adj[v]);
            adj[v].clear();
            // Each neighbour u: N(u) ← (N(u) ∪ N(v)) \ {u, v}, by one merge of sorted lists.
            for (int64_t u : clique) {
                if (touched[u] != round) changed.push_back(u);
                touched[u] = round;
                const std::vector<int64_t>& nu = adj[u];
                merged.clear();
                auto i = nu.begin(), j = clique.begin();
                while (i != nu.end() || j != clique.end()) {
                    int64_t x;
                    if (j == clique.end() || (i != nu.end() && *i < *j)) {
                        x = *i++;
                    } else if (i == nu.end() || *j < *i) {
                        x = *j++;
                    } else {
                        x = *i++;
                        ++j;
                    }
                    if (x != u && x != v) merged.push_back(x);
                }
                adj[u].swap(merged);  // no copy: merged takes over u's old list's storage
            }
        }
        // Indistinguishable neighbours (equal closed neighbourhoods) become one supervariable.
        // Candidates are grouped by the sum of their closed neighbourhood (equal for equal
        // sets), sorted so that the result does not depend on a hash table's order.
        keyed.clear();
        for (int64_t u : changed) {
            if (done[u]) continue;
            int64_t h = u;
            for (int64_t x : adj[u]) h += x;
            keyed.emplace_back(h, u);
        }
        std::sort(keyed.begin(), keyed.end());
        for (size_t g0 = 0, g1; g0 < keyed.size(); g0 = g1) {
            for (g1 = g0 + 1; g1 < keyed.size() && keyed[g1].first == keyed[g0].first;) ++g1;
            for (size_t p = g0; p < g1; ++p) {
                const int64_t u = keyed[p].second;
                if (done[u]) continue;
                for (size_t q = p + 1; q < g1; ++q) {
                    const int64_t x = keyed[q].second;
                    if (done[x] || adj[x].size() != adj[u].size()) continue;
                    // closed neighbourhoods equal: N(u) \ {x} == N(x) \ {u}, u ∈ N(x)
                    if (!std::binary_search(adj[x].begin(), adj[x].end(), u)) continue;
                    bool same = true;
                    auto i = adj[u].begin(), j = adj[x].begin();
                    while (same && (i != adj[u].end() || j != adj[x].end())) {
                        if (i != adj[u].end() && *i == x) { ++i; continue; }
                        if (j != adj[x].end() && *j == u) { ++j; continue; }
                        same = i != adj[u].end() && j != adj[x].end() && *i == *j;
                        ++i;
                        ++j;
                    }
                    if (!same) continue;
                    done[x] = 1;  // absorbed into u
                    remove(x);
                    --alive;
                    weight[u] += weight[x];
                    members[u].insert(members[u].end(), members[x].begin(), members[x].end());
                    for (int64_t y : adj[x]) {
                        auto& ny = adj[y];
                        ny.erase(std::lower_bound(ny.begin(), ny.end(), x));
                    }
                    adj[x].clear();
                }
            }
        }
        for (int64_t u : changed)  // the neighbours of this round's nodes: new degrees
            if (!done[u]) {
                remove(u);
                insert(u, external(u));
            }
    }
    return order;
}

std::vector<int64_t> components(int64_t n, int64_t m, const int64_t* a, const int64_t* b) {
    std::vector<int64_t> parent(n), size(n, 1);
    for (int64_t v = 0; v < n; ++v) parent[v] = v;
    auto find = [&](int64_t v) {
        while (parent[v] != v) v = parent[v] = parent[parent[v]];
        return v;
    };
    for (int64_t e = 0; e < m; ++e) {
        int64_t x = find(a[e]), y = find(b[e]);
        if (x == y) continue;
        if (size[x] < size[y]) std::swap(x, y);
        parent[y] = x;
        size[x] += size[y];
    }
    std::vector<int64_t> label(n), of_root(n, -1);
    int64_t count = 0;
    for (int64_t v = 0; v < n; ++v) {
        int64_t& l = of_root[find(v)];
        if (l < 0) l = count++;
        label[v] = l;
    }
    return label;
}

void register_ordering(nb::module_& m) {
    m.def(
        "minimum_degree",
        [](int64_t n, Index1 a, Index1 b) {
            const int64_t count = static_cast<int64_t>(a.shape(0));
            if (static_cast<int64_t>(b.shape(0)) != count)
                throw nb::value_error("a and b must have the same length");
            for (int64_t e = 0; e < count; ++e)
                if (a.data()[e] < 0 || a.data()[e] >= n || b.data()[e] < 0 || b.data()[e] >= n)
                    throw nb::value_error("edge end out of range");
            std::vector<int64_t> order;
            {
                nb::gil_scoped_release unlocked;
                order = minimum_degree(n, count, a.data(), b.data());
            }
            return vector_array(order);
        },
        nb::arg("n"), nb::arg("a"), nb::arg("b"),
        "Multiple minimum degree ordering (new → old) of the graph with n nodes and edges "
        "(a, b).");
    m.def(
        "components",
        [](int64_t n, Index1 a, Index1 b) {
            const int64_t count = static_cast<int64_t>(a.shape(0));
            if (n < 0 || static_cast<int64_t>(b.shape(0)) != count)
                throw nb::value_error("n >= 0, and a and b of the same length");
            for (int64_t e = 0; e < count; ++e)
                if (a.data()[e] < 0 || a.data()[e] >= n || b.data()[e] < 0 || b.data()[e] >= n)
                    throw nb::value_error("edge end out of range");
            return vector_array(components(n, count, a.data(), b.data()));
        },
        nb::arg("n"), nb::arg("a"), nb::arg("b"),
        "Connected components of the graph with n nodes and edges (a, b): a label per node, "
        "0, 1, … in order of each component's lowest node.");
}

}  // namespace relmap
