// Zero-rest-length damped springs between hand nodes and their material points on the
// handle (Eqs. 4-5), their Jacobians (Eq. 11 with Appendix A), and the coupling blocks of
// the implicit system, Aht and Ath (Eqs. 8-10).
//
// Handle-state derivatives are taken with respect to (x_com, theta), theta a world-frame
// rotation increment, so that the velocity unknowns are v_h = (v_com, omega) as in Eq. 1:
// d/dtheta = d/dq_h * G (Eq. 10), with d(R r_B)/dq_h from Eq. 14.
#pragma once
#include <vector>

#include "common/types.h"

namespace hh {

struct HandleState {
    Vec3 x_com = Vec3::Zero();
    Vec4 q = Vec4(0, 0, 0, 1);
    Vec3 v_com = Vec3::Zero();
    Vec3 omega = Vec3::Zero();
};

struct SpringForce {
    Vec3 on_node;     // F_A, Eq. 4
    Vec3 on_handle;   // F_B = -F_A
    Vec3 torque;      // T_B = (R r_B) x F_B, Eq. 5, about x_com
};

SpringForce spring_force(double k, double d, const Vec3& x_a, const Vec3& v_a, const Vec3& r_body,
                         const HandleState& h);

struct SpringJacobian {
    Mat3 dfa_dxa, dfa_dva;   // node force w.r.t. its own node
    Mat36 dfa_dxh, dfa_dvh;  // node force w.r.t. handle (x_com, theta) and (v_com, omega)
    Mat63 dfh_dxa, dfh_dva;  // handle force and torque w.r.t. the node
    Mat6 dfh_dxh, dfh_dvh;   // handle force and torque w.r.t. the handle
};

SpringJacobian spring_jacobian(double k, double d, const Vec3& x_a, const Vec3& v_a,
                               const Vec3& r_body, const HandleState& h);

// The coupling part of Eq. 7 for one step of length dt, linearized about the given state
// (x, v, h): per captured node the blocks Ath_j (3x6) and Aht_j (6x3) of Eqs. 8 and 10, plus
// what the springs add to the node's diagonal block of At and to Ah, and to the right-hand
// sides dt times the spring forces at that state. The step passes the state its rigid frame
// carries the hand to (sim/step_frame.h) and solves for the velocities relative to that state's,
// so the forces there enter whole, damping included.
struct CouplingBlocks {
    std::vector<Mat36> ath;
    std::vector<Mat63> aht;
    std::vector<Mat3> at_diagonal;
    Mat6 ah = Mat6::Zero();
    std::vector<Vec3> bt;
    Vec6 bh = Vec6::Zero();
};

// Aht_j for a spring whose handle point sits at lever R r_B from the handle's centre: the
// blocks depend on the handle's orientation alone (Eq. 11: dF_B/dx_A = k I, dT_B/dx_A =
// [R r_B]x k I, and the same with d for the velocities).
Mat63 handle_flesh_block(double k, double d, double dt, const Vec3& lever);

void assemble_coupling(double k, double d, double dt, const std::vector<int>& nodes,
                       const std::vector<Vec3>& r_body, const VecX& x, const VecX& v,
                       const HandleState& h, CouplingBlocks& out);

}  // namespace hh
