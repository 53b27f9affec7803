// The list of the core's parts: each part's register function is declared and called here.
#include "core.hpp"
#include "se3.hpp"

namespace relmap {

void register_parts(nb::module_& m) {
    register_se3(m);
}

}  // namespace relmap
