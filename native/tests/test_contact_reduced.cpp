// The reduced form of the contact problem (W = sum_b P_b C_b P_b^T, never formed) against the
// dense one: the same sweeps must give the same impulses, sweep for sweep.
#include <random>

#include "check.h"
#include "contact/pgs.h"

using namespace hh;

namespace {
// Two bodies sharing some contacts, many redundant contacts on few unknowns (as on an
// embedded surface): m_b unknowns per body, c contacts.
ReducedContactProblem random_problem(std::mt19937& rng, int c, int m0, int m1) {
    std::uniform_real_distribution<double> u(-1, 1);
    ReducedContactProblem p;
    p.dt = 1.0 / 30;
    for (int m : {m0, m1}) {
        MatX a = MatX::Random(m, m);
        p.bodies.push_back({a * a.transpose() / m + 0.05 * MatX::Identity(m, m)});
    }
    p.begin.assign(1, 0);
    p.u_free.resize(3 * c);
    p.gap.resize(c);
    p.friction.resize(c);
    p.kinetic.resize(c);
    for (int i = 0; i < c; ++i) {
        const int sides = i % 3 == 0 ? 2 : 1;  // a third of the contacts between the two bodies
        for (int s = 0; s < sides; ++s) {
            const int body = sides == 2 ? s : i % 2;
            const int m = body == 0 ? m0 : m1;
            for (int k = 0; k < 4; ++k) {
                const int index = static_cast<int>((u(rng) + 1) / 2 * (m - 1));
                p.entries.push_back({body, index, Vec3(u(rng), u(rng), u(rng)) * (s == 0 ? 1 : -1)});
            }
        }
        p.begin.push_back(static_cast<int>(p.entries.size()));
        p.u_free.segment<3>(3 * i) = Vec3(-0.2 + 0.1 * u(rng), 0.1 * u(rng), 0.1 * u(rng));
        p.gap[i] = 1e-4 * u(rng);
        p.friction[i] = 0.5;
        p.kinetic[i] = i % 4 == 0 ? 0.3 : 0.5;
    }
    return p;
}
}  // namespace

TEST(reduced_sweeps_equal_dense_sweeps) {
    std::mt19937 rng(7);
    for (int trial = 0; trial < 5; ++trial) {
        const ReducedContactProblem r = random_problem(rng, 60, 12, 18);
        ContactProblem d;
        d.W = r.delassus();
        CHECK_LT((d.W - d.W.transpose()).cwiseAbs().maxCoeff(), 1e-12);
        d.u_free = r.u_free;
        d.gap = r.gap;
        d.friction = r.friction;
        d.kinetic = r.kinetic;
        d.dt = r.dt;
        for (int cap : {1, 7, 200}) {
            VecX lr, ld;
            const PgsResult a = solve_pgs(r, lr, cap, 1e-9);
            const PgsResult b = solve_pgs(d, ld, cap, 1e-9);
            CHECK(a.iterations == b.iterations);
            CHECK_LT((lr - ld).cwiseAbs().maxCoeff(), 1e-9 * (1 + ld.cwiseAbs().maxCoeff()));
            CHECK_LT(std::abs(a.residual - b.residual), 1e-9);
            // the impulses satisfy the cone
            for (int i = 0; i < 60; ++i) {
                CHECK(lr[3 * i] >= 0);
                CHECK(std::hypot(lr[3 * i + 1], lr[3 * i + 2]) <= r.friction[i] * lr[3 * i] * (1 + 1e-12) + 1e-15);
            }
        }
    }
}

TEST(a_contact_without_normal_impulse_may_slide) {
    // one contact opening (u_n > 0 after any impulse) while sliding: no impulse, and the
    // residual does not ask it to stick, so the solve ends at once
    ReducedContactProblem p;
    p.dt = 0.01;
    p.bodies.push_back({Mat3::Identity()});
    p.begin = {0, 3};
    for (int d = 0; d < 3; ++d) p.entries.push_back({0, d, Vec3::Unit(d)});
    p.u_free = Vec3(0.1, 0.3, 0);
    p.gap = VecX::Constant(1, 0.0);
    p.friction = VecX::Constant(1, 0.5);
    p.kinetic = VecX::Constant(1, 0.5);
    VecX lambda;
    const PgsResult res = solve_pgs(p, lambda, 300, 1e-9);
    CHECK(res.iterations == 1);
    CHECK_LT(lambda.cwiseAbs().maxCoeff(), 1e-15);
    CHECK_LT(res.residual, 1e-15);
}
