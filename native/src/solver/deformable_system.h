// The deformable body's linear system: At is sparse symmetric positive definite (Eq. 7).
// Three solvers:
// - Cholesky: sparse block LDL^T, factored on the first solve after At changes, then reused
//   by all the solves of the step (exact to round-off).
// - ConjugateGradient: Jacobi-preconditioned CG, warm started from the previous solution of
//   the same right-hand-side slot.
// - ReusedCholesky: the block LDL^T factor of an earlier step's At, "warped" by each node's
//   rotation since then, preconditions CG warm started per slot, to the relative residual
//   cg_tolerance (the hand's Schur columns tighter, see set_tolerance_scale). The
//   factor is renewed when a step's solves start to cost more than the average step since the
//   last factorization (so the mean cost per step is close to its minimum), or at once when a
//   solve needs reuse_iteration_limit iterations. Costs are counted in passes over the factor
//   (a factorization is worth factor_flops / (4.8 x stored entries) one-lane passes), not
//   timed, so the policy and the results do not depend on the machine's load.
//   The factor is kept in supernodal form (dense panels) with single- and half-precision
//   copies for the preconditioner passes (direct solves use the double panels); CG runs on node-major blocks of up to 8 columns (flexible beta), warm
//   started by the Galerkin combination of each slot's last two solutions.
//   Meant for large meshes, where a factorization costs many times a solve.
#pragma once
#include <functional>
#include <memory>
#include <vector>

#include "common/beside.h"
#include "solver/linear_system.h"
#include "solver/panels.h"

namespace hh {

enum class DeformableSolver { Cholesky, ConjugateGradient, ReusedCholesky };

// How a DeformableSystem keeps its factor. The defaults are the forms measured fastest; the
// others are there for benchmarks and tests to compare against (C++ only: no user setting).
struct FactorForms {
    // ReusedCholesky: the copy its preconditioner passes read (Half where the CPU converts
    // halves, else Single; the direct solves always read the double panels)
    Panels preconditioner = Panels::Half;
    bool reused_supernodal = true;  // ReusedCholesky: the supernodal form (false: up-looking)
    // Cholesky: the up-looking block LDL^T below kSupernodalFlops a factorization, the
    // supernodal form above (Auto), or one of them always
    enum class PerStep { Auto, UpLooking, Supernodal } per_step = PerStep::Auto;
};


class DeformableSystem : public LinearSystem {
public:
    DeformableSystem();
    ~DeformableSystem() override;
    SpMat A;  // both triangles stored
    // Marks the start of a new step: At has new values.
    void matrix_changed();
    // Keeps the reused factor when nothing changes (it is called before every step).
    void configure(DeformableSolver solver, double cg_tolerance, int cg_max_iterations);
    DeformableSolver solver() const;
    // The factor's forms (FactorForms); setting them drops any factor made so far.
    void set_factor_forms(const FactorForms& forms);
    const FactorForms& factor_forms() const;
    // Warm-start slot for CG: the Schur solve uses slots 0-6 (b_t and the 6 columns of Ath).
    void select_slot(int slot);
    // ReusedCholesky: the tolerance of a slot's solves is cg_tolerance * scale
    // (default scale 1). The hand asks 1e-3 for the columns A_t^-1 Ath that form the Schur
    // complement, whose conditioning amplifies their error.
    void set_tolerance_scale(int slot, double scale);
    // ReusedCholesky and ConjugateGradient, the next solve_many only: the slot's relative
    // residual is measured against max(|b|, norm) instead of |b|. For a right-hand side that is
    // a load nearly cancelled by another: the hand's free solve takes b_t plus the last step's
    // contact impulses, which at rest balance it to a few percent (World::solve_free); measured
    // against that remainder, its solve would be asked ~30x more absolute accuracy than the
    // step's own b_t (the pressed 17006-tet hand: 13.3 CG lane-iterations a step, 11.9 with it).
    void set_reference_norm(int slot, double norm);
    void solve() override;
    // X = A^-1 B, column j of B in warm-start slot first_slot + j: one factorization and
    // batched passes over it serve all the columns.
    // wanted_nodes (Cholesky only; ignored by the other solvers): only the rows of these nodes
    // of X are asked for, the others are left unspecified (BlockLDLT::solve).
    void solve_many(const MatX& b, MatX& x, int first_slot, const std::vector<int>* wanted_nodes = nullptr);
    // The same, ReusedCholesky: columns [0, split) and [split, k) as two groups of CG lanes
    // that `beside` may solve side by side (they share only the factor, which both read); a
    // lane at reuse_iteration_limit stops its group, and once both are done the factor is
    // renewed and every column solved on it. The hand's b_t needs 5-12 iterations a step on
    // the ~17000-tet hand, its Schur columns 1-3 from their warm starts: solved together, the
    // columns' 8-lane passes held up b_t's one-lane ones. The result does not depend on whether
    // the groups ran side by side. Other solvers: solve_many.
    // after_second: a job for the second group's thread once that group is done (the hand's
    // carried impulses' pass, HandSystem::solve). A step that renews the factor gives `beside`
    // its rest's shares of updates too (BlockLDLT::factorize).
    void solve_many_split(const MatX& b, MatX& x, int first_slot, int split, const Beside& beside,
                          const std::function<void()>& after_second = nullptr);
    // Cholesky: factors the step's matrix now if that is not done yet; after it, solve_many
    // only reads the factor, so calls on different right-hand sides may run on two threads at
    // once (a soft body's contact responses, World::step). Returns whether that holds (false
    // for the iterative solvers, whose warm-start slots each call writes).
    bool prepare_concurrent_solves();
    // Cholesky solvers: the symbolic analysis of A's pattern now (once A holds it), instead of in
    // the first step's solve, where a loop sees it as a dropped frame (the grasping hand's first
    // step: ~15 ms of its ~21). The same analysis either way. Nothing for CG.
    void analyse_ahead();
    // Cholesky with the supernodal factor: the factorization's parts that may run on two threads
    // at once (BlockLDLT::factor_parts: 2 for large factors, else 0; 0 for CG; analyses the
    // pattern if that is not done yet). ReusedCholesky: the same for a step that renews its
    // factor (the first, or one the policy renews), else 0; call it before the step's
    // matrix_changed (or after: the answer is the same). Once At holds the step's values and before
    // its first solve, factorize_part(0) and (1) may run side by side; the first solve (or
    // prepare_concurrent_solves) does the rest. Same factor, bit for bit.
    int factor_parts();
    void factorize_part(int part);
    // Cholesky (false otherwise, and out untouched): columns of A^-1 for unit right-hand sides
    // at the given rows only, out[r + j ld] = (A^-1)(rows[r], units[j]) (BlockLDLT::solve_units):
    // the contact responses of solve_many's unit columns without their full length. Only reads
    // the factor (after prepare_concurrent_solves), so calls may run side by side.
    bool solve_units(const int* units, int k, const std::vector<int>& rows, double* out, long ld);
    // Cholesky, after prepare_concurrent_solves (else -1): the step of the factor's elimination
    // at which the node goes. Unit solves batched in that order share their paths to the root.
    int elimination_position(int node) const;
    // X = the step's response operator applied to B, for the contact responses (the Delassus
    // operator and the impulses' velocities): with Cholesky and CG the solve above (slots 8 and
    // up); with ReusedCholesky the warped factor itself, W Af^-1 W^T, one pass and no CG. That
    // operator is symmetric positive definite, close to At^-1 and the same for every response
    // of the step, so the impulses the contact solve finds with it are exactly those the
    // velocities then receive (the constraints hold); only the flesh's response to them departs
    // from Eq. 7's by the factor's lag. A CG solve per response would cost tens of passes.
    void solve_response(const MatX& b, MatX& x, const std::vector<int>* wanted_nodes = nullptr);
    // solve_response for one column, with ReusedCholesky through the factor's single-precision
    // copy when it keeps one (half the memory traffic of a full pass; the operator to within
    // float round-off of solve_response's). For what need not be the very same operator: the
    // hand's carried impulses (World::solve_free).
    void solve_response_single(const VecX& b, VecX& x);
    // solve_response for one column, with ReusedCholesky the factor's two parts as two jobs for
    // `beside` (BlockLDLT::solve_node_major_split: the same operator to round-off, and the same
    // result whether the jobs run side by side or not).
    void solve_response_split(const VecX& b, VecX& x, const Beside& beside);
    // ReusedCholesky only (false otherwise, outputs untouched): the response operator's columns
    // of the nodes `columns` at the nodes `columns` and `rows`, as unwarped 3x3 blocks. The
    // operator is W Af^-1 W^T with Af fixed until the next factorization, so these blocks of
    // Af^-1 are kept from step to step and only columns not seen since then cost solves: at the
    // kept rows only (unit solves, BlockLDLT::solve_units), the fresh nodes' rows at the kept
    // columns by symmetry. (A row-only node never asked before costs every kept column again:
    // meant for rows that stay, like the handle's coupled nodes.) Af^-1's block (i, k) is at
    // data + 3 column_slot[k] ld + 3 row_slot[i] (3x3, column-major, leading dimension ld;
    // valid until the next call); warp: W (null: the identity). Then column d of node k's
    // response at node i is W_i (Af^-1)_{ik} W_k^T e_d.
    // beside (World::step's hand, HandSystem::beside): the fresh columns' unit solves in two
    // shares, every other batch, that may run side by side (after a factorization, every
    // touched node's: ~20-35 ms of one thread on the ~17000-tet hand); same blocks either way.
    bool response_blocks(const std::vector<int>& columns, const std::vector<int>& rows, const double*& data, long& ld,
                         const std::vector<int>*& row_slot, const std::vector<int>*& column_slot,
                         const std::vector<Mat3>*& warp, const Beside& beside = nullptr);
    // ReusedCholesky only (false otherwise, out untouched): out(r, j) = the response operator's
    // entry at (unknowns[r], unknowns[j]) (scalar unknowns), from the kept blocks above: a soft
    // body's contact responses on the unknowns its contacts touch (World::ready_contact_body),
    // which then cost unit solves only for nodes not seen since the last factorization, where
    // on the per-step factor every one of them is solved every step. beside: as above.
    bool response_units(const std::vector<int>& unknowns, MatX& out, const Beside& beside = nullptr);
    // ReusedCholesky with a factor: how many of these unknowns' response columns response_units
    // would solve afresh (every unknown of a node whose blocks are not kept since the last
    // factorization). -1 on the other solvers, which keep none.
    int fresh_response_unknowns(const std::vector<int>& unknowns) const;
    // ReusedCholesky with a factor: out[i] = (W Af^-1 W^T f)[unknowns[i]], the response operator
    // applied to f (3n, nonzero at few nodes) at the given unknowns only, from the blocks kept
    // between f's nodes and theirs (solving those not kept yet, as response_units). False on the
    // other solvers, before the first factorization, or past the blocks' budget.
    bool response_at(const std::vector<int>& unknowns, const VecX& f, VecX& out, const Beside& beside = nullptr);
    // Element rotations of the step (the co-rotation), for ReusedCholesky's warp: each node's
    // rotation (the rotation of the sum of its elements' rotations) relative to its rotation
    // when the factor was made. Ignored by the other solvers.
    void set_element_rotations(const std::vector<Eigen::Vector4i>& tets, const std::vector<Mat3>& rotations);

    int iterations = 0;         // CG iterations summed since reset_counters()
    double max_residual = 0;    // largest CG relative residual since reset_counters()
    int factorizations = 0;     // numeric factorizations since reset_counters()
    void reset_counters() { iterations = 0; max_residual = 0; factorizations = 0; }
    // Iterations of one ReusedCholesky solve after which the factor is renewed on the spot.
    int reuse_iteration_limit = 25;

private:
    void solve_response_column(const VecX& b, VecX& x, bool single, const Beside& beside);
    struct Impl;
    std::unique_ptr<Impl> impl_;
    bool factor_valid_ = false;
    int slot_ = 0;
};

}  // namespace hh
