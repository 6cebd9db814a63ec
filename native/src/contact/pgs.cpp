#include "contact/pgs.h"

#include <algorithm>
#include <cmath>

namespace hh {

namespace {
// argmin over |x| <= radius of 1/2 x^T W x - c^T x, W symmetric positive definite 2x2:
// inside, x = W^-1 c; else x = (W + nu I)^-1 c with nu >= 0 such that |x| = radius (the norm
// decreases monotonically in nu; Newton's method from nu = 0 converges from the left).
// y += h0 d0 + h1 d1 + h2 d2 over m entries, h_k = h + k ld: a contact's update of one body's
// y (the sweeps' inner loop). Built for AVX2/FMA too, chosen at load time where supported.
// (Not under ThreadSanitizer: its load-time resolver would run before the sanitizer's runtime.)
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && __GNUC__ >= 12 && !defined(__SANITIZE_THREAD__)
__attribute__((target_clones("arch=x86-64-v3", "default")))
#endif
void add_three_columns(double* __restrict y, const double* __restrict h, long m, long ld, double d0, double d1, double d2) {
    const double* __restrict h0 = h;
    const double* __restrict h1 = h + ld;
    const double* __restrict h2 = h + 2 * ld;
    for (long k = 0; k < m; ++k) y[k] += h0[k] * d0 + h1[k] * d1 + h2[k] * d2;
}

// The same with the columns in single precision (half the memory traffic; see ReducedOp).
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && __GNUC__ >= 12 && !defined(__SANITIZE_THREAD__)
__attribute__((target_clones("arch=x86-64-v3", "default")))
#endif
void add_three_columns_single(double* __restrict y, const float* __restrict h, long m, long ld, double d0, double d1,
                              double d2) {
    const float* __restrict h0 = h;
    const float* __restrict h1 = h + ld;
    const float* __restrict h2 = h + 2 * ld;
    for (long k = 0; k < m; ++k) y[k] += double(h0[k]) * d0 + double(h1[k]) * d1 + double(h2[k]) * d2;
}

// h_d = sum_e c_e a_e[d] (d = 0, 1, 2; h_d = h + d ld) over m entries, for the n columns c_e:
// one contact's three response columns H = C P^T on a body, formed at the start of each solve.
// Four columns a pass, so that the three outputs are read and written once per four columns.
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && __GNUC__ >= 12 && !defined(__SANITIZE_THREAD__)
__attribute__((target_clones("arch=x86-64-v3", "default")))
#endif
void form_three_columns(double* __restrict h, long m, long ld, const double* const* c, const Vec3* a, int n) {
    double* __restrict h0 = h;
    double* __restrict h1 = h + ld;
    double* __restrict h2 = h + 2 * ld;
    for (long k = 0; k < m; ++k) h0[k] = h1[k] = h2[k] = 0.0;
    int e = 0;
    for (; e + 4 <= n; e += 4) {
        const double* __restrict c0 = c[e];
        const double* __restrict c1 = c[e + 1];
        const double* __restrict c2 = c[e + 2];
        const double* __restrict c3 = c[e + 3];
        const Vec3 &x0 = a[e], &x1 = a[e + 1], &x2 = a[e + 2], &x3 = a[e + 3];
        for (long k = 0; k < m; ++k) {
            h0[k] += c0[k] * x0[0] + c1[k] * x1[0] + c2[k] * x2[0] + c3[k] * x3[0];
            h1[k] += c0[k] * x0[1] + c1[k] * x1[1] + c2[k] * x2[1] + c3[k] * x3[1];
            h2[k] += c0[k] * x0[2] + c1[k] * x1[2] + c2[k] * x2[2] + c3[k] * x3[2];
        }
    }
    for (; e < n; ++e) {
        const double* __restrict c0 = c[e];
        const double x0 = a[e][0], x1 = a[e][1], x2 = a[e][2];
        for (long k = 0; k < m; ++k) {
            h0[k] += c0[k] * x0;
            h1[k] += c0[k] * x1;
            h2[k] += c0[k] * x2;
        }
    }
}

// The elimination step of basic_solve: the trailing r x r block of a column-major matrix (leading
// dimension ld, block at a) loses l u^T, l = the pivot's column below it, u_j = a[j ld - 1]
// (the pivot's row). The library is built for baseline x86-64; this loop is a large share of a
// small problem's contact solve, so it gets the AVX2 clone too.
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && __GNUC__ >= 12 && !defined(__SANITIZE_THREAD__)
__attribute__((target_clones("arch=x86-64-v3", "default")))
#endif
void eliminate(double* __restrict a, const double* __restrict l, long r, long ld) {
    for (long j = 0; j < r; ++j) {
        double* __restrict c = a + j * ld;
        const double f = c[-1];  // the pivot row's entry in this column
        for (long i = 0; i < r; ++i) c[i] -= l[i] * f;
    }
}

// The eigen-decomposition of a contact's 2x2 tangential block, made once per solve.
struct Disk {
    Eigen::Matrix2d vectors;
    Eigen::Vector2d values;
    explicit Disk(const Eigen::Matrix2d& w = Eigen::Matrix2d::Identity()) {
        Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> eig(w);
        values = eig.eigenvalues().cwiseMax(1e-300);
        vectors = eig.eigenvectors();
    }
};
Eigen::Vector2d disk_constrained_minimum(const Disk& eig, const Eigen::Vector2d& c, double radius) {
    const Eigen::Vector2d& a = eig.values;
    const Eigen::Vector2d d = eig.vectors.transpose() * c;
    auto point = [&](double nu) { return Eigen::Vector2d(d[0] / (a[0] + nu), d[1] / (a[1] + nu)); };
    if (point(0).norm() <= radius) return eig.vectors * point(0);
    if (radius <= 0) return Eigen::Vector2d::Zero();
    double nu = 0;
    for (int it = 0; it < 50; ++it) {
        const Eigen::Vector2d x = point(nu);
        const double norm = x.norm();
        if (std::abs(norm - radius) <= 1e-12 * radius) break;
        // d|x|/dnu = -sum x_k^2 / (a_k + nu) / |x|; Newton on 1/|x| - 1/radius is better behaved
        const double slope = (x[0] * x[0] / (a[0] + nu) + x[1] * x[1] / (a[1] + nu)) / (norm * norm * norm);
        nu += (1.0 / radius - 1.0 / norm) / slope;
    }
    return eig.vectors * point(nu);
}
}  // namespace

namespace {
// Subspace minimization between sweeps (after PGS-SM, Silcowitz, Niebe & Erleben 2010).
// Gauss-Seidel finds which contacts push, stick or slide within a few sweeps but then converges
// linearly, slowly where many contacts ride on few nodes (nearly dependent rows: the bunny's
// ground contacts on a coarse tet mesh). With the contacts the sweeps hold active, this solves
// their equality conditions at once:
//   sticking (|lambda_t| < mu lambda_n): u_n + gap/dt = 0 and u_t = 0 (3 unknowns, 3 rows)
//   sliding (on the rim): u_n + gap/dt = 0 with lambda_t = mu lambda_n d, d the direction of
//     its friction impulse now (1 unknown, 1 row; PGS-SM's sliding contacts)
// on a few dozen unknowns, factored densely. The sliding contacts' friction follows their
// normal impulse: keeping the friction impulse itself instead (as first done here) left it
// outside the disk whenever the solve lowered lambda_n, and cutting it back to the rim
// afterwards undid the solve (velocities of cm/s on the bunny's hand contacts, so every step
// was rejected). With sliding contacts the system is not symmetric; it is eliminated with
// diagonal pivoting (basic_solve), damped (below). Rows still implied by the others to 1e-6 of
// their diagonal after the damping (sliding contacts' nonsymmetric columns, or round-off at the
// smallest damping) take no impulse. The
// contacts the solve would pull (lambda_n < 0) leave the set, all at once, a
// sticking one the solve would take outside its friction disk becomes sliding, and once neither
// happens, a contact out of the set that the solve would push through comes back (the worst
// first, once each); then solve again. Contacts the previous step took out start out (the
// sweeps between two steps tend to give them an impulse again; starting them in cost a solve
// per contact each time). The caller keeps the result only when the sweep after it leaves a
// smaller residual.
// Returns false when nothing was solved.
//
// The damping (Levenberg-Marquardt): each solve is for the change z - z0 from the sweeps'
// impulses z0, on W's active block plus `damping` times its diagonal. A combination of rows
// whose own stiffness is well above the damping (relative to the rows' diagonals) is solved
// nearly exactly; one far below it (nearly dependent rows) keeps nearly the sweeps' impulses.
// The caller adapts the damping as Marquardt did: ten times larger after a step it rejected,
// ten times smaller after one it kept, within [kDampingMin, kDampingMax]. Undamped, rows
// implied by the others to 1e-6 - 1e-4 of their diagonal, whose targets differ by the sweeps'
// residual, take impulses tens of times the sweeps' that push sticking contacts out of their
// friction disks, and the step is rejected. A fixed damping would make each step on two clean
// nearly dependent rows (test_contact_reduced) gain only a little; damping the whole solve
// towards zero instead of towards the sweeps' impulses biases every step.
//
// A contact on its disk's rim that the sweeps leave slipping slower than `slow_slip` times the
// tolerance starts the step sticking: the direction of so slow a slip may be the sweeps' noise,
// and a step keeping it while raising the contact's normal impulse makes it slide off the
// direction against its friction, and is rejected. Sticking, the solve finds its friction;
// outside the disk it turns sliding along the solved friction (no cycling: a step never turns
// a sliding contact sticking). Which rim contacts are slow enough is the caller's, adapted with
// the damping: ten times the tolerance (kSlowSlip, as the kinetic-friction test takes such a
// contact for a sticking one still converging), and after a step it rejected, the other of
// kSlowSlip and kSlowSlipWide. Neither reading suits every scene: where a grasp's fingers
// squeeze a ball, ~20 rim contacts slip at ~1 mm/s while their friction turns ~1% a sweep,
// steps keeping those directions are rejected time after time and the sweeps reach their cap;
// read as sticking they are solved at once (the grasp's sweeps 37 a frame to 23, none at the
// cap). Starting with the wide reading instead costs the pinched letter's closing, whose slow
// rim contacts do slide, 1.25x its contact time; alternating leaves it as it was.
//
// The direction d of a sliding contact stays as the sweeps left it: moving it after each solve
// to the solved friction or against the solved sliding velocity makes strongly coupled hand
// contacts cycle between sticking and sliding. The contacts a solve pulls leave the set all at
// once (one at a time took up to 10 dense solves per step and converged no better).
constexpr int kSubspaceEvery = 10;     // sweeps between subspace steps while they help
constexpr int kSubspaceMaxInterval = 80;  // ... and at most, after steps that did not
constexpr int kSubspaceRounds = 10;    // solves per step (set changes)
constexpr double kDependent = 1e-6;    // pivot / diagonal below which a row counts as implied
constexpr double kSlowSlip = 10;       // slip (x tolerance) below which a rim contact starts sticking
constexpr double kSlowSlipWide = 100;  // ... the same after a step rejected with the narrow reading
// Damping of the step's solves (relative to W's diagonal): the first step of a solve, and the
// bounds of its adaptation (see subspace_step)
constexpr double kDampingStart = 1e-4, kDampingMin = 1e-6, kDampingMax = 1e-3;
// Largest active set the step takes on: its cost grows as a^2 blocks of W and (3a)^3 / 3 per
// dense solve, while a sweep costs ~ contacts x touched unknowns. On the paper's bunny ~20
// contacts are active; in the 10x bunny scene several hundred, where the dense steps would cost
// far more than the sweeps: there the sweeps go on alone.
constexpr int kSubspaceMaxActive = 64;
// Sweeps between full ones, with the open contacts left out in between (see sweep)
constexpr int kFullEvery = 10;
// ... and, where the subspace step cannot run (more active contacts than it takes), the
// settled ones too: a contact whose own residual is within the tolerance or this fraction of
// the worst sits out until the next full sweep, every kFullEveryLarge sweeps (see sweep)
constexpr double kHotFraction = 0.1;
constexpr int kFullEveryLarge = 30;
// The stall stop (see sweep): the rate of progress is measured over this many sweeps. Long
// enough to span a few subspace steps (every 10 sweeps while kept; a rejected one delays the
// next), whose successes come in jumps.
constexpr int kStallWindow = 50;
// Response columns (all bodies, double) above which the sweeps use single-precision copies
constexpr size_t kSingleColumnsBytes = size_t(6) << 20;

// A basic solution of m z = rhs (m square, nearly symmetric, possibly singular): Gaussian
// elimination with diagonal pivoting, each step taking the row least implied by those taken
// before (the largest remaining pivot relative to its own diagonal, `scale`); once every
// remaining pivot is below kDependent of its diagonal, the remaining rows count as implied and
// their unknowns are 0. m is overwritten.
bool basic_solve(MatX& m, VecX rhs, VecX scale, VecX& z) {
    const int n = static_cast<int>(m.rows());
    std::vector<int> perm(n);
    for (int k = 0; k < n; ++k) perm[k] = k;
    int rank = n;
    for (int k = 0; k < n; ++k) {
        int best = -1;
        double ratio = kDependent;
        for (int j = k; j < n; ++j) {
            const double r = std::abs(m(j, j)) / scale[j];
            if (r > ratio) {
                ratio = r;
                best = j;
            }
        }
        if (best < 0) {
            rank = k;
            break;
        }
        if (best != k) {
            m.row(k).swap(m.row(best));
            m.col(k).swap(m.col(best));
            std::swap(rhs[k], rhs[best]);
            std::swap(scale[k], scale[best]);
            std::swap(perm[k], perm[best]);
        }
        const int r = n - k - 1;
        if (r > 0) {
            m.col(k).tail(r) /= m(k, k);
            eliminate(&m(k + 1, k + 1), &m(k + 1, k), r, m.outerStride());  // m -= l u^T below and right of the pivot
            rhs.tail(r) -= m.col(k).tail(r) * rhs[k];
        }
    }
    VecX x = VecX::Zero(n);
    for (int k = rank - 1; k >= 0; --k)
        x[k] = (rhs[k] - m.row(k).segment(k + 1, rank - k - 1).dot(x.segment(k + 1, rank - k - 1))) / m(k, k);
    z.resize(n);
    for (int k = 0; k < n; ++k) z[perm[k]] = x[k];
    return z.allFinite();
}

// W's 3x3 blocks between contacts that have been active in a subspace step, kept through one
// solve: the active sets of successive steps mostly overlap. A contact gets a slot the first
// time it is active; block (i, j) sits at (slot i, slot j) of a dense table, formed on first
// use. (A hash map keyed by the pair had taken a quarter of the steps' time on the paper's bunny,
// ~3600 lookups a solve.)
struct ActiveBlocks {
    explicit ActiveBlocks(int contacts) : slot(contacts, -1) {}
    std::vector<int> slot;  // per contact, its slot or -1
    int slots = 0, capacity = 0;
    std::vector<Mat3> table;             // capacity x capacity
    std::vector<unsigned char> known;    // per table entry: formed
    // W's block (i, j), i <= j contacts with slots s, t: op's cross block once, its transpose
    // stored for (j, i)
    template <class Op>
    const Mat3& get(const Op& op, int i, int j, int s, int t) {
        const size_t k = static_cast<size_t>(s) * capacity + t;
        if (!known[k]) {
            const Mat3 w = op.cross_block(i, j);
            const size_t kt = static_cast<size_t>(t) * capacity + s;
            table[k] = w;
            table[kt] = w.transpose();
            known[k] = known[kt] = 1;
            if (i == j) table[k] = w;  // (as formed; the transpose would overwrite it)
        }
        return table[k];
    }
    // the slots of the contacts act (at most kMaxSlots of them)
    void slots_of(const std::vector<int>& act, std::vector<int>& out) {
        int fresh = 0;
        for (const int i : act) fresh += slot[i] < 0;
        if (slots + fresh > kMaxSlots) {  // many contacts came and went: start over (bounded memory)
            for (int& s : slot) s = -1;
            slots = 0;
            std::fill(known.begin(), known.end(), 0);
        }
        out.resize(act.size());
        for (size_t p = 0; p < act.size(); ++p) {
            int& s = slot[act[p]];
            if (s < 0) {
                if (slots == capacity) grow();
                s = slots++;
            }
            out[p] = s;
        }
    }
    static constexpr int kMaxSlots = 256;

private:
    void grow() {
        const int wider = std::min(kMaxSlots, std::max(32, 2 * capacity));
        std::vector<Mat3> t(static_cast<size_t>(wider) * wider);
        std::vector<unsigned char> k(t.size(), 0);
        for (int s = 0; s < slots; ++s)
            for (int r = 0; r < slots; ++r) {
                t[static_cast<size_t>(s) * wider + r] = table[static_cast<size_t>(s) * capacity + r];
                k[static_cast<size_t>(s) * wider + r] = known[static_cast<size_t>(s) * capacity + r];
            }
        table.swap(t);
        known.swap(k);
        capacity = wider;
    }
};

template <class Op>
bool subspace_step(const Op& op, int c, const VecX& bias, const VecX& coefficient, const std::vector<Vec3>& u,
                   double tolerance, double slow_slip, double damping, ActiveBlocks& cache, std::vector<int>& last_state, VecX& lambda) {
    std::vector<int> act;
    for (int i = 0; i < c; ++i)
        if (lambda[3 * i] > 0 && op.block(i)(0, 0) > 0) act.push_back(i);
    if (act.empty() || static_cast<int>(act.size()) > kSubspaceMaxActive) return false;
    const int a = static_cast<int>(act.size());
    // W's blocks between active contacts: constant through the solve, so kept from the
    // previous steps (the active sets of successive steps mostly overlap)
    std::vector<Mat3> blocks(static_cast<size_t>(a) * a);
    static_assert(kSubspaceMaxActive <= ActiveBlocks::kMaxSlots, "an active set must fit the table");
    std::vector<int> slots;
    cache.slots_of(act, slots);
    for (int p = 0; p < a; ++p)
        for (int q = p; q < a; ++q) {
            const Mat3& w = cache.get(op, act[p], act[q], slots[p], slots[q]);
            blocks[p * a + q] = w;
            blocks[q * a + p] = w.transpose();  // W symmetric (the sweeps' symmetric part)
        }
    // per active contact: 0 out of the set, 1 sliding (normal unknown, lambda_t = lambda_n
    // slope), 3 sticking; `natural` as its impulse says
    std::vector<int> state(a), first(a), natural(a), added(a, 0);
    std::vector<Eigen::Vector2d> slope(a);  // sliding: mu d (zero without friction)
    // velocities without the active contacts' impulses, plus the bias
    std::vector<Vec3> v0(a);
    for (int p = 0; p < a; ++p) {
        const int i = act[p];
        const Eigen::Vector2d lt(lambda[3 * i + 1], lambda[3 * i + 2]);
        const bool inside = lt.norm() < coefficient[i] * lambda[3 * i] * (1 - 1e-9);
        const bool slow = Eigen::Vector2d(u[i][1], u[i][2]).norm() <= slow_slip * tolerance;
        natural[p] = coefficient[i] > 0 && (inside || slow) ? 3 : 1;
        // a contact the last step took out (the sweeps gave it an impulse again since) starts
        // out: successive steps mostly remove the same contacts, one solve each
        state[p] = last_state[i] == 0 ? 0 : natural[p];
        slope[p] = lt.norm() > 0 ? Eigen::Vector2d(lt * (coefficient[i] / lt.norm())) : Eigen::Vector2d::Zero();
        v0[p] = u[i];
        v0[p][0] += bias[i];
        for (int q = 0; q < a; ++q) v0[p] -= blocks[p * a + q] * lambda.segment<3>(3 * act[q]);
    }
    VecX z, z0, rhs, scale;
    MatX m;
    std::vector<int> z_state, z_first;  // the states z was solved with
    for (int round = 0; round < kSubspaceRounds; ++round) {
        int na = 0;
        for (int p = 0; p < a; ++p) {
            first[p] = na;
            na += state[p];
        }
        if (na == 0) break;
        m.resize(na, na);
        rhs.resize(na);
        scale.resize(na);
        // m entry by entry (Eigen's dynamic-size block copies, one per pair of active contacts and
        // round, cost a large share of the step next to the solve itself)
        double* const md = m.data();
        for (int q = 0; q < a; ++q) {
            if (!state[q]) continue;
            double* const col = md + static_cast<size_t>(first[q]) * na;
            for (int p = 0; p < a; ++p) {
                if (!state[p]) continue;
                const Mat3& w = blocks[p * a + q];
                double* const out = col + first[p];
                for (int r = 0; r < state[p]; ++r) {
                    if (state[q] == 3) {
                        out[r] = w(r, 0);
                        out[r + na] = w(r, 1);
                        out[r + 2 * na] = w(r, 2);
                    } else {  // the column of lambda_n with its friction lambda_n slope
                        out[r] = w(r, 0) + (w(r, 1) * slope[q][0] + w(r, 2) * slope[q][1]);
                    }
                }
            }
        }
        // the change from the sweeps' impulses z0 (a sliding contact's friction on its rim is
        // slope x lambda_n, as its column has it), on the damped block
        z0.setZero(na);
        for (int p = 0; p < a; ++p)
            for (int r = 0; r < state[p]; ++r) {
                rhs[first[p] + r] = -v0[p][r];
                scale[first[p] + r] = blocks[p * a + p](r, r);
                z0[first[p] + r] = lambda[3 * act[p] + r];
            }
        rhs.noalias() -= m * z0;
        for (int k = 0; k < na; ++k) m(k, k) += damping * scale[k];
        if (!basic_solve(m, rhs, scale, z)) return false;
        z += z0;
        z_state = state;
        z_first = first;
        bool pulled = false;
        for (int p = 0; p < a; ++p)
            if (state[p] && z[first[p]] < 0) {
                state[p] = 0;
                pulled = true;
            }
        if (pulled) continue;
        bool changed = false;
        for (int p = 0; p < a; ++p) {
            if (state[p] != 3) continue;
            const double limit = coefficient[act[p]] * z[first[p]];
            const Eigen::Vector2d zt = z.segment<2>(first[p] + 1);
            if (zt.norm() > limit) {
                state[p] = 1;
                slope[p] = zt * (coefficient[act[p]] / zt.norm());
                changed = true;
            }
        }
        if (!changed) {
            // a contact out of the set whose gap the solve would close faster than allowed
            // (u_n + gap/dt < 0): back in, the worst first, each at most once (no cycling)
            int worst = -1;
            double worst_un = 0;
            for (int p = 0; p < a; ++p) {
                if (state[p] || added[p]) continue;
                double un = v0[p][0];
                for (int q = 0; q < a; ++q) {
                    if (!state[q]) continue;
                    const double ln = z[first[q]];
                    const Eigen::Vector2d lt = state[q] == 3 ? Eigen::Vector2d(z.segment<2>(first[q] + 1)) : Eigen::Vector2d(slope[q] * ln);
                    un += blocks[p * a + q](0, 0) * ln + blocks[p * a + q].block<1, 2>(0, 1).dot(lt);
                }
                if (un < worst_un) {
                    worst_un = un;
                    worst = p;
                }
            }
            if (worst >= 0) {
                state[worst] = natural[worst];
                added[worst] = 1;
                changed = true;
            }
        }
        if (!changed) break;
    }
    if (z_state.empty()) return false;
    for (int p = 0; p < a; ++p) last_state[act[p]] = z_state[p];
    // the impulses of the last solve (when the rounds ran out, with the states it was made for)
    for (int p = 0; p < a; ++p) {
        const int i = act[p];
        const int s = z_state[p];
        const double ln = s ? std::max(0.0, z[z_first[p]]) : 0.0;
        Eigen::Vector2d lt = s == 3 ? Eigen::Vector2d(z.segment<2>(z_first[p] + 1)) : Eigen::Vector2d(slope[p] * ln);
        const double limit = coefficient[i] * ln;
        if (lt.norm() > limit) lt *= limit / lt.norm();
        lambda[3 * i] = ln;
        lambda[3 * i + 1] = lt[0];
        lambda[3 * i + 2] = lt[1];
    }
    return true;
}

// The sweeps, on any form of W. Op gives, per contact i, its current relative velocity
// velocity(i) (3: normal, tangent1, tangent2), the symmetric 3x3 diagonal block block(i) of
// W, and apply(i, delta): the impulses of contact i change by delta.
//
// Which contacts a sweep visits. Open contacts are left out: a contact without impulse whose
// gap stays open (u_n + gap/dt > 0) is a no-op in a sweep (its update leaves lambda = 0). Most
// contacts of the paper's bunny are such (about 20 of 250 push), yet each would cost a
// velocity in every sweep and in every residual. A full sweep (every contact, and the residual
// on every contact) every kFullEvery sweeps marks those without impulse that are open by more
// than the tolerance; the sweeps in between visit the others only. A contact that closes in
// between is caught at the next full sweep, and every decision (to stop, to take or keep a
// subspace step) is made on the residual of every contact, so the stopping criterion is
// unchanged; while the left-out contacts stay open the sweeps are exactly the full ones. (The
// margin is the tolerance: a wider one leaves more contacts in.)
// Where the subspace step cannot run (more active contacts than it takes), settled contacts
// are left out in between too: those whose own residual at the full sweep is within the
// tolerance or within kHotFraction of the worst; full sweeps then come every kFullEveryLarge
// sweeps. There (the 10x bunny ends every frame at the cap) the error sits in a few groups of
// 2-5 nearly dependent contacts (the eigen-directions of W that carry most of the hand's
// impulse error), while most contacts the sweeps visit are already far closer than the worst:
// the partial sweeps, focused on the contacts they visit (ReducedOp::focus), then cost a
// fraction of the full ones, and the residual left at the cap, and the hand's generalized
// impulse's distance from the converged one, stay as they are with full sweeps.
//
// Subspace steps: every `interval` sweeps, kSubspaceEvery while the steps are kept, doubled (up
// to kSubspaceMaxInterval) after each rejected one. Steps come in pairs: step_due is taken
// before a pending step is decided, so the sweep that decides one takes the next at once (after
// a rejection from the restored impulses, the contacts the rejected step took out starting
// out); skipping that second step leaves a larger residual. A rejected step costs its dense
// solves and the sweep after it, hence the longer interval after one.
//
// The stall stop. Near the tolerance the sweeps often crawl: on the paper bunny's pressed
// frames the residual comes within a few times the tolerance in tens of sweeps and then falls
// ~10% every 30 sweeps, so many frames would sweep on to the cap for a residual a little lower
// (micrometres over a step). With stall_factor, once the residual on every contact is within
// stall_factor x the tolerance and the best residual's rate of fall over the last kStallWindow
// sweeps would not bring it to the tolerance within the sweeps left, the solve ends as if
// converged (the reported residual is the one reached). Far from the tolerance the sweeps go
// on: there they still matter (the 10x scenes end at the cap 10-20x above it).
template <class Op>
class Sweeps {
public:
    Sweeps(Op& op, int c, const VecX& gap, const VecX& friction, const VecX& kinetic, double dt, double recovery_speed,
           VecX& lambda, int max_iterations, double tolerance, double stall_factor)
        : op(op), c(c), kinetic(kinetic), lambda(lambda), max_iterations(max_iterations), tolerance(tolerance),
          stall_factor(stall_factor), bias(c), coefficient(friction), u(c), all(c), own(c, 0.0), disks(c),
          disk_made(c, 0), blocks_cache(c), last_state(c, -1) {
        // target normal velocity: close an open gap exactly within the step, never faster; push
        // out of a penetration at a bounded speed, so a deep one is resolved over a few steps
        // instead of by one violent impulse that would feed energy into the scene
        for (int i = 0; i < c; ++i) bias[i] = std::max(gap[i] / dt, -recovery_speed);
        for (int i = 0; i < c; ++i) all[i] = i;
    }

    PgsResult run() {
        for (int it = 0, pass = 0; it < max_iterations; ++it) {
            const bool full = it >= next_full;
            if (full && it > 0) op.refresh(lambda);
            const std::vector<int>& visit = full ? all : live;
            const double estimate = sweep(visit, full);
            result.iterations = it + 1;
            result.residual = full ? residual(visit) : estimate;
            if (full) after_full_sweep(it);
            // every decision below (stop, subspace step, keep a step) on the residual of every
            // contact. With more active contacts than the subspace step takes (`large`), a step
            // that falls due in a partial sweep waits for the next full sweep, whose residual is
            // every contact's anyway: measuring it in the partial sweep before (a catch-up of
            // the focused contacts' columns and a velocity per contact, then a full sweep next)
            // is wasted on a step that cannot run there unless the active set shrank.
            const bool step_due = it + 1 >= next_step && (full || !large);
            const bool deciding = pending || result.residual <= tolerance || it + 1 >= max_iterations || step_due;
            if (!full && deciding) {
                op.refresh(lambda);
                result.residual = residual(all);
                next_full = it + 1;  // the next sweep visits every contact again
            }
            if (pending) judge_step(it);
            if (result.residual > tolerance && it + 1 < max_iterations && step_due && take_step(it)) continue;
            // (a residual on every contact: after a full sweep or one that decided something)
            const bool measured_all = full || deciding;
            if (result.residual > tolerance && it + 1 < max_iterations && !(measured_all && stalled(it, result.residual)))
                continue;
            if (pass++ > 0 || !break_loose()) break;
            next_full = it + 1;
            progress.clear();  // the kinetic problem's progress is its own
        }
        return result;
    }

private:
    Op& op;
    const int c;
    const VecX& kinetic;
    VecX& lambda;
    const int max_iterations;
    const double tolerance, stall_factor;
    PgsResult result;
    VecX bias;
    // Friction coefficient each contact's disk uses: static first; contacts still sliding once
    // the static problem is solved break loose and are solved again against kinetic friction.
    // (Deciding per contact inside the sweep would let the first contact of a resting block
    // give way before its neighbours had taken their share.)
    VecX coefficient;
    std::vector<Vec3> u;  // per contact, its relative velocity when its residual was last measured
    // How far the current impulses are from satisfying every condition, in m/s: normal
    // complementarity, sticking contacts at rest, sliding ones sliding against their friction.
    // `all` the contacts, `live` those the partial sweeps visit; `own` each contact's residual
    // when last measured
    std::vector<int> all, live;
    std::vector<double> own;
    // per contact, the eigen-decomposition of its tangential block, made when first needed
    // (with the reduced form, a contact's block is formed with its columns: see below)
    std::vector<Disk> disks;
    std::vector<unsigned char> disk_made;
    // the subspace steps: the impulses and residual before the pending one, the blocks of W
    // they keep, each contact's state at the end of the last one, their solves' damping
    VecX saved;
    double saved_residual = 0;
    ActiveBlocks blocks_cache;
    std::vector<int> last_state;
    double damping = kDampingStart;  // (adapted: see subspace_step)
    double slow_slip = kSlowSlip;    // (alternated: see subspace_step)
    bool pending = false;
    int interval = kSubspaceEvery, next_step = kSubspaceEvery;
    int next_full = 0;
    bool large = false;  // more active contacts than the subspace step takes (at the last full sweep)
    // (sweep, best residual so far) at each measurement of every contact's residual (stalled)
    std::vector<std::pair<int, double>> progress;

    // contact i's conditions at relative velocity ui and its current impulses
    double local_residual(int i, const Vec3& ui) const {
        const int n = 3 * i;
        const double un = ui[0] + bias[i];
        double r = lambda[n] > 0 ? std::abs(un) : std::max(0.0, -un);
        const Eigen::Vector2d ut(ui[1], ui[2]), lt(lambda[n + 1], lambda[n + 2]);
        const double limit = coefficient[i] * lambda[n];
        // without normal impulse there is no friction (its disk is the point 0): any sliding is allowed
        if (limit > 0) {
            if (lt.norm() < limit * (1 - 1e-9) || lt.norm() == 0)
                r = std::max(r, ut.norm());  // sticking: no sliding allowed
            else
                r = std::max(r, (ut + (ut.norm() / lt.norm()) * lt).norm());  // anti-parallel
        }
        return r;
    }

    double residual(const std::vector<int>& contacts) {
        double worst = 0;
        for (const int i : contacts) {
            const Vec3 ui = op.velocity(i);
            u[i] = ui;
            own[i] = local_residual(i, ui);
            worst = std::max(worst, own[i]);
        }
        return worst;
    }

    // One sweep over `visit`. A partial sweep measures no residual of its own: each contact's
    // conditions as the sweep finds it (before its update, with the contacts visited before it
    // updated) estimate where the last sweep left them, returned; only when that estimate is
    // within the tolerance is every contact's residual measured (run: `deciding`). The
    // measurement after each partial sweep would be a second pass of velocities over the
    // visited contacts.
    double sweep(const std::vector<int>& visit, bool full) {
        double estimate = 0;
        for (const int i : visit) {
            const int n = 3 * i;
            Vec3 ui;
            const bool bare = !op.formed(i);
            if (bare) {
                // A contact whose columns are not formed yet (ReducedColumns) has had no impulse.
                // Open (u_n + gap/dt >= 0), the update below leaves it without impulse whatever
                // its block of W (as long as it is positive; its residual is 0 then), so it is
                // left as it is; otherwise its columns and block are formed now.
                ui = op.velocity(i);
                if (lambda[n] == 0 && lambda[n + 1] == 0 && lambda[n + 2] == 0 && ui[0] + bias[i] >= 0) continue;
            }
            const Mat3& w = op.block(i);
            if (w(0, 0) <= 0) {  // both sides immovable: no impulse changes its residual
                estimate = std::max(estimate, own[i]);
                continue;
            }
            if (!bare) ui = op.velocity(i);
            if (!full) estimate = std::max(estimate, local_residual(i, ui));
            update(i, w, ui);
        }
        return estimate;
    }

    // Contact i's impulses given the others': the normal one projected, then friction as the
    // exact solution of the contact's 2x2 subproblem (the impulse inside the disk of radius
    // mu lambda_n minimizing the block's kinetic energy), whose optimality conditions are
    // Coulomb's: sticking inside the disk, or on its rim exactly opposite the post-step sliding
    // velocity (maximal dissipation).
    void update(int i, const Mat3& w, Vec3 ui) {
        const int n = 3 * i;
        const double ln = std::max(0.0, lambda[n] - (ui[0] + bias[i]) / w(0, 0));
        Vec3 delta(ln - lambda[n], 0, 0);
        lambda[n] = ln;
        ui += w.col(0) * delta[0];
        const Eigen::Matrix2d wtt = 0.5 * (w.block<2, 2>(1, 1) + w.block<2, 2>(1, 1).transpose());
        if (wtt.trace() > 0) {
            const Eigen::Vector2d ut(ui[1], ui[2]);
            const Eigen::Vector2d lt(lambda[n + 1], lambda[n + 2]);
            if (!disk_made[i]) {
                disks[i] = Disk(wtt);
                disk_made[i] = 1;
            }
            const Eigen::Vector2d target = disk_constrained_minimum(disks[i], wtt * lt - ut, coefficient[i] * lambda[n]);
            delta[1] = target[0] - lt[0];
            delta[2] = target[1] - lt[1];
            lambda[n + 1] = target[0];
            lambda[n + 2] = target[1];
        }
        op.apply(i, delta);
    }

    // After a full sweep (every contact's residual measured): the contacts the partial sweeps
    // visit until the next one, and when that comes
    void after_full_sweep(int it) {
        select_live(result.residual);
        next_full = it + (large ? kFullEveryLarge : kFullEvery);
        // (on small problems the focus's copies cost more than they save)
        if (large) op.focus(live, lambda);
    }

    // the contacts the partial sweeps visit, from every contact's residual (own, u) against the worst
    void select_live(double worst) {
        live.clear();
        // settled contacts left out only where the subspace steps cannot run (too many
        // active contacts): with them, the sweeps converge together and leaving contacts
        // out slows them (test_contact_reduced's contacts on one element take more sweeps)
        int active = 0;
        for (int i = 0; i < c; ++i) active += lambda[3 * i] > 0;
        large = active > kSubspaceMaxActive;
        const double settled = large ? std::max(tolerance, kHotFraction * worst) : -1.0;
        const double open_margin = tolerance;
        for (int i = 0; i < c; ++i)
            if ((lambda[3 * i] > 0 || lambda[3 * i + 1] != 0 || lambda[3 * i + 2] != 0 || !(u[i][0] + bias[i] > open_margin)) &&
                own[i] > settled)
                live.push_back(i);
    }

    // The pending subspace step, then this sweep: kept only if the residual fell
    void judge_step(int it) {
        pending = false;
        const bool rejected = result.residual > saved_residual;
        interval = rejected ? std::min(kSubspaceMaxInterval, 2 * interval) : kSubspaceEvery;
        damping = rejected ? std::min(kDampingMax, 10 * damping) : std::max(kDampingMin, damping / 10);
        if (rejected) slow_slip = slow_slip == kSlowSlip ? kSlowSlipWide : kSlowSlip;
        next_step = it + 1 + interval;
        if (rejected) {
            lambda = saved;
            op.reset(lambda);
            result.residual = residual(all);
        }
    }

    // A subspace step now, decided after the next sweep (judge_step); false when none could be
    // taken (no active contact, or too many)
    bool take_step(int it) {
        saved = lambda;
        saved_residual = result.residual;
        if (subspace_step(op, c, bias, coefficient, u, tolerance, slow_slip, damping, blocks_cache, last_state, lambda)) {
            op.reset(lambda);
            pending = true;
            next_full = it + 1;  // the step may close left-out contacts: the sweep after it visits all
            return true;
        }
        // not before then (with too many, not before the next full sweep: each step decision
        // costs a residual on every contact)
        next_step = it + 1 + (large ? kFullEveryLarge : interval);
        return false;
    }

    // The stall stop (see the class's comment), on the residual r of every contact after sweep it
    bool stalled(int it, double r) {
        const double best = progress.empty() ? r : std::min(r, progress.back().second);
        progress.emplace_back(it, best);
        if (!(stall_factor > 0) || r > stall_factor * tolerance) return false;
        int k = static_cast<int>(progress.size()) - 1;  // the last measurement kStallWindow or more sweeps before
        while (k >= 0 && progress[k].first > it - kStallWindow) --k;
        if (k < 0) return false;
        const double fall = best / progress[k].second;  // over it - progress[k].first sweeps
        if (fall >= 1) return true;
        const double needed = (it - progress[k].first) * std::log(best / tolerance) / -std::log(fall);
        return needed > max_iterations - 1 - it;
    }

    // The static problem solved: contacts sliding clearly faster than the solver's tolerance
    // (not sticking ones still converging) while at the static limit break loose, to kinetic
    // friction. Whether any did.
    bool break_loose() {
        bool any = false;
        for (int i = 0; i < c; ++i) {
            const Eigen::Vector2d ut(u[i][1], u[i][2]);
            const Eigen::Vector2d lt(lambda[3 * i + 1], lambda[3 * i + 2]);
            if (kinetic[i] < coefficient[i] && ut.norm() > kSlowSlip * tolerance &&
                lt.norm() >= coefficient[i] * lambda[3 * i] * (1 - 1e-9)) {
                coefficient[i] = kinetic[i];
                any = true;
            }
        }
        return any;
    }
};

template <class Op>
PgsResult sweep(Op& op, int c, const VecX& gap, const VecX& friction, const VecX& kinetic, double dt,
                double recovery_speed, VecX& lambda, int max_iterations, double tolerance, double stall_factor) {
    return Sweeps<Op>(op, c, gap, friction, kinetic, dt, recovery_speed, lambda, max_iterations, tolerance, stall_factor)
        .run();
}

// W dense: u = u_free + W lambda kept up to date, a column per changed impulse.
struct DenseOp {
    const MatX& W;
    VecX u;
    std::vector<Mat3> blocks;
    DenseOp(const ContactProblem& p, const VecX& lambda) : W(p.W), u(p.u_free + p.W * lambda), u_free(p.u_free) {
        const int c = static_cast<int>(p.gap.size());
        blocks.resize(c);
        for (int i = 0; i < c; ++i) blocks[i] = W.block<3, 3>(3 * i, 3 * i);
    }
    Vec3 velocity(int i) const { return u.segment<3>(3 * i); }
    bool formed(int) const { return true; }
    const Mat3& block(int i) const { return blocks[i]; }
    Mat3 cross_block(int i, int j) const { return W.block<3, 3>(3 * i, 3 * j); }
    const VecX& u_free;
    void reset(const VecX& lambda) { u.noalias() = u_free + W * lambda; }
    void refresh(const VecX&) {}
    void focus(const std::vector<int>&, const VecX&) {}
    void apply(int i, const Vec3& delta) {
        for (int d = 0; d < 3; ++d)
            if (delta[d] != 0) u.noalias() += W.col(3 * i + d) * delta[d];
    }
};

// W = sum_b P_b C_b P_b^T: y_b = C_b P_b^T lambda kept up to date.
void reduced_velocities(const ReducedContactProblem& p, const VecX& lambda, std::vector<VecX>& f, std::vector<VecX>& y,
                        VecX& u);

// W = sum_b P_b C_b P_b^T: y_b = C_b P_b^T lambda kept up to date. Per contact and body the
// three columns H = C_b P_b^T (m_b x 3) are formed once, so a contact's update is three
// columns of length m_b per body it touches.
//
// Focused on the contacts the partial sweeps visit (focus, sweep), only the entries of y those
// contacts read are kept up to date: S_b, the union of their entries on body b, on copies of
// their columns restricted to S_b. The rest of y catches up at the next full sweep with each
// focused contact's net change of impulse over the partial sweeps: one column update per
// contact instead of one per contact and sweep. On the 10x bunny S_b is a third to a tenth of
// body b's entries and the partial sweeps visit each focused contact ~9 times.
struct ReducedOp {
    const ReducedContactProblem& p;
    std::vector<VecX> y, f;
    // focus: per body, entry -> index in S_b (or -1) and back, y on S_b, and per focused
    // contact and body its three columns on S_b (`focus_parts`: per contact, (body, first
    // column in hc[body]); only the focused contacts' are current)
    bool focused = false;
    int refreshes = 0;
    std::vector<int> focus_live;
    std::vector<Vec3> focus_lambda;  // per focused contact: its impulse at focus()
    std::vector<std::vector<int>> s_index, s_entries;
    std::vector<VecX> ys;
    std::vector<MatX> hc;
    // per focused contact, its entries as they read ys: (body's ys, position in it, coefficient),
    // contact i's at [gather_begin[i], gather_begin[i] + p.begin[i + 1] - p.begin[i]); a visit
    // then reads them in a row instead of looking up each entry's position in S_b (same
    // products, same order)
    struct Gather {
        const double* y;
        Vec3 coefficient;
    };
    std::vector<Gather> gather;
    std::vector<int> gather_begin;
    std::vector<std::vector<std::pair<int, int>>> focus_parts;
    ReducedColumns& columns;  // (contacts' columns formed as the sweeps first need them)
    const std::vector<Mat3>& blocks;
    const std::vector<MatX>& h;                                  // (see ReducedColumns)
    const std::vector<Eigen::MatrixXf>& hs;
    const std::vector<std::vector<std::pair<int, int>>>& parts;
    ReducedOp(ReducedColumns& columns, const VecX& lambda)
        : p(columns.p), columns(columns), blocks(columns.blocks), h(columns.h), hs(columns.hs), parts(columns.parts) {
        reset(lambda);
    }
    void reset(const VecX& lambda) {
        VecX u;
        reduced_velocities(p, lambda, f, y, u);
        focused = false;
    }
    // Before a full sweep: y caught up after a focus; with single-precision columns, every
    // fourth time recomputed exactly (their round-off, ~1e-7 of each change, would otherwise
    // add up over the solve)
    void refresh(const VecX& lambda) {
        if (focused) {
            focused = false;
            for (size_t k = 0; k < focus_live.size(); ++k) {
                const int i = focus_live[k];
                apply(i, Vec3(lambda.segment<3>(3 * i) - focus_lambda[k]));
            }
        }
        if (!hs.empty() && ++refreshes % 4 == 0) reset(lambda);
    }
    void focus(const std::vector<int>& live, const VecX& lambda) {
        if (focused) refresh(lambda);
        focus_live = live;
        focus_lambda.resize(live.size());
        for (size_t k = 0; k < live.size(); ++k) focus_lambda[k] = lambda.segment<3>(3 * live[k]);
        const int nb = static_cast<int>(p.bodies.size());
        s_index.resize(nb);
        s_entries.resize(nb);
        ys.resize(nb);
        hc.resize(nb);
        focus_parts.resize(parts.size());
        for (int b = 0; b < nb; ++b) {
            for (int k : s_entries[b]) s_index[b][k] = -1;
            s_index[b].resize(p.bodies[b].C.rows(), -1);
            s_entries[b].clear();
        }
        std::vector<int> columns(nb, 0);
        for (const int i : live) {
            this->columns.ensure(i);
            for (int e = p.begin[i]; e < p.begin[i + 1]; ++e) {
                const auto& a = p.entries[e];
                if (s_index[a.body][a.index] < 0) {
                    s_index[a.body][a.index] = static_cast<int>(s_entries[a.body].size());
                    s_entries[a.body].push_back(a.index);
                }
            }
            focus_parts[i].clear();
            for (const auto& q : parts[i]) {
                focus_parts[i].emplace_back(q.first, columns[q.first]);
                columns[q.first] += 3;
            }
        }
        for (int b = 0; b < nb; ++b) {
            const int sb = static_cast<int>(s_entries[b].size());
            ys[b].resize(sb);
            for (int k = 0; k < sb; ++k) ys[b][k] = y[b][s_entries[b][k]];
            hc[b].resize(sb, columns[b]);
        }
        gather.clear();
        gather_begin.resize(parts.size());
        for (const int i : live) {
            gather_begin[i] = static_cast<int>(gather.size());
            for (int e = p.begin[i]; e < p.begin[i + 1]; ++e) {
                const auto& a = p.entries[e];
                gather.push_back(Gather{ys[a.body].data() + s_index[a.body][a.index], a.coefficient});
            }
        }
        for (const int i : live)
            for (size_t k = 0; k < parts[i].size(); ++k) {
                const int b = parts[i][k].first, from = parts[i][k].second, to = focus_parts[i][k].second;
                for (int col = 0; col < 3; ++col)
                    for (int r = 0; r < hc[b].rows(); ++r)
                        hc[b](r, to + col) = hs.empty() ? h[b](s_entries[b][r], from + col) : double(hs[b](s_entries[b][r], from + col));
            }
        focused = true;
    }
    Vec3 velocity(int i) const {
        Vec3 out = p.u_free.segment<3>(3 * i);
        if (focused) {
            const Gather* g = gather.data() + gather_begin[i];
            for (int e = p.begin[i]; e < p.begin[i + 1]; ++e, ++g) out += g->coefficient * *g->y;
            return out;
        }
        for (int e = p.begin[i]; e < p.begin[i + 1]; ++e) out += p.entries[e].coefficient * y[p.entries[e].body][p.entries[e].index];
        return out;
    }
    // (a contact's block comes with its columns: formed now if they were not yet)
    const Mat3& block(int i) const {
        columns.ensure(i);
        return blocks[i];
    }
    bool formed(int i) const { return columns.formed[i] != 0; }
    Mat3 cross_block(int i, int j) const {
        Mat3 out = Mat3::Zero();
        for (int e = p.begin[i]; e < p.begin[i + 1]; ++e) {
            const auto& a = p.entries[e];
            if (hs.empty()) {
                columns.ensure(j);
                for (const auto& q : parts[j])
                    if (q.first == a.body) out += a.coefficient * h[a.body].row(a.index).segment<3>(q.second);
                continue;
            }
            // (single-precision columns keep no double copy: from C itself, as delassus())
            for (int g = p.begin[j]; g < p.begin[j + 1]; ++g)
                if (p.entries[g].body == a.body)
                    out += p.bodies[a.body].C(a.index, p.entries[g].index) * a.coefficient * p.entries[g].coefficient.transpose();
        }
        return out;
    }
    void apply(int i, const Vec3& delta) {
        if (delta[0] == 0 && delta[1] == 0 && delta[2] == 0) return;  // an open contact staying open
        if (focused) {
            for (const auto& q : focus_parts[i]) {
                const MatX& hb = hc[q.first];
                add_three_columns(ys[q.first].data(), hb.data() + hb.rows() * q.second, hb.rows(), hb.rows(), delta[0], delta[1], delta[2]);
            }
            return;
        }
        columns.ensure(i);
        for (const auto& q : parts[i]) {
            if (!hs.empty()) {
                const Eigen::MatrixXf& hf = hs[q.first];
                add_three_columns_single(y[q.first].data(), hf.data() + hf.rows() * q.second, hf.rows(), hf.rows(), delta[0], delta[1], delta[2]);
                continue;
            }
            const MatX& hb = h[q.first];
            add_three_columns(y[q.first].data(), hb.data() + hb.rows() * q.second, hb.rows(), hb.rows(), delta[0], delta[1], delta[2]);
        }
    }
};

void start(int c, VecX& lambda) {
    if (lambda.size() != 3 * c) lambda = VecX::Zero(3 * c);  // else: a warm start
    for (int i = 0; i < c; ++i) lambda[3 * i] = std::max(0.0, lambda[3 * i]);
}
}  // namespace

PgsResult solve_pgs(const ContactProblem& p, VecX& lambda, int max_iterations, double tolerance, double stall_factor) {
    const int c = static_cast<int>(p.gap.size());
    start(c, lambda);
    DenseOp op(p, lambda);
    return sweep(op, c, p.gap, p.friction, p.kinetic, p.dt, p.recovery_speed, lambda, max_iterations, tolerance,
                 stall_factor);
}

namespace {
// u = u_free + W lambda on the reduced form: f_b = P_b^T lambda, y_b = C_b f_b, u = u_free + sum_b P_b y_b
// (one product with each small C_b: far cheaper than a Gauss-Seidel sweep, which updates y_b
// after every contact).
void reduced_velocities(const ReducedContactProblem& p, const VecX& lambda, std::vector<VecX>& f, std::vector<VecX>& y,
                        VecX& u) {
    const int c = static_cast<int>(p.gap.size());
    f.resize(p.bodies.size());
    y.resize(p.bodies.size());
    for (size_t b = 0; b < p.bodies.size(); ++b) f[b].setZero(p.bodies[b].C.rows());
    for (int i = 0; i < c; ++i)
        for (int e = p.begin[i]; e < p.begin[i + 1]; ++e)
            f[p.entries[e].body][p.entries[e].index] += p.entries[e].coefficient.dot(lambda.segment<3>(3 * i));
    for (size_t b = 0; b < p.bodies.size(); ++b) y[b].noalias() = p.bodies[b].C * f[b];
    u = p.u_free;
    for (int i = 0; i < c; ++i)
        for (int e = p.begin[i]; e < p.begin[i + 1]; ++e)
            u.segment<3>(3 * i) += p.entries[e].coefficient * y[p.entries[e].body][p.entries[e].index];
}

}  // namespace

ReducedColumns::ReducedColumns(const ReducedContactProblem& p, const VecX* warm) : p(p) {
    const int c = static_cast<int>(p.gap.size());
    const int nb = static_cast<int>(p.bodies.size());
    std::vector<int> columns(nb, 0);
    parts.resize(c);
    for (int i = 0; i < c; ++i)
        for (int e = p.begin[i]; e < p.begin[i + 1]; ++e) {
            const int b = p.entries[e].body;
            bool seen = false;
            for (const auto& q : parts[i]) seen = seen || q.first == b;
            if (!seen) {
                parts[i].emplace_back(b, columns[b]);
                columns[b] += 3;
            }
        }
    for (int b = 0; b < nb; ++b) bytes += sizeof(double) * static_cast<size_t>(p.bodies[b].C.rows()) * columns[b];
    blocks.assign(c, Mat3::Zero());
    formed.assign(c, 0);
    up_front.assign(c, 1);
    if (warm && warm->size() == 3 * c)
        for (int i = 0; i < c; ++i) up_front[i] = warm->segment<3>(3 * i) != Vec3::Zero();
    for (int i = 0; i < c; ++i) formed[i] = parts[i].empty();  // (no dynamic body: no columns, W's block 0)
    // The columns in single precision when they outgrow the caches: a sweep then streams
    // them from memory, and half the bytes is most of the sweep's time (the 10x bunny's ~950
    // contacts on ~590 unknowns have ~13 MB of columns). The
    // velocities are kept in double and recomputed exactly from time to time (refresh), so
    // the single-precision round-off (~1e-7 relative) does not accumulate; the paper bunny's
    // ~2 MB stay double (the copy would cost more than it saves there). No double copy is kept
    // then: each contact's columns are formed in double in a scratch and rounded; each contact's own 3x3 block of W is
    // taken from its columns as they are formed, the subspace step's blocks between contacts
    // from C itself.
    const bool single = p.single_columns == 1 || (p.single_columns < 0 && bytes > kSingleColumnsBytes);
    for (int b = 0; b < nb; ++b) {  // (each contact's share writes its own columns)
        if (single) hs.emplace_back(p.bodies[b].C.rows(), columns[b]);
        else h.emplace_back(p.bodies[b].C.rows(), columns[b]);
    }
}

void ReducedColumns::form(int part, int parts_count) {
    const int c = static_cast<int>(p.gap.size());
    for (int i = part; i < c; i += parts_count)
        if (up_front[i] && !formed[i]) form_contact(i);
}

int ReducedColumns::formed_count() const {
    return static_cast<int>(std::count(formed.begin(), formed.end(), 1));
}

// The contact's columns, and its diagonal block of W from their rows at its own entries
void ReducedColumns::form_contact(int i) {
    const bool single = !hs.empty();
    MatX scratch;  // single: one contact's columns on one body, in double
    std::vector<const double*> cols;
    std::vector<Vec3> coefficients;
    for (const auto& q : parts[i]) {
        const int b = q.first;
        const long m = p.bodies[b].C.rows();
        double* hb;
        if (single) {
            scratch.resize(m, 3);
            hb = scratch.data();
        } else {
            hb = h[b].data() + m * q.second;
        }
        // the contact's entries on this body: its columns of C and their coefficients
        cols.clear();
        coefficients.clear();
        for (int e = p.begin[i]; e < p.begin[i + 1]; ++e) {
            const auto& a = p.entries[e];
            if (a.body != b) continue;
            cols.push_back(p.bodies[b].C.col(a.index).data());
            coefficients.push_back(a.coefficient);
        }
        form_three_columns(hb, m, m, cols.data(), coefficients.data(), static_cast<int>(cols.size()));
        const Eigen::Map<const MatX> hi(hb, m, 3);
        for (int e = p.begin[i]; e < p.begin[i + 1]; ++e)
            if (p.entries[e].body == b) blocks[i] += p.entries[e].coefficient * hi.row(p.entries[e].index);
        if (single) hs[b].middleCols(q.second, 3) = scratch.cast<float>();
    }
    formed[i] = 1;
}

PgsResult solve_pgs(const ReducedContactProblem& p, VecX& lambda, int max_iterations, double tolerance,
                    double stall_factor) {
    ReducedColumns columns(p, &lambda);
    columns.form(0, 1);
    return solve_pgs(p, columns, lambda, max_iterations, tolerance, stall_factor);
}

PgsResult solve_pgs(const ReducedContactProblem& p, ReducedColumns& columns, VecX& lambda, int max_iterations,
                    double tolerance, double stall_factor) {
    const int c = static_cast<int>(p.gap.size());
    start(c, lambda);
    ReducedOp op(columns, lambda);
    return sweep(op, c, p.gap, p.friction, p.kinetic, p.dt, p.recovery_speed, lambda, max_iterations, tolerance,
                 stall_factor);
}

MatX ReducedContactProblem::delassus() const {
    const int c = static_cast<int>(gap.size());
    MatX w = MatX::Zero(3 * c, 3 * c);
    for (int i = 0; i < c; ++i)
        for (int j = 0; j < c; ++j)
            for (int e = begin[i]; e < begin[i + 1]; ++e)
                for (int g = begin[j]; g < begin[j + 1]; ++g)
                    if (entries[e].body == entries[g].body)
                        w.block<3, 3>(3 * i, 3 * j) += bodies[entries[e].body].C(entries[e].index, entries[g].index) *
                                                       entries[e].coefficient * entries[g].coefficient.transpose();
    return w;
}

}  // namespace hh
