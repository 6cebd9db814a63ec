#include "solver/deformable_system.h"

#include <Eigen/IterativeLinearSolvers>
#include <algorithm>
#include <chrono>
#include <cmath>

#include "fem/corotational.h"
#include "rigid/quaternion.h"
#include "solver/block_ldlt.h"

namespace hh {

namespace {
double seconds_since(std::chrono::steady_clock::time_point t0) {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

// Width of a node-major block of k right-hand sides (the kernels take 1, 4 or 8).
int padded_width(int k) { return k == 1 ? 1 : (k <= 4 ? 4 : 8); }

// Y = A X on node-major storage (node i's 3 x w values at 3 w i): A is symmetric, so column
// 3c + k of its compressed-column storage is row 3c + k, a dot product with X's rows.
template <int W>
void multiply_node_major(const SpMat& a, const double* x, double* y) {
    const int* outer = a.outerIndexPtr();
    const int* inner = a.innerIndexPtr();
    const double* values = a.valuePtr();
    for (Eigen::Index c = 0; c < a.outerSize(); ++c) {
        double acc[W] = {};
        for (int p = outer[c]; p < outer[c + 1]; ++p) {
            const double v = values[p];
            const double* xr = x + static_cast<size_t>(W) * inner[p];
            for (int j = 0; j < W; ++j) acc[j] += v * xr[j];
        }
        std::copy(acc, acc + W, y + static_cast<size_t>(W) * c);
    }
}
void multiply_node_major(const SpMat& a, const double* x, double* y, int w) {
    if (w == 1) multiply_node_major<1>(a, x, y);
    else if (w == 4) multiply_node_major<4>(a, x, y);
    else multiply_node_major<8>(a, x, y);
}
}  // namespace

struct DeformableSystem::Impl {
    DeformableSolver solver = DeformableSolver::Cholesky;
    double cg_tolerance = 1e-10;
    int cg_max_iterations = 2000;
    // The pattern of At never changes, so the symbolic analysis (AMD ordering, elimination
    // tree) is done once and only the numeric factorization is repeated.
    BlockLDLT cholesky;
    Eigen::ConjugateGradient<SpMat, Eigen::Lower | Eigen::Upper, Eigen::DiagonalPreconditioner<double>> cg;
    std::vector<VecX> warm;

    // ReusedCholesky
    bool have_factor = false;        // cholesky holds the factor of some earlier At
    bool factor_current = false;     // ... of this step's At
    std::vector<Vec4> node_q;        // nodes' rotations this step (warm starts of the polar decomposition)
    std::vector<Mat3> node_r, node_r_factor, warp;  // this step's, at the factorization, and R R_factor^T
    bool have_rotations = false;
    // cost bookkeeping of the refactorization policy (seconds)
    double factor_seconds = 0;       // the last factorization
    double epoch_seconds = 0;        // solves since the last factorization, its own step included
    int epoch_steps = 0;             // steps since the last factorization, its own included
    double step_seconds = 0;         // solves of the current step
    bool renew = false;              // refactor at the start of the next step
    double factored_in_call = 0;     // factorization time inside the current solve_many
    // PCG workspaces (node-major blocks)
    std::vector<double> nb, nx, nr, nz, np, nq;

    void factor(DeformableSystem& sys) {
        const auto t0 = std::chrono::steady_clock::now();
        if (!cholesky.analysed()) cholesky.analyze(sys.A);
        cholesky.factorize(sys.A);
        factor_seconds = seconds_since(t0);
        ++sys.factorizations;
        have_factor = factor_current = true;
        factored_in_call += factor_seconds;
        if (have_rotations) node_r_factor = node_r;
        else node_r_factor.clear();  // no warp until the next factorization
        epoch_seconds = 0;
        epoch_steps = 1;
        renew = false;
    }
    const std::vector<Mat3>* current_warp() {
        if (!have_rotations || node_r_factor.size() != node_r.size()) return nullptr;
        warp.resize(node_r.size());
        for (size_t i = 0; i < node_r.size(); ++i) warp[i] = node_r[i] * node_r_factor[i].transpose();
        return &warp;
    }
    void pcg(DeformableSystem& sys, const MatX& b, MatX& x, int first_slot);
};

DeformableSystem::DeformableSystem() : impl_(new Impl) {}
DeformableSystem::~DeformableSystem() = default;

void DeformableSystem::configure(DeformableSolver solver, double cg_tolerance, int cg_max_iterations) {
    Impl& m = *impl_;
    if (solver == m.solver && cg_tolerance == m.cg_tolerance && cg_max_iterations == m.cg_max_iterations) return;
    m.solver = solver;
    m.cg_tolerance = cg_tolerance;
    m.cg_max_iterations = cg_max_iterations;
    m.have_factor = m.factor_current = false;
    factor_valid_ = false;
}

DeformableSolver DeformableSystem::solver() const { return impl_->solver; }

void DeformableSystem::matrix_changed() {
    Impl& m = *impl_;
    factor_valid_ = false;
    m.factor_current = false;
    m.have_rotations = false;
    if (m.solver != DeformableSolver::ReusedCholesky || !m.have_factor) return;
    // Close the bookkeeping of the step that ended: the mean cost per step since the last
    // factorization, (factorization + solves) / steps, decreases while a step costs less than
    // that mean; once a step costs more, renewing the factor lowers the mean again.
    if (m.step_seconds > 0) {
        const double mean = (m.factor_seconds + m.epoch_seconds) / m.epoch_steps;
        if (m.step_seconds > mean && m.epoch_steps > 1) m.renew = true;
        ++m.epoch_steps;
    }
    m.step_seconds = 0;
}

void DeformableSystem::set_element_rotations(const std::vector<Eigen::Vector4i>& tets, const std::vector<Mat3>& rotations) {
    Impl& m = *impl_;
    if (m.solver != DeformableSolver::ReusedCholesky) return;
    const int n = static_cast<int>(A.rows() / 3);
    std::vector<Mat3> sum(n, Mat3::Zero());
    for (size_t e = 0; e < tets.size() && e < rotations.size(); ++e)
        for (int a = 0; a < 4; ++a) sum[tets[e][a]] += rotations[e];
    if (static_cast<int>(m.node_q.size()) != n) m.node_q.assign(n, quat_identity());
    m.node_r.resize(n);
    for (int i = 0; i < n; ++i) m.node_r[i] = polar_rotation(sum[i], m.node_q[i]);
    m.have_rotations = true;
}

void DeformableSystem::select_slot(int slot) { slot_ = slot; }

void DeformableSystem::solve() {
    MatX b = r, x;
    solve_many(b, x, slot_);
    s = x.col(0);
}

void DeformableSystem::solve_many(const MatX& b, MatX& x, int first_slot) {
    Impl& m = *impl_;
    if (m.solver == DeformableSolver::Cholesky) {
        if (!factor_valid_) {
            if (!m.cholesky.analysed()) m.cholesky.analyze(A);
            m.cholesky.factorize(A);
            ++factorizations;
            factor_valid_ = true;
        }
        x = b;
        m.cholesky.solve(x);
    } else if (m.solver == DeformableSolver::ConjugateGradient) {
        if (!factor_valid_) {
            m.cg.setTolerance(m.cg_tolerance);
            m.cg.setMaxIterations(m.cg_max_iterations);
            m.cg.compute(A);
            factor_valid_ = true;
        }
        x.resize(b.rows(), b.cols());
        for (Eigen::Index j = 0; j < b.cols(); ++j) {
            const int slot = first_slot + static_cast<int>(j);
            if (static_cast<int>(m.warm.size()) <= slot) m.warm.resize(slot + 1);
            VecX& guess = m.warm[slot];
            if (guess.size() != b.rows()) guess = VecX::Zero(b.rows());
            x.col(j) = m.cg.solveWithGuess(b.col(j), guess);
            guess = x.col(j);
            iterations += static_cast<int>(m.cg.iterations());
            // Eigen's relative residual estimate; Cholesky is exact to round-off so it costs no check
            max_residual = std::max(max_residual, m.cg.error());
        }
    } else {
        const auto t0 = std::chrono::steady_clock::now();
        m.factored_in_call = 0;
        m.pcg(*this, b, x, first_slot);
        const double spent = seconds_since(t0) - m.factored_in_call;
        m.step_seconds += spent;
        m.epoch_seconds += spent;
    }
    if (!x.allFinite())
        throw NumericalError("the deformable solve produced non-finite values: reduce the time step");
}

// Conjugate gradient on every column of b at once, preconditioned by the (warped) reused
// factor: each iteration is one batched pass over the factor and one over At.
void DeformableSystem::Impl::pcg(DeformableSystem& sys, const MatX& b, MatX& x, int first_slot) {
    const int n3 = static_cast<int>(sys.A.rows());
    const int k = static_cast<int>(b.cols());
    if (!have_factor || renew) factor(sys);
    const double tol = std::min(cg_tolerance, 1e-10);
    x.resize(n3, k);
    if (factor_current) {  // the factor is this step's: a direct solve
        x = b;
        cholesky.solve(x, nullptr);
        return;
    }
    const std::vector<Mat3>* w = current_warp();
    // per column: warm start, norms, state
    std::vector<double> bnorm(k), rz(k);
    std::vector<int> active, its(k, 0);
    for (int j = 0; j < k; ++j) {
        const int slot = first_slot + j;
        if (static_cast<int>(warm.size()) <= slot) warm.resize(slot + 1);
        if (warm[slot].size() != n3) warm[slot] = VecX::Zero(n3);
        x.col(j) = warm[slot];
        bnorm[j] = b.col(j).norm();
        if (bnorm[j] == 0) x.col(j).setZero();
        else active.push_back(j);
    }
    MatX r(n3, k), p(n3, k);
    // pack / unpack the active columns into node-major blocks of width wd
    auto pack = [&](const MatX& from, std::vector<double>& to, int wd) {
        to.assign(static_cast<size_t>(n3) * wd, 0.0);
        for (size_t a = 0; a < active.size(); ++a)
            for (int e = 0; e < n3; ++e) to[static_cast<size_t>(wd) * e + a] = from(e, active[a]);
    };
    auto unpack = [&](const std::vector<double>& from, MatX& to, int wd) {
        for (size_t a = 0; a < active.size(); ++a)
            for (int e = 0; e < n3; ++e) to(e, active[a]) = from[static_cast<size_t>(wd) * e + a];
    };
    MatX z(n3, k), q(n3, k);
    // r = b - A x
    auto residual_of_active = [&]() {
        const int wd = padded_width(static_cast<int>(active.size()));
        pack(x, nx, wd);
        nq.resize(nx.size());
        multiply_node_major(sys.A, nx.data(), nq.data(), wd);
        unpack(nq, q, wd);
        for (int j : active) r.col(j) = b.col(j) - q.col(j);
    };
    auto precondition_active = [&]() {  // z = M^-1 r
        const int wd = padded_width(static_cast<int>(active.size()));
        pack(r, nz, wd);
        cholesky.solve_node_major(nz.data(), wd, w);
        unpack(nz, z, wd);
    };
    auto drop_converged = [&]() {
        std::vector<int> still;
        for (int j : active) {
            const double rel = r.col(j).norm() / bnorm[j];
            if (rel > tol) still.push_back(j);
            else sys.max_residual = std::max(sys.max_residual, rel);
        }
        active.swap(still);
    };
    if (active.empty()) return;
    residual_of_active();
    drop_converged();
    bool restarted = false;
    while (!active.empty()) {
        precondition_active();
        for (int j : active) {
            rz[j] = r.col(j).dot(z.col(j));
            p.col(j) = z.col(j);
        }
        bool need_restart = false;
        while (!active.empty()) {
            const int wd = padded_width(static_cast<int>(active.size()));
            pack(p, np, wd);
            nq.resize(np.size());
            multiply_node_major(sys.A, np.data(), nq.data(), wd);
            unpack(nq, q, wd);
            for (int j : active) {
                const double alpha = rz[j] / p.col(j).dot(q.col(j));
                x.col(j) += alpha * p.col(j);
                r.col(j) -= alpha * q.col(j);
                ++its[j];
                ++sys.iterations;
            }
            drop_converged();
            if (active.empty()) break;
            int worst = 0;
            for (int j : active) worst = std::max(worst, its[j]);
            if (worst >= sys.reuse_iteration_limit && !restarted) {  // the factor is too stale: renew it now
                need_restart = true;
                break;
            }
            if (worst >= std::max(cg_max_iterations, sys.reuse_iteration_limit + 5)) {
                for (int j : active) sys.max_residual = std::max(sys.max_residual, r.col(j).norm() / bnorm[j]);
                active.clear();
                break;
            }
            precondition_active();
            for (int j : active) {
                const double rz_new = r.col(j).dot(z.col(j));
                p.col(j) = z.col(j) + (rz_new / rz[j]) * p.col(j);
                rz[j] = rz_new;
            }
        }
        if (!need_restart) break;
        // renew the factor with this step's At and restart CG from the current iterates: with
        // the exact factor one more iteration reaches round-off
        factor(sys);
        w = nullptr;
        restarted = true;
        residual_of_active();
        drop_converged();
    }
    for (int j = 0; j < k; ++j) warm[first_slot + j] = x.col(j);
}

}  // namespace hh
