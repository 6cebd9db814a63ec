// The contact problem of one step at velocity level, after Otaduy et al. 2009 (implicit
// contact handling): with W = J A^-1 J^T (the Delassus operator, built from each body's
// black-box solve) and u = J v* + W lambda the relative velocities in the contact frames,
// find impulses lambda with, per contact,
//   normal:   lambda_n >= 0,  u_n + gap/dt >= 0,  lambda_n (u_n + gap/dt) = 0
//   friction: |lambda_t| <= mu lambda_n; sticking (u_t = 0) inside the cone, sliding on its
//             boundary against the sliding direction (maximal dissipation)
// solved by projected Gauss-Seidel over 3x3 contact blocks.
#pragma once
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

struct PgsResult {
    int iterations = 0;
    double residual = 0;  // m/s: largest violation of the conditions above (see solve_pgs)
};

// lambda: in, a warm start when it has 3c entries (the previous step's impulses of the same
// contacts); out, the impulses. Sweeps end when every condition holds to `tolerance` m/s.
PgsResult solve_pgs(const ContactProblem& p, VecX& lambda, int max_iterations, double tolerance);

}  // namespace hh
