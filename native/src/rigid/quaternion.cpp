#include "rigid/quaternion.h"

#include <cmath>

namespace hh {

Vec4 quat_identity() { return Vec4(0, 0, 0, 1); }

Vec4 quat_multiply(const Vec4& a, const Vec4& b) {
    const Vec3 av = a.head<3>(), bv = b.head<3>();
    Vec4 out;
    out.head<3>() = a.w() * bv + b.w() * av + av.cross(bv);
    out.w() = a.w() * b.w() - av.dot(bv);
    return out;
}

Vec4 quat_conjugate(const Vec4& q) { return Vec4(-q.x(), -q.y(), -q.z(), q.w()); }

Mat3 quat_to_matrix(const Vec4& q) {
    const double x = q.x(), y = q.y(), z = q.z(), s = q.w();
    Mat3 r;
    r << 1 - 2 * (y * y + z * z), 2 * (x * y - s * z), 2 * (x * z + s * y),
        2 * (x * y + s * z), 1 - 2 * (x * x + z * z), 2 * (y * z - s * x),
        2 * (x * z - s * y), 2 * (y * z + s * x), 1 - 2 * (x * x + y * y);
    return r;
}

Vec4 quat_from_matrix(const Mat3& r) {
    const Eigen::Quaterniond e(r);  // Eigen stores (x, y, z, w) as coeffs()
    return Vec4(e.x(), e.y(), e.z(), e.w()).normalized();
}

Eigen::Matrix4d quat_left_matrix(const Vec4& q) {
    Eigen::Matrix4d m;
    m.topLeftCorner<3, 3>() = q.w() * Mat3::Identity() + skew(q.head<3>());
    m.topRightCorner<3, 1>() = q.head<3>();
    m.bottomLeftCorner<1, 3>() = -q.head<3>().transpose();
    m(3, 3) = q.w();
    return m;
}

Eigen::Matrix4d quat_right_matrix(const Vec4& p) {
    Eigen::Matrix4d m;
    m.topLeftCorner<3, 3>() = p.w() * Mat3::Identity() - skew(p.head<3>());
    m.topRightCorner<3, 1>() = p.head<3>();
    m.bottomLeftCorner<1, 3>() = -p.head<3>().transpose();
    m(3, 3) = p.w();
    return m;
}

Vec4 quat_from_rotation_vector(const Vec3& theta) {
    const double angle = theta.norm();
    Vec4 q;
    // sin(a/2)/a by its series below 1e-8 rad so tiny rotations keep full precision
    const double k = angle < 1e-8 ? 0.5 - angle * angle / 48.0 : std::sin(0.5 * angle) / angle;
    q.head<3>() = k * theta;
    q.w() = std::cos(0.5 * angle);
    return q;
}

Vec3 quat_to_rotation_vector(const Vec4& q_in) {
    Vec4 q = q_in.w() < 0 ? Vec4(-q_in) : q_in;  // shortest arc
    const double vn = q.head<3>().norm();
    if (vn < 1e-12) return 2.0 * q.head<3>();
    return (2.0 * std::atan2(vn, q.w()) / vn) * q.head<3>();
}

Mat43 quat_rate_matrix(const Vec4& q) {
    // dq/dt = 1/2 (omega, 0) o q = 1/2 [right-product matrix of q] (omega, 0)
    return 0.5 * quat_right_matrix(q).leftCols<3>();
}

Mat34 rotated_point_jacobian(const Vec4& q, const Vec3& r_body) {
    const Vec4 p(r_body.x(), r_body.y(), r_body.z(), 0.0);
    const Vec4 qp = quat_multiply(q, p);
    const Vec4 pq_conj = quat_multiply(p, quat_conjugate(q));
    const Eigen::Vector4d conj_diag(-1, -1, -1, 1);
    const Eigen::Matrix4d d = quat_left_matrix(qp) * conj_diag.asDiagonal().toDenseMatrix() +
                              quat_right_matrix(pq_conj);
    return d.topRows<3>();
}

Mat3 left_jacobian(const Vec3& phi) {
    const double a = phi.norm();
    const Mat3 k = skew(phi);
    if (a < 1e-6) return Mat3::Identity() + 0.5 * k + k * k / 6.0;
    return Mat3::Identity() + (1 - std::cos(a)) / (a * a) * k + (a - std::sin(a)) / (a * a * a) * k * k;
}

Mat3 left_jacobian_inverse(const Vec3& phi) {
    const double a = phi.norm();
    const Mat3 k = skew(phi);
    // 1/a^2 - (1 + cos a) / (2 a sin a), by its series below 1e-4 rad
    const double c = a < 1e-4 ? 1.0 / 12.0 + a * a / 720.0 : 1.0 / (a * a) - (1 + std::cos(a)) / (2 * a * std::sin(a));
    return Mat3::Identity() - 0.5 * k + c * k * k;
}

}  // namespace hh
