#include "coupling/joints.h"

#include "rigid/quaternion.h"

namespace hh {

namespace {
// Each end's lever R_s r_s and its sign in e = p_child - p_parent
struct Ends {
    const HandleState* h[2];
    Vec3 lever[2];
    double sign[2] = {-1.0, 1.0};
};

Ends ends(const HandleState& parent, const Vec3& r_parent, const HandleState& child, const Vec3& r_child) {
    Ends e;
    e.h[kParent] = &parent;
    e.h[kChild] = &child;
    e.lever[kParent] = quat_to_matrix(parent.q) * r_parent;
    e.lever[kChild] = quat_to_matrix(child.q) * r_child;
    return e;
}
}  // namespace

JointForce joint_force(double k, double d, const HandleState& parent, const Vec3& r_parent, const HandleState& child,
                       const Vec3& r_child) {
    const Ends e = ends(parent, r_parent, child, r_child);
    Vec3 gap = Vec3::Zero(), rate = Vec3::Zero();
    for (int s = 0; s < 2; ++s) {
        gap += e.sign[s] * (e.h[s]->x_com + e.lever[s]);
        rate += e.sign[s] * (e.h[s]->v_com + e.h[s]->omega.cross(e.lever[s]));
    }
    JointForce out;
    out.on_child = -k * gap - d * rate;  // Eq. 4 with both ends rigid
    out.energy = 0.5 * k * gap.squaredNorm();
    for (int s = 0; s < 2; ++s) {
        const Vec3 f = e.sign[s] * out.on_child;  // Eq. 5: equal and opposite
        out.wrench[s] << f, e.lever[s].cross(f);
    }
    return out;
}

JointJacobian joint_jacobian(double k, double d, const HandleState& parent, const Vec3& r_parent,
                             const HandleState& child, const Vec3& r_child) {
    const Ends e = ends(parent, r_parent, child, r_child);
    const Vec3 f = joint_force(k, d, parent, r_parent, child, r_child).on_child;
    const Mat3 eye = Mat3::Identity();
    JointJacobian j;
    for (int t = 0; t < 2; ++t) {
        const Mat3 lever_x = skew(e.lever[t]);
        // dF/d(x_t, theta_t) and dF/d(v_t, omega_t), F the force on the child: e moves by
        // sign_t (dx_t - [R r]x dtheta), de/dt by sign_t (dv_t - [R r]x domega - [omega]x [R r]x dtheta)
        Mat36 df_dx, df_dv;
        df_dx << -k * eye, k * lever_x + d * skew(e.h[t]->omega) * lever_x;
        df_dv << -d * eye, d * lever_x;
        df_dx *= e.sign[t];
        df_dv *= e.sign[t];
        for (int s = 0; s < 2; ++s) {
            // W_s = (sign_s F, [R_s r_s]x sign_s F), and its own lever turns with theta_s
            const Mat3 arm = skew(e.lever[s]);
            j.dw_dx[s][t] << e.sign[s] * df_dx, e.sign[s] * arm * df_dx;
            j.dw_dv[s][t] << e.sign[s] * df_dv, e.sign[s] * arm * df_dv;
            if (s == t) j.dw_dx[s][t].bottomRightCorner<3, 3>() += skew(e.sign[s] * f) * arm;
        }
    }
    return j;
}

JointBlocks joint_blocks(double k, double d, double dt, const HandleState& parent, const Vec3& r_parent,
                         const HandleState& child, const Vec3& r_child) {
    const JointJacobian j = joint_jacobian(k, d, parent, r_parent, child, r_child);
    const JointForce f = joint_force(k, d, parent, r_parent, child, r_child);
    JointBlocks out;
    for (int s = 0; s < 2; ++s) {
        for (int t = 0; t < 2; ++t) out.ah[s][t] = -dt * j.dw_dv[s][t] - dt * dt * j.dw_dx[s][t];
        out.bh[s] = dt * f.wrench[s];
    }
    return out;
}

}  // namespace hh
