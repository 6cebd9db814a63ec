#include "coupling/springs.h"

#include "rigid/quaternion.h"

namespace hh {

SpringForce spring_force(double k, double d, const Vec3& x_a, const Vec3& v_a, const Vec3& r_body,
                         const HandleState& h) {
    const Vec3 rr = quat_to_matrix(h.q) * r_body;  // R_h r_B
    const Vec3 x_b = h.x_com + rr;
    const Vec3 v_b = h.v_com + h.omega.cross(rr);
    SpringForce out;
    out.on_node = -k * (x_a - x_b) - d * (v_a - v_b);
    out.on_handle = -out.on_node;
    out.torque = rr.cross(out.on_handle);
    return out;
}

SpringJacobian spring_jacobian(double k, double d, const Vec3& x_a, const Vec3& v_a,
                               const Vec3& r_body, const HandleState& h) {
    const Mat3 eye = Mat3::Identity();
    const Vec3 rr = quat_to_matrix(h.q) * r_body;
    const Mat3 rr_x = skew(rr);
    // Eq. 14 times G (Eq. 10): d(R r_B)/dtheta, which equals -[R r_B]x for a unit quaternion.
    const Mat3 drr_dtheta = rotated_point_jacobian(h.q, r_body) * quat_rate_matrix(h.q);
    const Mat3 omega_x = skew(h.omega);
    const SpringForce f = spring_force(k, d, x_a, v_a, r_body, h);

    SpringJacobian j;
    j.dfa_dxa = -k * eye;
    j.dfa_dva = -d * eye;
    // Eq. 11: dF_A/dx_com = k I; dF_A/dq_h = k d(R r_B)/dq_h + d omega x d(R r_B)/dq_h
    j.dfa_dxh << k * eye, k * drr_dtheta + d * omega_x * drr_dtheta;
    j.dfa_dvh << d * eye, -d * rr_x;
    // Eq. 11: dF_B/dx_A = k I, dT_B/dx_A = (R r_B) x dF_B/dx_A
    j.dfh_dxa << k * eye, rr_x * k;
    j.dfh_dva << d * eye, rr_x * d;
    const Mat3 dfb_dtheta = -j.dfa_dxh.rightCols<3>();
    const Mat3 dfb_domega = d * rr_x;
    // T_B = rr x F_B: product rule, with d(rr)/dtheta from Eq. 14
    j.dfh_dxh << -k * eye, dfb_dtheta, -rr_x * k, -skew(f.on_handle) * drr_dtheta + rr_x * dfb_dtheta;
    j.dfh_dvh << -d * eye, dfb_domega, -rr_x * d, rr_x * dfb_domega;
    return j;
}

Mat63 handle_flesh_block(double k, double d, double dt, const Vec3& lever) {
    Mat63 block;
    block << Mat3::Identity(), skew(lever);
    return -(dt * d + dt * dt * k) * block;  // Eq. 8: -dt dF_h/dv_A - dt^2 dF_h/dx_A
}

void assemble_coupling(double k, double d, double dt, const std::vector<int>& nodes,
                       const std::vector<Vec3>& r_body, const VecX& x, const VecX& v,
                       const HandleState& h, CouplingBlocks& out) {
    const size_t c = nodes.size();
    out.ath.resize(c);
    out.aht.resize(c);
    out.at_diagonal.resize(c);
    out.bt.resize(c);
    out.ah.setZero();
    out.bh.setZero();
    for (size_t j = 0; j < c; ++j) {
        const Vec3 x_a = x.segment<3>(3 * nodes[j]), v_a = v.segment<3>(3 * nodes[j]);
        const SpringJacobian jac = spring_jacobian(k, d, x_a, v_a, r_body[j], h);
        // Eqs. 8 and 10 (Mht = Mth = 0)
        out.aht[j] = -dt * jac.dfh_dva - dt * dt * jac.dfh_dxa;
        out.ath[j] = -dt * jac.dfa_dvh - dt * dt * jac.dfa_dxh;
        out.at_diagonal[j] = -dt * jac.dfa_dva - dt * dt * jac.dfa_dxa;
        out.ah += -dt * jac.dfh_dvh - dt * dt * jac.dfh_dxh;
        const SpringForce f = spring_force(k, d, x_a, v_a, r_body[j], h);
        out.bt[j] = dt * f.on_node;
        out.bh.head<3>() += dt * f.on_handle;
        out.bh.tail<3>() += dt * f.torque;
    }
}

}  // namespace hh
