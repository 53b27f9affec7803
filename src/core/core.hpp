// Shared declarations of relmap's compiled core.
#pragma once

#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>

#define RELMAP_CORE_VERSION "1"

namespace nb = nanobind;

namespace relmap {

// Registers every part of the core on the module (parts.cpp lists them).
void register_parts(nb::module_& m);

}  // namespace relmap
