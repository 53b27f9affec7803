// The extended Kalman filter (see ekf.hpp).
#include "ekf.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>
#include <type_traits>

#include "arrays.hpp"
#include "multiversion.hpp"

#if defined(_MSC_VER)
#define RELMAP_NOINLINE __declspec(noinline)
#define RELMAP_INLINE __forceinline
#else
#define RELMAP_NOINLINE __attribute__((noinline))
#define RELMAP_INLINE inline __attribute__((always_inline))
#endif

// The Kalman update's lanes (kalman_lanes) carry RELMAP_MULTIVERSION: compiled for baseline
// x86-64 (SSE2: two doubles per vector) and for x86-64-v3 (AVX2: four, the LANES filters of a
// step in one vector). This file is compiled with -ffp-contract=off (CMakeLists.txt: no fused
// multiply-adds, which v3 has), so both copies do the same IEEE operations in the same order
// and the filter's results are bitwise those of the baseline build on every processor.

namespace relmap::ekf {

namespace {

constexpr double PI = 3.14159265358979323846;
constexpr double TWO_PI = 2.0 * PI;
constexpr double NaN = std::numeric_limits<double>::quiet_NaN();
constexpr double INF = std::numeric_limits<double>::infinity();

// An angle wrapped to [-π, π), as relmap.lie.se2.wrap_angle (angles in range untouched).
inline double wrap(double a) {
    if (a >= -PI && a < PI) return a;
    double w = std::fmod(a + PI, TWO_PI);
    if (w < 0) w += TWO_PI;
    w -= PI;
    if (w >= PI) w -= TWO_PI;
    return w;
}

// Log-density of a D-dimensional reading model at an innovation with Mahalanobis distance
// d2 = yᵀS⁻¹y and logdet = log det S: the normal N(0, S) for nu infinite, else the Student-t
// with nu dof and *scale* S (its covariance is S ν/(ν - 2)). The one copy of this density:
// relmap.autocalibration.logpdf calls it through the binding below.
inline double log_density(double d2, double logdet, int D, double nu) {
    if (std::isinf(nu)) return -0.5 * (d2 + logdet + D * std::log(TWO_PI));
    return std::lgamma(0.5 * (nu + D)) - std::lgamma(0.5 * nu) - 0.5 * D * std::log(nu * PI) -
           0.5 * logdet - 0.5 * (nu + D) * std::log1p(d2 / nu);
}

// log det S of a stacked update, from the diagonals of its blocks' Cholesky factors
// (log det S = 2 log Π Lᵢᵢ): their product, with one log at the end rather than one per block
// (a time stamp's readings are blocks of one update); the product is taken in pieces that can
// neither overflow nor underflow.
struct LogDet {
    double log = 0.0, prod = 1.0;
    void times(double l) {
        prod *= l;
        if (!(prod > 1e-150 && prod < 1e150)) log += std::log(prod), prod = 1.0;
    }
    double value() const { return 2.0 * (log + std::log(prod)); }
};

// Scratch of SIZE doubles: on the stack when the size is known at compile time (SIZE > 0),
// else a vector of the runtime size.
template <int SIZE>
struct Scratch {
    double a[SIZE];
    explicit Scratch(size_t) {}
    double* data() { return a; }
};
template <>
struct Scratch<0> {
    std::vector<double> a;
    explicit Scratch(size_t n) : a(n) {}
    double* data() { return a.data(); }
};

// P⁻ = F P Fᵀ + Q (n × n, row-major), symmetrized; out may alias P. N_ > 0 fixes n. Inlined:
// a pose filter's F and Q then stay in registers (an out-of-line call had the odometry step
// store them, zeroing F with a slow string store, every step).
template <int N_>
RELMAP_INLINE void predict_cov(int n, const double* F, const double* P, const double* Q,
                               double* out) {
    if (N_ > 0) n = N_;
    constexpr int NN = N_ * N_;
    Scratch<NN> fp_(NN ? 0 : static_cast<size_t>(n) * n), t_(NN ? 0 : static_cast<size_t>(n) * n);
    double *fp = fp_.data(), *t = t_.data();
    for (int i = 0; i < n; ++i)
        for (int j = 0; j < n; ++j) {
            double s = 0.0;
            for (int k = 0; k < n; ++k) s += F[i * n + k] * P[k * n + j];
            fp[i * n + j] = s;
        }
    for (int i = 0; i < n; ++i)
        for (int j = 0; j < n; ++j) {
            double s = Q[i * n + j];
            for (int k = 0; k < n; ++k) s += fp[i * n + k] * F[j * n + k];
            t[i * n + j] = s;
        }
    for (int i = 0; i < n; ++i)
        for (int j = 0; j < n; ++j) out[i * n + j] = 0.5 * (t[i * n + j] + t[j * n + i]);
}

// One block of a correction (Eqs. 26-28) on the running correction δ (n) of the prior mean
// and the running covariance P (n × n), with the block's innovation y (D) at the prior, its
// Jacobian H (D × n) and noise R (D × D):
//   y' = y - H δ                  (what the blocks before did not explain: linear in δ)
//   S = H P Hᵀ + R,  K = P Hᵀ S⁻¹,  δ ← δ + K y',
//   P ← (I - KH) P (I - KH)ᵀ + K R Kᵀ   (Joseph form, see below)
// and adds y'ᵀ S⁻¹ y' to nis and log det S to logdet (a LogDet: one log per stacked update).
// Blocks whose noises are independent (R block diagonal) processed one after the other give
// exactly the stacked update of them all:
// the stacked S factors into the blocks' S (its block Cholesky / Schur complements), so the
// sums of nis and log det are the stacked yᵀS⁻¹y and log det S, and δ, P the stacked ones;
// a 2k × 2k solve becomes k 2 × 2 ones. False (δ, P partly updated: the caller keeps copies)
// when S is not positive definite (a 0/0), i.e. exactly when the stacked S is not.
// S_out (D × D) if non-null. N_, D_ > 0 fix the sizes at compile time.
//
// W lanes: the blocks of W independent filters side by side, each lane's arithmetic exactly that
// of the lane alone. One block's steps depend on each other (P → S → its factor → K → P), so one
// filter's blocks in turn leave the processor waiting; several filters' chains interleaved keep
// it busy (the batch runners take their filters LANES at a time). Every array holds its lanes
// innermost (entry e of lane l at e W + l), so that each step's loop over the lanes is one over
// contiguous values, which the compiler vectorizes; the running δ and P stay so laid out from one
// block to the next (their caller's, not gathered and scattered per block). A lane takes part if
// active[l] (the others compute on whatever inputs they hold, harmlessly, and keep their δ, P,
// nis and logdet); ok[l]: whether its S is positive definite (set for the active lanes). A lane
// whose S is not keeps its δ, P, nis and logdet (S_out is written all the same). With W = 1
// the layout is the plain one (kalman_block below); the sizes known at run time (N_ = 0) have
// one lane.
template <int N_, int D_, int W>
RELMAP_MULTIVERSION void kalman_lanes(int n, int D, double* delta, double* P, const double* y,
                                      const double* H, const double* R, const bool* active,
                                      double* const* S_out, double* nis, LogDet* logdet,
                                      bool* ok) {
    static_assert(W >= 1 && (N_ > 0 || W == 1), "lanes need sizes known at compile time");
    if (N_ > 0) n = N_;
    if (D_ > 0) D = D_;
    constexpr int ND = N_ * D_ * W, DD = D_ * D_ * W, NN = N_ * N_ * W, DW = D_ * W;
    const size_t nD = static_cast<size_t>(n) * D, dd = static_cast<size_t>(D) * D,
                 nn = static_cast<size_t>(n) * n;
    Scratch<ND> PHt_(ND ? 0 : nD), K_(ND ? 0 : nD), KR_(ND ? 0 : nD);
    Scratch<DD> S_(DD ? 0 : dd), L_(DD ? 0 : dd);
    Scratch<NN> A_(NN ? 0 : nn), AP_(NN ? 0 : nn);
    Scratch<DW> u_(DW ? 0 : D), inv_(DW ? 0 : D);
    double *PHt = PHt_.data(), *K = K_.data(), *KR = KR_.data(), *S = S_.data(), *Lw = L_.data();
    double *A = A_.data(), *AP = AP_.data(), *u = u_.data(), *inv = inv_.data();
    for (int i = 0; i < n; ++i)  // P Hᵀ
        for (int a = 0; a < D; ++a)
            for (int l = 0; l < W; ++l) {
                double s = 0.0;
                for (int k = 0; k < n; ++k) s += P[(i * n + k) * W + l] * H[(a * n + k) * W + l];
                PHt[(i * D + a) * W + l] = s;
            }
    for (int a = 0; a < D; ++a)  // S = H P Hᵀ + R, symmetrized
        for (int b = 0; b <= a; ++b)
            for (int l = 0; l < W; ++l) {
                double s = 0.0;
                for (int k = 0; k < n; ++k) s += H[(a * n + k) * W + l] * PHt[(k * D + b) * W + l];
                S[(a * D + b) * W + l] = S[(b * D + a) * W + l] =
                    s + 0.5 * (R[(a * D + b) * W + l] + R[(b * D + a) * W + l]);
            }
    // S's lower Cholesky factor L and its diagonal's reciprocals (one division per row, the
    // rest multiplications); a lane's S is positive definite if every pivot is positive and
    // finite (sum <= DBL_MAX: not +inf, not NaN). Without branches, so that the lanes'
    // square roots and divisions are vector ones: a pivot that is not goes on as 1 (a harmless
    // factor: the lane's results are dropped).
    bool pd[W];
    for (int l = 0; l < W; ++l) pd[l] = true;
    for (int i = 0; i < D; ++i)
        for (int j = 0; j <= i; ++j)
            for (int l = 0; l < W; ++l) {
                double sum = S[(i * D + j) * W + l];
                for (int k = 0; k < j; ++k) sum -= Lw[(i * D + k) * W + l] * Lw[(j * D + k) * W + l];
                if (i == j) {
                    const bool good = sum > 0.0 && sum <= std::numeric_limits<double>::max();
                    pd[l] = pd[l] && good;
                    Lw[(i * D + i) * W + l] = std::sqrt(good ? sum : 1.0);
                    inv[i * W + l] = 1.0 / Lw[(i * D + i) * W + l];
                } else {
                    Lw[(i * D + j) * W + l] = sum * inv[j * W + l];
                }
            }
    bool keep[W], any = false;  // keep: the lanes whose results are kept
    for (int l = 0; l < W; ++l) {
        if (active[l]) ok[l] = pd[l];
        keep[l] = active[l] && pd[l];
        any = any || keep[l];
        if (active[l] && S_out[l])
            for (size_t e = 0; e < dd; ++e) S_out[l][e] = S[e * W + l];
    }
    if (!any) return;
    // y' = y - H δ; y'ᵀ S⁻¹ y' = |L⁻¹ y'|², log det S = 2 log Π Lᵢᵢ
    double q[W];
    for (int l = 0; l < W; ++l) q[l] = 0.0;
    for (int a = 0; a < D; ++a)
        for (int l = 0; l < W; ++l) {
            double s = y[a * W + l];
            for (int k = 0; k < n; ++k) s -= H[(a * n + k) * W + l] * delta[k * W + l];
            for (int k = 0; k < a; ++k) s -= Lw[(a * D + k) * W + l] * u[k * W + l];
            u[a * W + l] = s * inv[a * W + l];
            q[l] += u[a * W + l] * u[a * W + l];
        }
    for (int l = 0; l < W; ++l)
        if (keep[l]) {
            nis[l] += q[l];
            for (int a = 0; a < D; ++a) logdet[l].times(Lw[(a * D + a) * W + l]);
        }
    for (int a = D - 1; a >= 0; --a)  // u = S⁻¹ y' (Lᵀ u = L⁻¹ y')
        for (int l = 0; l < W; ++l) {
            double s = u[a * W + l];
            for (int k = a + 1; k < D; ++k) s -= Lw[(k * D + a) * W + l] * u[k * W + l];
            u[a * W + l] = s * inv[a * W + l];
        }
    for (int i = 0; i < n; ++i) {  // row i of K = P Hᵀ S⁻¹ (L Lᵀ Kᵢᵀ = (P Hᵀ)ᵢᵀ); δ += P Hᵀ u
        for (int a = 0; a < D; ++a)
            for (int l = 0; l < W; ++l) {
                double s = PHt[(i * D + a) * W + l];
                for (int k = 0; k < a; ++k) s -= Lw[(a * D + k) * W + l] * K[(i * D + k) * W + l];
                K[(i * D + a) * W + l] = s * inv[a * W + l];
            }
        for (int a = D - 1; a >= 0; --a)
            for (int l = 0; l < W; ++l) {
                double s = K[(i * D + a) * W + l];
                for (int k = a + 1; k < D; ++k)
                    s -= Lw[(k * D + a) * W + l] * K[(i * D + k) * W + l];
                K[(i * D + a) * W + l] = s * inv[a * W + l];
            }
        for (int l = 0; l < W; ++l) {
            double s = 0.0;
            for (int a = 0; a < D; ++a) s += PHt[(i * D + a) * W + l] * u[a * W + l];
            const double v = delta[i * W + l] + s;
            delta[i * W + l] = keep[l] ? v : delta[i * W + l];
        }
    }
    // Joseph form P = (I - KH) P (I - KH)ᵀ + K R Kᵀ rather than Eq. 28's P - K S Kᵀ: a sum of
    // two congruences, so P stays symmetric positive semi-definite under rounding (and for any
    // gain, e.g. a robust filter's reweighted one), even after many updates or with a reading
    // far more precise than the prior, where the difference form can lose definiteness.
    // Evaluated without forming I - KH (P symmetric, so H P = (P Hᵀ)ᵀ):
    //   AP = (I - KH) P = P - K (P Hᵀ)ᵀ,   AP (I - KH)ᵀ + K R Kᵀ = AP - (AP Hᵀ - K R) Kᵀ.
    for (int i = 0; i < n; ++i)
        for (int j = 0; j < n; ++j)
            for (int l = 0; l < W; ++l) {
                double s = P[(i * n + j) * W + l];
                for (int a = 0; a < D; ++a)
                    s -= K[(i * D + a) * W + l] * PHt[(j * D + a) * W + l];
                AP[(i * n + j) * W + l] = s;
            }
    for (int i = 0; i < n; ++i)  // KR ← AP Hᵀ - K R
        for (int b = 0; b < D; ++b)
            for (int l = 0; l < W; ++l) {
                double s = 0.0;
                for (int k = 0; k < n; ++k) s += AP[(i * n + k) * W + l] * H[(b * n + k) * W + l];
                for (int a = 0; a < D; ++a) s -= K[(i * D + a) * W + l] * R[(a * D + b) * W + l];
                KR[(i * D + b) * W + l] = s;
            }
    for (int i = 0; i < n; ++i)
        for (int j = 0; j < n; ++j)
            for (int l = 0; l < W; ++l) {
                double s = AP[(i * n + j) * W + l];
                for (int b = 0; b < D; ++b) s -= KR[(i * D + b) * W + l] * K[(j * D + b) * W + l];
                A[(i * n + j) * W + l] = s;
            }
    for (int i = 0; i < n; ++i)  // symmetrized, into P
        for (int j = 0; j < n; ++j)
            for (int l = 0; l < W; ++l) {
                const double v = 0.5 * (A[(i * n + j) * W + l] + A[(j * n + i) * W + l]);
                P[(i * n + j) * W + l] = keep[l] ? v : P[(i * n + j) * W + l];
            }
}

// One filter's block (kalman_lanes with one lane); false (nothing updated) when S is not
// positive definite.
template <int N_, int D_>
bool kalman_block(int n, int D, double* delta, double* P, const double* y, const double* H,
                  const double* R, double* S_out, double& nis, LogDet& logdet) {
    const bool active = true;
    bool ok;
    kalman_lanes<N_, D_, 1>(n, D, delta, P, y, H, R, &active, &S_out, &nis, &logdet, &ok);
    return ok;
}

}  // namespace

void predict_covariance(int n, const double* F, const double* P, const double* Q, double* out) {
    if (n == 3)
        predict_cov<3>(3, F, P, Q, out);
    else
        predict_cov<0>(n, F, P, Q, out);
}

bool kalman_update(int n, int D, double* x, double* P, const double* y, const double* H,
                   const double* R, double* S, double* nis, double* logdet) {
    thread_local std::vector<double> delta, Pw;
    delta.assign(n, 0.0);
    Pw.assign(P, P + static_cast<size_t>(n) * n);
    double q = 0.0;
    LogDet ld;
    if (!kalman_block<0, 0>(n, D, delta.data(), Pw.data(), y, H, R, S, q, ld)) return false;
    bool finite = true;
    for (double v : Pw) finite = finite && std::isfinite(v);
    for (double v : delta) finite = finite && std::isfinite(v);
    if (!finite) return false;
    for (int i = 0; i < n; ++i) x[i] += delta[i];
    std::copy(Pw.begin(), Pw.end(), P);
    *nis = q;
    *logdet = ld.value();
    return true;
}

namespace {

// An odometry step with its trigonometry (shared by the filters of a batch).
struct Step {
    double ds, dth, a, b;  // a = cos(Δθ/2), b = sin(Δθ/2)
};

inline Step make_step(double ds, double dth) {
    return {ds, dth, std::cos(0.5 * dth), std::sin(0.5 * dth)};
}

// Eqs. 10-13: Δ = (Δs cos(Δθ/2), Δs sin(Δθ/2), Δθ) in the robot frame, C = J diag(var Δs,
// var Δθ) Jᵀ with J = ∂Δ/∂(Δs, Δθ); then x⁻ = x ⊕ Δ, P⁻ = F P Fᵀ + Q with F = ∂(x ⊕ Δ)/∂x and
// Q = G C Gᵀ, G = ∂(x ⊕ Δ)/∂Δ (the paper's compounding, Eqs. 1-4).
inline void predict_step(double* x, double* P, const Step& st, const double* p) {
    const double ads = std::fabs(st.ds), adt = std::fabs(st.dth);
    const double s00 = p[K_S] * ads, s11 = p[K_THETA] * adt + p[K_THETA_S] * ads;
    const double e = -0.5 * st.ds * st.b, f = 0.5 * st.ds * st.a;  // ∂Δ/∂Δθ
    const double c00 = st.a * st.a * s00 + e * e * s11, c01 = st.a * st.b * s00 + e * f * s11;
    const double c11 = st.b * st.b * s00 + f * f * s11, c02 = e * s11, c12 = f * s11;
    const double bx = st.ds * st.a, by = st.ds * st.b;
    const double c = std::cos(x[2]), s = std::sin(x[2]);
    const double dx = c * bx - s * by, dy = s * bx + c * by;
    double F[9];  // {1, 0, -dy, 0, 1, dx, 0, 0, 1}, set entry by entry (an initializer list
    // zero-fills with a slow string store first)
    F[0] = F[4] = F[8] = 1.0;
    F[1] = F[3] = F[6] = F[7] = 0.0;
    F[2] = -dy;
    F[5] = dx;
    // Q = G C Gᵀ with G = blkdiag(R(θ), 1)
    const double g00 = c * c00 - s * c01, g01 = c * c01 - s * c11, g02 = c * c02 - s * c12;
    const double g10 = s * c00 + c * c01, g11 = s * c01 + c * c11, g12 = s * c02 + c * c12;
    const double Q[9] = {g00 * c - g01 * s, g00 * s + g01 * c, g02,
                         g10 * c - g11 * s, g10 * s + g11 * c, g12,
                         g02,               g12,               s11};
    predict_cov<3>(3, F, P, Q, P);
    x[0] += dx;
    x[1] += dy;
    x[2] = wrap(x[2] + st.dth);
}

// The sensor's pose for one filter state at one time stamp (shared by its landmarks).
struct SensorPose {
    double x, y, heading, ox, oy;  // position, heading; (ox, oy) the mount in the world frame
};

inline SensorPose sensor_pose(const double* x, const double* p) {
    const double c = std::cos(x[2]), s = std::sin(x[2]);
    const double ox = c * p[MOUNT_X] - s * p[MOUNT_Y], oy = s * p[MOUNT_X] + c * p[MOUNT_Y];
    return {x[0] + ox, x[1] + oy, x[2] + p[MOUNT_THETA], ox, oy};
}

// The range noise variance of a reading at range r (the sensor's noise model).
inline double range_variance(double r, const double* p, const Options& opt) {
    const double scale = opt.noise_model == PROPORTIONAL ? r
                         : opt.noise_model == QUADRATIC  ? r * r
                                                         : 1.0;
    return (p[SIGMA_R] * scale) * (p[SIGMA_R] * scale);
}

// The bearing noise variance of a reading at range r (the sensor's noise model, as
// predict_landmark's).
inline double bearing_variance(double r, const double* p, const Options& opt) {
    const double scale = opt.noise_model == PROPORTIONAL ? r
                         : opt.noise_model == QUADRATIC  ? r * r
                                                         : 1.0;
    return (p[SIGMA_B] * scale) * (p[SIGMA_B] * scale);
}

// A landmark's predicted reading from the filter's sensor pose: h (d), H (d × 3), S (d × d),
// R's diagonal (d); ok false for 0/0 (the landmark at the sensor, or S not positive definite).
// Rx: R's off-diagonal entry (0 for a landmark's reading; a mixture's spread, see mix_reading).
struct Predicted {
    double h[2], H[6], S[4], R[2], det, inv_det;  // inv_det = 1 / det
    bool ok;
    double Rx = 0.0;
};

// A reading-landmark pair.
struct Pair {
    double cost, d2, v[2];
    int64_t i, l;
};

// The innovation covariance S = H P Hᵀ + R of a predicted reading (d × d; R diagonal
// but for Rx off it), its determinant and the determinant's reciprocal (for the readings' d²:
// one division per prediction, not per pair), and whether S is positive definite. D_ > 0
// fixes d.
template <int D_>
RELMAP_INLINE void innovation_cov(Predicted& out, const double* P, int d) {
    if (D_ > 0) d = D_;
    double HP[6];
    for (int a = 0; a < d; ++a)
        for (int j = 0; j < 3; ++j)
            HP[a * 3 + j] = out.H[a * 3] * P[j] + out.H[a * 3 + 1] * P[3 + j] +
                            out.H[a * 3 + 2] * P[6 + j];
    for (int a = 0; a < d; ++a)
        for (int b = 0; b <= a; ++b)
            out.S[a * d + b] = out.S[b * d + a] = (a == b ? out.R[a] : out.Rx) +
                HP[a * 3] * out.H[b * 3] + HP[a * 3 + 1] * out.H[b * 3 + 1] +
                HP[a * 3 + 2] * out.H[b * 3 + 2];
    out.det = d == 2 ? out.S[0] * out.S[3] - out.S[1] * out.S[1] : out.S[0];
    out.inv_det = 1.0 / out.det;
    out.ok = out.det > 0.0 && std::isfinite(out.det) && out.S[0] > 0.0;
}

inline void innovation_cov(Predicted& out, const double* P, int d) {
    if (d == 2)
        innovation_cov<2>(out, P, d);
    else
        innovation_cov<1>(out, P, d);
}

void predict_landmark(const SensorPose& sp, const double* P, const double* lm, const double* p,
                      const Options& opt, int d, Predicted& out) {
    const double dx = lm[0] - sp.x, dy = lm[1] - sp.y, ox = sp.ox, oy = sp.oy;
    const double q = dx * dx + dy * dy, r = std::sqrt(q);
    out.ok = q > 0.0 && std::isfinite(q);
    if (!out.ok) return;
    double scale = 1.0;
    if (opt.noise_model == PROPORTIONAL) scale = r;
    if (opt.noise_model == QUADRATIC) scale = q;
    // one division: 1/r, and 1/r² as its square (a division's latency is that of many
    // multiplications, and this is on every reading's path)
    const double ir = 1.0 / r, iq = ir * ir;
    out.h[0] = r;
    out.H[0] = -dx * ir;
    out.H[1] = -dy * ir;
    out.H[2] = (dx * oy - dy * ox) * ir;  // through the mount: ∂sensor/∂θ = (-oy, ox)
    out.R[0] = range_variance(r, p, opt);
    if (d == 2) {
        out.h[1] = wrap(wrap(std::atan2(dy, dx) - sp.heading));
        out.H[3] = dy * iq;
        out.H[4] = -dx * iq;
        out.H[5] = -(dy * oy + dx * ox) * iq - 1.0;
        out.R[1] = (p[SIGMA_B] * scale) * (p[SIGMA_B] * scale);
    }
    out.Rx = 0.0;
    innovation_cov(out, P, d);
}

inline double mahalanobis2(const Predicted& pr, const double* v, int d) {
    if (d == 1) return v[0] * v[0] * pr.inv_det;
    return (v[0] * v[0] * pr.S[3] - 2.0 * v[0] * v[1] * pr.S[1] + v[1] * v[1] * pr.S[0]) *
           pr.inv_det;
}

// A pair's innovation v (d) given the correction δ (3, entries stride apart) of the pairs before
// it: v - H δ.
inline void innovation_given(int d, const double* v, const double* H, const double* delta,
                             double* out, int stride = 1) {
    for (int a = 0; a < d; ++a)
        out[a] = v[a] - H[3 * a] * delta[0] - H[3 * a + 1] * delta[stride] -
                 H[3 * a + 2] * delta[2 * stride];
}

// One pair's block of the stacked correction, on the running (δ, P) of a pose filter (see
// kalman_block), with the pair's noise R (d, diagonal) divided by weight w.
// y_out (d), S_out (d × d) if non-null: the block's innovation y' = y - H δ and its S.
// W lanes: one pair of each of W filters (kalman_lanes: δ (3 W) and P (9 W) lane innermost; the
// inactive lanes' q and pr are not read); pair_block: one filter's.
template <int W>
void pair_lanes(int d, double* delta, double* P, const Pair* const* q, const Predicted* const* pr,
                const double* w, const bool* active, double* nis, LogDet* logdet,
                double* const* y_out, double* const* S_out, bool* ok) {
    auto lanes = [&](auto dim) {
        constexpr int D = decltype(dim)::value;
        double H[3 * D * W], y[D * W], R[D * D * W];  // lane innermost
        for (int l = 0; l < W; ++l) {
            if (!active[l]) {  // a harmless block (H = 0, R = I): its results are not kept
                for (int e = 0; e < 3 * D; ++e) H[e * W + l] = 0.0;
                for (int e = 0; e < D; ++e) y[e * W + l] = 0.0;
                for (int e = 0; e < D * D; ++e) R[e * W + l] = e % (D + 1) == 0 ? 1.0 : 0.0;
                continue;
            }
            const Predicted& p = *pr[l];
            const double wl = w[l];
            const double r[4] = {p.R[0], p.Rx, p.Rx, p.R[1]};  // (d = 1: its first entry)
            // (x / 1 is x: no division for an unweighted reading)
            for (int e = 0; e < D * D; ++e) R[e * W + l] = wl == 1.0 ? r[e] : r[e] / wl;
            for (int e = 0; e < 3 * D; ++e) H[e * W + l] = p.H[e];
            for (int e = 0; e < D; ++e) y[e * W + l] = q[l]->v[e];
            if (y_out[l]) innovation_given(D, q[l]->v, p.H, delta + l, y_out[l], W);
        }
        kalman_lanes<3, D, W>(3, D, delta, P, y, H, R, active, S_out, nis, logdet, ok);
    };
    if (d == 2)
        lanes(std::integral_constant<int, 2>{});
    else
        lanes(std::integral_constant<int, 1>{});
}

inline bool pair_block(int d, double* delta, double* P, const Pair& q, const Predicted& pr,
                       double w, double& nis, LogDet& logdet, double* y_out = nullptr,
                       double* S_out = nullptr) {
    const Pair* qq = &q;
    const Predicted* pp = &pr;
    const bool active = true;
    bool ok;
    pair_lanes<1>(d, delta, P, &qq, &pp, &w, &active, &nis, &logdet, &y_out, &S_out, &ok);
    return ok;
}

// A reading with k >= 2 landmarks inside its gate (candidates c[0..k), pairs of one reading i)
// is of one of them, which one unknown: its likelihood is the mixture Σ β_j N(z; h_j, S_j) with
// the association probabilities β_j ∝ |S_j|^(-1/2) exp(-d²_j / 2) (Bayes with equal priors,
// the probabilistic data association of Bar-Shalom & Tse 1975 without clutter: the gate has
// already rejected what is far from every landmark). It enters the update moment-matched, as a
// reading of one virtual landmark: ẑ = Σ β_j h_j, H = Σ β_j H_j and noise
// R = Σ β_j R_j + Σ β_j (h_j - ẑ)(h_j - ẑ)ᵀ, the spread of the candidates' predictions
// (bearings taken relative to the most probable one). One candidate of β ≈ 1 gives its own
// pair back; a cluster of landmarks closer than the reading can tell apart gives their centroid
// with their spread as noise, never one of them chosen wrongly with full confidence. Writes
// the virtual landmark's prediction (S = H P Hᵀ + R) and its pair (innovation, d²); false if
// its S is not positive definite.
bool mix_reading(const Pair* const* c, int k, const Predicted* pred, const double* P,
                 int d, Predicted& mp, Pair& mq) {
    double beta[64], lmax = -INF;
    const int kk = std::min(k, 64);
    int best = 0;
    for (int j = 0; j < kk; ++j) {
        beta[j] = -0.5 * c[j]->d2 - 0.5 * std::log(pred[c[j]->l].det);
        if (beta[j] > lmax) lmax = beta[j], best = j;
    }
    double sum = 0.0;
    for (int j = 0; j < kk; ++j) sum += (beta[j] = std::exp(beta[j] - lmax));
    const Predicted& pb = pred[c[best]->l];
    double dh[64][2];
    for (int a = 0; a < 2; ++a) mp.h[a] = 0.0, mp.R[a] = 0.0;
    for (int a = 0; a < 6; ++a) mp.H[a] = 0.0;
    for (int j = 0; j < kk; ++j) {
        const Predicted& pj = pred[c[j]->l];
        beta[j] /= sum;
        dh[j][0] = pj.h[0] - pb.h[0];
        dh[j][1] = d == 2 ? wrap(pj.h[1] - pb.h[1]) : 0.0;
        for (int a = 0; a < d; ++a) mp.h[a] += beta[j] * dh[j][a], mp.R[a] += beta[j] * pj.R[a];
        for (int a = 0; a < 3 * d; ++a) mp.H[a] += beta[j] * pj.H[a];
    }
    mp.Rx = 0.0;
    for (int j = 0; j < kk; ++j) {
        const double e0 = dh[j][0] - mp.h[0], e1 = dh[j][1] - mp.h[1];
        mp.R[0] += beta[j] * e0 * e0;
        if (d == 2) mp.R[1] += beta[j] * e1 * e1, mp.Rx += beta[j] * e0 * e1;
    }
    // ẑ relative to the best candidate's prediction; the innovation z ⊖ ẑ
    mq = *c[best];
    mq.v[0] = c[best]->v[0] - mp.h[0];
    mq.v[1] = d == 2 ? wrap(c[best]->v[1] - mp.h[1]) : 0.0;
    mp.h[0] += pb.h[0];
    if (d == 2) mp.h[1] = wrap(pb.h[1] + mp.h[1]);
    innovation_cov(mp, P, d);
    if (mp.ok) mq.d2 = mahalanobis2(mp, mq.v, d);
    return mp.ok;
}

// Clutter (probabilistic data association with clutter, Bar-Shalom & Tse 1975): a reading is
// either of its paired landmark, density g(z) = the reading model at the pair's innovation
// (N(v; 0, S), or the Student-t of scale S for a robust filter; for an ambiguous reading the
// mixture's virtual landmark, mix_reading), or of something not in the map, of density λ
// (p[CLUTTER], relative to the landmark hypothesis: the clutter's uniform density over the
// measurement volume times the odds of clutter). The probability that it is of the landmark,
// w = g / (g + λ), weighs its update (R / w, as the Student-t weight): likely clutter barely
// moves the filter.
inline double landmark_probability(const Pair& q, const Predicted& pr, int d, const double* p,
                                   double lambda) {
    const double logg = log_density(q.d2, std::log(pr.det), d, p[NU]);
    return 1.0 / (1.0 + std::exp(std::log(lambda) - logg));
}

// The joint d² of a set of pairs: the stacked innovation against its stacked S, pair by pair.
double joint_d2(const std::vector<const Pair*>& pairs, const Predicted* pred,
                const double* P, int d) {
    double delta[3] = {0.0, 0.0, 0.0}, Pw[9], q = 0.0;
    LogDet ld;
    std::copy(P, P + 9, Pw);
    for (const Pair* p : pairs)
        if (!pair_block(d, delta, Pw, *p, pred[p->l], 1.0, q, ld)) return INF;
    return q;
}

// JCBB (Neira & Tardós 2001): the largest set of individually compatible pairs, one landmark
// per reading and one reading per landmark, whose stacked innovation passes the joint χ² gate;
// of equally large sets the one of least joint d². Depth-first over the readings in order, each
// reading's pairs in increasing d², then the reading left unpaired; a branch is cut when even
// pairing every remaining reading could not beat the best set. At most opt.jcbb_nodes nodes.
std::vector<const Pair*> jcbb(const std::vector<std::vector<const Pair*>>& options,
                              const Predicted* pred, const double* P, int d,
                              const Options& opt) {
    std::vector<const Pair*> best, current;
    double best_d2 = INF;
    std::vector<char> taken;
    int64_t maxl = 0;
    for (auto& o : options)
        for (auto* p : o) maxl = std::max(maxl, p->l + 1);
    taken.assign(maxl, 0);
    std::vector<int> remaining(options.size() + 1, 0);
    for (size_t i = options.size(); i-- > 0;)
        remaining[i] = remaining[i + 1] + (options[i].empty() ? 0 : 1);
    int64_t nodes = 0;
    auto gate = [&](size_t k) {
        return k < opt.joint_gate2.size() ? opt.joint_gate2[k] : INF;
    };
    auto search = [&](auto&& self, size_t level, double current_d2) -> void {
        if (++nodes > opt.jcbb_nodes) return;
        if (level == options.size()) {
            if (current.size() > best.size() ||
                (current.size() == best.size() && current_d2 < best_d2)) {
                best = current;
                best_d2 = current_d2;
            }
            return;
        }
        if (current.size() + remaining[level] < best.size()) return;
        for (const Pair* p : options[level]) {
            if (taken[p->l]) continue;
            current.push_back(p);
            const double j2 = joint_d2(current, pred, P, d);
            if (j2 <= gate(current.size())) {
                taken[p->l] = 1;
                self(self, level + 1, j2);
                taken[p->l] = 0;
            }
            current.pop_back();
        }
        self(self, level + 1, current_d2);
    };
    search(search, 0, 0.0);
    return best;
}

}  // namespace

namespace {

// The part of the map where a reading's candidates whose bounds may not exceed a limit lie
// (associate's window_of): ranges r0..r1 from the sensor and, range-bearing, within rho of the
// point where the reading puts its landmark.
struct Window {
    double r0, r1, rho;
};

// The scratch of correct_readings.
struct Work {
    std::vector<int8_t> status;
    std::vector<int32_t> landmark;
    std::vector<double> nearest, zc, pair_d2, range, bound, bound_phi, keys, point;
    std::vector<Window> gate_window;
    std::vector<Predicted> pred;
    std::vector<char> done, taken, full;
    std::vector<Pair> pairs, mixed;  // mixed: a reading's mixture pair (mix_reading)
    std::vector<Predicted> mixpred;  // and its virtual landmark's prediction
    std::vector<int64_t> row_start, lo, hi, owner, near;
    std::vector<const Pair*> chosen, update, best, order;
    std::vector<const Predicted*> upred;  // the prediction of each pair of update
};

// This thread's scratch, looked up once per call: not inlined, so the compiler cannot redo the
// lookup (a call, __tls_get_addr, in a shared library) at every use.
RELMAP_NOINLINE Work* thread_work() {
    thread_local Work work[LANES];  // a call corrects up to LANES filters side by side
    return work;
}

}  // namespace

void predict_odometry(double* x, double* P, double ds, double dth, const double* params) {
    predict_step(x, P, make_step(ds, dth), params);
}

void signature_candidates(const Map& map, int64_t m, const int64_t* signature,
                          int64_t* candidates) {
    for (int64_t i = 0; i < m; ++i) map.find(signature[i], candidates[2 * i], candidates[2 * i + 1]);
}

namespace {

// The association of a filter's readings (Eqs. 21-25) and the pairs of its update: fills w's
// status, landmark, pair_d2, chosen, pred and update / upred (the used pairs in update order
// and their predictions; an ambiguous reading's mixture, w.mixed / w.mixpred).
void associate(const Call& c, const Map& map, const Options& opt, Work& w) {
    const double* const x = c.x;
    const double* const P = c.P;
    const int64_t m = c.m;
    const double* const z = c.z;
    const uint8_t* const present = c.present;
    const int64_t* const candidates = c.candidates;
    const double* const p = c.p;
    const int d = opt.sensor == RANGE_ONLY ? 1 : 2;
    // (resized only: status, lo and hi are set below, zc where read, nearest and row_start by
    // collect)
    w.status.resize(m);
    w.landmark.assign(m, -1);
    w.nearest.resize(m);
    w.zc.resize(m * d);
    w.point.resize(2 * m);
    w.gate_window.resize(m);
    w.pair_d2.assign(m, INF);
    w.lo.resize(m);
    w.hi.resize(m);
    if (static_cast<int64_t>(w.pred.size()) < map.L) {
        w.pred.resize(map.L);
        w.range.resize(map.L);
        w.bound.resize(map.L);
        w.bound_phi.resize(map.L);
    }
    w.done.assign(map.L, 0);  // per landmark: bit 1 its bound is known, bit 2 its prediction
    w.pairs.clear();
    w.row_start.resize(m + 1);
    w.chosen.assign(m, nullptr);
    w.update.clear();
    // raw pointers: the compiler keeps them in registers (a vector's would be reloaded after
    // every byte store, which may alias it)
    int8_t* const status = w.status.data();
    int32_t* const landmark = w.landmark.data();
    char* const done = w.done.data();
    double *const nearest = w.nearest.data(), *const zc = w.zc.data(),
                  *const pair_d2 = w.pair_d2.data(), *const range = w.range.data(),
                  *const bound = w.bound.data(),
                  *const bound_phi = w.bound_phi.data();
    Predicted* const pred = w.pred.data();
    int64_t *const row_start = w.row_start.data(), *const lo = w.lo.data(),
                   *const hi = w.hi.data();
    const Pair** const chosen = w.chosen.data();
    auto& pairs = w.pairs;
    auto& update = w.update;
    const SensorPose sp = sensor_pose(x, p);
    // The cheap bound that spares most landmarks their prediction (atan2, H, S) and most pairs
    // their d². For the landmark at range r from the sensor, |H_r|² = 1 + (dx oy - dy ox)²/r²
    // <= 1 + |o|² (Cauchy-Schwarz) and λmax(P) <= tr P, so S_rr <= tr P (1 + |o|²) + R_rr =: b;
    // a 2-vector's d² is at least that of its first component (a marginal), so
    //   d² >= (z_r - r)² / b    and the Euclidean cost |v|² >= (z_r - r)².
    const double trace_p = P[0] + P[4] + P[8];
    const double trace_gain = trace_p * (1.0 + sp.ox * sp.ox + sp.oy * sp.oy);
    const double mount_norm = std::sqrt(sp.ox * sp.ox + sp.oy * sp.oy);
    const bool by_d2 = opt.cost == MAHALANOBIS || opt.method == JCBB;  // (see value below)
    // A landmark's range r and its b; b_φ for the point bound (collect's bounds).
    auto bound_of = [&](int64_t l) {
        if (!(done[l] & 1)) {
            const double dx = map.xy[2 * l] - sp.x, dy = map.xy[2 * l + 1] - sp.y;
            const double r = std::sqrt(dx * dx + dy * dy);
            range[l] = r;
            bound[l] = trace_gain + range_variance(r, p, opt);
            if (d == 2 && by_d2) {
                const double ir = 1.0 / r, u = 1.0 + mount_norm * ir;
                bound_phi[l] = (ir * ir + u * u) * trace_p + bearing_variance(r, p, opt);
            }
            done[l] |= 1;
        }
    };
    auto predicted = [&](int64_t l) -> const Predicted& {
        if (!(done[l] & 2)) {
            predict_landmark(sp, P, map.xy + 2 * l, p, opt, d, pred[l]);
            done[l] |= 2;
        }
        return pred[l];
    };
    // a reading's candidates: rows lo[i]..hi[i] of these
    const int64_t* const cand = opt.signatures ? map.sig_landmark.data() : map.rows.data();
    auto add_pair = [&](int64_t i, int64_t l) {
        const Predicted& pr = predicted(l);
        if (!pr.ok) return;
        // written in place (a Pair built aside and copied in is read back, 16 bytes at a time,
        // before its 8-byte stores have landed: a store-forwarding stall per pair)
        Pair& q = pairs.emplace_back();
        q.i = i;
        q.l = l;
        q.v[0] = zc[i * d] - pr.h[0];
        q.v[1] = d == 2 ? wrap(zc[i * d + 1] - pr.h[1]) : 0.0;
        q.d2 = mahalanobis2(pr, q.v, d);
        q.cost = opt.cost == EUCLIDEAN ? q.v[0] * q.v[0] + q.v[1] * q.v[1] : q.d2;
        nearest[i] = std::min(nearest[i], q.d2);
    };
    // The value a reading's pair is chosen by, and its bound from the range alone (above):
    // one-to-one pairing takes the pair of least cost (Mahalanobis d² or Euclidean |v|²);
    // JCBB looks at the pairs inside the gate and the nearest by d² (by_d2).
    auto value = [&](int64_t i, int64_t l) {
        const Predicted& pr = predicted(l);
        if (!pr.ok) return INF;
        const double v[2] = {zc[i * d] - pr.h[0], d == 2 ? wrap(zc[i * d + 1] - pr.h[1]) : 0.0};
        return by_d2 ? mahalanobis2(pr, v, d) : v[0] * v[0] + v[1] * v[1];
    };
    // The largest bound b (the range variance grows with the range): at the corner of the map's
    // box farthest from the sensor.
    const double far_x = std::max(std::fabs(map.box[0] - sp.x), std::fabs(map.box[1] - sp.x));
    const double far_y = std::max(std::fabs(map.box[2] - sp.y), std::fabs(map.box[3] - sp.y));
    const double b_max =
        trace_gain + range_variance(std::sqrt(far_x * far_x + far_y * far_y), p, opt);
    // The limit of the candidates' bounds for a least value (JCBB and the Mahalanobis cost: at
    // least the gate's), with a margin for rounding: the bound is a bound of the exact values.
    auto limit = [&](double least) {
        const double t = by_d2 ? std::max(least, opt.gate2) : least;
        return t * (1.0 + 1e-9) + 1e-300;
    };
    // The window of reading i for the limit tau (every landmark a candidate): ranges r0..r1 (the
    // range bound: h² = τ max b, or τ for the Euclidean cost) and, range-bearing with the point
    // bound (see collect), within rho of where the reading puts its landmark, the point bound's
    // denominator at most its value with each term at its largest over r0..r1 (1/r terms at r0,
    // the others at r1). (Rounding here is inside the margins.)
    // h: half_width(tau), the same for all readings.
    auto half_width = [&](double tau) {
        return std::sqrt(by_d2 ? tau * b_max : tau) * (1.0 + 1e-6);
    };
    auto window_of = [&](int64_t i, double tau, double h) {
        const double zr = zc[i * d];
        Window wd{zr - h, zr + h, INF};
        if (d == 2 && by_d2 && zr > 0.0 && wd.r0 > 0.0) {
            const double inv = 1.0 / wd.r0, u = 1.0 + mount_norm * inv;
            const double b_phi = (inv * inv + u * u) * trace_p + bearing_variance(wd.r1, p, opt);
            wd.rho = std::sqrt(tau * (trace_gain + range_variance(wd.r1, p, opt) +
                                      wd.r1 * zr * b_phi));
        }
        return wd;
    };
    // The landmarks that may lie in the annulus rlo <= r <= rhi around the sensor and within rho
    // of the point (px, py) (rho = INF: anywhere), each passed to f: the map's grid cells that
    // meet both (by the box of their landmarks), then each landmark's own squared distances, with
    // a margin for rounding: a superset (the caller tests exactly what it needs). The distances
    // are computed as the bounds compute them, and a landmark's are no less (no more) than its
    // box's nearest (farthest) ones (rounding is monotone). Non-finite input: every landmark.
    auto region = [&](double rlo, double rhi, double px, double py, double rho, auto&& f) {
        const double qlo = rlo > 0.0 ? rlo * rlo * (1.0 - 1e-6) : -INF;
        const double qhi = rhi * rhi * (1.0 + 1e-6), rho2 = rho * rho * (1.0 + 1e-6);
        const bool clip = std::isfinite(sp.x) && std::isfinite(sp.y) && std::isfinite(px) &&
                          std::isfinite(py) && !std::isnan(qlo) && !std::isnan(qhi) &&
                          !std::isnan(rho2);
        int64_t x0 = 0, x1 = map.nx - 1, y0 = 0, y1 = map.ny - 1;
        if (clip) {  // the cells of the box around both discs (the grid's cell of a coordinate)
            const double es = rhi * (1.0 + 1e-5), ep = rho * (1.0 + 1e-5);
            const double slack =
                1e-12 * (std::fabs(sp.x) + std::fabs(sp.y) + std::fabs(px) + std::fabs(py));
            auto cells = [&](double a, double b, double g, int64_t n, int64_t& ca, int64_t& cb) {
                const double fa = (a - slack - g) * map.inv_cell, fb = (b + slack - g) * map.inv_cell;
                ca = fa > 0.0 ? (fa < n - 1 ? static_cast<int64_t>(fa) : n - 1) : 0;
                cb = fb < n - 1 ? (fb > 0.0 ? static_cast<int64_t>(fb) : 0) : n - 1;
            };
            cells(std::max(sp.x - es, px - ep), std::min(sp.x + es, px + ep), map.gx, map.nx, x0,
                  x1);
            cells(std::max(sp.y - es, py - ep), std::min(sp.y + es, py + ep), map.gy, map.ny, y0,
                  y1);
        }
        // |a| nearest to 0 over the interval [a0, a1]: a0 if a0 > 0, -a1 if a1 < 0, else 0,
        // i.e. the largest of the three (maxima: no branches, whose outcome varies by cell)
        auto nearest_abs = [](double a0, double a1) { return std::max(std::max(a0, -a1), 0.0); };
        for (int64_t cy = y0; cy <= y1; ++cy)
            for (int64_t cx = x0; cx <= x1; ++cx) {
                const int64_t c = cy * map.nx + cx;
                const int64_t k0 = map.cell_start[c], k1 = map.cell_start[c + 1];
                if (k0 == k1) continue;
                if (clip) {
                    const double* b = map.cell_box.data() + 4 * c;
                    const double sx0 = b[0] - sp.x, sx1 = b[1] - sp.x, sy0 = b[2] - sp.y,
                                 sy1 = b[3] - sp.y;
                    const double ax = nearest_abs(sx0, sx1), ay = nearest_abs(sy0, sy1);
                    const double fx = std::max(-sx0, sx1), fy = std::max(-sy0, sy1);
                    if (ax * ax + ay * ay > qhi || fx * fx + fy * fy < qlo) continue;
                    const double bx = nearest_abs(b[0] - px, b[1] - px),
                                 by = nearest_abs(b[2] - py, b[3] - py);
                    if (bx * bx + by * by > rho2) continue;
                }
                for (int64_t k = k0; k < k1; ++k) {
                    const int64_t l = map.cell_landmark[k];
                    if (clip) {
                        const double dx = map.xy[2 * l] - sp.x, dy = map.xy[2 * l + 1] - sp.y;
                        const double q = dx * dx + dy * dy;
                        if (q > qhi || q < qlo) continue;
                        const double ex = map.xy[2 * l] - px, ey = map.xy[2 * l + 1] - py;
                        if (ex * ex + ey * ey > rho2) continue;
                    }
                    f(l);
                }
            }
    };
    // Each usable reading's candidates (its signature's landmarks, or all) and their pairs, in
    // increasing landmark row (the reference's order for ties). Pruned (all = false): the
    // candidates whose bound does not exceed the limit τ of the least value (JCBB: nor the
    // gate), i.e. each reading's cheapest pair (what one-to-one pairing takes when no two
    // readings want the same landmark) and, with the Mahalanobis cost or JCBB, every pair inside
    // the gate. With those, τ is the gate's own limit as soon as one candidate lies inside the
    // gate: that is tried first (on the gate's window, a superset). Else the least value, best
    // first: from a guess, candidates in increasing bound, exactly, until the next bound
    // exceeds the least value found (no candidate left can beat it).
    // all = true: every candidate (Eq. 21, and the Euclidean one-to-one when two readings want
    // the same landmark); full[i]: every candidate of reading i (the readings the gate's pass
    // of one-to-one pairing left).
    // With every landmark a candidate, those whose bound may pass τ lie within h of the
    // reading's range (h² = τ max b, or τ for the Euclidean cost) and, range-bearing, within
    // ρ of where the reading puts its landmark (ρ² = τ times the point bound's largest
    // denominator over those ranges): the map's grid gives them (region), so a reading looks
    // at the landmarks near it only.
    auto collect = [&](bool all, const char* full = nullptr) {
        pairs.clear();
        pairs.reserve(static_cast<size_t>(m) * std::max<int64_t>(map.L, 1));
        if (static_cast<int64_t>(w.keys.size()) < map.L) w.keys.resize(map.L), w.near.resize(map.L);
        double* const keys = w.keys.data();  // per landmark: its bound (-1: evaluated)
        int64_t* const near = w.near.data();  // candidates (landmark rows) that may matter
        for (int64_t i = 0; i < m; ++i) {
            row_start[i] = static_cast<int64_t>(pairs.size());
            nearest[i] = INF;
            if (status[i] != UNKNOWN || lo[i] == hi[i]) continue;
            const int64_t n = hi[i] - lo[i];
            const int64_t* const ci = cand + lo[i];
            int64_t nn = 0;
            if (all || n == 1 || (full && full[i])) {  // (one candidate: nothing to prune)
                for (int64_t k = 0; k < n; ++k) near[nn++] = ci[k];
            } else {
                const double zr = zc[i * d];
                const double px = w.point[2 * i], py = w.point[2 * i + 1];
                auto dist2 = [&](int64_t l) {
                    const double ex = map.xy[2 * l] - px, ey = map.xy[2 * l + 1] - py;
                    return ex * ex + ey * ey;
                };
                // A second bound of d², from the whole reading (range-bearing, z_r > 0): with
                // c = r z_r, |landmark - (px, py)|² = v_r² + 4c sin²(v_φ/2) <= v_r² + c v_φ² =
                // vᵀ diag(1, c) v, so d² = vᵀ S⁻¹ v >= |landmark - (px, py)|² / (S_rr + c S_φφ)
                // (λmax of diag(1, c)^½ S diag(1, c)^½ <= its trace), with S_rr <= b and
                // S_φφ <= |H_φ|² tr P + R_φφ, |H_φ|² = 1/r² + (1 + (dy oy + dx ox)/r²)² <=
                // 1/r² + (1 + |o|/r)²: no bearing (atan2) needed. The key is the larger bound.
                const bool point = d == 2 && by_d2 && zr > 0.0;
                // The two bounds of landmark l as fractions: the range's g²/b (by_d2; else the
                // Euclidean g²/1) and, with point, the point's dist2/(b + r z_r b_φ).
                struct Bounds {
                    double num, den, num_p, den_p;
                };
                auto bounds = [&](int64_t l) {  // (b and b_φ of the landmark from bound_of)
                    bound_of(l);
                    const double r = range[l], g = zr - r;
                    Bounds f{g * g, by_d2 ? bound[l] : 1.0, 0.0, 1.0};
                    if (point) f.num_p = dist2(l), f.den_p = bound[l] + r * zr * bound_phi[l];
                    return f;
                };
                // The key: the larger bound (a NaN range bound stays NaN).
                auto key_of = [&](int64_t l) {
                    const Bounds f = bounds(l);
                    const double k = f.num / f.den;
                    return point ? std::max(k, f.num_p / f.den_p) : k;
                };
                // Whether the key exceeds tau, without its divisions (num > τ den: the same to
                // rounding, inside the limit's margin; a NaN bound exceeds nothing).
                auto exceeds = [&](int64_t l, double tau) {
                    const Bounds f = bounds(l);
                    return f.num > tau * f.den || f.num_p > tau * f.den_p;
                };
                // The candidates whose bound does not exceed tau, in near (a NaN bound keeps
                // one), from every candidate (signatures) or the reading's window wd in the map
                // (all landmarks).
                const bool window = !opt.signatures;
                auto gather = [&](double tau, const Window& wd) {
                    nn = 0;
                    auto keep = [&](int64_t l) {
                        if (!exceeds(l, tau)) near[nn++] = l;
                    };
                    if (window)
                        region(wd.r0, wd.r1, px, py, wd.rho, keep);
                    else
                        for (int64_t k = 0; k < n; ++k) keep(ci[k]);
                };
                if (by_d2) {  // τ is at least the gate's limit, that if a candidate is inside
                    // (mostly the case): the pairs of the gate's candidates, kept if one is
                    // inside the gate (so the reading is not degenerate), else dropped for the
                    // search below. The candidates: those in the gate's window (every landmark
                    // a candidate) or all of them (signatures), their bounds not tested: the
                    // window's landmarks are mostly those the bounds keep, and a pair outside
                    // the gate next to one inside changes nothing (not the cheapest, not in the
                    // gate's pass of one-to-one pairing, not of JCBB, not of the mixture).
                    nn = 0;
                    if (window) {
                        const Window& wd = w.gate_window[i];
                        region(wd.r0, wd.r1, px, py, wd.rho, [&](int64_t l) { near[nn++] = l; });
                    } else {
                        for (int64_t k = 0; k < n; ++k) near[nn++] = ci[k];
                    }
                    std::sort(near, near + nn);  // increasing row (the grid's cells are by place)
                    for (int64_t j = 0; j < nn; ++j) add_pair(i, near[j]);
                    bool settled = false;
                    for (size_t k = row_start[i]; k < pairs.size(); ++k)
                        settled = settled || pairs[k].d2 <= opt.gate2;
                    if (settled) continue;
                    pairs.resize(row_start[i]);
                    nearest[i] = INF;
                }
                {  // (no candidate inside the gate, or the Euclidean cost's one-to-one pairing)
                    // The first candidate evaluated: a guess at the cheapest, which only sets
                    // how many candidates the search below evaluates, never what it finds (the
                    // least value over all of them): the landmark nearest to where the reading
                    // puts it (range-bearing), so that the least value (and the search's limit)
                    // is small from the start; range only: the least bound (signatures) or a
                    // landmark near in range (from the grid, one cell around first, wider until
                    // one is found).
                    int64_t first = ci[0];
                    double best = INF;
                    if (!window) {
                        for (int64_t k = 0; k < n; ++k) {
                            const double e = d == 2 ? dist2(ci[k]) : key_of(ci[k]);
                            if (e < best) best = e, first = ci[k];
                        }
                    } else {
                        bool found = false;
                        for (double delta = map.cell; !found; delta *= 2.0)
                            region(zr - delta, zr + delta, px, py, d == 2 ? delta : INF,
                                   [&](int64_t l) {
                                       const double dx = map.xy[2 * l] - sp.x,
                                                    dy = map.xy[2 * l + 1] - sp.y;
                                       const double e = d == 2 ? dist2(l)
                                                               : std::fabs(dx * dx + dy * dy -
                                                                           zr * zr);
                                       if (!found || e < best) best = e, first = l;
                                       found = true;
                                   });
                    }
                    double least = value(i, first);
                    gather(limit(least), window_of(i, limit(least), half_width(limit(least))));
                    for (int64_t j = 0; j < nn; ++j) keys[near[j]] = key_of(near[j]);
                    const double done_key = -1.0;  // marks a candidate evaluated
                    keys[first] = done_key;
                    for (;;) {  // best first among the rest
                        int64_t next = -1;
                        for (int64_t j = 0; j < nn; ++j) {
                            const double kk = keys[near[j]];
                            if (kk != done_key && (next < 0 || kk < keys[near[next]])) next = j;
                        }
                        if (next < 0 || keys[near[next]] > least * (1.0 + 1e-9)) break;
                        least = std::min(least, value(i, near[next]));
                        keys[near[next]] = done_key;
                    }
                    const double tau = limit(least);
                    int64_t kept = 0;
                    for (int64_t j = 0; j < nn; ++j)
                        if (!exceeds(near[j], tau)) near[kept++] = near[j];
                    nn = kept;
                }
                std::sort(near, near + nn);  // increasing row (the grid's cells are by place)
            }
            for (int64_t j = 0; j < nn; ++j) add_pair(i, near[j]);
            if (static_cast<int64_t>(pairs.size()) == row_start[i]) status[i] = DEGENERATE;
        }
        row_start[m] = static_cast<int64_t>(pairs.size());
    };
    for (int64_t i = 0; i < m; ++i) {
        const double* zi = z + i * d;
        bool usable = std::isfinite(zi[0]) && zi[0] > 0.0;
        if (d == 2) usable = usable && std::isfinite(zi[1]);
        status[i] = (present && !present[i]) ? ABSENT : (usable ? UNKNOWN : INVALID);
        if (status[i] != UNKNOWN) continue;
        zc[i * d] = zi[0] - p[BIAS_R];
        if (d == 2) zc[i * d + 1] = zi[1] - p[BIAS_B];
        lo[i] = 0, hi[i] = map.L;
        if (opt.signatures) lo[i] = candidates[2 * i], hi[i] = candidates[2 * i + 1];
        // A reading of several candidates: where it puts its landmark (range-bearing; range
        // only: the sensor), and below its window for the gate's limit, the first that collect
        // looks in: computed here, for all readings before any search, so that their
        // trigonometry, divisions and square roots (independent of each other) overlap.
        if (hi[i] - lo[i] < 2) continue;
        double* const pt = w.point.data() + 2 * i;
        pt[0] = sp.x, pt[1] = sp.y;
        if (d == 2) {
            const double a = sp.heading + zc[i * d + 1];
            pt[0] += zc[i * d] * std::cos(a), pt[1] += zc[i * d] * std::sin(a);
        }
    }
    // (The windows in a loop of their own, after the points: glibc's sincos begins by saving
    // the rounding mode (stmxcsr, where a profile puts much of its time), which presumably
    // waits for the floating-point operations before it, here each window's divisions and
    // square roots.)
    if (by_d2 && !opt.signatures) {
        const double gate_tau = limit(0.0), gate_h = half_width(gate_tau);
        for (int64_t i = 0; i < m; ++i)
            if (status[i] == UNKNOWN && hi[i] - lo[i] >= 2)
                w.gate_window[i] = window_of(i, gate_tau, gate_h);
    }
    collect(opt.method == PER_LANDMARK);
    // chosen: each reading's pair (used or gated); update: the pairs of the stacked update
    auto usable_with_pairs = [&](int64_t i) {
        return status[i] == UNKNOWN && row_start[i + 1] > row_start[i];
    };
    if (opt.method == GREEDY) {
        // Greedy one-to-one, cheapest pair first (ties: lower reading, then lower landmark).
        // When no two readings share their cheapest landmark, that is each reading's cheapest.
        auto& best = w.best;
        auto& owner = w.owner;
        auto cheapest = [&]() {
            best.assign(m, nullptr);
            for (const Pair& q : pairs)
                if (!best[q.i] || q.cost < best[q.i]->cost) best[q.i] = &q;
            owner.resize(map.L, -1);  // (all -1 between calls: reset below)
            bool clash = false;
            int64_t i = 0;
            for (; i < m && !clash; ++i)
                if (best[i]) {
                    clash = owner[best[i]->l] >= 0;
                    if (!clash) owner[best[i]->l] = i;
                }
            for (int64_t k = 0; k < i; ++k)
                if (best[k] && owner[best[k]->l] == k) owner[best[k]->l] = -1;
            return clash;
        };
        bool clash = cheapest();
        if (clash) {
            // The greedy run over all pairs sorted by (cost, reading, landmark). With the
            // Mahalanobis cost the pairs inside the gate come first, so they are paired first
            // on their own; then the pairs outside, of the readings and landmarks left. The
            // pruned pairs hold every pair inside the gate, so the first pass runs on them and
            // only the readings it leaves get all their pairs for the second (the pairs of the
            // others cannot be taken there); with the Euclidean cost every pair may matter.
            const bool split = opt.cost == MAHALANOBIS;
            if (!split) collect(true);
            auto& order = w.order;
            auto& taken = w.taken;
            taken.assign(map.L, 0);
            auto by_cost = [](const Pair* a, const Pair* b) {
                if (a->cost != b->cost) return a->cost < b->cost;
                if (a->i != b->i) return a->i < b->i;
                return a->l < b->l;
            };
            for (int pass = 0; pass < (split ? 2 : 1); ++pass) {
                if (pass == 1) {
                    auto& full = w.full;
                    full.assign(m, 0);
                    bool left = false;
                    for (int64_t i = 0; i < m; ++i)
                        if (usable_with_pairs(i) && !chosen[i]) full[i] = 1, left = true;
                    if (!left) break;
                    // the pairs rebuilt (the same for the readings paired): chosen re-pointed
                    for (int64_t i = 0; i < m; ++i) landmark[i] = chosen[i] ? chosen[i]->l : -1;
                    collect(false, full.data());
                    for (int64_t i = 0; i < m; ++i) {
                        chosen[i] = nullptr;
                        for (int64_t k = row_start[i]; k < row_start[i + 1] && landmark[i] >= 0; ++k)
                            if (pairs[k].l == landmark[i]) chosen[i] = &pairs[k];
                        landmark[i] = -1;
                    }
                }
                order.clear();
                for (const Pair& q : pairs) {
                    if (!std::isfinite(q.cost) || chosen[q.i] || taken[q.l]) continue;
                    if (split && (pass == 0) != (q.d2 <= opt.gate2)) continue;
                    order.push_back(&q);
                }
                std::sort(order.begin(), order.end(), by_cost);
                for (const Pair* q : order)
                    if (!chosen[q->i] && !taken[q->l]) {
                        chosen[q->i] = q;
                        taken[q->l] = 1;
                    }
            }
        } else {
            for (int64_t i = 0; i < m; ++i) chosen[i] = best[i];
        }
        for (int64_t i = 0; i < m; ++i) {
            if (!usable_with_pairs(i)) continue;
            if (!chosen[i]) {
                status[i] = LOST;
                pair_d2[i] = nearest[i];
                continue;
            }
            landmark[i] = static_cast<int32_t>(chosen[i]->l);
            pair_d2[i] = chosen[i]->d2;
            status[i] = chosen[i]->d2 <= opt.gate2 ? USED : GATED;
            if (status[i] == USED) update.push_back(chosen[i]);
        }
    } else if (opt.method == PER_LANDMARK) {
        // Eq. 21: each landmark takes its cheapest reading (ties: the lower reading).
        std::vector<const Pair*> best(map.L, nullptr);
        for (const Pair& q : pairs)
            if (!best[q.l] || q.cost < best[q.l]->cost) best[q.l] = &q;
        std::vector<const Pair*> served(m, nullptr), refused(m, nullptr);
        for (int64_t l = 0; l < map.L; ++l) {
            const Pair* q = best[l];
            if (!q || !std::isfinite(q->cost)) continue;
            if (q->d2 <= opt.gate2) {
                update.push_back(q);
                if (!served[q->i]) served[q->i] = q;
            } else if (!refused[q->i]) {
                refused[q->i] = q;
            }
        }
        for (int64_t i = 0; i < m; ++i) {
            if (!usable_with_pairs(i)) continue;
            const Pair* q = served[i] ? served[i] : refused[i];
            status[i] = served[i] ? USED : (refused[i] ? GATED : LOST);
            chosen[i] = q;
            if (q) landmark[i] = static_cast<int32_t>(q->l), pair_d2[i] = q->d2;
        }
    } else {  // JCBB
        std::vector<std::vector<const Pair*>> options(m);
        for (const Pair& q : pairs)
            if (q.d2 <= opt.gate2) options[q.i].push_back(&q);
        for (auto& o : options)
            std::stable_sort(o.begin(), o.end(),
                             [](const Pair* a, const Pair* b) { return a->d2 < b->d2; });
        update = jcbb(options, pred, P, d, opt);
        for (const Pair* q : update) chosen[q->i] = q;
        for (int64_t i = 0; i < m; ++i) {
            if (!usable_with_pairs(i)) continue;
            if (chosen[i]) {
                status[i] = USED;
            } else {  // no individually or jointly compatible landmark: its nearest, gated
                status[i] = GATED;
                for (int64_t k = row_start[i]; k < row_start[i + 1]; ++k)
                    if (!chosen[i] || pairs[k].d2 < chosen[i]->d2) chosen[i] = &pairs[k];
            }
            landmark[i] = static_cast<int32_t>(chosen[i]->l);
            pair_d2[i] = chosen[i]->d2;
        }
    }
    // A used reading with more than one landmark inside its gate (Mahalanobis cost or JCBB:
    // not Euclidean Eq. 22 nor Eq. 21, which stay as the lecture has them) enters the update
    // as the mixture of its candidates (mix_reading); with signatures there is one candidate.
    w.mixed.resize(m);
    w.mixpred.resize(m);
    std::vector<const Predicted*>& upred = w.upred;
    upred.clear();
    for (const Pair*& q : update) {
        upred.push_back(&pred[q->l]);
        if (!(by_d2 && opt.method != PER_LANDMARK)) continue;
        const int64_t i = q->i;
        std::vector<const Pair*>& cands = w.order;
        cands.clear();
        for (int64_t k = row_start[i]; k < row_start[i + 1]; ++k)
            if (pairs[k].d2 <= opt.gate2) cands.push_back(&pairs[k]);
        if (cands.size() < 2) continue;
        if (!mix_reading(cands.data(), static_cast<int>(cands.size()), pred, P, d, w.mixpred[i],
                         w.mixed[i]))
            continue;
        w.mixed[i].l = q->l;  // the reading's landmark stays the one its association chose
        q = &w.mixed[i];
        chosen[i] = q;
        pair_d2[i] = q->d2;
        upred.back() = &w.mixpred[i];
    }
}

void report(const Call& c, const Options& opt, Work& w, const double* delta, const double* Pn,
            double nis, LogDet logdet, bool ok);

// The correction of W filters (each its own call and scratch), their association first, then
// their updates side by side (kalman_lanes), then what each reports. (The filters of a batch
// often see the same readings: associated one after the other, they also take the same
// branches.)
template <int W>
void correct_lanes(const Call* calls, const Map& map, const Options& opt) {
    const int d = opt.sensor == RANGE_ONLY ? 1 : 2;
    // scratch of this thread, reused between calls (no allocation per time stamp)
    Work* const work = thread_work();
    for (int l = 0; l < W; ++l) associate(calls[l], map, opt, work[l]);
    // The correction with the used pairs (Eqs. 26-28), one per time stamp: their stacked
    // update, done pair by pair (kalman_block: each pair's noise is its own, so R is block
    // diagonal and the 2 × 2 blocks in turn are the stacked 2k × 2k update). The lanes' running
    // δ and P lane innermost (kalman_lanes), from one pair to the next.
    struct Lane {
        double nis = 0.0, c2, lambda;
        LogDet logdet;
        bool ok = true, robust, reweighted;
    };
    Lane lane[W];
    double delta[3 * W], Pn[9 * W];
    size_t most = 0;  // the most pairs of a lane
    for (int l = 0; l < W; ++l) {
        Lane& s = lane[l];
        const double* p = calls[l].p;
        for (int e = 0; e < 3; ++e) delta[e * W + l] = 0.0;
        for (int e = 0; e < 9; ++e) Pn[e * W + l] = calls[l].P[e];
        s.robust = std::isfinite(p[NU]);
        // correlated readings carry less information than their spread says: the update's R
        // is inflated by c² (NoiseParameters.inflation); association, gate and likelihood
        // keep the readings' R
        s.c2 = p[INFLATION] * p[INFLATION];
        s.lambda = p[CLUTTER];
        s.reweighted = s.robust || s.c2 != 1.0 || s.lambda > 0.0;
        most = std::max(most, work[l].update.size());
    }
    auto given = [&](int l, const Pair* q, int k) -> double* {  // where the pair's y', S' go
        const ReadingOut& out = calls[l].out;
        return !out.y_given ? nullptr
                            : (k ? out.S_given + q->i * d * d : out.y_given + q->i * d);
    };
    // Pair u of every lane that has one (and has not failed), those lanes side by side (the
    // others idle in their lanes).
    for (size_t u = 0; u < most; ++u) {
        double wgt[W], nis[W];
        double *yo[W], *So[W];
        const Pair* q[W];
        const Predicted* pr[W];
        bool active[W], okl[W];
        LogDet logdet[W];
        for (int l = 0; l < W; ++l) {
            Lane& s = lane[l];
            active[l] = s.ok && u < work[l].update.size();
            nis[l] = s.nis, logdet[l] = s.logdet;
            yo[l] = So[l] = nullptr;
            if (!active[l]) continue;
            const double* p = calls[l].p;
            q[l] = work[l].update[u];
            pr[l] = work[l].upred[u];
            // Student-t readings: the reading's weight (ν + d)/(ν + d²) scales R by its inverse
            wgt[l] = s.robust ? (p[NU] + d) / (p[NU] + q[l]->d2) : 1.0;
            if (s.c2 != 1.0) wgt[l] /= s.c2;  // (x / 1 is x: no division without inflation)
            if (s.lambda > 0.0) wgt[l] *= landmark_probability(*q[l], *pr[l], d, p, s.lambda);
            if (!s.reweighted) yo[l] = given(l, q[l], 0), So[l] = given(l, q[l], 1);
        }
        if (std::none_of(active, active + W, [](bool a) { return a; })) break;  // all failed
        pair_lanes<W>(d, delta, Pn, q, pr, wgt, active, nis, logdet, yo, So, okl);
        for (int l = 0; l < W; ++l) {
            if (!active[l]) continue;
            Lane& s = lane[l];
            s.ok = okl[l], s.nis = nis[l], s.logdet = logdet[l];
        }
    }
    for (int l = 0; l < W; ++l) {
        double dl[3], Pl[9];
        for (int e = 0; e < 3; ++e) dl[e] = delta[e * W + l];
        for (int e = 0; e < 9; ++e) Pl[e] = Pn[e * W + l];
        report(calls[l], opt, work[l], dl, Pl, lane[l].nis, lane[l].logdet, lane[l].ok);
    }
}

// After the update of a filter's used pairs (delta, Pn, nis, logdet, ok from correct_lanes):
// the likelihood's sequence for a reweighted update, the filter's new state and totals, and
// what it reports per reading.
void report(const Call& c, const Options& opt, Work& w, const double* delta, const double* Pn,
            double nis, LogDet logdet, bool ok) {
    double* const x = c.x;
    double* const P = c.P;
    const int64_t m = c.m;
    const double* const p = c.p;
    const ReadingOut& out = c.out;
    Totals& totals = *c.totals;
    const int d = opt.sensor == RANGE_ONLY ? 1 : 2;
    int8_t* const status = w.status.data();
    const int32_t* const landmark = w.landmark.data();
    const double* const pair_d2 = w.pair_d2.data();
    const Pair* const* const chosen = w.chosen.data();
    const Predicted* const pred = w.pred.data();
    const std::vector<const Pair*>& update = w.update;
    const std::vector<const Predicted*>& upred = w.upred;
    // The likelihood's sequence (R itself) through the used pairs, each pair's innovation and S
    // given the pairs before it (ReadingOut::y_given), and where it ends: a gated reading's
    // given state.
    double dL[3] = {0.0, 0.0, 0.0}, PL[9];
    std::copy(P, P + 9, PL);
    bool given_ok = true;
    auto given = [&](const Pair* q, int k) {  // where the pair's y', S' go (null: not kept)
        return !out.y_given ? nullptr
                            : (k ? out.S_given + q->i * d * d : out.y_given + q->i * d);
    };
    if (!update.empty()) {
        const int D = d * static_cast<int>(update.size());
        const bool robust = std::isfinite(p[NU]);
        const bool reweighted =
            robust || p[INFLATION] * p[INFLATION] != 1.0 || p[CLUTTER] > 0.0;
        if (reweighted && ok) {  // the likelihood is that of S with R itself, not reweighted
            nis = 0.0;
            logdet = LogDet();
            for (size_t u = 0; u < update.size(); ++u)
                ok = ok && pair_block(d, dL, PL, *update[u], *upred[u], 1.0, nis, logdet,
                                      given(update[u], 0), given(update[u], 1));
        } else {
            std::copy(delta, delta + 3, dL);
            std::copy(Pn, Pn + 9, PL);
        }
        for (int k = 0; k < 9; ++k) ok = ok && std::isfinite(Pn[k]);
        for (int k = 0; k < 3; ++k) ok = ok && std::isfinite(delta[k]);
        if (ok) {
            x[0] += delta[0];
            x[1] += delta[1];
            x[2] = wrap(x[2] + delta[2]);
            std::copy(Pn, Pn + 9, P);
            // robust: the multivariate Student-t of dimension D, scale S, ν dof
            totals.loglik += log_density(nis, logdet.value(), D, robust ? p[NU] : INF);
            totals.nis += nis;
            totals.dof += D;
            totals.updates += 1;
            for (const Pair* q : update) totals.ambiguous += q == &w.mixed[q->i];
        } else {
            for (const Pair* q : update) status[q->i] = DEGENERATE;
            given_ok = false;
        }
    }
    for (int64_t i = 0; i < m; ++i) {
        totals.counts[status[i]] += 1;
        if (out.status) out.status[i] = status[i];
        if (out.landmark) out.landmark[i] = landmark[i];
        if (out.d2) out.d2[i] = pair_d2[i];
        const Pair* q = chosen[i];
        const bool has = q && landmark[i] >= 0;
        if (out.y)
            for (int a = 0; a < d; ++a) out.y[i * d + a] = has ? q->v[a] : NaN;
        if (out.S)
            for (int a = 0; a < d * d; ++a)
                out.S[i * d * d + a] =
                    !has ? NaN : (q == &w.mixed[i] ? w.mixpred[i].S[a] : pred[q->l].S[a]);
        if (!out.y_given || (status[i] == USED && given_ok)) continue;  // USED: written above
        if (status[i] == GATED && given_ok && has) {  // given the used readings (if any)
            Predicted g = pred[q->l];
            innovation_cov(g, PL, d);
            innovation_given(d, q->v, g.H, dL, out.y_given + i * d);
            std::copy(g.S, g.S + d * d, out.S_given + i * d * d);
        } else {
            for (int a = 0; a < d; ++a) out.y_given[i * d + a] = NaN;
            for (int a = 0; a < d * d; ++a) out.S_given[i * d * d + a] = NaN;
        }
    }
}

}  // namespace

void correct_filters(int W, const Call* calls, const Map& map, const Options& opt) {
    if (W == LANES)
        correct_lanes<LANES>(calls, map, opt);
    else
        for (int l = 0; l < W; ++l) correct_lanes<1>(calls + l, map, opt);
}

Map::Map(int64_t L_, const double* xy_, const int64_t* s) : L(L_), store(xy_, xy_ + 2 * L_) {
    xy = store.data();
    rows.resize(L);
    for (int64_t l = 0; l < L; ++l) rows[l] = l;
    sig_landmark = rows;
    if (!std::is_sorted(s, s + L))  // (sorted already: the rows are their order)
        std::stable_sort(sig_landmark.begin(), sig_landmark.end(),
                         [&](int64_t a, int64_t b) { return s[a] < s[b]; });
    sig_sorted.resize(L);
    for (int64_t k = 0; k < L; ++k) sig_sorted[k] = s[sig_landmark[k]];
    // the grid: cells of side sqrt(area / L), at least span / L (a thin map: at most about 3L
    // cells); all landmarks at one place: one cell
    for (int64_t l = 0; l < L; ++l) {
        const double x = xy[2 * l], y = xy[2 * l + 1];
        if (!l) box[0] = box[1] = x, box[2] = box[3] = y;
        box[0] = std::min(box[0], x), box[1] = std::max(box[1], x);
        box[2] = std::min(box[2], y), box[3] = std::max(box[3], y);
    }
    const double w = box[1] - box[0], h = box[3] - box[2];
    cell = L ? std::max(std::sqrt(w * h / static_cast<double>(L)),
                        std::max(w, h) / static_cast<double>(L))
             : 1.0;
    if (!(cell > 0.0 && std::isfinite(cell))) cell = 1.0;
    gx = box[0], gy = box[2], inv_cell = 1.0 / cell;
    nx = static_cast<int64_t>(w * inv_cell) + 1, ny = static_cast<int64_t>(h * inv_cell) + 1;
    const int64_t C = nx * ny;
    std::vector<int64_t> of(L);
    cell_start.assign(C + 1, 0);
    for (int64_t l = 0; l < L; ++l) {
        const int64_t cx = std::min(static_cast<int64_t>((xy[2 * l] - gx) * inv_cell), nx - 1);
        const int64_t cy = std::min(static_cast<int64_t>((xy[2 * l + 1] - gy) * inv_cell), ny - 1);
        of[l] = cy * nx + cx;
        ++cell_start[of[l] + 1];
    }
    for (int64_t c = 0; c < C; ++c) cell_start[c + 1] += cell_start[c];
    cell_landmark.resize(L);
    cell_box.assign(4 * C, 0.0);
    std::vector<int64_t> fill(cell_start.begin(), cell_start.end() - 1);
    for (int64_t l = 0; l < L; ++l) {
        const int64_t c = of[l];
        const double x = xy[2 * l], y = xy[2 * l + 1];
        double* b = cell_box.data() + 4 * c;
        if (fill[c] == cell_start[c]) b[0] = b[1] = x, b[2] = b[3] = y;
        b[0] = std::min(b[0], x), b[1] = std::max(b[1], x);
        b[2] = std::min(b[2], y), b[3] = std::max(b[3], y);
        cell_landmark[fill[c]++] = l;
    }
    // the table: at least twice as many slots as signatures (short probes)
    size_t size = 2;
    while (size < 2 * static_cast<size_t>(L)) size *= 2, --shift;
    table.assign(size, Slot{});
    for (int64_t k = 0; k < L;) {
        int64_t e = k + 1;
        while (e < L && sig_sorted[e] == sig_sorted[k]) ++e;
        size_t h = slot_of(sig_sorted[k]);
        while (table[h].lo >= 0) h = (h + 1) & (size - 1);
        table[h] = {sig_sorted[k], k, e};
        k = e;
    }
}

void Map::find(int64_t s, int64_t& lo, int64_t& hi) const {
    const size_t mask = table.size() - 1;
    for (size_t h = slot_of(s);; h = (h + 1) & mask) {
        const Slot& e = table[h];
        if (e.lo < 0 || e.key == s) {
            lo = e.lo < 0 ? 0 : e.lo;
            hi = e.lo < 0 ? 0 : e.hi;
            return;
        }
    }
}

// ----------------------------------------------------------------------------- bindings
namespace {

Options make_options(int sensor, int noise_model, int method, int cost, bool signatures,
                     double gate2, Float1 joint_gate2, int64_t jcbb_nodes) {
    if (sensor < 0 || sensor > 1) throw nb::value_error("unknown sensor kind");
    if (noise_model < 0 || noise_model > 2) throw nb::value_error("unknown noise model");
    if (method < 0 || method > 2) throw nb::value_error("unknown pairing method");
    if (cost < 0 || cost > 1) throw nb::value_error("unknown association cost");
    Options o;
    o.sensor = sensor;
    o.noise_model = noise_model;
    o.method = method;
    o.cost = cost;
    o.signatures = signatures;
    o.gate2 = gate2;
    o.joint_gate2.assign(joint_gate2.data(), joint_gate2.data() + joint_gate2.shape(0));
    o.jcbb_nodes = jcbb_nodes;
    return o;
}

// The parameter rows of B filters: (B, N_PARAMS), or (1, N_PARAMS) shared by all (then the row
// stride is 0: no copy per filter). Returns the row stride.
size_t check_params(Float2 params, size_t B) {
    if ((params.shape(0) != B && params.shape(0) != 1) || params.shape(1) != N_PARAMS)
        throw nb::value_error(("params must be (B, " + std::to_string(N_PARAMS) + ") or (1, " +
                               std::to_string(N_PARAMS) + ")").c_str());
    return params.shape(0) == 1 ? 0 : N_PARAMS;
}

void check_filters(Float2 x, Float3 P) {
    if (x.shape(1) != 3 || P.shape(0) != x.shape(0) || P.shape(1) != 3 || P.shape(2) != 3)
        throw nb::value_error("x must be (B, 3) and P (B, 3, 3)");
}

nb::dict totals_dict(const std::vector<Totals>& t) {
    const size_t B = t.size();
    auto loglik = new_array({B}), nis = new_array({B});
    auto dof = new_array<int64_t>({B}), updates = new_array<int64_t>({B});
    auto overflow = new_array<int64_t>({B}), ambiguous = new_array<int64_t>({B});
    auto counts = new_array<int64_t>({B, static_cast<size_t>(N_STATUS)});
    for (size_t b = 0; b < B; ++b) {
        loglik.data()[b] = t[b].loglik;
        nis.data()[b] = t[b].nis;
        dof.data()[b] = t[b].dof;
        updates.data()[b] = t[b].updates;
        overflow.data()[b] = t[b].overflow;
        ambiguous.data()[b] = t[b].ambiguous;
        for (int s = 0; s < N_STATUS; ++s) counts.data()[b * N_STATUS + s] = t[b].counts[s];
    }
    nb::dict out;
    out["loglik"] = loglik;
    out["nis"] = nis;
    out["dof"] = dof;
    out["updates"] = updates;
    out["overflow"] = overflow;
    out["ambiguous"] = ambiguous;
    out["counts"] = counts;
    return out;
}

}  // namespace

void register_ekf(nb::module_& m) {
    m.def(
        "log_density",
        [](Float1 d2, Float1 logdet, int D, Float1 nu) {
            const size_t n = d2.shape(0);
            if (logdet.shape(0) != n || nu.shape(0) != n)
                throw nb::value_error("d2, logdet and nu must have one length");
            if (D < 1) throw nb::value_error("the dimension must be at least 1");
            auto out = new_array({n});
            for (size_t k = 0; k < n; ++k)
                out.data()[k] = log_density(d2.data()[k], logdet.data()[k], D, nu.data()[k]);
            return out;
        },
        nb::arg("d2"), nb::arg("logdet"), nb::arg("D"), nb::arg("nu"),
        "Log-density (n,) of the normal (nu inf) or the Student-t with scale S and nu dof, at "
        "Mahalanobis d2 = yᵀS⁻¹y with logdet = log det S.");
    nb::class_<Map>(m, "EkfMap",
                    "A landmark map checked and prepared once (internal: see "
                    "relmap.ekf.LandmarkMap).")
        .def(
            "__init__",
            [](Map* self, Float2 landmarks, Index1 signatures) {
                if (landmarks.shape(1) != 2) throw nb::value_error("landmarks must be (L, 2)");
                if (signatures.shape(0) != landmarks.shape(0))
                    throw nb::value_error("landmark signatures must be (L,)");
                new (self) Map(static_cast<int64_t>(landmarks.shape(0)), landmarks.data(),
                               signatures.data());
            },
            nb::arg("landmarks"), nb::arg("signatures"))
        .def_prop_ro("L", [](const Map& map) { return map.L; });
    m.def(
        "ekf_predict_covariance",
        [](Float3 P, Float3 F, Float3 Q) {
            const size_t B = P.shape(0), n = P.shape(1);
            for (auto* a : {&P, &F, &Q})
                if (a->shape(0) != B || a->shape(1) != n || a->shape(2) != n)
                    throw nb::value_error("P, F and Q must be (B, n, n) alike");
            auto out = new_array({B, n, n});
            const size_t nn = n * n;
            for (size_t b = 0; b < B; ++b)
                predict_covariance(static_cast<int>(n), F.data() + b * nn, P.data() + b * nn,
                                   Q.data() + b * nn, out.data() + b * nn);
            return out;
        },
        nb::arg("P"), nb::arg("F"), nb::arg("Q"), "P⁻ = F P Fᵀ + Q for a batch (B, n, n).");

    m.def(
        "ekf_correct",
        [](Float2 x, Float3 P, Float2 y, Float3 H, Float3 R) {
            const size_t B = x.shape(0), n = x.shape(1), D = y.shape(1);
            if (P.shape(0) != B || P.shape(1) != n || P.shape(2) != n || y.shape(0) != B ||
                H.shape(0) != B || H.shape(1) != D || H.shape(2) != n || R.shape(0) != B ||
                R.shape(1) != D || R.shape(2) != D)
                throw nb::value_error("need x (B, n), P (B, n, n), y (B, D), H (B, D, n), R (B, D, D)");
            auto xo = new_array({B, n}), Po = new_array({B, n, n}), So = new_array({B, D, D});
            auto nis = new_array({B}), logdet = new_array({B});
            auto ok = new_array<bool>({B});
            std::copy(x.data(), x.data() + B * n, xo.data());
            std::copy(P.data(), P.data() + B * n * n, Po.data());
            for (size_t b = 0; b < B; ++b) {
                ok.data()[b] = kalman_update(
                    static_cast<int>(n), static_cast<int>(D), xo.data() + b * n,
                    Po.data() + b * n * n, y.data() + b * D, H.data() + b * D * n,
                    R.data() + b * D * D, So.data() + b * D * D, nis.data() + b,
                    logdet.data() + b);
                if (!ok.data()[b]) nis.data()[b] = logdet.data()[b] = NaN;
            }
            return nb::make_tuple(xo, Po, So, nis, logdet, ok);
        },
        nb::arg("x"), nb::arg("P"), nb::arg("y"), nb::arg("H"), nb::arg("R"),
        "The Kalman correction of a batch (Joseph form): (x + K y, P, S, yᵀS⁻¹y, log det S, "
        "ok); where S is not positive definite ok is False and x, P are returned unchanged.");

    m.def(
        "ekf_predict_odometry",
        [](FloatN x, FloatN P, FloatN motion, Float2 params) {
            const size_t n = x.ndim();
            if (n < 1 || x.shape(n - 1) != 3 || P.ndim() != n + 1 || P.shape(n) != 3 ||
                P.shape(n - 1) != 3 || motion.ndim() < 1 || motion.shape(motion.ndim() - 1) != 2)
                throw nb::value_error("x must be (..., 3), P (..., 3, 3) and motion (..., 2)");
            const size_t B = x.size() / 3;
            if (P.size() != 9 * B || (motion.size() != 2 * B && motion.size() != 2))
                throw nb::value_error("x, P and motion must have one batch (or one motion)");
            const double* mo = motion.data();
            const size_t ms = motion.size() == 2 * B ? 2 : 0;  // one step shared: stride 0
            for (size_t k = 0; k < motion.size(); ++k)
                if (!std::isfinite(mo[k]))
                    raise_relmap_error("NonFiniteError",
                                       "odometry steps must be finite; (Δs, Δθ) of filter " +
                                           std::to_string(k / 2) + " has " +
                                           std::to_string(mo[k]));
            const size_t ps = check_params(params, B);
            auto xo = new_result_like(x, n), Po = new_result_like(P, n + 1);
            std::copy(x.data(), x.data() + B * 3, xo.data);
            std::copy(P.data(), P.data() + B * 9, Po.data);
            for (size_t b = 0; b < B; ++b)
                predict_odometry(xo.data + 3 * b, Po.data + 9 * b, mo[ms * b], mo[ms * b + 1],
                                 params.data() + b * ps);
            return nb::make_tuple(xo.array, Po.array);
        },
        nb::arg("x"), nb::arg("P"), nb::arg("motion"), nb::arg("params"),
        "One odometry prediction (midpoint, DistanceNoise) per filter: x (..., 3), P (..., 3, "
        "3), motion (..., 2) of one batch or (2,) for all; non-finite motion raises relmap's "
        "NonFiniteError.");

    m.def(
        "ekf_correct_readings",
        [](FloatN x, FloatN P, FloatN z, BoolN present, IndexN signature, const Map& map,
           Float2 params, int sensor, int noise_model, int method, int cost,
           bool signatures, double gate2, Float1 joint_gate2, int64_t jcbb_nodes) {
            const size_t n = x.ndim();  // the batch: x's leading n - 1 axes
            if (n < 1 || x.shape(n - 1) != 3 || P.ndim() != n + 1 || P.shape(n) != 3 ||
                P.shape(n - 1) != 3 || z.ndim() != n + 1)
                throw nb::value_error("x must be (..., 3), P (..., 3, 3) and z (..., m, d)");
            const size_t B = x.size() / 3, mm = z.shape(n - 1), d = z.shape(n);
            const Options opt = make_options(sensor, noise_model, method, cost, signatures, gate2,
                                             joint_gate2, jcbb_nodes);
            if (P.size() != 9 * B || z.size() != B * mm * d ||
                d != (opt.sensor == RANGE_ONLY ? 1u : 2u))
                throw nb::value_error("z must be (..., m, d), d = 2 (range-bearing) or 1 (range)");
            if (present.size() != B * mm || signature.size() != B * mm)
                throw nb::value_error("present and signature must be (..., m)");
            const uint8_t* const pr = reinterpret_cast<const uint8_t*>(present.data());
            const size_t ps = check_params(params, B);
            // the state x, P (contiguous, as the next prediction reads it) and two packed
            // outputs (one NumPy array each costs more than the arithmetic here): floats per
            // filter y (m d), S (m d d), d² (m), loglik, nis; integers per filter status (m),
            // landmark (m)
            const size_t F = mm * (d + d * d + 1) + 2, I = 2 * mm;
            auto xo = new_result_like(x, n), Po = new_result_like(P, n + 1);
            auto fo = new_result_like(x, n - 1, {F});
            auto io = new_result_like<int64_t>(x, n - 1, {I});
            std::copy(x.data(), x.data() + 3 * B, xo.data);
            std::copy(P.data(), P.data() + 9 * B, Po.data);
            std::vector<int8_t> st(LANES * mm);
            std::vector<int32_t> lmo(LANES * mm);
            std::vector<int64_t> cands(2 * LANES * mm);
            for (size_t b0 = 0; b0 < B; b0 += LANES) {  // LANES filters side by side
                const int W = static_cast<int>(std::min<size_t>(LANES, B - b0));
                Call calls[LANES];
                Totals totals[LANES];
                for (int l = 0; l < W; ++l) {
                    const size_t b = b0 + l;
                    double* f = fo.data + b * F;
                    int64_t* cl = cands.data() + 2 * mm * l;
                    if (opt.signatures)
                        signature_candidates(map, static_cast<int64_t>(mm),
                                             signature.data() + b * mm, cl);
                    calls[l] = {xo.data + 3 * b, Po.data + 9 * b, static_cast<int64_t>(mm),
                                z.data() + b * mm * d, pr + b * mm, cl, params.data() + b * ps,
                                ReadingOut{f, f + mm * d, f + mm * (d + d * d),
                                           st.data() + mm * l, lmo.data() + mm * l},
                                &totals[l]};
                }
                correct_filters(W, calls, map, opt);
                for (int l = 0; l < W; ++l) {
                    const size_t b = b0 + l;
                    double* f = fo.data + b * F;
                    int64_t* iv = io.data + b * I;
                    f[F - 2] = totals[l].loglik;
                    f[F - 1] = totals[l].nis;
                    for (size_t i = 0; i < mm; ++i)
                        iv[i] = st[mm * l + i], iv[mm + i] = lmo[mm * l + i];
                }
            }
            return nb::make_tuple(xo.array, Po.array, fo.array, io.array);
        },
        nb::arg("x"), nb::arg("P"), nb::arg("z"), nb::arg("present"), nb::arg("signature"),
        nb::arg("map"), nb::arg("params"), nb::arg("sensor"),
        nb::arg("noise_model"), nb::arg("method"), nb::arg("cost"), nb::arg("signatures"),
        nb::arg("gate2"), nb::arg("joint_gate2"), nb::arg("jcbb_nodes"),
        "Association, gating and one stacked correction per filter of the readings of one time "
        "stamp (each filter its own readings): x (..., 3), P (..., 3, 3), z (..., m, d), "
        "present and signature (..., m) of one batch; x, P and packed outputs (..., F), (..., I).");

    m.def(
        "ekf_run",
        [](Float2 x0, Float3 P0, Float2 motion, Index1 reading_index, Float2 z, Index1 signature,
           const Map& map, Float2 params, int sensor, int noise_model,
           int method, int cost, bool signatures, double gate2, Float1 joint_gate2,
           int64_t jcbb_nodes, int keep, bool readings_out) {
            check_filters(x0, P0);
            const size_t B = x0.shape(0), K = motion.shape(0), M = z.shape(0), d = z.shape(1);
            const Options opt = make_options(sensor, noise_model, method, cost, signatures, gate2,
                                             joint_gate2, jcbb_nodes);
            if (motion.shape(1) != 2) throw nb::value_error("motion must be (K, 2)");
            if (d != (opt.sensor == RANGE_ONLY ? 1u : 2u))
                throw nb::value_error("z must be (M, d), d = 2 (range-bearing) or 1 (range)");
            if (reading_index.shape(0) != M || signature.shape(0) != M)
                throw nb::value_error("reading_index and signature must be (M,)");
            const int64_t* ri = reading_index.data();
            for (size_t r = 0; r < M; ++r)
                if (ri[r] < 0 || ri[r] > static_cast<int64_t>(K) || (r && ri[r] < ri[r - 1]))
                    throw nb::value_error("reading_index must be non-decreasing in [0, K]");
            const size_t ps = check_params(params, B);
            if (keep < 0 || keep > 2) throw nb::value_error("keep must be 0, 1 or 2");
            // the time stamps with readings: readings lo[e]:lo[e + 1] at time index at[e]
            std::vector<int64_t> lo, at;
            for (size_t r = 0; r < M; ++r)
                if (!r || ri[r] != ri[r - 1]) lo.push_back(r), at.push_back(ri[r]);
            lo.push_back(static_cast<int64_t>(M));
            const size_t E = at.size();
            const size_t T = keep == 2 ? K + 1 : (keep == 1 ? E + 1 : 1);
            // each reading's candidates (its signature's landmarks), the same for every filter
            std::vector<int64_t> cands(opt.signatures ? 2 * M : 0);
            if (opt.signatures)
                signature_candidates(map, static_cast<int64_t>(M), signature.data(), cands.data());
            std::vector<Step> steps(K);
            for (size_t k = 0; k < K; ++k)
                steps[k] = make_step(motion.data()[2 * k], motion.data()[2 * k + 1]);
            auto mean = new_array({B, T, 3}), cov = new_array({B, T, 3, 3});
            const size_t Mo = readings_out ? M : 0;
            auto yo = new_array({B, Mo, d}), So = new_array({B, Mo, d, d}), d2 = new_array({B, Mo});
            auto yg = new_array({B, Mo, d}), Sg = new_array({B, Mo, d, d});
            auto st = new_array<int8_t>({B, Mo});
            auto lmo = new_array<int32_t>({B, Mo});
            std::vector<Totals> totals(B);
            {
                nb::gil_scoped_release release;
                for (size_t b0 = 0; b0 < B; b0 += LANES) {  // LANES filters side by side
                    const int W = static_cast<int>(std::min<size_t>(LANES, B - b0));
                    double x[LANES][3], P[LANES][9];
                    const double* p[LANES];
                    for (int l = 0; l < W; ++l) {
                        const size_t b = b0 + l;
                        std::copy(x0.data() + 3 * b, x0.data() + 3 * b + 3, x[l]);
                        std::copy(P0.data() + 9 * b, P0.data() + 9 * b + 9, P[l]);
                        p[l] = params.data() + b * ps;
                    }
                    auto store = [&](size_t slot) {
                        for (int l = 0; l < W; ++l) {
                            const size_t b = b0 + l;
                            std::copy(x[l], x[l] + 3, mean.data() + (b * T + slot) * 3);
                            std::copy(P[l], P[l] + 9, cov.data() + (b * T + slot) * 9);
                        }
                    };
                    if (keep == 1) store(0);
                    size_t e = 0;
                    for (size_t j = 0; j <= K; ++j) {
                        if (j > 0)
                            for (int l = 0; l < W; ++l) predict_step(x[l], P[l], steps[j - 1], p[l]);
                        if (e < E && at[e] == static_cast<int64_t>(j)) {
                            const int64_t r0 = lo[e], m = lo[e + 1] - lo[e];
                            Call calls[LANES];
                            for (int l = 0; l < W; ++l) {
                                const size_t b = b0 + l;
                                ReadingOut out;
                                if (readings_out) {
                                    const size_t o = b * M + r0;
                                    out = {yo.data() + o * d, So.data() + o * d * d, d2.data() + o,
                                           st.data() + o, lmo.data() + o, yg.data() + o * d,
                                           Sg.data() + o * d * d};
                                }
                                calls[l] = {x[l], P[l], m, z.data() + r0 * d, nullptr,
                                            opt.signatures ? cands.data() + 2 * r0 : nullptr, p[l],
                                            out, &totals[b]};
                            }
                            correct_filters(W, calls, map, opt);
                            ++e;
                            if (keep == 1) store(e);
                        }
                        if (keep == 2) store(j);
                        for (int l = 0; l < W; ++l) {
                            Totals& t = totals[b0 + l];
                            if (t.overflow >= 0) continue;
                            bool finite = true;
                            for (int k = 0; k < 3; ++k) finite = finite && std::isfinite(x[l][k]);
                            for (int k = 0; k < 9; ++k) finite = finite && std::isfinite(P[l][k]);
                            if (!finite) t.overflow = static_cast<int64_t>(j);
                        }
                    }
                    if (keep == 0) store(0);
                }
            }
            nb::dict res = totals_dict(totals);
            res["mean"] = mean;
            res["cov"] = cov;
            res["y"] = yo;
            res["S"] = So;
            res["y_given"] = yg;
            res["S_given"] = Sg;
            res["d2"] = d2;
            res["status"] = st;
            res["landmark"] = lmo;
            res["event_index"] = vector_array(at);
            return res;
        },
        nb::arg("x0"), nb::arg("P0"), nb::arg("motion"), nb::arg("reading_index"), nb::arg("z"),
        nb::arg("signature"), nb::arg("map"), nb::arg("params"), nb::arg("sensor"), nb::arg("noise_model"), nb::arg("method"), nb::arg("cost"),
        nb::arg("signatures"), nb::arg("gate2"), nb::arg("joint_gate2"), nb::arg("jcbb_nodes"),
        nb::arg("keep"), nb::arg("readings_out"),
        "A batch of pose filters over one log: predict each odometry step, correct at the time "
        "indices with readings (all readings of a time index in one stacked update).");
}

}  // namespace relmap::ekf
