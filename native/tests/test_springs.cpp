// The spring force and torque Jacobians (Eq. 11 with Appendix A) against central finite
// differences of the forces of Eqs. 4-5, for every argument.
#include <functional>
#include <random>

#include "check.h"
#include "coupling/springs.h"
#include "rigid/quaternion.h"

using namespace hh;

namespace {
struct Args {
    Vec3 xa, va, rb;
    HandleState h;
};
// (F_A, F_B, T_B) stacked as 9 numbers
Eigen::Matrix<double, 9, 1> forces(double k, double d, const Args& a) {
    const SpringForce f = spring_force(k, d, a.xa, a.va, a.rb, a.h);
    Eigen::Matrix<double, 9, 1> out;
    out << f.on_node, f.on_handle, f.torque;
    return out;
}
// Central differences of forces() with respect to 3 scalar parameters applied by `perturb`.
Eigen::Matrix<double, 9, 3> numeric(double k, double d, const Args& a,
                                    const std::function<void(Args&, int, double)>& perturb) {
    Eigen::Matrix<double, 9, 3> j;
    const double h = 1e-6;
    for (int c = 0; c < 3; ++c) {
        Args p = a, m = a;
        perturb(p, c, h);
        perturb(m, c, -h);
        j.col(c) = (forces(k, d, p) - forces(k, d, m)) / (2 * h);
    }
    return j;
}
double relative_error(const Eigen::Matrix<double, 9, 3>& analytic, const Eigen::Matrix<double, 9, 3>& num) {
    return (analytic - num).norm() / std::max(num.norm(), 1e-300);
}
}  // namespace

TEST(spring_jacobians_match_finite_differences) {
    std::mt19937 rng(7);
    std::uniform_real_distribution<double> u(-1, 1);
    auto rv = [&](double s) { return Vec3(s * u(rng), s * u(rng), s * u(rng)); };
    const double k = 1e4, d = 30;
    for (int trial = 0; trial < 10; ++trial) {
        Args a;
        a.rb = rv(0.04);
        a.h.x_com = rv(0.1);
        a.h.q = Vec4(u(rng), u(rng), u(rng), u(rng)).normalized();
        a.h.v_com = rv(0.5);
        a.h.omega = rv(3.0);
        a.xa = a.h.x_com + quat_to_matrix(a.h.q) * a.rb + rv(0.01);  // stretched spring
        a.va = rv(0.5);
        const SpringJacobian j = spring_jacobian(k, d, a.xa, a.va, a.rb, a.h);
        auto stack = [](const Mat3& node, const Eigen::Matrix<double, 6, 3>& handle) {
            Eigen::Matrix<double, 9, 3> s;
            s << node, handle;
            return s;
        };
        CHECK_LT(relative_error(stack(j.dfa_dxa, j.dfh_dxa), numeric(k, d, a, [](Args& p, int c, double h) { p.xa[c] += h; })), 1e-6);
        CHECK_LT(relative_error(stack(j.dfa_dva, j.dfh_dva), numeric(k, d, a, [](Args& p, int c, double h) { p.va[c] += h; })), 1e-6);
        Eigen::Matrix<double, 6, 3> hx, ht, hv, hw;
        hx << j.dfh_dxh.block<3, 3>(0, 0), j.dfh_dxh.block<3, 3>(3, 0);
        ht << j.dfh_dxh.block<3, 3>(0, 3), j.dfh_dxh.block<3, 3>(3, 3);
        hv << j.dfh_dvh.block<3, 3>(0, 0), j.dfh_dvh.block<3, 3>(3, 0);
        hw << j.dfh_dvh.block<3, 3>(0, 3), j.dfh_dvh.block<3, 3>(3, 3);
        CHECK_LT(relative_error(stack(j.dfa_dxh.leftCols<3>(), hx), numeric(k, d, a, [](Args& p, int c, double h) { p.h.x_com[c] += h; })), 1e-6);
        CHECK_LT(relative_error(stack(j.dfa_dvh.leftCols<3>(), hv), numeric(k, d, a, [](Args& p, int c, double h) { p.h.v_com[c] += h; })), 1e-6);
        CHECK_LT(relative_error(stack(j.dfa_dvh.rightCols<3>(), hw), numeric(k, d, a, [](Args& p, int c, double h) { p.h.omega[c] += h; })), 1e-6);
        // orientation: a world-frame rotation increment theta, q <- exp(theta) o q
        CHECK_LT(relative_error(stack(j.dfa_dxh.rightCols<3>(), ht), numeric(k, d, a, [](Args& p, int c, double h) {
                     Vec3 th = Vec3::Zero();
                     th[c] = h;
                     p.h.q = quat_multiply(quat_from_rotation_vector(th), p.h.q);
                 })), 1e-6);
    }
}

TEST(spring_forces_are_equal_and_opposite) {
    HandleState h;
    h.q = Vec4(0.1, -0.2, 0.3, 0.9).normalized();
    const SpringForce f = spring_force(100, 1, Vec3(0.1, 0.2, 0.3), Vec3(1, 0, 0), Vec3(0.01, 0.02, 0), h);
    CHECK_LT((f.on_node + f.on_handle).norm(), 1e-15);
}
