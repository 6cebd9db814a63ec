#include "contact/pgs.h"

#include <algorithm>
#include <cmath>

namespace hh {

namespace {
// argmin over |x| <= radius of 1/2 x^T W x - c^T x, W symmetric positive definite 2x2:
// inside, x = W^-1 c; else x = (W + nu I)^-1 c with nu >= 0 such that |x| = radius (the norm
// decreases monotonically in nu; Newton's method from nu = 0 converges from the left).
Eigen::Vector2d disk_constrained_minimum(const Eigen::Matrix2d& w, const Eigen::Vector2d& c, double radius) {
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> eig(w);
    const Eigen::Vector2d a = eig.eigenvalues().cwiseMax(1e-300);
    const Eigen::Vector2d d = eig.eigenvectors().transpose() * c;
    auto point = [&](double nu) { return Eigen::Vector2d(d[0] / (a[0] + nu), d[1] / (a[1] + nu)); };
    if (point(0).norm() <= radius) return eig.eigenvectors() * point(0);
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
    return eig.eigenvectors() * point(nu);
}
}  // namespace

PgsResult solve_pgs(const ContactProblem& p, VecX& lambda, int max_iterations, double tolerance) {
    const int c = static_cast<int>(p.gap.size());
    if (lambda.size() != 3 * c) lambda = VecX::Zero(3 * c);  // else: a warm start
    for (int i = 0; i < c; ++i) lambda[3 * i] = std::max(0.0, lambda[3 * i]);
    VecX u = p.u_free + p.W * lambda;
    PgsResult result;
    // target normal velocity: close an open gap exactly within the step, never faster; push
    // out of a penetration at a bounded speed, so a deep one is resolved over a few steps
    // instead of by one violent impulse that would feed energy into the scene
    VecX bias(c);
    for (int i = 0; i < c; ++i) bias[i] = std::max(p.gap[i] / p.dt, -p.recovery_speed);
    auto apply = [&](int col, double delta) {
        if (delta != 0) u.noalias() += p.W.col(col) * delta;
        lambda[col] += delta;
    };
    // Friction coefficient each contact's disk uses: static first; contacts still sliding once
    // the static problem is solved break loose and are solved again against kinetic friction.
    // (Deciding per contact inside the sweep would let the first contact of a resting block
    // give way before its neighbours had taken their share.)
    VecX coefficient = p.friction;
    // How far the current impulses are from satisfying every condition, in m/s: normal
    // complementarity, sticking contacts at rest, sliding ones sliding against their friction.
    auto residual = [&]() {
        double worst = 0;
        for (int i = 0; i < c; ++i) {
            const int n = 3 * i;
            const double un = u[n] + bias[i];
            worst = std::max(worst, lambda[n] > 0 ? std::abs(un) : std::max(0.0, -un));
            const Eigen::Vector2d ut(u[n + 1], u[n + 2]), lt(lambda[n + 1], lambda[n + 2]);
            const double limit = coefficient[i] * lambda[n];
            if (lt.norm() < limit * (1 - 1e-9) || lt.norm() == 0)
                worst = std::max(worst, ut.norm());  // sticking: no sliding allowed
            else
                worst = std::max(worst, (ut + (ut.norm() / lt.norm()) * lt).norm());  // anti-parallel
        }
        return worst;
    };
    for (int it = 0, pass = 0; it < max_iterations; ++it) {
        for (int i = 0; i < c; ++i) {
            const int n = 3 * i;
            const double wnn = p.W(n, n);
            if (wnn <= 0) continue;  // both sides immovable
            const double ln = std::max(0.0, lambda[n] - (u[n] + bias[i]) / wnn);
            apply(n, ln - lambda[n]);
            // friction: the exact solution of this contact's 2x2 subproblem (impulse inside
            // the disk of radius mu lambda_n minimizing the block's kinetic energy), whose
            // optimality conditions are Coulomb's: sticking inside the disk, or on its rim
            // exactly opposite the post-step sliding velocity (maximal dissipation).
            const Eigen::Matrix2d wtt = 0.5 * (p.W.block<2, 2>(n + 1, n + 1) + p.W.block<2, 2>(n + 1, n + 1).transpose());
            if (!(wtt.trace() > 0)) continue;
            const Eigen::Vector2d ut(u[n + 1], u[n + 2]);
            const Eigen::Vector2d lt(lambda[n + 1], lambda[n + 2]);
            const Eigen::Vector2d target = disk_constrained_minimum(wtt, wtt * lt - ut, coefficient[i] * lambda[n]);
            apply(n + 1, target[0] - lt[0]);
            apply(n + 2, target[1] - lt[1]);
        }
        result.iterations = it + 1;
        result.residual = residual();
        if (result.residual > tolerance && it + 1 < max_iterations) continue;
        if (pass++ > 0) break;
        bool broke_loose = false;
        for (int i = 0; i < c; ++i) {
            const Eigen::Vector2d ut(u[3 * i + 1], u[3 * i + 2]);
            // sliding clearly faster than the solver's tolerance (not a sticking contact
            // still converging) while at the static limit: it breaks loose
            const Eigen::Vector2d lt(lambda[3 * i + 1], lambda[3 * i + 2]);
            if (p.kinetic[i] < coefficient[i] && ut.norm() > 10 * tolerance &&
                lt.norm() >= coefficient[i] * lambda[3 * i] * (1 - 1e-9)) {
                coefficient[i] = p.kinetic[i];
                broke_loose = true;
            }
        }
        if (!broke_loose) break;
    }
    return result;
}

}  // namespace hh
