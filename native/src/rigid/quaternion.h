// Unit quaternions q = (x, y, z, s) (vector part first, as in the paper's Appendix A),
// Hamilton product, and the two derivatives the coupling needs: the G matrix relating
// angular velocity to quaternion rate (Eq. 10) and d(R r)/dq (Eq. 14).
#pragma once
#include "common/types.h"

namespace hh {

Vec4 quat_identity();
Vec4 quat_multiply(const Vec4& a, const Vec4& b);
Vec4 quat_conjugate(const Vec4& q);
Mat3 quat_to_matrix(const Vec4& q);  // R such that R r = q o (r, 0) o q'
Vec4 quat_from_matrix(const Mat3& r);  // inverse of quat_to_matrix for a rotation matrix
// q o p written as a matrix acting on p (left factor fixed) or on q (right factor fixed).
Eigen::Matrix4d quat_left_matrix(const Vec4& q);
Eigen::Matrix4d quat_right_matrix(const Vec4& p);
// Rotation by the vector theta (axis * angle), and its inverse (angle in [0, pi]).
Vec4 quat_from_rotation_vector(const Vec3& theta);
Vec3 quat_to_rotation_vector(const Vec4& q);

// G with dq/dt = G(q) omega for a world-frame angular velocity omega.
Mat43 quat_rate_matrix(const Vec4& q);

// Eq. 14: the Jacobian of R(q) r_B = q o q(r_B) o q' with respect to the four components
// of q, by the product rule: Q C + Qbar, with Q the left-product matrix of q o q(r_B),
// C = diag(-1, -1, -1, 1) the conjugation, Qbar the right-product matrix of q(r_B) o q'.
// (The paper prints Q from q alone and C = diag(-1, 1, 1, 1); see docs/maths.md.)
Mat34 rotated_point_jacobian(const Vec4& q, const Vec3& r_body);

// The left Jacobian of SO(3), J_l(phi): exp(phi + e) = exp(J_l(phi) e) exp(phi) to first order
// in e; and its inverse, the derivative of log(exp(d) exp(phi)) with respect to d at d = 0, so
// that a turn d of an end pose changes the turn phi that reaches it by J_l^-1 d.
Mat3 left_jacobian(const Vec3& phi);
Mat3 left_jacobian_inverse(const Vec3& phi);

}  // namespace hh
