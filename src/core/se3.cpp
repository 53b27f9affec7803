// SE(3) compounding and reversal with first-order covariance over a batch (relmap.uncertain.at3).
//
// Conventions (relmap.uncertain.at3, docs/architecture.md): a pose is a homogeneous 4×4 matrix, its
// covariance 6×6 on (δt, δφ): translation perturbation in the parent frame, rotation
// perturbation on the left, T' = (t + δt, Exp(δφ) R). Batches arrive entry-major, as relmap
// stores them: poses (4, 4, N), covariances (6, 6, N), any strides (a stride of 0 broadcasts one
// input against the batch); outputs are new C-contiguous (4, 4, N) and (6, 6, N) arrays.
//
// The Jacobians' structure is used, not 6×6 products: compounding's J_a = [[I, S], [0, I]]
// with S = -[R_a t_b]× is a shear, J_b = blkdiag(R_a, R_a) a rotation; the reversal's
// J = -blkdiag(Rᵀ, Rᵀ) [[I, [t]×], [0, I]] a shear and a rotation (its sign cancels). Output
// covariances are exactly symmetric (diagonal blocks averaged with their transposes).
//
// The batch is worked on in chunks of W elements, each quantity a row of W lanes (the layout
// relmap stores), so that every loop below runs over lanes and the compiler vectorizes it.
#include "se3.hpp"

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <initializer_list>
#include <memory>
#include <optional>

#include <nanobind/stl/optional.h>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include "dense.hpp"  // RELMAP_MULTIVERSION

namespace relmap {
namespace {

using Pose = nb::ndarray<const double, nb::shape<4, 4, -1>, nb::device::cpu>;
using Cov = nb::ndarray<const double, nb::shape<6, 6, -1>, nb::device::cpu>;
using PoseOut = nb::ndarray<nb::numpy, double, nb::shape<4, 4, -1>, nb::c_contig>;
using CovOut = nb::ndarray<nb::numpy, double, nb::shape<6, 6, -1>, nb::c_contig>;

// Batch elements per chunk (lanes). Each chunk reads about a hundred entry planes of the batch
// at once; long runs per plane (2 KB here) keep the hardware prefetchers streaming, which
// measured 2.3× faster per pair than chunks of 32 lanes (bench_se3.py). Contiguous inputs are
// read in place (In3); a chunk's computed blocks (9 × 9 × W doubles, 166 KB) and the copies of
// inputs that cannot be read in place live in a per-thread workspace on the heap.
constexpr size_t W = 256;

using Lanes = double[W];
struct M3 {  // a 3×3 block of W elements, row-major: m[3 i + j][lane]
    Lanes m[9];
};
struct V3 {
    Lanes v[3];
};

// An input's 3×3 block or 3-vector of one chunk, read in place: m[3 i + j][lane] (lanes
// contiguous). Inputs whose batch axis is contiguous are read where they are; others (strided,
// broadcast, or a chunk that is not a whole number of vectors) are first copied into a block of
// the workspace (see view).
struct In3 {
    const double* m[9];
};
struct InV {
    const double* v[3];
};

// The blocks of one chunk: allocated once per thread, reused by every call; `in` holds the
// copies of inputs that cannot be read in place.
struct Work {
    M3 m[9];
    V3 v[1];
    M3 in[10];
    V3 in_v[2];
    Lanes nan;  // the overflow watch of the outputs (see watch)
};

Work& workspace() {
    thread_local std::unique_ptr<Work> work;
    if (!work) work.reset(new Work);
    return *work;
}

// The lanes a chunk of w elements computes: w rounded up to a multiple of 8 (whole vectors), so
// that one pair costs a few lanes, not a whole chunk.
inline size_t lanes(size_t w) { return std::min(W, (w + 7) & ~size_t(7)); }

// Rows (r0..r0+3, c0..c0+3) of a chunk of an entry-major (R, C, N) array (any strides) into a
// 3×3 block; lanes beyond w (up to lanes(w)) are zero.
template <class A>
void load(const A& a, size_t r0, size_t c0, size_t n0, size_t w, M3& out) {
    const double* p = a.data();
    const int64_t s0 = a.stride(0), s1 = a.stride(1), s2 = a.stride(2);
    for (size_t i = 0; i < 3; ++i)
        for (size_t j = 0; j < 3; ++j) {
            const double* q = p + int64_t(r0 + i) * s0 + int64_t(c0 + j) * s1 + int64_t(n0) * s2;
            double* o = out.m[3 * i + j];
            if (s2 == 1)
                std::copy(q, q + w, o);
            else
                for (size_t l = 0; l < w; ++l) o[l] = q[int64_t(l) * s2];
            std::fill(o + w, o + lanes(w), 0.0);
        }
}

template <class A>
void load_column(const A& a, size_t c, size_t n0, size_t w, V3& out) {
    const double* p = a.data();
    const int64_t s0 = a.stride(0), s1 = a.stride(1), s2 = a.stride(2);
    for (size_t i = 0; i < 3; ++i) {
        const double* q = p + int64_t(i) * s0 + int64_t(c) * s1 + int64_t(n0) * s2;
        if (s2 == 1)
            std::copy(q, q + w, out.v[i]);
        else
            for (size_t l = 0; l < w; ++l) out.v[i][l] = q[int64_t(l) * s2];
        std::fill(out.v[i] + w, out.v[i] + lanes(w), 0.0);
    }
}

// Rows (r0..r0+3, c0..c0+3) of a chunk as an input block: in place where the batch axis is
// contiguous and the chunk is whole vectors (no padding lanes to zero), else copied into spare.
template <class A>
In3 view(const A& a, size_t r0, size_t c0, size_t n0, size_t w, M3& spare) {
    In3 out;
    if (a.stride(2) == 1 && lanes(w) == w) {
        const double* p = a.data() + int64_t(n0);
        for (size_t i = 0; i < 3; ++i)
            for (size_t j = 0; j < 3; ++j)
                out.m[3 * i + j] = p + int64_t(r0 + i) * a.stride(0) + int64_t(c0 + j) * a.stride(1);
        return out;
    }
    load(a, r0, c0, n0, w, spare);
    for (size_t k = 0; k < 9; ++k) out.m[k] = spare.m[k];
    return out;
}

template <class A>
InV view_column(const A& a, size_t c, size_t n0, size_t w, V3& spare) {
    InV out;
    if (a.stride(2) == 1 && lanes(w) == w) {
        const double* p = a.data() + int64_t(n0) + int64_t(c) * a.stride(1);
        for (size_t i = 0; i < 3; ++i) out.v[i] = p + int64_t(i) * a.stride(0);
        return out;
    }
    load_column(a, c, n0, w, spare);
    for (size_t i = 0; i < 3; ++i) out.v[i] = spare.v[i];
    return out;
}

// A chunk's lanes into an output plane. The outputs are new arrays, written once and not read
// here: non-temporal (streaming) stores where the machine has them, so that writing them does not
// first read their cache lines from memory (a third of the traffic of a compound).
inline void put(double* out, size_t N, size_t entry, size_t n0, size_t w, const double* lanes) {
    double* o = out + entry * N + n0;
#if defined(__SSE2__)
    size_t l = 0;
    if (reinterpret_cast<uintptr_t>(o) % 16 != 0 && w > 0) {  // to a 16-byte boundary
        o[0] = lanes[0];
        l = 1;
    }
    for (; l + 2 <= w; l += 2) _mm_stream_pd(o + l, _mm_loadu_pd(lanes + l));
    if (l < w) o[l] = lanes[l];
#else
    std::copy(lanes, lanes + w, o);
#endif
}

template <class A, class B>
inline void mul(size_t n, const A& a, const B& b, M3& o) {  // o = a b (o distinct from a, b)
    for (size_t i = 0; i < 3; ++i)
        for (size_t j = 0; j < 3; ++j)
            for (size_t l = 0; l < n; ++l)
                o.m[3 * i + j][l] = a.m[3 * i][l] * b.m[j][l] + a.m[3 * i + 1][l] * b.m[3 + j][l] +
                                    a.m[3 * i + 2][l] * b.m[6 + j][l];
}

template <class A, class B>
inline void mul_t(size_t n, const A& a, const B& b, M3& o) {  // o = a bᵀ
    for (size_t i = 0; i < 3; ++i)
        for (size_t j = 0; j < 3; ++j)
            for (size_t l = 0; l < n; ++l)
                o.m[3 * i + j][l] = a.m[3 * i][l] * b.m[3 * j][l] +
                                    a.m[3 * i + 1][l] * b.m[3 * j + 1][l] +
                                    a.m[3 * i + 2][l] * b.m[3 * j + 2][l];
}

template <class A, class B>
inline void t_mul(size_t n, const A& a, const B& b, M3& o) {  // o = aᵀ b
    for (size_t i = 0; i < 3; ++i)
        for (size_t j = 0; j < 3; ++j)
            for (size_t l = 0; l < n; ++l)
                o.m[3 * i + j][l] = a.m[i][l] * b.m[j][l] + a.m[3 + i][l] * b.m[3 + j][l] +
                                    a.m[6 + i][l] * b.m[6 + j][l];
}

template <class B>
inline void add_to(size_t n, M3& a, const B& b) {  // a += b
    for (size_t k = 0; k < 9; ++k)
        for (size_t l = 0; l < n; ++l) a.m[k][l] += b.m[k][l];
}

inline void add_t_to(size_t n, M3& a, const M3& b) {  // a += bᵀ
    for (size_t i = 0; i < 3; ++i)
        for (size_t j = 0; j < 3; ++j)
            for (size_t l = 0; l < n; ++l) a.m[3 * i + j][l] += b.m[3 * j + i][l];
}

template <class V>
inline void hat(size_t n, const V& u, double sign, M3& o) {  // o = sign [u]×
    for (size_t l = 0; l < n; ++l) {
        o.m[0][l] = o.m[4][l] = o.m[8][l] = 0.0;
        o.m[1][l] = -sign * u.v[2][l];
        o.m[2][l] = sign * u.v[1][l];
        o.m[3][l] = sign * u.v[2][l];
        o.m[5][l] = -sign * u.v[0][l];
        o.m[6][l] = -sign * u.v[1][l];
        o.m[7][l] = sign * u.v[0][l];
    }
}

// R M Rᵀ (rotate, R_left = false: Rᵀ M R) into o; tmp is scratch.
template <class Rot, class Mat>
inline void rotate(size_t n, const Rot& R, const Mat& M, bool transpose, M3& tmp, M3& o) {
    if (transpose) {
        t_mul(n, R, M, tmp);
        mul(n, tmp, R, o);
    } else {
        mul(n, R, M, tmp);
        mul_t(n, tmp, R, o);
    }
}

// The shear [[I, S], [0, I]] C [[I, S], [0, I]]ᵀ of C = [[A, B], [Bᵀ, D]]: its block (0, 1)
// B + S D into e, then (0, 0) A + S Bᵀ + e Sᵀ into a; block (1, 1) stays D. tmp is scratch.
template <class Ab, class Bb, class Db>
inline void shear(size_t n, const M3& S, const Ab& A, const Bb& B, const Db& D, M3& tmp, M3& a,
                  M3& e) {
    mul(n, S, D, e);
    add_to(n, e, B);
    mul_t(n, S, B, a);
    add_to(n, a, A);
    mul_t(n, e, S, tmp);
    add_to(n, a, tmp);
}

// Adds x·0 of every lane of the blocks to `nan`: it stays 0 while they are finite, and becomes NaN
// for good at an inf or NaN (the overflow check of relmap's results, done on data in cache).
inline void watch(size_t n, Lanes& nan, const double* x, size_t count) {
    for (size_t k = 0; k < count; ++k)
        for (size_t l = 0; l < n; ++l) nan[l] += x[k * W + l] * 0.0;
}

inline bool finite(const Lanes& nan) {
    double s = 0.0;
    for (size_t l = 0; l < W; ++l) s += nan[l];
    return s == 0.0;
}

// Writes a chunk's covariances from blocks (0, 0) a, (0, 1) e, (1, 1) d; a and d (symmetric to
// rounding) averaged with their transposes so that the result is exactly symmetric.
void write_cov(double* out, size_t N, size_t n0, size_t w, const M3& a, const M3& e, const M3& d,
               Lanes& nan) {
    const size_t n = lanes(w);
    watch(n, nan, a.m[0], 9);
    watch(n, nan, e.m[0], 9);
    watch(n, nan, d.m[0], 9);
    Lanes s;
    for (size_t i = 0; i < 3; ++i)
        for (size_t j = 0; j < 3; ++j) {
            for (size_t l = 0; l < n; ++l) s[l] = 0.5 * (a.m[3 * i + j][l] + a.m[3 * j + i][l]);
            put(out, N, 6 * i + j, n0, w, s);
            for (size_t l = 0; l < n; ++l) s[l] = 0.5 * (d.m[3 * i + j][l] + d.m[3 * j + i][l]);
            put(out, N, 6 * (3 + i) + 3 + j, n0, w, s);
            put(out, N, 6 * i + 3 + j, n0, w, e.m[3 * i + j]);
            put(out, N, 6 * (3 + j) + i, n0, w, e.m[3 * i + j]);
        }
}

void write_pose(double* out, size_t N, size_t n0, size_t w, const M3& R, const V3& t,
                Lanes& nan) {
    watch(lanes(w), nan, R.m[0], 9);
    watch(lanes(w), nan, t.v[0], 3);
    Lanes zero, one;
    std::fill(zero, zero + w, 0.0);
    std::fill(one, one + w, 1.0);
    for (size_t i = 0; i < 3; ++i) {
        for (size_t j = 0; j < 3; ++j) put(out, N, 4 * i + j, n0, w, R.m[3 * i + j]);
        put(out, N, 4 * i + 3, n0, w, t.v[i]);
        put(out, N, 12 + i, n0, w, zero);
    }
    put(out, N, 15, n0, w, one);
}

// Orders the streaming stores of put before the arrays are handed to Python.
inline void fence() {
#if defined(__SSE2__)
    _mm_sfence();
#endif
}

size_t batch_size(size_t n, std::initializer_list<size_t> others) {
    for (size_t m : others)
        if (m != n) throw nb::value_error("relmap._core: batch sizes differ");
    return n;
}

// New C-contiguous numpy array of shape (R, C, N) owning `data`.
template <class Out, size_t R, size_t C>
Out owned(double* data, size_t N) {
    nb::capsule owner(data, [](void* p) noexcept { delete[] static_cast<double*>(p); });
    return Out(data, {R, C, N}, owner);
}

// a ⊕ b for N pairs: C = J_a C_a J_aᵀ + J_b C_b J_bᵀ (+ K + Kᵀ, K = J_a X J_bᵀ, for a dependent
// pair with cross-covariance X = E[δa δbᵀ]).
RELMAP_MULTIVERSION
nb::tuple compound3(Pose Ta, Cov Ca, Pose Tb, Cov Cb, std::optional<Cov> X) {
    const size_t N = batch_size(Ta.shape(2), {Ca.shape(2), Tb.shape(2), Cb.shape(2)});
    if (X) batch_size(N, {X->shape(2)});
    double* To = new double[16 * N];
    double* Co = new double[36 * N];
    bool ok;
    {
        nb::gil_scoped_release release;
        Work& work = workspace();
        Lanes& nan = work.nan;
        std::fill(nan, nan + W, 0.0);
        auto& [R, S, a, e, d, blk, tmp, k11, k12] = work.m;
        auto& t = work.v[0];
        M3* sp = work.in;
        for (size_t n0 = 0; n0 < N; n0 += W) {
            const size_t w = std::min(W, N - n0), n = lanes(w);
            const In3 Ra = view(Ta, 0, 0, n0, w, sp[0]), Rb = view(Tb, 0, 0, n0, w, sp[1]);
            const InV ta = view_column(Ta, 3, n0, w, work.in_v[0]);
            const InV tb = view_column(Tb, 3, n0, w, work.in_v[1]);
            // the mean: (Ra Rb, ta + u) with u = Ra tb
            mul(n, Ra, Rb, R);
            for (size_t i = 0; i < 3; ++i)
                for (size_t l = 0; l < n; ++l)
                    t.v[i][l] = Ra.m[3 * i][l] * tb.v[0][l] + Ra.m[3 * i + 1][l] * tb.v[1][l] +
                                Ra.m[3 * i + 2][l] * tb.v[2][l];
            hat(n, t, -1.0, S);  // S = -[u]× (t holds u here)
            for (size_t i = 0; i < 3; ++i)
                for (size_t l = 0; l < n; ++l) t.v[i][l] += ta.v[i][l];
            write_pose(To, N, n0, w, R, t, nan);
            // J_a C_a J_aᵀ: the shear; block (1, 1) is D_a
            const In3 Da = view(Ca, 3, 3, n0, w, sp[4]);
            shear(n, S, view(Ca, 0, 0, n0, w, sp[2]), view(Ca, 0, 3, n0, w, sp[3]), Da, tmp, a, e);
            // + J_b C_b J_bᵀ: each block rotated by Ra
            rotate(n, Ra, view(Cb, 0, 0, n0, w, sp[5]), false, tmp, blk);
            add_to(n, a, blk);
            rotate(n, Ra, view(Cb, 0, 3, n0, w, sp[6]), false, tmp, blk);
            add_to(n, e, blk);
            rotate(n, Ra, view(Cb, 3, 3, n0, w, sp[7]), false, tmp, d);
            add_to(n, d, Da);  // D_a + Ra D_b Raᵀ
            if (X) {  // + K + Kᵀ, K = J_a X J_bᵀ = [[X11 + S X21, X12 + S X22], [X21, X22]] Raᵀ
                const In3 x21 = view(*X, 3, 0, n0, w, sp[8]), x22 = view(*X, 3, 3, n0, w, sp[9]);
                mul(n, S, x21, k11);
                add_to(n, k11, view(*X, 0, 0, n0, w, sp[5]));
                mul_t(n, k11, Ra, tmp);  // K11
                add_to(n, a, tmp);
                add_t_to(n, a, tmp);
                mul(n, S, x22, k12);
                add_to(n, k12, view(*X, 0, 3, n0, w, sp[6]));
                mul_t(n, k12, Ra, tmp);  // K12
                add_to(n, e, tmp);
                mul_t(n, x21, Ra, tmp);  // K21
                add_t_to(n, e, tmp);
                mul_t(n, x22, Ra, tmp);  // K22
                add_to(n, d, tmp);
                add_t_to(n, d, tmp);
            }
            write_cov(Co, N, n0, w, a, e, d, nan);
        }
        fence();
        ok = finite(nan);
    }
    return nb::make_tuple(owned<PoseOut, 4, 4>(To, N), owned<CovOut, 6, 6>(Co, N), ok);
}

// Aᴿ for N poses: T⁻¹ = (Rᵀ, -Rᵀ t), C' = M C Mᵀ with M = blkdiag(Rᵀ, Rᵀ) [[I, [t]×], [0, I]].
RELMAP_MULTIVERSION
nb::tuple reverse3(Pose T, Cov C) {
    const size_t N = batch_size(T.shape(2), {C.shape(2)});
    double* To = new double[16 * N];
    double* Co = new double[36 * N];
    bool ok;
    {
        nb::gil_scoped_release release;
        Work& work = workspace();
        Lanes& nan = work.nan;
        std::fill(nan, nan + W, 0.0);
        auto& [Rt, S, a, e, tmp, o1, o2, o3, spare] = work.m;
        auto& v = work.v[0];
        M3* sp = work.in;
        (void)spare;
        for (size_t n0 = 0; n0 < N; n0 += W) {
            const size_t w = std::min(W, N - n0), n = lanes(w);
            const In3 R = view(T, 0, 0, n0, w, sp[0]);
            const InV t = view_column(T, 3, n0, w, work.in_v[0]);
            for (size_t i = 0; i < 3; ++i)
                for (size_t j = 0; j < 3; ++j)
                    for (size_t l = 0; l < n; ++l) Rt.m[3 * i + j][l] = R.m[3 * j + i][l];
            for (size_t i = 0; i < 3; ++i)
                for (size_t l = 0; l < n; ++l)
                    v.v[i][l] = -(R.m[i][l] * t.v[0][l] + R.m[3 + i][l] * t.v[1][l] +
                                  R.m[6 + i][l] * t.v[2][l]);
            write_pose(To, N, n0, w, Rt, v, nan);
            const In3 D = view(C, 3, 3, n0, w, sp[3]);
            hat(n, t, 1.0, S);  // S = [t]×
            shear(n, S, view(C, 0, 0, n0, w, sp[1]), view(C, 0, 3, n0, w, sp[2]), D, tmp, a, e);
            rotate(n, R, a, true, tmp, o1);  // Rᵀ X R for each block
            rotate(n, R, e, true, tmp, o2);
            rotate(n, R, D, true, tmp, o3);
            write_cov(Co, N, n0, w, o1, o2, o3, nan);
        }
        fence();
        ok = finite(nan);
    }
    return nb::make_tuple(owned<PoseOut, 4, 4>(To, N), owned<CovOut, 6, 6>(Co, N), ok);
}

}  // namespace

void register_se3(nb::module_& m) {
    m.def("compound3", &compound3, nb::arg("Ta"), nb::arg("Ca"), nb::arg("Tb"), nb::arg("Cb"),
          nb::arg("X").none(),
          "a ⊕ b for N SE(3) pairs, entry-major (4, 4, N) poses and (6, 6, N) covariances (any "
          "strides), X the (6, 6, N) cross-covariance E[δa δbᵀ] or None: new (T, C) arrays and "
          "whether all their entries are finite.");
    m.def("reverse3", &reverse3, nb::arg("T"), nb::arg("C"),
          "Aᴿ for N SE(3) poses, entry-major (4, 4, N) and (6, 6, N) (any strides): new (T, C) "
          "and whether all their entries are finite.");
}

}  // namespace relmap
