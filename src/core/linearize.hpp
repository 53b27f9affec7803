// The Gauss-Newton normal equations of a planar pose graph: for each measurement k between
// frames i and j, with information W_k (Σ_k⁻¹, times the k-th robust weight when the caller
// has one), the residual d = p_i⁻¹ ∘ p_j, r = d ⊟ z in relmap's chart (heading wrapped as
// relmap.lie.se2.wrap_angle; residuals2) and its Jacobians J_i, J_j give
//   cost += r_kᵀ W_k r_k,  H_ab += J_aᵀ W_k J_b (a, b ∈ {i, j}),  g_a += J_aᵀ W_k r_k,
// added straight into the CSC data of the normal matrix and into the gradient, so that a
// Gauss-Newton iteration is one pass over the measurements (normal_equations2).
#pragma once

#include <cstdint>

#include "core.hpp"

namespace relmap {

void register_linearize(nb::module_& m);

}  // namespace relmap
