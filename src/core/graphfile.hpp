// Text of pose-graph files (relmap.io.posegraph): records written with the shortest decimal
// form of each number that reads back to the same double (std::to_chars), one record a line.
#pragma once

#include "core.hpp"

namespace relmap {

void register_graphfile(nb::module_& m);

}  // namespace relmap
