// The residuals and chart Jacobians of a 3-D pose graph (relmap.network.optimal, SE(3)):
// for each measurement k of frame j seen from frame i,
//   d = T_i⁻¹ T_j,  r_k = d ⊟ z_k = (t_d - t_z, Log(R_d R_zᵀ)),
//   J_i = ∂r/∂δ_i = -Jr blkdiag(R_iᵀ, R_iᵀ) [[I, -[t_j - t_i]×], [0, I]],
//   J_j = ∂r/∂δ_j =  Jr blkdiag(R_iᵀ, R_iᵀ),  Jr = blkdiag(I, J_l(r_φ)⁻¹),
// in relmap's chart on both sides (a pose moves as T ⊞ δ = (t + δt, Exp(δφ) R), lie/se3.py).
// The normal equations are accumulated in the same pass (normal_equations3), by blocks.
#pragma once

#include "core.hpp"

namespace relmap {

void register_linearize3(nb::module_& m);

}  // namespace relmap
