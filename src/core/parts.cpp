// The list of the core's parts: each part's register function is declared and called here.
#include "core.hpp"

namespace relmap {

void register_parts(nb::module_& m) { (void)m; }

}  // namespace relmap
