#include "contact/pgs.h"

#include <algorithm>
#include <cmath>

namespace hh {

PgsResult solve_pgs(const ContactProblem& p, VecX& lambda, int max_iterations, double tolerance) {
    const int c = static_cast<int>(p.gap.size());
    lambda = VecX::Zero(3 * c);
    VecX u = p.u_free;
    PgsResult result;
    // target normal velocity: close the gap exactly within the step, never faster
    VecX bias(c);
    for (int i = 0; i < c; ++i) bias[i] = p.gap[i] / p.dt;
    auto apply = [&](int col, double delta) {
        if (delta != 0) u.noalias() += p.W.col(col) * delta;
        lambda[col] += delta;
    };
    for (int it = 0; it < max_iterations; ++it) {
        double change = 0, scale = 1e-300;
        for (int i = 0; i < c; ++i) {
            const int n = 3 * i;
            const double wnn = p.W(n, n);
            if (wnn <= 0) continue;  // both sides immovable
            const double ln = std::max(0.0, lambda[n] - (u[n] + bias[i]) / wnn);
            const double dn = ln - lambda[n];
            apply(n, dn);
            // friction: a step against the sliding velocity, projected onto the disk of radius
            // mu lambda_n. The step is isotropic (1 / largest eigenvalue of the 2x2 block): its
            // fixed points have the impulse exactly opposite the sliding velocity, as Coulomb's
            // maximal dissipation requires; a full 2x2 solve followed by a radial projection
            // would tilt the friction whenever the block is anisotropic (rigid bodies).
            const Eigen::Matrix2d wtt = p.W.block<2, 2>(n + 1, n + 1);
            const double wmax = 0.5 * (wtt.trace() + std::sqrt(std::pow(wtt(0, 0) - wtt(1, 1), 2) + 4 * wtt(0, 1) * wtt(1, 0)));
            if (!(wmax > 0)) continue;
            const Eigen::Vector2d ut(u[n + 1], u[n + 2]);
            const Eigen::Vector2d lt(lambda[n + 1], lambda[n + 2]);
            Eigen::Vector2d target = lt - ut / wmax;
            const double limit = p.friction[i] * lambda[n];
            const double norm = target.norm();
            if (norm > limit) target *= limit / norm;
            const Eigen::Vector2d dt = target - lt;
            apply(n + 1, dt[0]);
            apply(n + 2, dt[1]);
            change = std::max({change, std::abs(dn), dt.cwiseAbs().maxCoeff()});
            scale = std::max(scale, std::abs(lambda[n]));
        }
        result.iterations = it + 1;
        if (change <= tolerance * scale) break;
    }
    for (int i = 0; i < c; ++i) {
        const int n = 3 * i;
        // normal velocity below the target, or a pulling impulse left after the sweep
        const double normal_violation = std::max(0.0, -(u[n] + bias[i]));
        result.residual = std::max(result.residual, normal_violation);
    }
    return result;
}

}  // namespace hh
