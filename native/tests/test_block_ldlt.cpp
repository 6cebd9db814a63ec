// The block LDL^T solver against a dense solve, on the warped-stiffness systems it is built for.
#include <random>

#include "box_mesh.h"
#include "check.h"
#include "fem/corotational.h"
#include "rigid/quaternion.h"
#include "solver/block_ldlt.h"

using namespace hh;

namespace {
// A = M + s R K R^T for a box mesh with random element rotations: SPD, 3x3-block pattern.
SpMat system_matrix(int nx, int ny, int nz, unsigned seed) {
    const BoxMesh b = make_box(nx, ny, nz, 0.01);
    TetMesh mesh;
    mesh.n_nodes = b.n_nodes();
    mesh.rest = Eigen::Map<const VecX>(b.nodes.data(), b.nodes.size());
    for (int e = 0; e < b.n_tets(); ++e) mesh.tets.emplace_back(b.tets[4 * e], b.tets[4 * e + 1], b.tets[4 * e + 2], b.tets[4 * e + 3]);
    const CorotationalElements el = precompute_elements(mesh, Material{5e4, 0.3, 1000});
    const StiffnessPattern pat = build_stiffness_pattern(mesh);
    std::mt19937 rng(seed);
    std::normal_distribution<double> n(0, 1);
    std::vector<Mat3> rot;
    for (size_t e = 0; e < mesh.tets.size(); ++e) rot.push_back(quat_to_matrix(Vec4(n(rng), n(rng), n(rng), n(rng)).normalized()));
    SpMat a = pat.matrix;
    add_warped_stiffness(el, rot, pat, 1e-3, a.valuePtr());
    const VecX m = lumped_masses(mesh, el, 1000);
    for (int i = 0; i < mesh.n_nodes; ++i)
        for (int c = 0; c < 3; ++c) a.coeffRef(3 * i + c, 3 * i + c) += m[i];
    return a;
}
}  // namespace

TEST(block_ldlt_solves_like_a_dense_solver) {
    for (unsigned seed : {1u, 2u}) {
        const SpMat a = system_matrix(4, 3, 3, seed);
        BlockLDLT f;
        f.analyze(a);
        f.factorize(a);
        std::mt19937 rng(seed);
        std::normal_distribution<double> n(0, 1);
        VecX b(a.rows());
        for (int i = 0; i < b.size(); ++i) b[i] = n(rng);
        const VecX x = f.solve(b);
        const VecX dense = MatX(a).ldlt().solve(b);
        CHECK_LT((x - dense).norm() / dense.norm(), 1e-12);
        CHECK_LT((a * x - b).norm() / b.norm(), 1e-12);
    }
}

TEST(block_ldlt_refactorizes_with_new_values) {
    const SpMat a1 = system_matrix(3, 3, 2, 5), a2 = system_matrix(3, 3, 2, 6);
    BlockLDLT f;
    f.analyze(a1);
    f.factorize(a1);
    f.factorize(a2);  // same pattern, new values: the analysis is reused
    VecX b = VecX::Ones(a2.rows());
    CHECK_LT((a2 * f.solve(b) - b).norm() / b.norm(), 1e-12);
}

TEST(block_ldlt_rejects_an_indefinite_matrix) {
    SpMat a = system_matrix(2, 2, 2, 7);
    for (int i = 0; i < a.rows(); ++i) a.coeffRef(i, i) -= 1e6;
    BlockLDLT f;
    f.analyze(a);
    bool thrown = false;
    try {
        f.factorize(a);
    } catch (const NumericalError&) {
        thrown = true;
    }
    CHECK(thrown);
}

TEST(block_ldlt_solves_many_right_hand_sides_at_once) {
    const SpMat a = system_matrix(4, 3, 3, 3);
    BlockLDLT f;
    f.analyze(a);
    f.factorize(a);
    std::mt19937 rng(4);
    std::normal_distribution<double> n(0, 1);
    // 1, 4 and 8 fill the kernels exactly; 2, 3, 5-7 are padded; 9 and 17 take several passes
    for (int k : {1, 2, 3, 4, 5, 7, 8, 9, 17}) {
        MatX b(a.rows(), k);
        for (int i = 0; i < b.size(); ++i) b.data()[i] = n(rng);
        MatX x = b;
        f.solve(x);
        for (int j = 0; j < k; ++j) {
            const VecX single = f.solve(VecX(b.col(j)));
            CHECK_LT((x.col(j) - single).norm() / single.norm(), 1e-13);
            CHECK_LT((a * x.col(j) - b.col(j)).norm() / b.col(j).norm(), 1e-12);
        }
    }
}

TEST(block_ldlt_warped_solve_inverts_the_rotated_matrix) {
    // x = W A^-1 W^T b solves (W A W^T) x = b for a block-diagonal rotation W
    const SpMat a = system_matrix(3, 3, 2, 8);
    const int n = static_cast<int>(a.rows() / 3);
    BlockLDLT f;
    f.analyze(a);
    f.factorize(a);
    std::mt19937 rng(9);
    std::normal_distribution<double> g(0, 1);
    std::vector<Mat3> w(n);
    MatX wd = MatX::Zero(a.rows(), a.rows());
    for (int i = 0; i < n; ++i) {
        w[i] = quat_to_matrix(Vec4(g(rng), g(rng), g(rng), g(rng)).normalized());
        wd.block<3, 3>(3 * i, 3 * i) = w[i];
    }
    const MatX rotated = wd * MatX(a) * wd.transpose();
    MatX b(a.rows(), 6);
    for (int i = 0; i < b.size(); ++i) b.data()[i] = g(rng);
    MatX x = b;
    f.solve(x, &w);
    const MatX dense = rotated.ldlt().solve(b);
    CHECK_LT((x - dense).norm() / dense.norm(), 1e-12);
    CHECK_LT((rotated * x - b).norm() / b.norm(), 1e-12);
    // node-major storage, width 4 (3 columns and a zero one)
    std::vector<double> nm(3 * n * 4, 0.0);
    for (int e = 0; e < 3 * n; ++e)
        for (int j = 0; j < 3; ++j) nm[4 * e + j] = b(e, j);
    f.solve_node_major(nm.data(), 4, &w);
    double diff = 0;
    for (int e = 0; e < 3 * n; ++e) {
        for (int j = 0; j < 3; ++j) diff = std::max(diff, std::abs(nm[4 * e + j] - x(e, j)));
        CHECK(nm[4 * e + 3] == 0.0);
    }
    CHECK_LT(diff / x.leftCols(3).cwiseAbs().maxCoeff(), 1e-13);
}
