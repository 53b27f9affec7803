// The association search (see association.hpp).
#include "association.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>

#include "arrays.hpp"

namespace relmap::association {

namespace {

constexpr double INF = std::numeric_limits<double>::infinity();
constexpr int64_t NONE = -1;

// One pass of greedy pairing over the candidate pairs (cost < +inf, NaN never is; with a mask,
// only the pairs where it is true): again and again the least pair in the order (cost, i, l)
// whose reading i is unpaired (landmark[i] = -1) and whose landmark l is untaken is taken. This
// is the greedy run over the candidates sorted by (cost, i, l): a pair the run skips has its
// reading or its landmark already used, and they stay used. Found without sorting: each
// unpaired reading keeps its least candidate among the untaken landmarks (landmark best[i] of
// cost least[i]; -1 and +inf for none; of equal costs the lowest l), recomputed only when that
// landmark is taken; the least of those (of equal costs the lowest i) is the next pair.
void greedy_pass(int64_t m, int64_t L, const double* cost, const bool* mask, PairingScratch& s,
                 int64_t* landmark) {
    auto least_of = [&](int64_t i) {
        const double* row = cost + i * L;
        const bool* in = mask ? mask + i * L : nullptr;
        int64_t b = NONE;
        double c = INF;
        for (int64_t l = 0; l < L; ++l) {
            if (in && !in[l]) continue;
            // (without a branch: where a new least comes is unpredictable)
            const bool better = (row[l] < c) & !s.taken[l];
            c = better ? row[l] : c;
            b = better ? l : b;
        }
        s.best[i] = b;
        s.least[i] = c;
    };
    for (int64_t i = 0; i < m; ++i) {
        s.best[i] = NONE;
        s.least[i] = INF;
        if (landmark[i] == NONE) least_of(i);
    }
    for (;;) {
        int64_t pick = NONE;
        double c = INF;
        for (int64_t i = 0; i < m; ++i)
            if (s.least[i] < c) pick = i, c = s.least[i];
        if (pick == NONE) return;
        const int64_t l = s.best[pick];
        landmark[pick] = l;
        s.taken[l] = 1;
        s.best[pick] = NONE;
        s.least[pick] = INF;
        for (int64_t i = 0; i < m; ++i)
            if (s.best[i] == l) least_of(i);
    }
}

}  // namespace

// Greedy one-to-one pairing (association.hpp): one pass over the candidates; with split, first
// one over those inside the gate, then one over all the pairs of the readings and landmarks
// left, which all lie outside the gate (the first pass ended when no pair inside was left).
void pair_one_to_one(int64_t m, int64_t L, const double* cost, const bool* inside, bool split,
                     int64_t* landmark, PairingScratch& s) {
    s.taken.assign(L, 0);
    s.best.resize(m);
    s.least.resize(m);
    std::fill(landmark, landmark + m, NONE);
    if (split) greedy_pass(m, L, cost, inside, s, landmark);
    greedy_pass(m, L, cost, nullptr, s, landmark);
}

namespace {

// The scratch of one pair's block (n, d: the filter's and the reading's dimensions).
struct Block {
    std::vector<double> PHt, S, C, u, K, AP, M;  // n×d, d×d, d×d, d, n×d, n×n, n×d
    Block(int64_t n, int64_t d)
        : PHt(n * d), S(d * d), C(d * d), u(d), K(n * d), AP(n * n), M(n * d) {}
};

// The Cholesky factor C (lower, d × d) of S = C Cᵀ; false unless every pivot is positive and
// finite (S positive definite).
bool cholesky(int64_t d, const double* S, double* C) {
    for (int64_t i = 0; i < d; ++i)
        for (int64_t j = 0; j <= i; ++j) {
            double s = S[i * d + j];
            for (int64_t k = 0; k < j; ++k) s -= C[i * d + k] * C[j * d + k];
            if (i == j) {
                if (!(s > 0.0 && s <= std::numeric_limits<double>::max())) return false;
                C[i * d + i] = std::sqrt(s);
            } else {
                C[i * d + j] = s / C[j * d + j];
            }
        }
    return true;
}

// x ← C⁻¹ x (forward substitution; C lower, d × d).
void solve_lower(int64_t d, const double* C, double* x) {
    for (int64_t i = 0; i < d; ++i) {
        for (int64_t k = 0; k < i; ++k) x[i] -= C[i * d + k] * x[k];
        x[i] /= C[i * d + i];
    }
}

// x ← C⁻ᵀ x (back substitution).
void solve_upper(int64_t d, const double* C, double* x) {
    for (int64_t i = d - 1; i >= 0; --i) {
        for (int64_t k = i + 1; k < d; ++k) x[i] -= C[k * d + i] * x[k];
        x[i] /= C[i * d + i];
    }
}

// One pair's block of a set's joint d², in the sequential (Schur complement) form: with the
// running correction δ (n) and covariance P (n × n) of the pairs before it, the pair's
// innovation v (d), Jacobian H (d × n) and noise R (d × d):
//   v' = v − H δ,  S = H P Hᵀ + R,  q = v'ᵀ S⁻¹ v',  K = P Hᵀ S⁻¹,  δ' = δ + K v',
//   P' = (I − K H) P (I − K H)ᵀ + K R Kᵀ   (Joseph form: stays symmetric PSD under rounding).
// With R block diagonal (independent readings) the stacked S = H_s P H_sᵀ + R_s factors block
// by block (each block's S is the Schur complement of the blocks before it, P' the covariance
// given them), so the blocks' q sum to the stacked yᵀ S⁻¹ y. Writes δ', P'; returns q, or +inf
// (δ', P' not written) when S is not positive definite.
double joint_block(int64_t n, int64_t d, const double* v, const double* H, const double* R,
                   const double* delta, const double* P, double* delta_out, double* P_out,
                   Block& b) {
    for (int64_t i = 0; i < n; ++i)  // P Hᵀ
        for (int64_t a = 0; a < d; ++a) {
            double s = 0.0;
            for (int64_t k = 0; k < n; ++k) s += P[i * n + k] * H[a * n + k];
            b.PHt[i * d + a] = s;
        }
    for (int64_t a = 0; a < d; ++a)  // S = H P Hᵀ + R, symmetrized
        for (int64_t c = 0; c <= a; ++c) {
            double s = 0.5 * (R[a * d + c] + R[c * d + a]);
            for (int64_t k = 0; k < n; ++k) s += H[a * n + k] * b.PHt[k * d + c];
            b.S[a * d + c] = b.S[c * d + a] = s;
        }
    if (!cholesky(d, b.S.data(), b.C.data())) return INF;
    double q = 0.0;  // v' = v − H δ;  q = |C⁻¹ v'|²
    for (int64_t a = 0; a < d; ++a) {
        b.u[a] = v[a];
        for (int64_t k = 0; k < n; ++k) b.u[a] -= H[a * n + k] * delta[k];
    }
    solve_lower(d, b.C.data(), b.u.data());
    for (int64_t a = 0; a < d; ++a) q += b.u[a] * b.u[a];
    solve_upper(d, b.C.data(), b.u.data());  // u = S⁻¹ v'
    for (int64_t i = 0; i < n; ++i) {        // Kᵢ = S⁻¹ (P Hᵀ)ᵢᵀ;  δ' = δ + P Hᵀ S⁻¹ v'
        double* Ki = b.K.data() + i * d;
        std::copy(b.PHt.begin() + i * d, b.PHt.begin() + (i + 1) * d, Ki);
        solve_lower(d, b.C.data(), Ki);
        solve_upper(d, b.C.data(), Ki);
        double s = delta[i];
        for (int64_t a = 0; a < d; ++a) s += b.PHt[i * d + a] * b.u[a];
        delta_out[i] = s;
    }
    // Joseph form without I − K H: (I − K H) P = P − K (P Hᵀ)ᵀ =: AP (P symmetric), and
    // AP (I − K H)ᵀ + K R Kᵀ = AP − M Kᵀ with M = AP Hᵀ − K R.
    for (int64_t i = 0; i < n; ++i)
        for (int64_t j = 0; j < n; ++j) {
            double s = P[i * n + j];
            for (int64_t a = 0; a < d; ++a) s -= b.K[i * d + a] * b.PHt[j * d + a];
            b.AP[i * n + j] = s;
        }
    for (int64_t i = 0; i < n; ++i)
        for (int64_t c = 0; c < d; ++c) {
            double s = 0.0;
            for (int64_t k = 0; k < n; ++k) s += b.AP[i * n + k] * H[c * n + k];
            for (int64_t a = 0; a < d; ++a) s -= b.K[i * d + a] * R[a * d + c];
            b.M[i * d + c] = s;
        }
    for (int64_t i = 0; i < n; ++i)
        for (int64_t j = 0; j < n; ++j) {
            double s = b.AP[i * n + j];
            for (int64_t c = 0; c < d; ++c) s -= b.M[i * d + c] * b.K[j * d + c];
            P_out[i * n + j] = s;
        }
    for (int64_t i = 0; i < n; ++i)  // symmetrized
        for (int64_t j = 0; j < i; ++j)
            P_out[i * n + j] = P_out[j * n + i] = 0.5 * (P_out[i * n + j] + P_out[j * n + i]);
    return q;
}

// The depth-first search of JCBB over one filter's problem. The set being built holds `size`
// pairs; depth k of the running state holds (δ, P, joint d²) of the set's first k pairs, so
// that extending the set by a pair costs one block (joint_block), not the whole set again.
class Search {
public:
    explicit Search(const JcbbProblem& p)
        : p_(p), options_(p.m), remaining_(p.m + 1, 0), taken_(p.L, 0),
          current_(p.m, NONE), best_(p.m, NONE), delta_((p.m + 1) * p.n, 0.0),
          P_((p.m + 1) * p.n * p.n), d2_(p.m + 1, 0.0), block_(p.n, p.d) {
        // each reading's individually compatible landmarks in increasing d² (ties: increasing
        // landmark; a NaN d² last); remaining_[i]: the readings from i on that have one
        for (int64_t i = 0; i < p.m; ++i) {
            auto key = [&](int64_t l) {
                const double x = p.d2[i * p.L + l];
                return std::isnan(x) ? INF : x;
            };
            for (int64_t l = 0; l < p.L; ++l)
                if (p.inside[i * p.L + l]) options_[i].push_back(l);
            std::stable_sort(options_[i].begin(), options_[i].end(),
                             [&](int64_t a, int64_t b) { return key(a) < key(b); });
        }
        for (int64_t i = p.m - 1; i >= 0; --i)
            remaining_[i] = remaining_[i + 1] + (options_[i].empty() ? 0 : 1);
        std::copy(p.P, p.P + p.n * p.n, P_.begin());
    }

    // Runs the search; writes the best set's landmark per reading (-1: unpaired).
    void run(int64_t* landmark) {
        visit(0, 0);
        std::copy(best_.begin(), best_.end(), landmark);
    }

private:
    // The joint gate of k pairs: gate2[k], +inf from K on.
    double gate(int64_t k) const { return k < p_.K ? p_.gate2[k] : INF; }

    // A node: reading `level` with `size` pairs chosen before it. At a leaf (every reading
    // decided) the set replaces the best if larger, or as large and of less joint d². A branch
    // is cut when even pairing every remaining reading that has a compatible pair could not
    // make the set as large as the best. Else each compatible pair of the reading whose
    // landmark is free and whose set passes the joint gate of its size (d² finite: S positive
    // definite) is explored, then the reading left unpaired. Each visit counts a node; past
    // max_nodes the search stops with the best set found.
    void visit(int64_t level, int64_t size) {
        if (++nodes_ > p_.max_nodes) return;
        if (level == p_.m) {
            if (size > best_size_ || (size == best_size_ && d2_[size] < best_d2_)) {
                best_ = current_;
                best_size_ = size;
                best_d2_ = d2_[size];
            }
            return;
        }
        if (size + remaining_[level] < best_size_) return;
        const int64_t n = p_.n, d = p_.d;
        for (const int64_t l : options_[level]) {
            if (taken_[l]) continue;
            const double q = joint_block(
                n, d, p_.v + (level * p_.L + l) * d, p_.H + l * d * n, p_.R + l * d * d,
                &delta_[size * n], &P_[size * n * n], &delta_[(size + 1) * n],
                &P_[(size + 1) * n * n], block_);
            const double joint = d2_[size] + q;
            if (!(std::isfinite(joint) && joint <= gate(size + 1))) continue;
            d2_[size + 1] = joint;
            taken_[l] = 1;
            current_[level] = l;
            visit(level + 1, size + 1);
            current_[level] = NONE;
            taken_[l] = 0;
        }
        visit(level + 1, size);
    }

    const JcbbProblem& p_;
    std::vector<std::vector<int64_t>> options_;
    std::vector<int64_t> remaining_;
    std::vector<char> taken_;
    std::vector<int64_t> current_, best_;
    std::vector<double> delta_, P_, d2_;  // per depth: δ (n), P (n × n), joint d²
    Block block_;
    int64_t nodes_ = 0, best_size_ = 0;
    double best_d2_ = INF;
};

}  // namespace

void jcbb(const JcbbProblem& problem, int64_t* landmark) { Search(problem).run(landmark); }

}  // namespace relmap::association

namespace relmap {

namespace {

// The shape of an array as text, "(2, 3)".
template <class A>
std::string shape_text(const A& a) {
    std::string s = "(";
    for (size_t k = 0; k < a.ndim(); ++k) s += (k ? ", " : "") + std::to_string(a.shape(k));
    return s + (a.ndim() == 1 ? ",)" : ")");
}

// ValueError unless array `name` has the shape `want` (its letters in `letters`, e.g.
// "(B, m, L)").
template <class A>
void check_shape(const char* name, const A& a, std::initializer_list<int64_t> want,
                 const char* letters) {
    bool ok = a.ndim() == want.size();
    size_t k = 0;
    for (const int64_t w : want) ok = ok && static_cast<int64_t>(a.shape(k++)) == w;
    if (!ok)
        throw nb::value_error((std::string(name) + " must be " + letters + ", got " +
                               shape_text(a))
                                  .c_str());
}

}  // namespace

void register_association(nb::module_& m) {
    m.def(
        "pair_one_to_one",
        [](FloatN cost, BoolN inside, bool split) {
            if (cost.ndim() != 3) throw nb::value_error("cost must be (B, m, L)");
            const int64_t B = cost.shape(0), n = cost.shape(1), L = cost.shape(2);
            check_shape("inside", inside, {B, n, L}, "(B, m, L) as cost");
            auto out = new_result_like<int64_t>(cost, 2);
            {
                nb::gil_scoped_release unlocked;
                association::PairingScratch scratch;
                for (int64_t b = 0; b < B; ++b)
                    association::pair_one_to_one(n, L, cost.data() + b * n * L,
                                                 inside.data() + b * n * L, split,
                                                 out.data + b * n, scratch);
            }
            return out.array;
        },
        nb::arg("cost"), nb::arg("inside"), nb::arg("split"),
        "Greedy one-to-one pairing of each filter's readings with landmarks, cheapest pair first: "
        "cost (B, m, L) float64 of pairing reading i with landmark l (+inf or NaN: not a "
        "candidate), inside (B, m, L) bool whether the pair lies inside the gate (read only with "
        "split). The candidates in increasing (cost, i, l), a pair taken when its reading is "
        "unpaired and its landmark untaken; with split first the pairs inside the gate, then "
        "those outside. Returns (B, m) int64: each reading's landmark, -1 for none.");

    m.def(
        "jcbb",
        [](FloatN v, FloatN H, FloatN R, FloatN P, FloatN d2, BoolN inside, Float1 joint_gate2,
           int64_t max_nodes) {
            if (v.ndim() != 4) throw nb::value_error("v must be (B, m, L, d)");
            if (P.ndim() != 3) throw nb::value_error("P must be (B, n, n)");
            const int64_t B = v.shape(0), n_read = v.shape(1), L = v.shape(2), d = v.shape(3);
            const int64_t n = P.shape(1);
            if (d < 1 || n < 1) throw nb::value_error("d and n must be at least 1");
            check_shape("P", P, {B, n, n}, "(B, n, n)");
            check_shape("H", H, {B, L, d, n}, "(B, L, d, n)");
            check_shape("R", R, {B, L, d, d}, "(B, L, d, d)");
            check_shape("d2", d2, {B, n_read, L}, "(B, m, L)");
            check_shape("inside", inside, {B, n_read, L}, "(B, m, L)");
            if (max_nodes < 0) throw nb::value_error("max_nodes must be >= 0");
            auto out = new_result_like<int64_t>(d2, 2);
            {
                nb::gil_scoped_release unlocked;
                for (int64_t b = 0; b < B; ++b) {
                    const association::JcbbProblem p{
                        n_read, L, d, n,
                        v.data() + b * n_read * L * d, H.data() + b * L * d * n,
                        R.data() + b * L * d * d, P.data() + b * n * n,
                        d2.data() + b * n_read * L, inside.data() + b * n_read * L,
                        joint_gate2.data(), static_cast<int64_t>(joint_gate2.shape(0)),
                        max_nodes};
                    association::jcbb(p, out.data + b * n_read);
                }
            }
            return out.array;
        },
        nb::arg("v"), nb::arg("H"), nb::arg("R"), nb::arg("P"), nb::arg("d2"), nb::arg("inside"),
        nb::arg("joint_gate2"), nb::arg("max_nodes"),
        "Joint compatibility branch and bound (Neira & Tardos 2001) per filter: v (B, m, L, d) "
        "the innovation of pair (i, l), H (B, L, d, n) and R (B, L, d, d) landmark l's "
        "Jacobian and noise, P (B, n, n) the covariance, d2 (B, m, L) each pair's own d², "
        "inside (B, m, L) the individually compatible pairs, joint_gate2 (K,) the gate of k "
        "pairs at index k (+inf from K on), at most max_nodes search nodes per filter. The "
        "largest one-to-one set of compatible pairs whose stacked innovation passes the joint "
        "gate of its size (S = H P Hᵀ + R positive definite), of equally large sets the least "
        "joint d²; depth first over readings 0..m-1, each reading's pairs in increasing d2, then "
        "the reading unpaired. Returns (B, m) int64: each reading's landmark, -1 for none.");
}

}  // namespace relmap
