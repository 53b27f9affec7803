// Array types of the core's bindings: read-only C-contiguous CPU inputs with fixed dtype and
// rank (nanobind copies an array of another dtype or layout; the Python layer passes the right
// ones), and new NumPy arrays owned by a capsule.
#pragma once

#include <cstdint>
#include <initializer_list>
#include <string>
#include <vector>

#include "core.hpp"
#include "dense.hpp"

namespace relmap {

using Index1 = nb::ndarray<const int64_t, nb::ndim<1>, nb::c_contig, nb::device::cpu>;
using Index2 = nb::ndarray<const int64_t, nb::ndim<2>, nb::c_contig, nb::device::cpu>;
using Float1 = nb::ndarray<const double, nb::ndim<1>, nb::c_contig, nb::device::cpu>;
using Float2 = nb::ndarray<const double, nb::ndim<2>, nb::c_contig, nb::device::cpu>;
using Float3 = nb::ndarray<const double, nb::ndim<3>, nb::c_contig, nb::device::cpu>;

// A new zero-filled NumPy array of the given shape.
template <class T = double>
nb::ndarray<nb::numpy, T> new_array(std::initializer_list<size_t> shape) {
    size_t size = 1;
    for (size_t s : shape) size *= s;
    T* data = new T[size ? size : 1]();
    nb::capsule owner(data, [](void* p) noexcept { delete[] static_cast<T*>(p); });
    return nb::ndarray<nb::numpy, T>(data, shape, owner);
}

// Arrays of any rank (a batch of vectors or matrices: the leading axes are the batch).
using FloatN = nb::ndarray<const double, nb::c_contig, nb::device::cpu>;
using IndexN = nb::ndarray<const int64_t, nb::c_contig, nb::device::cpu>;
using BoolN = nb::ndarray<const bool, nb::c_contig, nb::device::cpu>;

// A new NumPy array of the shape of a's first `lead` axes, then `tail`, read-only to Python (a
// result: relmap's values are immutable, and Python need not make a read-only view of it);
// `data` writes it. Not initialized: the caller writes every entry (a zero fill first showed
// in the profile of a batch of filters stepped from Python).
template <class T>
struct Result {
    nb::ndarray<nb::numpy, const T> array;
    T* data;
};
template <class T = double, class A>
Result<T> new_result_like(const A& a, size_t lead, std::initializer_list<size_t> tail = {}) {
    std::vector<size_t> shape;
    for (size_t k = 0; k < lead; ++k) shape.push_back(a.shape(k));
    shape.insert(shape.end(), tail.begin(), tail.end());
    size_t size = 1;
    for (size_t s : shape) size *= s;
    T* data = new T[size ? size : 1];
    nb::capsule owner(data, [](void* p) noexcept { delete[] static_cast<T*>(p); });
    return {nb::ndarray<nb::numpy, const T>(data, shape.size(), shape.data(), owner), data};
}

// Raises relmap.errors.<name>(message): the error relmap's Python API promises for bad input,
// when the core is where the input is first looked at.
[[noreturn]] inline void raise_relmap_error(const char* name, const std::string& message) {
    nb::object kind = nb::module_::import_("relmap.errors").attr(name);
    PyErr_SetString(kind.ptr(), message.c_str());
    throw nb::python_error();
}

// The normal equations' scatter targets in range (or ValueError): n_slots slots into the CSC
// data of nnz entries (nnz: the spill slot) and n_g gradient indices into size (size: spill).
inline void check_targets(const int64_t* slots, int64_t n_slots, const int64_t* g_index,
                          int64_t n_g, int64_t nnz, int64_t size) {
    if (!dense::all_within(slots, n_slots, nnz)) throw nb::value_error("slot out of range");
    if (!dense::all_within(g_index, n_g, size))
        throw nb::value_error("gradient index out of range");
}

// A NumPy copy of a vector.
template <class T>
nb::ndarray<nb::numpy, T> vector_array(const std::vector<T>& v) {
    auto out = new_array<T>({v.size()});
    std::copy(v.begin(), v.end(), out.data());
    return out;
}

// A NumPy array that takes over a vector's storage (no copy).
template <class T>
nb::ndarray<nb::numpy, T> owned_array(std::vector<T>&& v) {
    auto* owned = new std::vector<T>(std::move(v));
    nb::capsule owner(owned, [](void* p) noexcept { delete static_cast<std::vector<T>*>(p); });
    return nb::ndarray<nb::numpy, T>(owned->data(), {owned->size()}, owner);
}

}  // namespace relmap
