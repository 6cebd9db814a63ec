// Ball joints between a bone and its parent (docs/skeleton.md, Section 5): a zero-rest-length
// damped spring of Eq. 4 between the child's head as a point of the parent and as a point of the
// child, both ends rigid. Its force, its Jacobians (Eq. 11's, with the rotation terms on both
// sides) and its blocks of Eq. 7: the parent's and the child's diagonal blocks of A_h and the two
// off-diagonal blocks between them.
//
// As the flesh springs' (coupling/springs.h), derivatives are taken in each bone's (x_com, theta),
// theta a world-frame rotation increment, and (v_com, omega), with d(R r)/dtheta = -[R r]x (Eq. 14
// times G for a unit quaternion).
#pragma once

#include "coupling/springs.h"

namespace hh {

// The two ends of a joint: index 0 the parent, 1 the child.
enum JointEnd { kParent = 0, kChild = 1 };

struct JointForce {
    Vec3 on_child;      // F = -k e - d de/dt, e = (x_c + R_c r_c) - (x_p + R_p r_p)
    Vec6 wrench[2];     // (force, torque about the bone's centre of mass) on the parent, the child
    double energy = 0;  // k |e|^2 / 2
};

JointForce joint_force(double k, double d, const HandleState& parent, const Vec3& r_parent, const HandleState& child,
                       const Vec3& r_child);

struct JointJacobian {
    Mat6 dw_dx[2][2];  // dW_s / d(x_t, theta_t), s, t in {parent, child}
    Mat6 dw_dv[2][2];  // dW_s / d(v_t, omega_t)
};

JointJacobian joint_jacobian(double k, double d, const HandleState& parent, const Vec3& r_parent,
                             const HandleState& child, const Vec3& r_child);

// What the joint adds to Eq. 7 over a step of dt, linearized about the given states:
// ah[s][t] = -dt dW_s/dv_t - dt^2 dW_s/dx_t (to A_h's block of bones s, t) and bh[s] = dt W_s.
struct JointBlocks {
    Mat6 ah[2][2];
    Vec6 bh[2];
};

JointBlocks joint_blocks(double k, double d, double dt, const HandleState& parent, const Vec3& r_parent,
                         const HandleState& child, const Vec3& r_child);

}  // namespace hh
