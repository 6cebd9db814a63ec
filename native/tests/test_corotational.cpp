// Co-rotational elasticity: invariance to rigid motion, agreement with linear FEM for small
// strains, symmetric element stiffness, lumped masses that add up to the body's mass.
#include <random>

#include "box_mesh.h"
#include "check.h"
#include "fem/corotational.h"
#include "rigid/quaternion.h"

using namespace hh;

namespace {
TetMesh to_mesh(const BoxMesh& b) {
    TetMesh m;
    m.n_nodes = b.n_nodes();
    m.rest = Eigen::Map<const VecX>(b.nodes.data(), b.nodes.size());
    for (int e = 0; e < b.n_tets(); ++e)
        m.tets.emplace_back(b.tets[4 * e], b.tets[4 * e + 1], b.tets[4 * e + 2], b.tets[4 * e + 3]);
    return m;
}
const Material flesh{5e4, 0.3, 1000};
}  // namespace

TEST(zero_force_under_rigid_motion) {
    const TetMesh mesh = to_mesh(make_box(3, 2, 2, 0.01));
    const CorotationalElements el = precompute_elements(mesh, flesh);
    std::mt19937 rng(11);
    std::normal_distribution<double> n(0, 1);
    for (int trial = 0; trial < 10; ++trial) {
        const Mat3 r = quat_to_matrix(Vec4(n(rng), n(rng), n(rng), n(rng)).normalized());
        const Vec3 t(n(rng), n(rng), n(rng));
        VecX x(mesh.rest.size());
        for (int i = 0; i < mesh.n_nodes; ++i) x.segment<3>(3 * i) = r * mesh.rest.segment<3>(3 * i) + t;
        VecX f = VecX::Zero(x.size());
        const double energy = add_elastic_forces(mesh, el, x, f, nullptr);
        // scale: the force a 1% strain would give, so the tolerance is relative
        const double scale = flesh.young_modulus * 0.01 * 0.01 * 0.01;
        CHECK_LT(f.cwiseAbs().maxCoeff() / scale, 1e-9);
        const double energy_scale = flesh.young_modulus * 1e-4 * 0.03 * 0.02 * 0.02;  // 1% strain
        CHECK_LT(std::abs(energy) / energy_scale, 1e-9);
    }
}

TEST(matches_linear_fem_for_small_strain) {
    const TetMesh mesh = to_mesh(make_box(3, 2, 2, 0.01));
    const CorotationalElements el = precompute_elements(mesh, flesh);
    const StiffnessPattern pat = build_stiffness_pattern(mesh);
    std::vector<Mat3> identity(mesh.tets.size(), Mat3::Identity());
    SpMat k = pat.matrix;
    add_warped_stiffness(el, identity, pat, 1.0, k.valuePtr());
    std::mt19937 rng(12);
    std::normal_distribution<double> n(0, 1);
    VecX dir(mesh.rest.size());
    for (int i = 0; i < dir.size(); ++i) dir[i] = n(rng);
    dir /= dir.cwiseAbs().maxCoeff();
    // linear FEM force -K u; co-rotational differs by O(|u|^2): the error ratio shrinks with u
    double previous = 1;
    for (double amp : {1e-4, 1e-5, 1e-6}) {
        const VecX u = amp * 0.01 * dir;
        VecX f = VecX::Zero(u.size());
        add_elastic_forces(mesh, el, mesh.rest + u, f, nullptr);
        const VecX linear = -(k * u);
        const double rel = (f - linear).norm() / linear.norm();
        CHECK_LT(rel, 10 * amp);
        CHECK_LT(rel, previous);
        previous = rel;
    }
}

TEST(element_stiffness_is_symmetric_and_positive_semidefinite) {
    const TetMesh mesh = to_mesh(make_box(2, 2, 2, 0.01));
    const CorotationalElements el = precompute_elements(mesh, flesh);
    for (const Mat12& k : el.stiffness) {
        CHECK_LT((k - k.transpose()).norm() / k.norm(), 1e-14);
        Eigen::SelfAdjointEigenSolver<Mat12> eig(k);
        // six rigid modes with zero eigenvalue, six deformation modes with positive ones
        const auto ev = eig.eigenvalues();
        CHECK_LT(std::abs(ev[5]) / ev[11], 1e-10);
        CHECK(ev[6] > 1e-6 * ev[11]);
    }
}

TEST(stiffness_is_the_force_jacobian_at_rest) {
    const TetMesh mesh = to_mesh(make_box(2, 2, 1, 0.01));
    const CorotationalElements el = precompute_elements(mesh, flesh);
    const StiffnessPattern pat = build_stiffness_pattern(mesh);
    std::vector<Mat3> identity(mesh.tets.size(), Mat3::Identity());
    SpMat k = pat.matrix;
    add_warped_stiffness(el, identity, pat, 1.0, k.valuePtr());
    const MatX kd = MatX(k);
    const double h = 1e-7;
    for (int c = 0; c < mesh.rest.size(); c += 5) {
        VecX fp = VecX::Zero(mesh.rest.size()), fm = fp;
        VecX xp = mesh.rest, xm = mesh.rest;
        xp[c] += h;
        xm[c] -= h;
        add_elastic_forces(mesh, el, xp, fp, nullptr);
        add_elastic_forces(mesh, el, xm, fm, nullptr);
        const VecX numeric = (fp - fm) / (2 * h);
        CHECK_LT((numeric + kd.col(c)).norm() / kd.col(c).norm(), 1e-6);
    }
}

TEST(lumped_masses_sum_to_body_mass) {
    const TetMesh mesh = to_mesh(make_box(3, 2, 2, 0.01));
    const CorotationalElements el = precompute_elements(mesh, flesh);
    const VecX m = lumped_masses(mesh, el, flesh.density);
    const double body = flesh.density * 0.03 * 0.02 * 0.02;
    CHECK_LT(std::abs(m.sum() - body) / body, 1e-12);
    CHECK(m.minCoeff() > 0);
}

TEST(inverted_tet_is_rejected_with_its_index) {
    BoxMesh b = make_box(1, 1, 1, 0.01);
    std::swap(b.tets[4 * 3 + 1], b.tets[4 * 3 + 2]);
    bool thrown = false;
    try {
        precompute_elements(to_mesh(b), flesh);
    } catch (const InvalidArgument& e) {
        thrown = std::string(e.what()).find("tetrahedron 3") != std::string::npos &&
                 std::string(e.what()).find("inverted") != std::string::npos;
    }
    CHECK(thrown);
}
