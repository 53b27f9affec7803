// The extended Kalman filter of relmap (lecture Eqs. 13-28): its only implementation.
//
// - The generic steps, for a state of any size n: the prediction's covariance
//   P⁻ = F P Fᵀ + Q (Eq. 13) and the correction (Eqs. 26-28) of a stacked innovation y with its
//   Jacobian H and noise R: S = H P⁻ Hᵀ + R, K = P⁻ Hᵀ S⁻¹, x = x⁻ + K y, and the covariance in
//   Joseph form (see kalman_update). One template (ekf.cpp's kalman_block) does every
//   correction; the compiler fixes its sizes for a pose (3) and a reading (2 or 1), so the
//   pose filters' arithmetic is fixed-size, on the stack, with no allocation per step.
// - A time stamp's readings are independent (R block diagonal), so their stacked update is
//   done pair by pair: k 2 × 2 blocks in turn are the 2k × 2k update, to rounding (same x, P,
//   yᵀS⁻¹y and log det S).
// - The built-in models of a planar pose (x, y, θ), relmap's chart: differential-drive odometry
//   steps (Δs, Δθ) with midpoint integration and relmap.robot.DistanceNoise's random-walk noise
//   (Eqs. 10-13), range-bearing readings of point landmarks from a sensor mounted on the robot
//   (Eq. 20), range-only readings (its first row).
// - Association of a time stamp's readings with the map (Eqs. 21-25): candidates by signature
//   or all landmarks, Mahalanobis (Eq. 23) or Euclidean (Eq. 22) cost, greedy one-to-one or the
//   lecture's per-landmark pairing (Eq. 21), or joint compatibility branch and bound (JCBB,
//   Neira & Tardós 2001); χ² gates. A cheap bound on d² from the range alone spares the
//   landmarks that cannot matter their prediction (see correct_readings).
// - A runner over a whole time-ordered log, for a batch of filters each with its own noise
//   parameters: the loops over filters, steps and readings are here, none in Python.
#pragma once

#include <cstdint>
#include <vector>

#include "core.hpp"

namespace relmap::ekf {

// Per-filter noise parameters, in this order (relmap.ekf.NoiseParameters).
enum Param {
    K_S = 0,      // var Δs = k_s |Δs|                       (m²/m)
    K_THETA,      // var Δθ = k_theta |Δθ| + k_theta_s |Δs|  (rad²/rad)
    K_THETA_S,    //                                         (rad²/m)
    SIGMA_R,      // range σ (m; at 1 m for the proportional / quadratic models)
    SIGMA_B,      // bearing σ (rad)
    BIAS_R,       // range bias (m), subtracted from readings
    BIAS_B,       // bearing bias (rad), subtracted from readings
    MOUNT_X,      // sensor position on the robot (m, robot frame)
    MOUNT_Y,
    MOUNT_THETA,  // sensor heading on the robot (rad)
    NU,           // Student-t degrees of freedom of the readings (inf: Gaussian)
    INFLATION,    // σ factor of the update for readings whose errors repeat (1: none)
    CLUTTER,      // λ: density of readings of nothing in the map, relative to a landmark's
    N_PARAMS
};

// Status of a reading (relmap.ekf.Status has the same values).
enum Status : int8_t {
    USED = 0,        // in the update
    GATED = 1,       // its pair is outside the gate (individually, or jointly for JCBB)
    UNKNOWN = 2,     // no landmark of the map can be it (signature not in the map)
    INVALID = 3,     // not a finite reading with a positive range
    ABSENT = 4,      // padding: no reading
    LOST = 5,        // its landmark went to a cheaper reading
    DEGENERATE = 6,  // 0/0: its landmark is at the sensor, or S is not positive definite
    N_STATUS
};

enum SensorKind { RANGE_BEARING = 0, RANGE_ONLY = 1 };
enum NoiseModel { CONSTANT = 0, PROPORTIONAL = 1, QUADRATIC = 2 };
enum Method { GREEDY = 0, PER_LANDMARK = 1, JCBB = 2 };
enum Cost { MAHALANOBIS = 0, EUCLIDEAN = 1 };

// How a time stamp's readings are associated and gated (the same for every filter).
struct Options {
    int sensor = RANGE_BEARING;
    int noise_model = CONSTANT;
    int method = GREEDY;
    int cost = MAHALANOBIS;
    bool signatures = false;           // candidates: the landmarks of the reading's signature
    double gate2 = 0.0;                // χ²_d quantile of the individual gate
    std::vector<double> joint_gate2;   // JCBB: χ²_{d k} quantile for k pairs (index k)
    int64_t jcbb_nodes = 10000;        // JCBB: search nodes at most (then the best so far)
};

// The map: landmark positions and their signatures, checked and prepared once (Python's
// relmap.ekf.LandmarkMap holds one): the signatures sorted with the landmark of each (signature
// candidates) and the rows 0..L-1 (every landmark a candidate). Owns its data.
struct Map {
    int64_t L = 0;
    const double* xy = nullptr;        // (L, 2), into store
    std::vector<int64_t> sig_sorted;   // signatures in increasing order (signature candidates)
    std::vector<int64_t> sig_landmark; // the landmark of each sorted signature (ditto)
    std::vector<int64_t> rows;         // 0, 1, ..., L - 1 (every landmark a candidate)
    // A uniform grid over the landmarks (about one per cell), to find those near a place
    // without looking at the others: cell c = cy nx + cx, of side `cell` from (gx, gy), holds
    // the landmarks cell_landmark[cell_start[c] .. cell_start[c + 1]) (increasing rows); a
    // coordinate's cell is ⌊(x - gx) inv_cell⌋ (clamped); cell_box[4c .. 4c + 4) the box of its
    // landmarks (x min, x max, y min, y max); box the map's.
    double gx = 0.0, gy = 0.0, cell = 1.0, inv_cell = 1.0, box[4] = {0.0, 0.0, 0.0, 0.0};
    int64_t nx = 1, ny = 1;
    std::vector<int64_t> cell_start, cell_landmark;
    std::vector<double> cell_box;

    Map(int64_t L, const double* xy, const int64_t* signatures);
    Map(const Map&) = delete;
    Map& operator=(const Map&) = delete;

    // The landmarks of signature s: sig_landmark[lo .. hi) (lo == hi: none). A hash table of
    // the distinct signatures (open addressing, linear probing), built once.
    void find(int64_t s, int64_t& lo, int64_t& hi) const;

  private:
    struct Slot {
        int64_t key, lo = -1, hi = -1;  // lo < 0: empty
    };
    std::vector<double> store;
    std::vector<Slot> table;
    int shift = 63;  // the hash's top bits index the table
    size_t slot_of(int64_t s) const {
        return static_cast<size_t>((static_cast<uint64_t>(s) * 0x9E3779B97F4A7C15ull) >> shift);
    }
};

// What one correction reports per reading (pointers into the caller's arrays; may be null).
struct ReadingOut {
    double* y = nullptr;       // (m, d) innovation of the reading's pair (NaN: no pair)
    double* S = nullptr;       // (m, d, d) its innovation covariance (NaN: no pair)
    double* d2 = nullptr;      // (m,) Mahalanobis d² of the pair, or of the nearest candidate
    int8_t* status = nullptr;  // (m,)
    int32_t* landmark = nullptr;  // (m,) landmark row, -1 if none
    // (m, d), (m, d, d): the pair's innovation and its covariance given the readings before it
    // in the time stamp's stacked update, with R itself (the prediction-error decomposition:
    // the stacked likelihood is the product of their densities); a gated reading given all the
    // used ones. NaN: no pair, or a 0/0 update.
    double* y_given = nullptr;
    double* S_given = nullptr;
};

// Per-filter totals of a run.
struct Totals {
    double loglik = 0.0;   // Σ log p(y) of the stacked innovations (Gaussian or Student-t)
    double nis = 0.0;      // Σ yᵀ S⁻¹ y
    int64_t dof = 0;       // Σ dim y
    int64_t updates = 0;   // time stamps with a correction
    int64_t overflow = -1; // first time index with a non-finite state (-1: none)
    int64_t ambiguous = 0; // used readings with several landmarks in the gate (a mixture)
    int64_t counts[N_STATUS] = {};
};

// P⁻ = F P Fᵀ + Q (n × n, row-major), symmetrized. out may alias P.
void predict_covariance(int n, const double* F, const double* P, const double* Q, double* out);

// The correction of x (n) and P (n × n) with the innovation y (D), Jacobian H (D × n) and
// noise R (D × D), Joseph form. Writes S (D × D, may be null), the NIS yᵀS⁻¹y and log det S;
// returns false and leaves x and P untouched when S is not positive definite (0/0). (The
// landmark correction stacks its pairs the same way, one 2 × 2 block per pair: ekf.cpp's
// kalman_block, of which this is the single-block case.)
bool kalman_update(int n, int D, double* x, double* P, const double* y, const double* H,
                   const double* R, double* S, double* nis, double* logdet);

// One odometry step (Δs, Δθ) of a pose filter: midpoint integration, DistanceNoise (module
// notes), compounded x ⊕ Δ with P⁻ = Gx P Gxᵀ + Gu C Guᵀ.
void predict_odometry(double* x, double* P, double ds, double dth, const double* params);

// The candidates of m readings of signatures signature (m): reading i's are the landmarks
// map.sig_landmark[candidates[2i] .. candidates[2i + 1]) (Map::find).
void signature_candidates(const Map& map, int64_t m, const int64_t* signature,
                          int64_t* candidates);

// One pose filter's correction with the m readings z (m × d) of one time stamp: its state
// (x, P), updated in place, and what it reports (out, totals); present (m) or null (all
// present); with signature association, candidates (2m) from signature_candidates.
struct Call {
    double* x;
    double* P;
    int64_t m;
    const double* z;
    const uint8_t* present;
    const int64_t* candidates;
    const double* p;  // the filter's parameters (Param)
    ReadingOut out;
    Totals* totals;
};

// The corrections of W <= LANES filters (LANES of them are corrected side by side, their update
// blocks interleaved; each filter's result is what it gives alone, bit for bit).
constexpr int LANES = 4;
void correct_filters(int W, const Call* calls, const Map& map, const Options& opt);

void register_ekf(nb::module_& m);

}  // namespace relmap::ekf

namespace relmap {
inline void register_ekf(nb::module_& m) { ekf::register_ekf(m); }
}  // namespace relmap
