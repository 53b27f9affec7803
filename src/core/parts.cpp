// The list of the core's parts: each part's register function is declared and called here.
#include "core.hpp"
#include "association.hpp"
#include "blocks.hpp"
#include "graphfile.hpp"
#include "linearize.hpp"
#include "linearize3.hpp"
#include "ordering.hpp"
#include "se3.hpp"
#include "sparse_chol.hpp"

namespace relmap {

void register_parts(nb::module_& m) {
    register_se3(m);
    register_sparse_chol(m);
    register_blocks(m);
    register_ordering(m);
    register_linearize(m);
    register_linearize3(m);
    register_association(m);
    register_graphfile(m);
}

}  // namespace relmap
