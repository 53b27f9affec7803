// The extended Kalman filter (see ekf.hpp).
#include "ekf.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>

#include "arrays.hpp"

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

// Lower Cholesky factor of the D × D matrix S (row-major) into Lw; false unless S is positive
// definite with finite entries.
bool cholesky(int D, const double* S, double* Lw) {
    for (int i = 0; i < D; ++i)
        for (int j = 0; j <= i; ++j) {
            double sum = S[i * D + j];
            for (int k = 0; k < j; ++k) sum -= Lw[i * D + k] * Lw[j * D + k];
            if (i == j) {
                if (!(sum > 0.0) || !std::isfinite(sum)) return false;
                Lw[i * D + i] = std::sqrt(sum);
            } else {
                Lw[i * D + j] = sum / Lw[j * D + j];
            }
        }
    return true;
}

// Solves L Lᵀ u = b in place (L from cholesky).
void cholesky_solve(int D, const double* Lw, double* b) {
    for (int i = 0; i < D; ++i) {
        double sum = b[i];
        for (int k = 0; k < i; ++k) sum -= Lw[i * D + k] * b[k];
        b[i] = sum / Lw[i * D + i];
    }
    for (int i = D - 1; i >= 0; --i) {
        double sum = b[i];
        for (int k = i + 1; k < D; ++k) sum -= Lw[k * D + i] * b[k];
        b[i] = sum / Lw[i * D + i];
    }
}

// Scratch space of kalman_update, reused between calls of one thread.
struct Work {
    std::vector<double> PHt, S, Lw, Lu, K, A, AP, KR, u;
    void reserve(int n, int D) {
        const size_t nD = static_cast<size_t>(n) * D, DD = static_cast<size_t>(D) * D;
        if (PHt.size() < nD) PHt.resize(nD), K.resize(nD), KR.resize(nD);
        if (S.size() < DD) S.resize(DD), Lw.resize(DD), Lu.resize(DD);
        const size_t nn = static_cast<size_t>(n) * n;
        if (A.size() < nn) A.resize(nn), AP.resize(nn);
        if (u.size() < static_cast<size_t>(std::max(n, D))) u.resize(std::max(n, D));
    }
};

thread_local Work work;

}  // namespace

void predict_covariance(int n, const double* F, const double* P, const double* Q, double* out) {
    double FP[64], tmp[64];
    std::vector<double> big;
    double *fp = FP, *t = tmp;
    if (n > 8) {
        big.resize(2 * n * n);
        fp = big.data();
        t = big.data() + n * n;
    }
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

bool kalman_update(int n, int D, double* x, double* P, const double* y, const double* H,
                   const double* R, const double* R_update, double* S_out, double* nis,
                   double* logdet) {
    Work& w = work;
    w.reserve(n, D);
    double *PHt = w.PHt.data(), *S = w.S.data(), *Lw = w.Lw.data(), *K = w.K.data();
    for (int i = 0; i < n; ++i)  // P⁻ Hᵀ
        for (int a = 0; a < D; ++a) {
            double s = 0.0;
            for (int k = 0; k < n; ++k) s += P[i * n + k] * H[a * n + k];
            PHt[i * D + a] = s;
        }
    auto innovation_covariance = [&](const double* Rm) {  // S = H P⁻ Hᵀ + R, symmetrized
        for (int a = 0; a < D; ++a)
            for (int b = 0; b <= a; ++b) {
                double s = 0.0;
                for (int k = 0; k < n; ++k) s += H[a * n + k] * PHt[k * D + b];
                const double v = s + 0.5 * (Rm[a * D + b] + Rm[b * D + a]);
                S[a * D + b] = S[b * D + a] = v;
            }
    };
    innovation_covariance(R);
    if (S_out) std::copy(S, S + D * D, S_out);
    if (!cholesky(D, S, Lw)) return false;
    double q = 0.0, ld = 0.0;  // yᵀ S⁻¹ y = |L⁻¹ y|², log det S = 2 Σ log Lᵢᵢ
    for (int i = 0; i < D; ++i) {
        double s = y[i];
        for (int k = 0; k < i; ++k) s -= Lw[i * D + k] * w.u[k];
        w.u[i] = s / Lw[i * D + i];
        q += w.u[i] * w.u[i];
        ld += 2.0 * std::log(Lw[i * D + i]);
    }
    *nis = q;
    *logdet = ld;
    const double* Ru = R_update ? R_update : R;
    double* L = Lw;
    if (R_update) {
        innovation_covariance(R_update);
        if (!cholesky(D, S, w.Lu.data())) return false;
        L = w.Lu.data();
    }
    for (int i = 0; i < n; ++i) {  // row i of K = P⁻ Hᵀ S⁻¹: S⁻¹ (row i of P⁻ Hᵀ)
        std::copy(PHt + i * D, PHt + (i + 1) * D, K + i * D);
        cholesky_solve(D, L, K + i * D);
    }
    double dx[16];
    std::vector<double> dx_big;
    double* d = dx;
    if (n > 16) dx_big.resize(n), d = dx_big.data();
    for (int i = 0; i < n; ++i) {
        double s = 0.0;
        for (int a = 0; a < D; ++a) s += K[i * D + a] * y[a];
        d[i] = s;
    }
    // Joseph form P = (I - KH) P⁻ (I - KH)ᵀ + K R Kᵀ rather than Eq. 28's P⁻ - K S Kᵀ: a sum of
    // two congruences, so P stays symmetric positive semi-definite under rounding (and for any
    // gain, e.g. a robust filter's reweighted one), even after many updates or with a reading
    // far more precise than the prior, where the difference form can lose definiteness.
    double *A = w.A.data(), *AP = w.AP.data(), *KR = w.KR.data();
    for (int i = 0; i < n; ++i)
        for (int j = 0; j < n; ++j) {
            double s = (i == j) ? 1.0 : 0.0;
            for (int a = 0; a < D; ++a) s -= K[i * D + a] * H[a * n + j];
            A[i * n + j] = s;
        }
    for (int i = 0; i < n; ++i)
        for (int j = 0; j < n; ++j) {
            double s = 0.0;
            for (int k = 0; k < n; ++k) s += A[i * n + k] * P[k * n + j];
            AP[i * n + j] = s;
        }
    for (int i = 0; i < n * D; ++i) KR[i] = 0.0;
    for (int a = 0; a < D; ++a)  // K R, skipping R's zeros (R is often diagonal)
        for (int b = 0; b < D; ++b) {
            const double r = Ru[a * D + b];
            if (r == 0.0) continue;
            for (int i = 0; i < n; ++i) KR[i * D + b] += K[i * D + a] * r;
        }
    double Pn[64];
    std::vector<double> Pn_big;
    double* pn = Pn;
    if (n > 8) Pn_big.resize(n * n), pn = Pn_big.data();
    bool finite = true;
    for (int i = 0; i < n; ++i)
        for (int j = 0; j < n; ++j) {
            double s = 0.0;
            for (int k = 0; k < n; ++k) s += AP[i * n + k] * A[j * n + k];
            for (int b = 0; b < D; ++b) s += KR[i * D + b] * K[j * D + b];
            pn[i * n + j] = s;
        }
    for (int i = 0; i < n; ++i)  // symmetrized
        for (int j = 0; j <= i; ++j) {
            pn[i * n + j] = pn[j * n + i] = 0.5 * (pn[i * n + j] + pn[j * n + i]);
            finite = finite && std::isfinite(pn[i * n + j]);
        }
    for (int i = 0; i < n; ++i) finite = finite && std::isfinite(d[i]);
    if (!finite) return false;
    for (int i = 0; i < n; ++i) x[i] += d[i];
    std::copy(pn, pn + n * n, P);
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
    const double F[9] = {1, 0, -dy, 0, 1, dx, 0, 0, 1};
    // Q = G C Gᵀ with G = blkdiag(R(θ), 1)
    const double g00 = c * c00 - s * c01, g01 = c * c01 - s * c11, g02 = c * c02 - s * c12;
    const double g10 = s * c00 + c * c01, g11 = s * c01 + c * c11, g12 = s * c02 + c * c12;
    const double Q[9] = {g00 * c - g01 * s, g00 * s + g01 * c, g02,
                         g10 * c - g11 * s, g10 * s + g11 * c, g12,
                         g02,               g12,               s11};
    predict_covariance(3, F, P, Q, P);
    x[0] += dx;
    x[1] += dy;
    x[2] = wrap(x[2] + st.dth);
}

// A landmark's predicted reading from the filter's sensor pose: h (d), H (d × 3), S (d × d),
// R's diagonal (d); ok false for 0/0 (the landmark at the sensor, or S not positive definite).
struct Predicted {
    double h[2], H[6], S[4], R[2], det;
    bool ok;
};

// A reading-landmark pair.
struct Pair {
    double cost, d2, v[2];
    int64_t i, l;
};

void predict_landmark(const double* x, const double* P, const double* lm, const double* p,
                      const Options& opt, int d, Predicted& out) {
    const double c = std::cos(x[2]), s = std::sin(x[2]);
    const double ox = c * p[MOUNT_X] - s * p[MOUNT_Y], oy = s * p[MOUNT_X] + c * p[MOUNT_Y];
    const double dx = lm[0] - (x[0] + ox), dy = lm[1] - (x[1] + oy);
    const double q = dx * dx + dy * dy, r = std::sqrt(q);
    out.ok = q > 0.0 && std::isfinite(q);
    if (!out.ok) return;
    double scale = 1.0;
    if (opt.noise_model == PROPORTIONAL) scale = r;
    if (opt.noise_model == QUADRATIC) scale = q;
    out.h[0] = r;
    out.H[0] = -dx / r;
    out.H[1] = -dy / r;
    out.H[2] = (dx * oy - dy * ox) / r;  // through the mount: ∂sensor/∂θ = (-oy, ox)
    out.R[0] = (p[SIGMA_R] * scale) * (p[SIGMA_R] * scale);
    if (d == 2) {
        out.h[1] = wrap(wrap(std::atan2(dy, dx) - (x[2] + p[MOUNT_THETA])));
        out.H[3] = dy / q;
        out.H[4] = -dx / q;
        out.H[5] = -(dy * oy + dx * ox) / q - 1.0;
        out.R[1] = (p[SIGMA_B] * scale) * (p[SIGMA_B] * scale);
    }
    for (int a = 0; a < d; ++a)
        for (int b = 0; b < d; ++b) {
            double sum = (a == b) ? out.R[a] : 0.0;
            for (int i = 0; i < 3; ++i)
                for (int j = 0; j < 3; ++j) sum += out.H[a * 3 + i] * P[i * 3 + j] * out.H[b * 3 + j];
            out.S[a * d + b] = sum;
        }
    if (d == 2) {
        const double off = 0.5 * (out.S[1] + out.S[2]);
        out.S[1] = out.S[2] = off;
        out.det = out.S[0] * out.S[3] - off * off;
    } else {
        out.det = out.S[0];
    }
    out.ok = out.det > 0.0 && std::isfinite(out.det) && out.S[0] > 0.0;
}

inline double mahalanobis2(const Predicted& pr, const double* v, int d) {
    if (d == 1) return v[0] * v[0] / pr.S[0];
    return (v[0] * v[0] * pr.S[3] - 2.0 * v[0] * v[1] * pr.S[1] + v[1] * v[1] * pr.S[0]) / pr.det;
}

// The joint d² of a set of pairs: the stacked innovation against its stacked S.
double joint_d2(const std::vector<const Pair*>& pairs, const std::vector<Predicted>& pred,
                const double* P, int d, std::vector<double>& scratch) {
    const int D = d * static_cast<int>(pairs.size());
    scratch.assign(3 * D * D + 4 * D, 0.0);
    double *S = scratch.data(), *Lw = S + D * D, *Hs = Lw + D * D, *y = Hs + 3 * D;
    for (size_t k = 0; k < pairs.size(); ++k) {
        const Predicted& pr = pred[pairs[k]->l];
        for (int a = 0; a < d; ++a) {
            y[k * d + a] = pairs[k]->v[a];
            for (int j = 0; j < 3; ++j) Hs[(k * d + a) * 3 + j] = pr.H[a * 3 + j];
        }
    }
    for (int a = 0; a < D; ++a)
        for (int b = 0; b < D; ++b) {
            double sum = 0.0;
            for (int i = 0; i < 3; ++i)
                for (int j = 0; j < 3; ++j) sum += Hs[a * 3 + i] * P[i * 3 + j] * Hs[b * 3 + j];
            S[a * D + b] = sum;
        }
    for (size_t k = 0; k < pairs.size(); ++k)
        for (int a = 0; a < d; ++a) S[(k * d + a) * D + k * d + a] += pred[pairs[k]->l].R[a];
    if (!cholesky(D, S, Lw)) return INF;
    cholesky_solve(D, Lw, y);
    double q = 0.0;
    for (size_t k = 0; k < pairs.size(); ++k)
        for (int a = 0; a < d; ++a) q += pairs[k]->v[a] * y[k * d + a];
    return q;
}

// JCBB (Neira & Tardós 2001): the largest set of individually compatible pairs, one landmark
// per reading and one reading per landmark, whose stacked innovation passes the joint χ² gate;
// of equally large sets the one of least joint d². Depth-first over the readings in order, each
// reading's pairs in increasing d², then the reading left unpaired; a branch is cut when even
// pairing every remaining reading could not beat the best set. At most opt.jcbb_nodes nodes.
std::vector<const Pair*> jcbb(const std::vector<std::vector<const Pair*>>& options,
                              const std::vector<Predicted>& pred, const double* P, int d,
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
    std::vector<double> scratch;
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
            const double j2 = joint_d2(current, pred, P, d, scratch);
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

void predict_odometry(double* x, double* P, double ds, double dth, const double* params) {
    predict_step(x, P, make_step(ds, dth), params);
}

void correct_readings(double* x, double* P, int64_t m, const double* z, const uint8_t* present,
                      const int64_t* signature, const Map& map, const double* p,
                      const Options& opt, ReadingOut out, Totals& totals) {
    const int d = opt.sensor == RANGE_ONLY ? 1 : 2;
    // scratch of this thread, reused between calls (no allocation per time stamp)
    thread_local std::vector<int8_t> status;
    thread_local std::vector<int32_t> landmark;
    thread_local std::vector<double> nearest, zc, pair_d2;
    thread_local std::vector<Predicted> pred;
    thread_local std::vector<char> done;
    thread_local std::vector<Pair> pairs;
    thread_local std::vector<int64_t> row_start;
    thread_local std::vector<const Pair*> chosen, update;
    status.assign(m, 0);
    landmark.assign(m, -1);
    nearest.assign(m, INF);
    zc.assign(m * d, 0.0);
    pair_d2.assign(m, INF);
    if (static_cast<int64_t>(pred.size()) < map.L) pred.resize(map.L);
    done.assign(map.L, 0);
    pairs.clear();
    pairs.reserve(static_cast<size_t>(m) * std::max<int64_t>(map.L, 1));
    row_start.assign(m + 1, 0);
    chosen.assign(m, nullptr);
    update.clear();
    for (int64_t i = 0; i < m; ++i) {
        const double* zi = z + i * d;
        bool usable = std::isfinite(zi[0]) && zi[0] > 0.0;
        if (d == 2) usable = usable && std::isfinite(zi[1]);
        status[i] = (present && !present[i]) ? ABSENT : (usable ? UNKNOWN : INVALID);
        row_start[i] = static_cast<int64_t>(pairs.size());
        if (status[i] != UNKNOWN) continue;
        zc[i * d] = zi[0] - p[BIAS_R];
        if (d == 2) zc[i * d + 1] = zi[1] - p[BIAS_B];
        int64_t lo = 0, hi = map.L;
        if (opt.signatures) {
            auto range = std::equal_range(map.sig_sorted.begin(), map.sig_sorted.end(),
                                          signature[i]);
            lo = range.first - map.sig_sorted.begin();
            hi = range.second - map.sig_sorted.begin();
        }
        // candidates in increasing landmark row (the reference's order for ties; the map
        // keeps each signature's landmarks in increasing row)
        if (lo == hi) continue;
        for (int64_t k = lo; k < hi; ++k) {
            const int64_t l = opt.signatures ? map.sig_landmark[k] : k;
            if (!done[l]) {
                predict_landmark(x, P, map.xy + 2 * l, p, opt, d, pred[l]);
                done[l] = 1;
            }
            const Predicted& pr = pred[l];
            if (!pr.ok) continue;
            Pair q;
            q.i = i;
            q.l = l;
            q.v[0] = zc[i * d] - pr.h[0];
            q.v[1] = d == 2 ? wrap(zc[i * d + 1] - pr.h[1]) : 0.0;
            q.d2 = mahalanobis2(pr, q.v, d);
            q.cost = opt.cost == EUCLIDEAN ? q.v[0] * q.v[0] + q.v[1] * q.v[1] : q.d2;
            nearest[i] = std::min(nearest[i], q.d2);
            pairs.push_back(q);
        }
        if (static_cast<int64_t>(pairs.size()) == row_start[i]) status[i] = DEGENERATE;
    }
    row_start[m] = static_cast<int64_t>(pairs.size());
    // chosen: each reading's pair (used or gated); update: the pairs of the stacked update
    auto usable_with_pairs = [&](int64_t i) {
        return status[i] == UNKNOWN && row_start[i + 1] > row_start[i];
    };
    if (opt.method == GREEDY) {
        // Greedy one-to-one, cheapest pair first (ties: lower reading, then lower landmark).
        // When no two readings share their cheapest landmark, that is each reading's cheapest.
        thread_local std::vector<const Pair*> best;
        thread_local std::vector<int64_t> owner;
        best.assign(m, nullptr);
        for (const Pair& q : pairs)
            if (!best[q.i] || q.cost < best[q.i]->cost) best[q.i] = &q;
        owner.assign(map.L, -1);
        bool clash = false;
        for (int64_t i = 0; i < m && !clash; ++i)
            if (best[i]) {
                if (owner[best[i]->l] >= 0) clash = true;
                owner[best[i]->l] = i;
            }
        if (!clash) {
            for (int64_t i = 0; i < m; ++i) chosen[i] = best[i];
        } else {
            // The greedy run over the pairs sorted by (cost, reading, landmark). With the
            // Mahalanobis cost the pairs inside the gate come first, so they are paired first
            // on their own; then the pairs outside, of the readings and landmarks left.
            thread_local std::vector<const Pair*> order;
            thread_local std::vector<char> taken;
            taken.assign(map.L, 0);
            auto by_cost = [](const Pair* a, const Pair* b) {
                if (a->cost != b->cost) return a->cost < b->cost;
                if (a->i != b->i) return a->i < b->i;
                return a->l < b->l;
            };
            const bool split = opt.cost == MAHALANOBIS;
            for (int pass = 0; pass < (split ? 2 : 1); ++pass) {
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
    // The stacked update of the used pairs (Eqs. 26-28), one per time stamp.
    if (!update.empty()) {
        const int D = d * static_cast<int>(update.size());
        std::vector<double> y(D), H(D * 3), R(D * D, 0.0), Ru;
        const bool robust = std::isfinite(p[NU]);
        const bool inflated = p[INFLATION] != 1.0;
        if (robust || inflated) Ru.assign(D * D, 0.0);
        for (size_t k = 0; k < update.size(); ++k) {
            const Pair* q = update[k];
            const Predicted& pr = pred[q->l];
            // Student-t readings: the reading's weight (ν + d)/(ν + d²) scales R by its inverse
            const double wgt = robust ? (p[NU] + d) / (p[NU] + q->d2) : 1.0;
            // correlated readings carry less information than their spread says: the update's
            // R is inflated, the association, gate and likelihood keep the readings' R
            const double update_factor = p[INFLATION] * p[INFLATION] / wgt;
            for (int a = 0; a < d; ++a) {
                const int r = static_cast<int>(k) * d + a;
                y[r] = q->v[a];
                for (int j = 0; j < 3; ++j) H[r * 3 + j] = pr.H[a * 3 + j];
                R[r * D + r] = pr.R[a];
                if (robust || inflated) Ru[r * D + r] = pr.R[a] * update_factor;
            }
        }
        double nis = 0.0, logdet = 0.0;
        double x_new[3] = {x[0], x[1], x[2]};
        const bool ok = kalman_update(3, D, x_new, P, y.data(), H.data(), R.data(),
                                      Ru.empty() ? nullptr : Ru.data(), nullptr, &nis, &logdet);
        if (ok) {
            x[0] = x_new[0];
            x[1] = x_new[1];
            x[2] = wrap(x_new[2]);
            double ll;
            if (robust) {  // multivariate Student-t of dimension D, scale S, ν dof
                const double nu = p[NU];
                ll = std::lgamma(0.5 * (nu + D)) - std::lgamma(0.5 * nu) -
                     0.5 * D * std::log(nu * PI) - 0.5 * logdet -
                     0.5 * (nu + D) * std::log1p(nis / nu);
            } else {
                ll = -0.5 * (nis + logdet + D * std::log(TWO_PI));
            }
            totals.loglik += ll;
            totals.nis += nis;
            totals.dof += D;
            totals.updates += 1;
        } else {
            for (const Pair* q : update) status[q->i] = DEGENERATE;
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
            for (int a = 0; a < d * d; ++a) out.S[i * d * d + a] = has ? pred[q->l].S[a] : NaN;
    }
}

// ----------------------------------------------------------------------------- bindings
namespace {

using UInt8_2 = nb::ndarray<const uint8_t, nb::ndim<2>, nb::c_contig, nb::device::cpu>;

Map make_map(Float2 landmarks, Index1 landmark_sig) {
    Map map;
    map.L = static_cast<int64_t>(landmarks.shape(0));
    if (landmarks.shape(1) != 2) throw nb::value_error("landmarks must be (L, 2)");
    map.xy = landmarks.data();
    if (static_cast<int64_t>(landmark_sig.shape(0)) != map.L)
        throw nb::value_error("landmark signatures must be (L,)");
    std::vector<int64_t> order(map.L);
    for (int64_t l = 0; l < map.L; ++l) order[l] = l;
    const int64_t* s = landmark_sig.data();
    std::stable_sort(order.begin(), order.end(), [&](int64_t a, int64_t b) { return s[a] < s[b]; });
    for (int64_t l : order) {
        map.sig_sorted.push_back(s[l]);
        map.sig_landmark.push_back(l);
    }
    return map;
}

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

void check_params(Float2 params, size_t B) {
    if (params.shape(0) != B || params.shape(1) != N_PARAMS)
        throw nb::value_error("params must be (B, 11)");
}

void check_filters(Float2 x, Float3 P) {
    if (x.shape(1) != 3 || P.shape(0) != x.shape(0) || P.shape(1) != 3 || P.shape(2) != 3)
        throw nb::value_error("x must be (B, 3) and P (B, 3, 3)");
}

nb::dict totals_dict(const std::vector<Totals>& t) {
    const size_t B = t.size();
    auto loglik = new_array({B}), nis = new_array({B});
    auto dof = new_array<int64_t>({B}), updates = new_array<int64_t>({B});
    auto overflow = new_array<int64_t>({B});
    auto counts = new_array<int64_t>({B, static_cast<size_t>(N_STATUS)});
    for (size_t b = 0; b < B; ++b) {
        loglik.data()[b] = t[b].loglik;
        nis.data()[b] = t[b].nis;
        dof.data()[b] = t[b].dof;
        updates.data()[b] = t[b].updates;
        overflow.data()[b] = t[b].overflow;
        for (int s = 0; s < N_STATUS; ++s) counts.data()[b * N_STATUS + s] = t[b].counts[s];
    }
    nb::dict out;
    out["loglik"] = loglik;
    out["nis"] = nis;
    out["dof"] = dof;
    out["updates"] = updates;
    out["overflow"] = overflow;
    out["counts"] = counts;
    return out;
}

}  // namespace

void register_ekf(nb::module_& m) {
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
                    R.data() + b * D * D, nullptr, So.data() + b * D * D, nis.data() + b,
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
        [](Float2 x, Float3 P, Float2 motion, Float2 params) {
            check_filters(x, P);
            const size_t B = x.shape(0);
            if (motion.shape(0) != B || motion.shape(1) != 2)
                throw nb::value_error("motion must be (B, 2)");
            check_params(params, B);
            auto xo = new_array({B, 3}), Po = new_array({B, 3, 3});
            std::copy(x.data(), x.data() + B * 3, xo.data());
            std::copy(P.data(), P.data() + B * 9, Po.data());
            for (size_t b = 0; b < B; ++b)
                predict_odometry(xo.data() + 3 * b, Po.data() + 9 * b, motion.data()[2 * b],
                                 motion.data()[2 * b + 1], params.data() + b * N_PARAMS);
            return nb::make_tuple(xo, Po);
        },
        nb::arg("x"), nb::arg("P"), nb::arg("motion"), nb::arg("params"),
        "One odometry prediction (midpoint, DistanceNoise) per filter.");

    m.def(
        "ekf_correct_readings",
        [](Float2 x, Float3 P, Float3 z, UInt8_2 present, Index2 signature, Float2 landmarks,
           Index1 landmark_sig, Float2 params, int sensor, int noise_model, int method, int cost,
           bool signatures, double gate2, Float1 joint_gate2, int64_t jcbb_nodes) {
            check_filters(x, P);
            const size_t B = x.shape(0), mm = z.shape(1), d = z.shape(2);
            const Options opt = make_options(sensor, noise_model, method, cost, signatures, gate2,
                                             joint_gate2, jcbb_nodes);
            if (z.shape(0) != B || d != (opt.sensor == RANGE_ONLY ? 1u : 2u))
                throw nb::value_error("z must be (B, m, d), d = 2 (range-bearing) or 1 (range)");
            if (present.shape(0) != B || present.shape(1) != mm || signature.shape(0) != B ||
                signature.shape(1) != mm)
                throw nb::value_error("present and signature must be (B, m)");
            check_params(params, B);
            const Map map = make_map(landmarks, landmark_sig);
            // two packed outputs (one NumPy array each costs more than the arithmetic here):
            // floats per filter x (3), P (9), y (m d), S (m d d), d² (m), loglik, nis;
            // integers per filter status (m), landmark (m), dof
            const size_t F = 12 + mm * (d + d * d + 1) + 2, I = 2 * mm + 1;
            auto fo = new_array({B, F});
            auto io = new_array<int64_t>({B, I});
            for (size_t b = 0; b < B; ++b) {
                double* f = fo.data() + b * F;
                int64_t* iv = io.data() + b * I;
                std::copy(x.data() + 3 * b, x.data() + 3 * b + 3, f);
                std::copy(P.data() + 9 * b, P.data() + 9 * b + 9, f + 3);
                thread_local std::vector<int8_t> st;
                thread_local std::vector<int32_t> lmo;
                st.assign(mm, 0);
                lmo.assign(mm, -1);
                ReadingOut out{f + 12, f + 12 + mm * d, f + 12 + mm * (d + d * d), st.data(),
                               lmo.data()};
                Totals totals;
                correct_readings(f, f + 3, static_cast<int64_t>(mm), z.data() + b * mm * d,
                                 present.data() + b * mm, signature.data() + b * mm, map,
                                 params.data() + b * N_PARAMS, opt, out, totals);
                f[F - 2] = totals.loglik;
                f[F - 1] = totals.nis;
                for (size_t i = 0; i < mm; ++i) iv[i] = st[i], iv[mm + i] = lmo[i];
                iv[2 * mm] = totals.dof;
            }
            return nb::make_tuple(fo, io);
        },
        nb::arg("x"), nb::arg("P"), nb::arg("z"), nb::arg("present"), nb::arg("signature"),
        nb::arg("landmarks"), nb::arg("landmark_sig"), nb::arg("params"), nb::arg("sensor"),
        nb::arg("noise_model"), nb::arg("method"), nb::arg("cost"), nb::arg("signatures"),
        nb::arg("gate2"), nb::arg("joint_gate2"), nb::arg("jcbb_nodes"),
        "Association, gating and one stacked correction per filter of the readings of one time "
        "stamp (each filter its own readings).");

    m.def(
        "ekf_run",
        [](Float2 x0, Float3 P0, Float2 motion, Index1 reading_index, Float2 z, Index1 signature,
           Float2 landmarks, Index1 landmark_sig, Float2 params, int sensor, int noise_model,
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
            check_params(params, B);
            if (keep < 0 || keep > 2) throw nb::value_error("keep must be 0, 1 or 2");
            const Map map = make_map(landmarks, landmark_sig);
            // the time stamps with readings: readings lo[e]:lo[e + 1] at time index at[e]
            std::vector<int64_t> lo, at;
            for (size_t r = 0; r < M; ++r)
                if (!r || ri[r] != ri[r - 1]) lo.push_back(r), at.push_back(ri[r]);
            lo.push_back(static_cast<int64_t>(M));
            const size_t E = at.size();
            const size_t T = keep == 2 ? K + 1 : (keep == 1 ? E + 1 : 1);
            std::vector<Step> steps(K);
            for (size_t k = 0; k < K; ++k)
                steps[k] = make_step(motion.data()[2 * k], motion.data()[2 * k + 1]);
            auto mean = new_array({B, T, 3}), cov = new_array({B, T, 3, 3});
            const size_t Mo = readings_out ? M : 0;
            auto yo = new_array({B, Mo, d}), So = new_array({B, Mo, d, d}), d2 = new_array({B, Mo});
            auto st = new_array<int8_t>({B, Mo});
            auto lmo = new_array<int32_t>({B, Mo});
            std::vector<Totals> totals(B);
            {
                nb::gil_scoped_release release;
                for (size_t b = 0; b < B; ++b) {
                    double x[3] = {x0.data()[3 * b], x0.data()[3 * b + 1], x0.data()[3 * b + 2]};
                    double P[9];
                    std::copy(P0.data() + 9 * b, P0.data() + 9 * b + 9, P);
                    const double* p = params.data() + b * N_PARAMS;
                    double* mo = mean.data() + b * T * 3;
                    double* co = cov.data() + b * T * 9;
                    auto store = [&](size_t slot) {
                        std::copy(x, x + 3, mo + 3 * slot);
                        std::copy(P, P + 9, co + 9 * slot);
                    };
                    if (keep == 1) store(0);
                    size_t e = 0;
                    for (size_t j = 0; j <= K; ++j) {
                        if (j > 0) predict_step(x, P, steps[j - 1], p);
                        if (e < E && at[e] == static_cast<int64_t>(j)) {
                            const int64_t r0 = lo[e], m = lo[e + 1] - lo[e];
                            ReadingOut out;
                            if (readings_out) {
                                const size_t o = b * M + r0;
                                out = {yo.data() + o * d, So.data() + o * d * d, d2.data() + o,
                                       st.data() + o, lmo.data() + o};
                            }
                            correct_readings(x, P, m, z.data() + r0 * d, nullptr,
                                             signature.data() + r0, map, p, opt, out, totals[b]);
                            ++e;
                            if (keep == 1) store(e);
                        }
                        if (keep == 2) store(j);
                        if (totals[b].overflow < 0) {
                            bool finite = true;
                            for (int k = 0; k < 3; ++k) finite = finite && std::isfinite(x[k]);
                            for (int k = 0; k < 9; ++k) finite = finite && std::isfinite(P[k]);
                            if (!finite) totals[b].overflow = static_cast<int64_t>(j);
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
            res["d2"] = d2;
            res["status"] = st;
            res["landmark"] = lmo;
            res["event_index"] = vector_array(at);
            return res;
        },
        nb::arg("x0"), nb::arg("P0"), nb::arg("motion"), nb::arg("reading_index"), nb::arg("z"),
        nb::arg("signature"), nb::arg("landmarks"), nb::arg("landmark_sig"), nb::arg("params"),
        nb::arg("sensor"), nb::arg("noise_model"), nb::arg("method"), nb::arg("cost"),
        nb::arg("signatures"), nb::arg("gate2"), nb::arg("joint_gate2"), nb::arg("jcbb_nodes"),
        nb::arg("keep"), nb::arg("readings_out"),
        "A batch of pose filters over one log: predict each odometry step, correct at the time "
        "indices with readings (all readings of a time index in one stacked update).");
}

}  // namespace relmap::ekf
