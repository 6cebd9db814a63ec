// The complete hand (Section 6): deformable tool + rigid handle + coupling blocks, behind
// the same LinearSystem interface. solve() is the Schur-complement solution of Eq. 7
// (Eqs. 12-13): the paper's 8 solves with At (7 of them batched, the 8th a combination of
// those), one 6x6 solve with the Schur complement of At.
// r = (b_h, b_t) and s = (v_h, v_t), handle first as in Eq. 7.
#pragma once
#include <vector>

#include "solver/deformable_system.h"
#include "solver/rigid_system.h"

namespace hh {

class HandSystem : public LinearSystem {
public:
    HandSystem(DeformableSystem& tool, RigidSystem& handle) : tool(tool), handle(handle) {}
    DeformableSystem& tool;
    RigidSystem& handle;
    Mat6 Ah = Mat6::Zero();            // the handle's own block, kept: handle.A is overwritten
    std::vector<int> coupled_nodes;    // nodes with a spring to the handle
    std::vector<Mat36> Ath;            // 3x6 block of Ath per coupled node (Eq. 10)
    std::vector<Mat63> Aht;            // 6x3 block of Aht per coupled node (Eq. 8)

    // When set (the world's hand, World::step), solve() solves b_t and the Schur columns as two
    // groups that may run side by side on two threads (DeformableSystem::solve_many_split; the
    // same result either way), and apply_inverse_units the fresh response columns in two shares
    // (DeformableSystem::response_blocks). Empty: one batch, one after the other.
    Beside beside;
    // Set before solve() (the world's hand: the last step's contact impulses, World::solve_free):
    // solve() then also forms carried_response = apply_inverse(carried, true) and empties
    // carried. With `beside`, its At pass (the one costly part: the factor's single-precision
    // copy, ~1.5 ms on the ~17000-tet hand) runs on the Schur columns' side, beside b_t; it is
    // solved again after the groups if the factor was renewed once they were done.
    VecX carried, carried_response;
    void solve() override;
    // After solve(): A^-1 rhs for another right-hand side, reusing the factor of At, the
    // columns A_t^-1 Ath and the Schur complement (one At solve instead of eight). The
    // contact solver applies the impulses' velocities with it. The At solve is the tool's
    // response operator (DeformableSystem::solve_response: with ReusedCholesky the warped
    // factor, not CG), the same as apply_inverse_many's.
    // single: the At solve through DeformableSystem::solve_response_single instead; else, with
    // `beside`, through solve_response_split (the contact impulses' velocities, World::step: the
    // factor's two parts on the two threads, the other otherwise idle then).
    VecX apply_inverse(const VecX& rhs, bool single = false);
    // ... its handle part and Eq. 12, given the At pass s0 = A_t^-1 rhs_t
    VecX finish_inverse(const VecX& rhs, const VecX& s0);
    // After solve(): out = A^-1 rhs for every column of rhs at once (the At solves batched 8
    // columns per pass through the tool's solve_response). Added for the contact solver's
    // Delassus operator. rows: only these rows of A^-1 rhs (indices into (v_h, v_t)), in that
    // order; the contact solver needs a few hundred of thousands.
    void apply_inverse_many(const MatX& rhs, MatX& out, const std::vector<int>* rows = nullptr);
    // The same for unit right-hand sides, one per unknown in `unknowns` (indices into (v_h,
    // v_t)), from the tool's kept response columns (DeformableSystem::response_blocks: with
    // ReusedCholesky, only flesh nodes not seen since the last factorization cost solves).
    // The same operator as apply_inverse_many's. False (out untouched) when the tool keeps no
    // columns (other solvers).
    bool apply_inverse_units(const std::vector<int>& unknowns, const std::vector<int>& rows, MatX& out);
    // apply_inverse_many for the unit right-hand sides e_u (u = units[j], j < k) at `rows` only,
    // into out (rows x k): the tool's unit solves without full-length columns
    // (DeformableSystem::solve_units), then Eq. 12 on the rows. False (out untouched) unless the
    // tool is on the step's Cholesky factor; then it only reads, so calls may run side by side.
    // Before them: what apply_inverse_unit_columns needs besides each unit's own solve. Eq. 12
    // takes the handle's response to a flesh unit e_u from Aht A_t^-1 e_u, that is (At symmetric)
    // row u of A_t^-1 Aht^T: six solves a step at the units' rows, where reading every unit
    // column at the coupled nodes widened each one's backward pass to the handle's nodes and
    // their elimination-tree ancestors (36% of the ~17000-tet hand's factor per column). None
    // when Aht is zero (a prescribed handle). Not thread-safe; apply_inverse_unit_columns throws
    // for a unit not prepared since the last solve() unless Aht is zero.
    void prepare_unit_columns(const std::vector<int>& units);
    bool apply_inverse_unit_columns(const int* units, int k, const std::vector<int>& rows, Eigen::Ref<MatX> out);
    // After solve(), for the handle-space linearization (haptics/coupling_model.cpp): at the
    // flesh unknowns `unknowns` (indices into (v_h, v_t), all >= 6), the tool's response operator
    // applied to the columns of Ath and of aht^T (aht: the true handle-flesh blocks, per coupled
    // node; the step zeroes Aht when the handle is prescribed): out = [A_t^-1 Ath | A_t^-1 aht^T]
    // on those rows (unknowns x 12). With At symmetric, J A_t^-1 Ath and J A_t^-1 aht^T are then
    // what the model reads from a contact's response at the handle nodes. (The Ath half is
    // solve()'s A_t^-1 Ath, except with ReusedCholesky, whose contact responses use the warped
    // factor: there both halves go through it.)
    void handle_columns(const std::vector<int>& unknowns, const std::vector<Mat63>& aht, MatX& out);
    double t_deformable = 0;  // s spent in tool solves during the last solve()
    double t_schur = 0;       // s spent forming and solving the Schur complement

private:
    Vec6 aht_times(const VecX& vt) const;  // Aht * vt, touching only coupled nodes
    // Eq. 12 on asked rows: out(i, j) = v_h(row, j) for handle rows, else the flesh value at the
    // row (flesh_rows(i, j)) minus (A_t^-1 Ath v_h)(row); throws on non-finite values
    void eq12_on_rows(const std::vector<int>& rows, const MatX& flesh_rows, const Eigen::Matrix<double, 6, Eigen::Dynamic>& vh,
                      Eigen::Ref<MatX> out) const;
    MatX rhs_, solved_;                   // the 7 batched right-hand sides and solutions
    MatX response_;                       // A_t^-1 Ath: its 6 columns side by side
    MatX aht_response_;                   // A_t^-1 Aht^T at the prepared units' rows (prepare_unit_columns)
    std::vector<char> aht_prepared_;      // per flesh unknown: its row of aht_response_ is this step's
    bool aht_zero() const;
    // the rows of tool solves of `columns` (3n wide) at the flesh unknowns `unknowns`, through the
    // tool's response operator (only those nodes' rows are asked of it)
    MatX response_at(const MatX& columns, const std::vector<int>& unknowns);
    double schur_condition_ = 0;          // of the last step's Schur complement (0: none yet)

public:
    // After solve(): Aht A_t^-1 Ath, the flesh's part of the Schur complement (Eq. 13).
    Mat6 aht_inverse_ath;
    // After solve(): A_t^-1 Ath (3n x 6), the flesh's velocity response to a handle velocity.
    const MatX& flesh_response() const { return response_; }
};

// The reference: Eq. 7 assembled as one sparse (6 + 3n)^2 matrix and solved by sparse LU.
VecX solve_monolithic(const HandSystem& system, const VecX& rhs);

}  // namespace hh
