// SE(3) compounding and reversal with first-order covariance, batched (relmap.uncertain.at3).
#pragma once

#include "core.hpp"

namespace relmap {

// Registers compound3 and reverse3 (see se3.cpp).
void register_se3(nb::module_& m);

}  // namespace relmap
