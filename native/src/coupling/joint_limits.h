// Angular joint limits (docs/skeleton.md, Section 5): a bone's rotation relative to its parent,
// as a rotation vector in the bone's rest axes,
//   psi = B^T log(R_p^T R_c)            (body frames are the world frame at rest)
// kept within [psi_min, psi_max] per axis by a one-sided angular spring on each axis beyond its
// range, E = k/2 sum_i (psi_i - clamp(psi_i))^2, and a damper on those axes. The axes beyond
// their range are decided at the state the step linearizes about (as a contact's activity).
//
// With M = R_p J_l^-T(phi) B (phi = log(R_p^T R_c); dpsi = M^T (dtheta_c - dtheta_p), theta a
// world-frame rotation increment, J_l the left Jacobian of SO(3)) and Pi selecting the axes
// beyond range (a diagonal of 0 and 1):
//   tau_c = -M Pi k (psi - clamp(psi)) - M Pi d M^T (omega_c - omega_p),   tau_p = -tau_c
// a pure torque pair (no force). Its Jacobians in Eq. 7 are the Gauss-Newton ones,
// d tau_c / d theta_t = -sigma_t k M Pi M^T and d tau_c / d omega_t = -sigma_t d M Pi M^T
// (sigma_p = -1, sigma_c = +1): the terms with the derivative of M, proportional to the
// overshoot (and to the relative spin), are left out, as the co-rotational flesh leaves out its
// rotations' derivatives. Symmetric and positive semi-definite, so the Schur complement stays
// symmetric positive definite.
#pragma once

#include "coupling/joints.h"

namespace hh {

struct JointLimit {
    Vec3 psi = Vec3::Zero();  // rad, the rotation in the bone's rest axes
    Vec3 on_child = Vec3::Zero();  // N m, tau_c (the parent feels -tau_c)
    Mat3 stiffness = Mat3::Zero();  // k M Pi M^T
    Mat3 damping = Mat3::Zero();    // d M Pi M^T
    double energy = 0;              // k/2 |psi - clamp(psi)|^2
    bool active = false;            // an axis is beyond its range
};

// axes: the bone's rest axes (columns x, y, z, world frame); lo, hi: its ranges (rad, -inf /
// +inf for a free axis).
JointLimit joint_limit(double k, double d, const HandleState& parent, const HandleState& child, const Mat3& axes,
                       const Vec3& lo, const Vec3& hi);

// What the limit adds to Eq. 7 over a step of dt (as joint_blocks): the torque rows only.
JointBlocks joint_limit_blocks(const JointLimit& limit, double dt);

}  // namespace hh
