// The Gauss-Newton normal equations of a pose graph from its residuals and chart Jacobians:
// for each measurement k between frames i and j, with information W_k = Σ_k⁻¹,
//   cost += r_kᵀ W_k r_k,  H_ab += J_aᵀ W_k J_b (a, b ∈ {i, j}),  g_a += J_aᵀ W_k r_k,
// added straight into the CSC data of the normal matrix and into the gradient (one pass, no
// per-block temporaries). The residuals and Jacobians of 3-D graphs come from the caller; those
// of planar graphs are computed here too (residuals2, normal_equations2: d = p_i⁻¹ ∘ p_j,
// r = d ⊟ z in relmap's chart, heading wrapped as relmap.lie.se2.wrap_angle), so that a
// Gauss-Newton iteration of a planar graph is one pass over its measurements.
#pragma once

#include <cstdint>

#include "core.hpp"

namespace relmap {

void register_linearize(nb::module_& m);

}  // namespace relmap
