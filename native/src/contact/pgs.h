// The contact problem of one step at velocity level, after Otaduy et al. 2009 (implicit
// contact handling): with W = J A^-1 J^T (the Delassus operator, built from each body's
// black-box solve) and u = J v* + W lambda the relative velocities in the contact frames,
// find impulses lambda with, per contact,
//   normal:   lambda_n >= 0,  u_n + gap/dt >= 0,  lambda_n (u_n + gap/dt) = 0
//   friction: |lambda_t| <= mu lambda_n; sticking (u_t = 0) inside the cone, sliding on its
//             boundary against the sliding direction (maximal dissipation)
// solved by projected Gauss-Seidel over 3x3 contact blocks.
//
// Two forms of W, the same sweeps:
// - ContactProblem: W dense (3c x 3c).
// - ReducedContactProblem: W = sum_b P_b C_b P_b^T, per dynamic body b a small symmetric
//   matrix C_b (its response A_b^-1 on the m_b unknowns the contacts touch, or on its contact
//   rows) and the sparse P_b (each contact's three rows on those m_b entries). A sweep keeps
//   y_b = C_b P_b^T lambda instead of u, so W is never formed: a contact costs ~12 m_b per
//   body it touches instead of 3 x 3c, and forming W (3c x 3c x ~12) is skipped.
#pragma once
#include <utility>
#include <vector>

#include "common/types.h"

namespace hh {

struct ContactProblem {
    MatX W;         // 3c x 3c, rows per contact: normal, tangent1, tangent2
    VecX u_free;    // 3c: J v* (including the velocities of kinematic bodies)
    VecX gap;       // c: signed distance minus the contact thickness
    VecX friction;  // c: static Coulomb coefficient: sticking holds up to this
    VecX kinetic;   // c: kinetic coefficient (<= static): sliding feels this
    double dt = 0;
    double recovery_speed = 0.05;  // m/s: largest speed at which a penetration is pushed out
};

struct ReducedContactProblem {
    struct Body {
        MatX C;  // m x m, symmetric
    };
    struct Entry {   // contact rows (normal, tangent1, tangent2) on entry `index` of body `body`'s basis
        int body;
        int index;
        Vec3 coefficient;
    };
    std::vector<Body> bodies;
    std::vector<int> begin;       // c + 1: contact i's entries are entries[begin[i], begin[i + 1])
    std::vector<Entry> entries;
    VecX u_free, gap, friction, kinetic;  // as in ContactProblem
    double dt = 0;
    double recovery_speed = 0.05;
    // The sweeps' response columns in single precision (velocities stay double, recomputed
    // every full sweep): -1 when the columns outgrow the caches (6 MB), 0 never, 1 always.
    int single_columns = -1;
    // W = sum_b P_b C_b P_b^T, rows and columns of the given contacts (3 per contact)
    MatX delassus() const;
};

// The sweeps' response columns on the reduced form: per contact and dynamic body it touches,
// the three columns H = C_b P_b^T (m_b x 3), in double, or in single precision only when they
// outgrow the caches. Formed in shares (every parts-th contact; each contact's columns are its
// own), which the world runs on its two threads side by side; solve_pgs forms them itself
// when not given them.
// Only the contacts a sweep changes (or focuses on) read their columns or their diagonal
// block of W: on the 10x bunny a third to a half of them; the others stay open throughout.
// Given the warm start, the shares form the columns (and blocks) of the contacts it gives an
// impulse, nearly all of which the sweeps change, and the sweeps form any other contact's the
// first time they need them (ensure). Columns and block are the same values whoever forms
// them and whenever, so the sweeps' results do not depend on the split.
struct ReducedColumns {
    // lays them out (no arithmetic yet); warm: the sweeps' warm start (3c impulses), or null
    // (every contact's columns formed in the shares)
    explicit ReducedColumns(const ReducedContactProblem& p, const VecX* warm = nullptr);
    void form(int part, int parts);
    // contact i's columns, formed now if they were not yet (one thread at a time: the sweeps')
    void ensure(int i) {
        if (!formed[i]) form_contact(i);
    }
    const ReducedContactProblem& p;
    std::vector<MatX> h;                                  // per body: m_b x 3 (its contacts), or none
    std::vector<Eigen::MatrixXf> hs;                      // per body: the same in single precision, or none
    std::vector<std::vector<std::pair<int, int>>> parts;  // per contact: (body, first column in h[body])
    std::vector<Mat3> blocks;                             // per contact: its 3x3 diagonal block of W (once formed)
    std::vector<unsigned char> up_front;                  // per contact: formed by the shares
    std::vector<unsigned char> formed;                    // per contact: its columns (and block) are formed
    size_t bytes = 0;                                     // of the columns in double
    int formed_count() const;

private:
    void form_contact(int i);  // its columns, and its diagonal block of W from them
};

struct PgsResult {
    int iterations = 0;
    double residual = 0;  // m/s: largest violation of the conditions above (see solve_pgs)
};

// lambda: in, a warm start when it has 3c entries (the previous step's impulses of the same
// contacts); out, the impulses. Sweeps end when every condition holds to `tolerance` m/s, or
// after max_iterations; with stall_factor > 0 (at least 1) also once they stall near the
// tolerance: their residual within stall_factor x tolerance and, at the rate of their last
// kStallWindow sweeps (pgs.cpp), the tolerance out of reach within max_iterations.
PgsResult solve_pgs(const ContactProblem& p, VecX& lambda, int max_iterations, double tolerance,
                    double stall_factor = 0);
PgsResult solve_pgs(const ReducedContactProblem& p, VecX& lambda, int max_iterations, double tolerance,
                    double stall_factor = 0);
// the same on columns formed beforehand (every share of them)
// (the sweeps form the columns the shares left out as they need them)
PgsResult solve_pgs(const ReducedContactProblem& p, ReducedColumns& columns, VecX& lambda, int max_iterations,
                    double tolerance, double stall_factor = 0);

}  // namespace hh
