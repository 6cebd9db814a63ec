// The Schur-complement solve (Eqs. 12-13, Section 6) against the monolithic reference of
// Eq. 7, and the handle's mass properties (Eq. 3).
#include <random>

#include "box_mesh.h"
#include "check.h"
#include "rigid/quaternion.h"
#include "sim/data.h"

using namespace hh;

namespace {
hh_params box_params() {
    hh_params p = box_hand_params();
    p.spring_stiffness = 1e5;
    p.spring_damping = 30;
    return p;
}
void perturb(Data& d, std::mt19937& rng) {
    std::normal_distribution<double> n(0, 1);
    for (int i = 0; i < d.x.size(); ++i) {
        d.x[i] += 1e-3 * n(rng);
        d.v[i] = 0.1 * n(rng);
    }
    d.h.x_com += Vec3(n(rng), n(rng), n(rng)) * 1e-3;
    d.h.q = quat_multiply(quat_from_rotation_vector(Vec3(n(rng), n(rng), n(rng)) * 0.1), d.h.q);
    d.h.v_com = Vec3(n(rng), n(rng), n(rng)) * 0.1;
    d.h.omega = Vec3(n(rng), n(rng), n(rng));
    d.device.enabled = true;
    d.device.position = d.h.x_com + Vec3(0.01, 0, 0);
    d.device.quaternion = quat_from_rotation_vector(Vec3(0.2, 0, 0));
}
double schur_vs_monolithic(int solver, double cg_tol) {
    const BoxMesh b = make_box(4, 3, 2, 0.01);
    hh_params p = box_params();
    p.solver = solver;
    p.cg_tolerance = cg_tol;
    const Model m = build_model(b.nodes.data(), b.n_nodes(), b.tets.data(), b.n_tets(), p);
    Data d(m);
    std::mt19937 rng(21);
    perturb(d, rng);
    formulate(m, d);
    d.hand.solve();
    const VecX schur = d.hand.s;
    const VecX mono = solve_monolithic(d.hand, d.hand.r);
    return (schur - mono).cwiseAbs().maxCoeff() / mono.cwiseAbs().maxCoeff();
}
}  // namespace

TEST(schur_equals_monolithic_with_cholesky) { CHECK_LT(schur_vs_monolithic(HH_SOLVER_CHOLESKY, 1e-8), 1e-8); }

TEST(schur_equals_monolithic_with_cg) { CHECK_LT(schur_vs_monolithic(HH_SOLVER_CG, 1e-14), 1e-8); }

TEST(handle_mass_and_inertia_follow_eq3) {
    const BoxMesh b = make_box(4, 3, 2, 0.01);
    const hh_params p = box_params();
    const Model m = build_model(b.nodes.data(), b.n_nodes(), b.tets.data(), b.n_tets(), p);
    double mass = 0;
    Vec3 com = Vec3::Zero();
    for (int i : m.handle.nodes) {
        mass += m.masses[i];
        com += m.masses[i] * m.mesh.rest.segment<3>(3 * i);
    }
    com /= mass;
    Mat3 inertia = Mat3::Zero();
    for (int i : m.handle.nodes) {
        const Vec3 r = m.mesh.rest.segment<3>(3 * i) - com;
        inertia += m.masses[i] * (r.squaredNorm() * Mat3::Identity() - r * r.transpose());
    }
    CHECK(m.handle.nodes.size() >= 4);
    CHECK_LT(std::abs(m.handle.mass - mass) / mass, 1e-14);
    CHECK_LT((m.handle.rest_com - com).norm(), 1e-15);
    CHECK_LT((m.handle.inertia_body - inertia).norm() / inertia.norm(), 1e-14);
    // every captured node is within the radius, every other node outside
    const Vec3 seed(p.palm_seed[0], p.palm_seed[1], p.palm_seed[2]);
    size_t inside = 0;
    for (int i = 0; i < m.mesh.n_nodes; ++i) inside += (m.mesh.rest.segment<3>(3 * i) - seed).norm() <= p.handle_radius;
    CHECK(inside == m.handle.nodes.size());
}
