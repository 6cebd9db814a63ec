// The deformable body's linear system: At is sparse symmetric positive definite (Eq. 7).
// Two solvers: sparse block LDL^T, "cholesky" (factored on the first solve after At
// changes, then reused by all the solves of the step) and Jacobi-preconditioned conjugate gradient, warm started
// from the previous solution of the same right-hand-side slot.
#pragma once
#include <memory>
#include <vector>

#include "solver/linear_system.h"

namespace hh {

enum class DeformableSolver { Cholesky, ConjugateGradient };

class DeformableSystem : public LinearSystem {
public:
    DeformableSystem();
    ~DeformableSystem() override;
    SpMat A;  // both triangles stored
    void matrix_changed() { factor_valid_ = false; }
    void configure(DeformableSolver solver, double cg_tolerance, int cg_max_iterations);
    // Warm-start slot for CG: the Schur solve uses 8 slots (b_t, 6 columns, final).
    void select_slot(int slot);
    void solve() override;

    int iterations = 0;         // CG iterations summed since reset_counters()
    double max_residual = 0;    // largest CG relative residual since reset_counters()
    void reset_counters() { iterations = 0; max_residual = 0; }

private:
    struct Impl;
    std::unique_ptr<Impl> impl_;
    bool factor_valid_ = false;
    int slot_ = 0;
};

}  // namespace hh
