// Records of pose-graph files as text (see graphfile.hpp).
#include "graphfile.hpp"

#include <charconv>
#include <cstdint>
#include <map>
#include <string>
#include <string_view>
#include <vector>

#include <nanobind/stl/string.h>
#include <nanobind/stl/string_view.h>
#include <nanobind/stl/vector.h>

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

// ------------------------------------------------------------------------------------ reading
// Python's str.split() separators among the bytes the fast path accepts; any other control byte,
// and any non-ASCII byte (Unicode has more separators), sends the text to the plain path.
inline bool space(char c) { return c == ' ' || c == '\t' || c == '\r' || c == '\v' || c == '\f'; }
inline bool exotic(unsigned char c) {
    return c >= 0x80 || (c < 0x20 && c != '\n' && c != '\t' && c != '\r' && c != '\v' && c != '\f');
}

struct Cursor {
    const char* p;
    const char* end;
    // The next token, or an empty view at the end of the line.
    std::string_view next() {
        while (p < end && space(*p)) ++p;
        const char* start = p;
        while (p < end && !space(*p)) ++p;
        return {start, static_cast<size_t>(p - start)};
    }
};

// A sign '+' is accepted as Python accepts it, once ("+-2" is not a number).
inline bool strip_plus(std::string_view& tok) {
    if (!tok.empty() && tok[0] == '+') {
        tok.remove_prefix(1);
        if (tok.empty() || tok[0] == '+' || tok[0] == '-') return false;
    }
    return !tok.empty();
}

bool parse_int(std::string_view tok, int64_t& out) {
    if (!strip_plus(tok)) return false;
    auto res = std::from_chars(tok.data(), tok.data() + tok.size(), out);
    return res.ec == std::errc() && res.ptr == tok.data() + tok.size();
}

// A decimal number as Python's float reads it (no digit separators, no "nan(…)" payloads).
bool parse_double(std::string_view tok, double& out) {
    if (!strip_plus(tok) || tok.find('(') != tok.npos) return false;
    auto res = std::from_chars(tok.data(), tok.data() + tok.size(), out);
    return res.ec == std::errc() && res.ptr == tok.data() + tok.size();
}

struct Table {
    std::vector<int64_t> lines, ids;
    std::vector<double> values;
};

// Records of the given tags (n_ids < 0: any positive number of ids and no values, one row per
// id, as FIX lines); false when the text needs the plain path (an exotic byte, a record that
// does not parse).
bool scan(std::string_view text, const std::vector<std::string>& tags,
          const std::vector<int64_t>& n_ids, const std::vector<int64_t>& n_values,
          std::map<std::string, int64_t>& first, std::vector<Table>& tables) {
    for (char c : text)
        if (exotic(static_cast<unsigned char>(c))) return false;
    const char* p = text.data();
    const char* end = p + text.size();
    int64_t line = 0;
    while (p <= end) {
        ++line;
        const char* eol = p;
        while (eol < end && *eol != '\n') ++eol;
        Cursor cur{p, eol};
        p = eol + 1;
        const std::string_view tag = cur.next();
        if (tag.empty() || tag[0] == '#') continue;
        std::string name(tag);
        first.emplace(name, line);
        size_t t = 0;
        while (t < tags.size() && tags[t] != name) ++t;
        if (t == tags.size()) continue;
        Table& table = tables[t];
        if (n_ids[t] < 0) {
            size_t count = 0;
            for (std::string_view tok = cur.next(); !tok.empty(); tok = cur.next(), ++count) {
                int64_t id;
                if (!parse_int(tok, id)) return false;
                table.ids.push_back(id);
                table.lines.push_back(line);
            }
            if (!count) return false;
            continue;
        }
        table.lines.push_back(line);
        for (int64_t k = 0; k < n_ids[t]; ++k) {
            int64_t id;
            if (!parse_int(cur.next(), id)) return false;
            table.ids.push_back(id);
        }
        for (int64_t k = 0; k < n_values[t]; ++k) {
            double v;
            if (!parse_double(cur.next(), v)) return false;
            table.values.push_back(v);
        }
        if (!cur.next().empty()) return false;
    }
    return true;
}

}  // namespace

void register_graphfile(nb::module_& m) {
    m.def(
        "scan_records",
        [](std::string_view text, std::vector<std::string> tags, std::vector<int64_t> n_ids,
           std::vector<int64_t> n_values) -> nb::object {
            if (n_ids.size() != tags.size() || n_values.size() != tags.size())
                throw nb::value_error("one id count and one value count per tag");
            std::map<std::string, int64_t> first;
            std::vector<Table> tables(tags.size());
            bool ok;
            {
                nb::gil_scoped_release unlocked;
                ok = scan(text, tags, n_ids, n_values, first, tables);
            }
            if (!ok) return nb::none();
            nb::dict lines;
            for (const auto& [tag, line] : first) lines[nb::str(tag.data(), tag.size())] = line;
            nb::list out;
            for (size_t t = 0; t < tags.size(); ++t) {
                const Table& table = tables[t];
                const size_t k = table.lines.size();
                const size_t a = n_ids[t] < 0 ? 1 : static_cast<size_t>(n_ids[t]);
                const size_t b = n_ids[t] < 0 ? 0 : static_cast<size_t>(n_values[t]);
                auto ln = new_array<int64_t>({k});
                auto ids = new_array<int64_t>({k, a});
                auto values = new_array<double>({k, b});
                std::copy(table.lines.begin(), table.lines.end(), ln.data());
                std::copy(table.ids.begin(), table.ids.end(), ids.data());
                std::copy(table.values.begin(), table.values.end(), values.data());
                out.append(nb::make_tuple(ln, ids, values));
            }
            return nb::make_tuple(lines, out);
        },
        nb::arg("text"), nb::arg("tags"), nb::arg("n_ids"), nb::arg("n_values"),
        "The records of a pose-graph text: ({tag: first line} of every tag, [(lines (k,), ids "
        "(k, n_ids), values (k, n_values)) per requested tag]); n_ids < 0 takes any positive "
        "number of ids per line, one row each. None when the text needs the plain path: a "
        "record of a requested tag that does not parse, a non-ASCII or control byte.");
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
