// A filter's association search: which landmark of the map each of its m readings is of, given
// the pairs' costs (greedy one-to-one pairing) or the pairs' innovations and the filter's
// Gaussian (joint compatibility branch and bound, JCBB: J. Neira & J. D. Tardós, "Data
// association in stochastic mapping using the joint compatibility test", IEEE Trans. Robotics
// and Automation 17(6), 2001). The costs, innovations, Jacobians and gates come from the
// caller (numpy, batched over filters); here is only the search numpy cannot vectorize. A
// reading's result is a landmark index (0..L-1) or -1 for none.
#pragma once

#include <cstdint>
#include <vector>

#include "core.hpp"

namespace relmap::association {

// The scratch of pair_one_to_one (reused from one filter to the next).
struct PairingScratch {
    std::vector<char> taken;
    std::vector<int64_t> best;
    std::vector<double> least;
};

// Greedy one-to-one pairing of one filter, cheapest pair first: cost (m × L, row-major) of
// pairing reading i with landmark l, a candidate if < +inf (+inf and NaN: none); inside (m × L,
// read only when split) whether the pair lies inside the χ² gate. The candidates in increasing
// (cost, i, l), a pair taken when its reading is still unpaired and its landmark still untaken;
// with split, first the pairs inside the gate, then those outside. Writes landmark (m).
void pair_one_to_one(int64_t m, int64_t L, const double* cost, const bool* inside, bool split,
                     int64_t* landmark, PairingScratch& scratch);

// One filter's JCBB problem (row-major arrays): v (m × L × d) the pairs' innovations, H (L × d ×
// n) and R (L × d × d) each landmark's predicted reading's Jacobian and noise, P (n × n) the
// filter's covariance, d2 (m × L) each pair's own d², inside (m × L) the individually
// compatible pairs; gate2 (K) the joint gate of k pairs at index k (+inf from K on); at most
// max_nodes search nodes.
struct JcbbProblem {
    int64_t m, L, d, n;
    const double *v, *H, *R, *P, *d2;
    const bool* inside;
    const double* gate2;
    int64_t K, max_nodes;
};

// The largest jointly compatible one-to-one set of individually compatible pairs (of equally
// large ones the least joint d²): writes landmark (m).
void jcbb(const JcbbProblem& problem, int64_t* landmark);

}  // namespace relmap::association

namespace relmap {

void register_association(nb::module_& m);

}  // namespace relmap
