// Narrow- and broad-phase building blocks against brute force, and the contact solver on
// problems with known answers.
#include <random>

#include "check.h"
#include "contact/bvh.h"
#include "contact/geometry.h"
#include "contact/pgs.h"

using namespace hh;

namespace {
std::mt19937 rng(31);
Vec3 random_point(double s) {
    std::uniform_real_distribution<double> u(-s, s);
    return Vec3(u(rng), u(rng), u(rng));
}
}  // namespace

TEST(closest_point_on_triangle_beats_sampling) {
    for (int trial = 0; trial < 200; ++trial) {
        const Vec3 a = random_point(1), b = random_point(1), c = random_point(1), p = random_point(2);
        const Vec3 w = closest_on_triangle(p, a, b, c);
        CHECK(w.minCoeff() >= -1e-12 && std::abs(w.sum() - 1) < 1e-12);
        const double best = (p - (w[0] * a + w[1] * b + w[2] * c)).norm();
        // no point of a fine barycentric grid is closer
        for (int i = 0; i <= 40; ++i)
            for (int j = 0; i + j <= 40; ++j) {
                const Vec3 q = a + (i / 40.0) * (b - a) + (j / 40.0) * (c - a);
                CHECK((p - q).norm() >= best - 1e-12);
            }
    }
}

TEST(closest_points_between_segments_beat_sampling) {
    for (int trial = 0; trial < 200; ++trial) {
        const Vec3 p0 = random_point(1), p1 = random_point(1), q0 = random_point(1), q1 = random_point(1);
        double s, t;
        closest_between_segments(p0, p1, q0, q1, s, t);
        CHECK(s >= 0 && s <= 1 && t >= 0 && t <= 1);
        const double best = ((p0 + s * (p1 - p0)) - (q0 + t * (q1 - q0))).norm();
        for (int i = 0; i <= 50; ++i)
            for (int j = 0; j <= 50; ++j)
                CHECK(((p0 + (i / 50.0) * (p1 - p0)) - (q0 + (j / 50.0) * (q1 - q0))).norm() >= best - 1e-12);
    }
}

TEST(bvh_query_finds_exactly_the_overlapping_boxes) {
    std::vector<Aabb> boxes(500);
    for (auto& b : boxes) {
        const Vec3 c = random_point(1);
        b.grow(c);
        b.grow(c + random_point(0.1));
    }
    Bvh bvh;
    bvh.build(boxes);
    for (int round = 0; round < 2; ++round) {
        for (int q = 0; q < 100; ++q) {
            Aabb query;
            const Vec3 c = random_point(1);
            query.grow(c);
            query.grow(c + random_point(0.2));
            std::vector<char> hit(boxes.size(), 0);
            bvh.query(query, [&](int i) { hit[i] = 1; });
            for (size_t i = 0; i < boxes.size(); ++i) CHECK(hit[i] == boxes[i].overlaps(query));
        }
        for (auto& b : boxes) {  // move every box, refit, query again
            const Vec3 d = random_point(0.3);
            b.lo += d;
            b.hi += d;
        }
        bvh.refit(boxes);
    }
}

TEST(pgs_point_mass_on_ground_sticks_or_slides) {
    // a 1 kg point on the ground, pushed sideways: W = I (unit mass), contact frame (n, t1, t2)
    const double dt = 0.01, mu = 0.5;
    for (double push : {0.02, 0.2}) {  // tangential velocity to cancel: below or above mu * normal impulse
        ContactProblem p;
        p.dt = dt;
        p.W = MatX::Identity(3, 3);
        p.u_free = VecX(3);
        p.u_free << -9.81 * dt, push, 0;  // falling at g dt, sliding along t1
        p.gap = VecX::Zero(1);
        p.friction = VecX::Constant(1, mu);
        p.kinetic = VecX::Constant(1, mu);
        VecX lambda;
        solve_pgs(p, lambda, 100, 1e-12);
        CHECK_LT(std::abs(lambda[0] - 9.81 * dt), 1e-12);  // the normal impulse holds the weight
        const double stick = push;                          // impulse that stops the sliding
        const double expected = std::min(stick, mu * 9.81 * dt);
        CHECK_LT(std::abs(-lambda[1] - expected), 1e-12);
        CHECK_LT(std::abs(lambda[2]), 1e-15);
    }
}

TEST(pgs_static_friction_holds_then_kinetic_friction_slides) {
    // static 0.5, kinetic 0.3: a push needing 0.4 g dt of friction impulse is held; one
    // needing 0.6 g dt breaks loose and slides against 0.3 g dt
    const double dt = 0.01, g = 9.81;
    for (double need : {0.4, 0.6}) {
        ContactProblem p;
        p.dt = dt;
        p.W = MatX::Identity(3, 3);
        p.u_free = VecX(3);
        p.u_free << -g * dt, need * g * dt, 0;
        p.gap = VecX::Zero(1);
        p.friction = VecX::Constant(1, 0.5);
        p.kinetic = VecX::Constant(1, 0.3);
        VecX lambda;
        solve_pgs(p, lambda, 100, 1e-12);
        const double expected = need <= 0.5 ? need * g * dt : 0.3 * g * dt;
        CHECK_LT(std::abs(-lambda[1] - expected), 1e-12);
    }
}
