// relmap._core: the bindings of relmap's compiled core (one module, one place).
//
// Each part of the core lives in a source file of its own with a header, and registers its
// functions here through a `register_<part>(nb::module_&)` function declared in core.hpp.
#include "core.hpp"

NB_MODULE(_core, m) {
    m.doc() = "relmap's compiled core: the loops numpy cannot vectorize (internal; use relmap's "
              "Python API).";
    m.attr("__version__") = RELMAP_CORE_VERSION;
    relmap::register_parts(m);
}
