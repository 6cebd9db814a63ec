#include "solver/deformable_system.h"

#include <Eigen/IterativeLinearSolvers>

#include "solver/block_ldlt.h"

namespace hh {

struct DeformableSystem::Impl {
    DeformableSolver solver = DeformableSolver::Cholesky;
    double cg_tolerance = 1e-10;
    int cg_max_iterations = 2000;
    // The pattern of At never changes, so the symbolic analysis (AMD ordering, elimination
    // tree) is done once and only the numeric factorization is repeated each step.
    BlockLDLT cholesky;
    Eigen::ConjugateGradient<SpMat, Eigen::Lower | Eigen::Upper, Eigen::DiagonalPreconditioner<double>> cg;
    std::vector<VecX> warm;
};

DeformableSystem::DeformableSystem() : impl_(new Impl) {}
DeformableSystem::~DeformableSystem() = default;

void DeformableSystem::configure(DeformableSolver solver, double cg_tolerance, int cg_max_iterations) {
    impl_->solver = solver;
    impl_->cg_tolerance = cg_tolerance;
    impl_->cg_max_iterations = cg_max_iterations;
    factor_valid_ = false;
}

void DeformableSystem::select_slot(int slot) { slot_ = slot; }

void DeformableSystem::solve() {
    Impl& m = *impl_;
    if (m.solver == DeformableSolver::Cholesky) {
        if (!factor_valid_) {
            if (!m.cholesky.analysed()) m.cholesky.analyze(A);
            m.cholesky.factorize(A);
            factor_valid_ = true;
        }
        s = m.cholesky.solve(r);
    } else {
        if (!factor_valid_) {
            m.cg.setTolerance(m.cg_tolerance);
            m.cg.setMaxIterations(m.cg_max_iterations);
            m.cg.compute(A);
            factor_valid_ = true;
        }
        if (static_cast<int>(m.warm.size()) <= slot_) m.warm.resize(slot_ + 1);
        VecX& guess = m.warm[slot_];
        if (guess.size() != r.size()) guess = VecX::Zero(r.size());
        s = m.cg.solveWithGuess(r, guess);
        guess = s;
        iterations += static_cast<int>(m.cg.iterations());
    }
    if (!s.allFinite())
        throw NumericalError("the deformable solve produced non-finite values: reduce the time step");
    if (m.solver == DeformableSolver::ConjugateGradient) {
        // Eigen's relative residual estimate; Cholesky is exact to round-off so it costs no check
        const double res = m.cg.error();
        if (res > max_residual) max_residual = res;
    }
}

}  // namespace hh
