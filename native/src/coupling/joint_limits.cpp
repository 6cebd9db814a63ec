#include "coupling/joint_limits.h"

#include "rigid/quaternion.h"

namespace hh {

JointLimit joint_limit(double k, double d, const HandleState& parent, const HandleState& child, const Mat3& axes,
                       const Vec3& lo, const Vec3& hi) {
    JointLimit out;
    const Mat3 rp = quat_to_matrix(parent.q);
    const Vec3 phi = quat_to_rotation_vector(quat_multiply(quat_conjugate(parent.q), child.q));  // log(R_p^T R_c)
    out.psi = axes.transpose() * phi;
    Vec3 overshoot = Vec3::Zero();
    Mat3 select = Mat3::Zero();
    for (int i = 0; i < 3; ++i) {
        overshoot[i] = out.psi[i] - std::min(hi[i], std::max(lo[i], out.psi[i]));
        if (overshoot[i] != 0) select(i, i) = 1, out.active = true;
    }
    if (!out.active) return out;
    const Mat3 m = rp * left_jacobian_inverse(phi).transpose() * axes;  // dpsi = M^T (dtheta_c - dtheta_p)
    const Mat3 mm = m * select * m.transpose();
    out.stiffness = k * mm;
    out.damping = d * mm;
    out.on_child = -k * m * overshoot - out.damping * (child.omega - parent.omega);
    out.energy = 0.5 * k * overshoot.squaredNorm();
    return out;
}

JointBlocks joint_limit_blocks(const JointLimit& limit, double dt) {
    const double sign[2] = {-1.0, 1.0};  // (JointEnd: parent, child)
    JointBlocks out;
    for (int s = 0; s < 2; ++s) {
        for (int t = 0; t < 2; ++t) {
            // -dt dW_s/dv_t - dt^2 dW_s/dx_t, W_s's torque sign_s tau_c, tau_c's Jacobians -sign_t (K, D)
            out.ah[s][t].setZero();
            out.ah[s][t].bottomRightCorner<3, 3>() = sign[s] * sign[t] * (dt * limit.damping + dt * dt * limit.stiffness);
        }
        out.bh[s] << Vec3::Zero(), dt * sign[s] * limit.on_child;
    }
    return out;
}

}  // namespace hh
