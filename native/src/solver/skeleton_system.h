// The coupled system of Eq. 7 for a hand of B rigid bones (docs/skeleton.md, Section 3):
// unknowns (v_h, v_t), v_h = (v_1, omega_1, ..., v_B, omega_B). A_h has one 6x6 block per bone
// and, with ball joints (docs/skeleton.md Section 5), a 6x6 block each way between a bone and its
// parent (links): block-sparse along the tree, and S, dense anyway, stays 6B x 6B; bone b's rows of A_ht and columns of A_th are non-zero only at its own nodes
// N_b (Eq. 9), and the N_b are disjoint. solve() is the Schur complement of A_t (Eqs. 12-13)
// with the flesh solver a black box: one batch of 1 + 6B right-hand sides on one factor of
// A_t (b_t and the columns of A_th, each built from its bone's nodes only), the dense 6B x 6B
// S = A_h - A_ht A_t^-1 A_th formed from A_ht's sparse rows, one LU of S, and Eq. 12 as a
// combination of the solved columns. When every bone is prescribed (v_h = b_h, S = I) it is one
// flesh solve, v_t = A_t^-1 (b_t - A_th v_h), and the columns only on demand (flesh_response). (One bone is HandSystem's path, data.hand: the step never
// comes here with B = 1, so today's step is kept bit for bit.)
#pragma once
#include <vector>

#include "solver/deformable_system.h"

namespace hh {

class SkeletonSystem {
public:
    explicit SkeletonSystem(DeformableSystem& tool) : tool(tool) {}
    DeformableSystem& tool;
    // Per bone: its block of A_h, its nodes, and per node its 3x6 block of A_th (Eq. 10) and
    // 6x3 block of A_ht (Eq. 8)
    std::vector<Mat6> Ah;
    std::vector<const std::vector<int>*> nodes;
    std::vector<std::vector<Mat36>> Ath;
    std::vector<std::vector<Mat63>> Aht;
    // A_h's off-diagonal blocks: block (row, col) couples bone row's equations to bone col's
    // velocities (a joint's; none without joints)
    struct Link {
        int row, col;
        Mat6 block;
    };
    std::vector<Link> links;
    VecX r, s;  // (b_h, b_t) and (v_h, v_t)
    int n_bones() const { return static_cast<int>(Ah.size()); }
    void resize(int n_bones);
    void solve();
    double t_deformable = 0, t_schur = 0;  // s in the tool's solves, in forming and solving S
    int columns = 0;                       // right-hand sides of the last solve()'s A_t solve
    MatX schur;                            // S of the last solve (6B x 6B)
    // After solve(): A_t^-1 A_th (3n x 6B), the flesh's velocity response to the bones'. After an
    // all-prescribed solve it is solved here on first call (6B columns on the step's A_t, in
    // solve's warm-start slots 1..6B): only the bones' coupling model reads it. Not thread-safe;
    // call it after the step, before the next step's formulation changes A_t.
    const MatX& flesh_response() const;
    // Whether the last solve() was the all-prescribed one (one right-hand side)
    bool solved_prescribed() const { return prescribed_; }

    // The world's contact responses (solver/skeleton_response.cpp), after solve(), on its factor
    // of A_t, its A_t^-1 A_th and the LU of S, as HandSystem's (the one-bone hand's):
    // A^-1 rhs for a right-hand side (v_h, v_t) of 6B + 3n (one A_t solve, Eq. 13 for v_h, Eq. 12
    // for v_t), through the tool's response operator (DeformableSystem::solve_response: the
    // warped factor with ReusedCholesky). Only reads: calls may run side by side on the step's
    // Cholesky factor (World::solve_contact_body).
    VecX apply_inverse(const VecX& rhs) const;
    // the same for every column of rhs; rows: only those rows of the result (indices into (v_h, v_t))
    void apply_inverse_many(const MatX& rhs, MatX& out, const std::vector<int>* rows = nullptr) const;

private:
    bool all_prescribed() const;
    void solve_prescribed();
    void solve_schur();
    void ath_columns(MatX& out, Eigen::Index first_col) const;
    MatX rhs_, solved_;
    mutable MatX response_;
    mutable bool response_ready_ = false;
    bool prescribed_ = false;
    Eigen::PartialPivLU<MatX> schur_lu_;  // of the last step's S
    double schur_condition_ = 0;  // of the last step's S (0: none yet)
};

// The reference: Eq. 7 assembled as one sparse (6B + 3n)^2 matrix and solved by sparse LU.
VecX solve_monolithic(const SkeletonSystem& system, const VecX& rhs);

}  // namespace hh
