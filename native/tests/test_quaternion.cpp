// Appendix A (Eq. 14) and the G matrix of Eq. 10 against central finite differences.
#include <random>

#include "check.h"
#include "rigid/quaternion.h"

using namespace hh;

namespace {
Vec4 random_unit_quaternion(std::mt19937& rng) {
    std::normal_distribution<double> n(0, 1);
    Vec4 q(n(rng), n(rng), n(rng), n(rng));
    return q.normalized();
}
Vec3 random_vec(std::mt19937& rng, double scale) {
    std::uniform_real_distribution<double> u(-scale, scale);
    return Vec3(u(rng), u(rng), u(rng));
}
// R(q) r_B = q o q(r_B) o q', as a function of all four components of q (not normalized)
Vec3 rotate_by_product(const Vec4& q, const Vec3& r) {
    return quat_multiply(quat_multiply(q, Vec4(r.x(), r.y(), r.z(), 0)), quat_conjugate(q)).head<3>();
}
}  // namespace

TEST(eq14_matches_central_differences) {
    std::mt19937 rng(1);
    for (int trial = 0; trial < 20; ++trial) {
        const Vec4 q = random_unit_quaternion(rng);
        const Vec3 r = random_vec(rng, 0.05);
        const Mat34 analytic = rotated_point_jacobian(q, r);
        Mat34 numeric;
        const double h = 1e-6;
        for (int k = 0; k < 4; ++k) {
            Vec4 dq = Vec4::Zero();
            dq[k] = h;
            numeric.col(k) = (rotate_by_product(q + dq, r) - rotate_by_product(q - dq, r)) / (2 * h);
        }
        CHECK_LT((analytic - numeric).norm() / analytic.norm(), 1e-6);
    }
}

TEST(rotation_matrix_equals_quaternion_product) {
    std::mt19937 rng(2);
    for (int trial = 0; trial < 20; ++trial) {
        const Vec4 q = random_unit_quaternion(rng);
        const Vec3 r = random_vec(rng, 1.0);
        CHECK_LT((quat_to_matrix(q) * r - rotate_by_product(q, r)).norm(), 1e-14);
        CHECK_LT((quat_to_matrix(q) * quat_to_matrix(q).transpose() - Mat3::Identity()).norm(), 1e-14);
    }
}

TEST(g_matrix_maps_angular_velocity_to_quaternion_rate) {
    std::mt19937 rng(3);
    for (int trial = 0; trial < 20; ++trial) {
        const Vec4 q = random_unit_quaternion(rng);
        const Vec3 omega = random_vec(rng, 3.0);
        const double h = 1e-6;
        // q(t) = exp(t omega) o q for a world-frame angular velocity omega
        const Vec4 rate = (quat_multiply(quat_from_rotation_vector(h * omega), q) -
                           quat_multiply(quat_from_rotation_vector(-h * omega), q)) / (2 * h);
        CHECK_LT((quat_rate_matrix(q) * omega - rate).norm() / rate.norm(), 1e-6);
    }
}

TEST(eq14_times_g_is_minus_cross_matrix) {
    // d(R r_B)/dtheta = -[R r_B]x: the chain Eq. 14 * G must reproduce it
    std::mt19937 rng(4);
    for (int trial = 0; trial < 20; ++trial) {
        const Vec4 q = random_unit_quaternion(rng);
        const Vec3 r = random_vec(rng, 0.05);
        const Mat3 chain = rotated_point_jacobian(q, r) * quat_rate_matrix(q);
        CHECK_LT((chain + skew(quat_to_matrix(q) * r)).norm(), 1e-14);
    }
}

TEST(rotation_vector_round_trip) {
    std::mt19937 rng(5);
    for (int trial = 0; trial < 20; ++trial) {
        const Vec3 theta = random_vec(rng, 1.5);
        CHECK_LT((quat_to_rotation_vector(quat_from_rotation_vector(theta)) - theta).norm(), 1e-12);
    }
    CHECK_LT(quat_to_rotation_vector(quat_identity()).norm(), 1e-300);
}
