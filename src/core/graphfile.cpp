// Records of pose-graph files as text (see graphfile.hpp).
#include "graphfile.hpp"

#include <charconv>
#include <cstdint>
#include <string>

#include <nanobind/stl/string.h>

#include "arrays.hpp"

namespace relmap {

namespace {

// "TAG id … id v … v\n" for every row: ids as integers, values in their shortest round-trip
// decimal form (std::to_chars without a precision: reading the text gives the same doubles).
std::string format_records(const std::string& tag, const Index2& ids, const Float2& values) {
    const size_t k = ids.shape(0), a = ids.shape(1), b = values.shape(1);
    std::string out;
    out.reserve(k * (tag.size() + 12 * a + 24 * b + 1));
    char buf[64];
    for (size_t r = 0; r < k; ++r) {
        out += tag;
        for (size_t c = 0; c < a; ++c) {
            auto res = std::to_chars(buf, buf + sizeof buf, ids.data()[r * a + c]);
            out += ' ';
            out.append(buf, res.ptr);
        }
        for (size_t c = 0; c < b; ++c) {
            auto res = std::to_chars(buf, buf + sizeof buf, values.data()[r * b + c]);
            out += ' ';
            out.append(buf, res.ptr);
        }
        out += '\n';
    }
    return out;
}

}  // namespace

void register_graphfile(nb::module_& m) {
    m.def(
        "format_records",
        [](const std::string& tag, Index2 ids, Float2 values) {
            if (ids.shape(0) != values.shape(0))
                throw nb::value_error("ids and values need one row per record");
            std::string text;
            {
                nb::gil_scoped_release unlocked;
                text = format_records(tag, ids, values);
            }
            return nb::str(text.data(), text.size());
        },
        nb::arg("tag"), nb::arg("ids"), nb::arg("values"),
        "The lines 'tag id … v …' of the records, ids (k, a) int64, values (k, b) float64 in "
        "their shortest round-trip decimal form; each line ends with a newline.");
}

}  // namespace relmap
