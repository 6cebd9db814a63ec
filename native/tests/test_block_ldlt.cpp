// The block LDL^T solver against a dense solve, on the warped-stiffness systems it is built for.
#include <algorithm>
#include <cmath>
#include <cstring>
#include <functional>
#include <limits>
#include <random>
#include <thread>

#include "box_mesh.h"
#include "check.h"
#include "fem/corotational.h"
#include "rigid/quaternion.h"
#include "solver/block_ldlt.h"
#include "solver/panel_kernels.h"

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

// n random rotations (a warp: one per node), and the same as a dense block-diagonal matrix
std::vector<Mat3> random_rotations(int n, std::mt19937& rng) {
    std::normal_distribution<double> g(0, 1);
    std::vector<Mat3> w(n);
    for (int i = 0; i < n; ++i) w[i] = quat_to_matrix(Vec4(g(rng), g(rng), g(rng), g(rng)).normalized());
    return w;
}
MatX block_diagonal(const std::vector<Mat3>& w) {
    MatX out = MatX::Zero(3 * static_cast<Eigen::Index>(w.size()), 3 * static_cast<Eigen::Index>(w.size()));
    for (size_t i = 0; i < w.size(); ++i) out.block<3, 3>(3 * i, 3 * i) = w[i];
    return out;
}

// keep_half: with the half- and single-precision copies of the panels (supernodal form)
BlockLDLT factored(const SpMat& a, bool supernodal, bool keep_half = false) {
    BlockLDLT f;
    f.set_supernodal(supernodal);
    f.set_keep_half(keep_half);
    f.analyze(a);
    f.factorize(a);
    return f;
}

// Beside's two ways (common/beside.h): a thread for the other job, or one after the other
void side_by_side(const std::function<void()>& mine, const std::function<void()>& other) {
    std::thread t(other);
    mine();
    t.join();
}
void one_after_the_other(const std::function<void()>& mine, const std::function<void()>& other) {
    mine();
    other();
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
    const std::vector<Mat3> w = random_rotations(n, rng);
    const MatX wd = block_diagonal(w);
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

// ---- supernodal form, single-precision copy, SIMD levels, node-major products ----------------

namespace {
// node-major packing of the columns of b into width w (zero-padded)
std::vector<double> node_major(const MatX& b, int w) {
    std::vector<double> out(static_cast<size_t>(b.rows()) * w, 0.0);
    for (Eigen::Index e = 0; e < b.rows(); ++e)
        for (Eigen::Index j = 0; j < b.cols(); ++j) out[w * e + j] = b(e, j);
    return out;
}
double max_abs_diff(const std::vector<double>& nm, const MatX& x, int w) {
    double d = 0;
    for (Eigen::Index e = 0; e < x.rows(); ++e)
        for (Eigen::Index j = 0; j < x.cols(); ++j) d = std::max(d, std::abs(nm[w * e + j] - x(e, j)));
    return d;
}
// A pass in float arithmetic against its exact operator, relative: 2^-24 a rounding, and a
// row's value goes through a few dozen roundings (its supernode's columns, its updates)
constexpr double kFloatPassBound = 32 * 5.96e-8;
// max |x - reference| over max |reference| (infinite for a zero reference: no test passes on it)
double max_relative_difference(const std::vector<double>& x, const std::vector<double>& reference) {
    double diff = 0, size = 0;
    for (size_t e = 0; e < x.size(); ++e) {
        diff = std::max(diff, std::abs(x[e] - reference[e]));
        size = std::max(size, std::abs(reference[e]));
    }
    return size > 0 ? diff / size : std::numeric_limits<double>::infinity();
}
}  // namespace

TEST(supernodal_factor_solves_like_a_dense_solver_at_every_simd_level) {
    // a box large enough for supernodes several nodes wide (and the 8-column groups of the
    // kernels, with remainders), every width, with and without a warp, double and single (the
    // half-precision panels run here too, for their padding lanes; their accuracy: below)
    const SpMat a = system_matrix(7, 5, 4, 11);
    const int n = static_cast<int>(a.rows() / 3);
    BlockLDLT f;
    f.set_supernodal(true);
    f.set_keep_single(true);
    f.set_keep_half(true);
    f.analyze(a);
    f.factorize(a);
    CHECK(f.supernodes() < n);  // some supernodes hold several nodes
    CHECK(f.has_single());
    CHECK(f.has_half() == has_f16c());
    std::mt19937 rng(12);
    std::normal_distribution<double> g(0, 1);
    const std::vector<Mat3> w = random_rotations(n, rng);
    const MatX wd = block_diagonal(w);
    const MatX dense_a = MatX(a);
    const Eigen::LDLT<MatX> plain(dense_a);

    const Eigen::LDLT<MatX> rotated(wd * dense_a * wd.transpose());
    for (int level = 0; level <= detected_simd_level(); ++level) {
        simd_level_override() = level;
        for (int width : {1, 4, 8})
            for (int cols : {1, 3, 8}) {
                if (cols > width) continue;
                MatX b(a.rows(), cols);
                for (int i = 0; i < b.size(); ++i) b.data()[i] = g(rng);
                for (bool warped : {false, true}) {
                    const MatX exact = warped ? MatX(rotated.solve(b)) : MatX(plain.solve(b));
                    const double scale = exact.cwiseAbs().maxCoeff();
                    for (Panels panels : {Panels::Double, Panels::Single, Panels::Half}) {
                        std::vector<double> nm = node_major(b, width);
                        f.solve_node_major(nm.data(), width, warped ? &w : nullptr, panels);
                        const double err = max_abs_diff(nm, exact, width) / scale;
                        if (panels == Panels::Half) continue;  // (its bound: the next test)
                        // single: the inverse of a matrix within float round-off of A
                        CHECK_LT(err, panels == Panels::Single ? 1e-4 : 1e-12);
                        for (Eigen::Index e = 0; e < b.rows(); ++e)  // padding lanes stay zero
                            for (int j = cols; j < width; ++j) CHECK(nm[width * e + j] == 0.0);
                    }
                }
            }
    }
    simd_level_override() = -1;
}

TEST(half_precision_passes_apply_the_inverse_of_the_rounded_factor) {
    // A half pass applies W P^T (L_h L_h^T)^-1 P W^T, with L_h each scalar column of L below the
    // diagonal rounded to binary16 over the column's largest magnitude c_k (solver/half.h) and
    // multiplied back, the diagonal L's own: every width (1, 4, 8) in float arithmetic at the
    // SIMD levels that have it (BlockLDLT::float_passes). Rebuilt here from a dense Cholesky of
    // the permuted matrix (the same L to round-off, so the same halves but with probability
    // ~1e-13 per entry), that operator must match the pass to the arithmetic's round-off, while
    // the pass departs from A^-1 by the halves' rounding.
    if (!has_f16c()) return;
    const SpMat a = system_matrix(7, 5, 4, 11);
    const int n = static_cast<int>(a.rows() / 3);
    BlockLDLT f;
    f.set_supernodal(true);
    f.set_keep_half(true);
    f.analyze(a);
    f.factorize(a);
    CHECK(f.has_half() && f.has_single());
    std::vector<int> perm(3 * n);  // permuted scalar row -> original
    for (int i = 0; i < n; ++i)
        for (int d = 0; d < 3; ++d) perm[3 * f.position(i) + d] = 3 * i + d;
    const MatX dense_a = MatX(a);
    MatX pa(3 * n, 3 * n);
    for (int r = 0; r < 3 * n; ++r)
        for (int c = 0; c < 3 * n; ++c) pa(r, c) = dense_a(perm[r], perm[c]);
    MatX lh = Eigen::LLT<MatX>(pa).matrixL();
    for (int k = 0; k < 3 * n; ++k) {
        const float scale = static_cast<float>(lh.col(k).cwiseAbs().maxCoeff());
        std::vector<Half> h(3 * n);
        to_half(lh.col(k).data(), h.size(), scale, h.data());
        for (int i = k + 1; i < 3 * n; ++i) {  // (the diagonal: the kernels divide by L's own)
            _Float16 v;
            std::memcpy(&v, &h[i], sizeof v);
            lh(i, k) = static_cast<double>(static_cast<float>(v)) * scale;
        }
    }
    const Eigen::LLT<MatX> rounded(lh * lh.transpose());  // (its factor is lh itself)
    std::mt19937 rng(5);
    std::normal_distribution<double> g(0, 1);
    const std::vector<Mat3> w = random_rotations(n, rng);
    const MatX wd = block_diagonal(w);
    const Eigen::LDLT<MatX> plain(dense_a);
    for (int level = 1; level <= detected_simd_level(); ++level) {
        simd_level_override() = level;
        for (int width : {1, 4, 8})
            for (bool warped : {false, true}) {
                MatX b(a.rows(), width);
                for (int i = 0; i < b.size(); ++i) b.data()[i] = g(rng);
                std::vector<double> nm = node_major(b, width);
                f.solve_node_major(nm.data(), width, warped ? &w : nullptr, Panels::Half);
                for (int j = 0; j < width; ++j) {
                    const VecX bw = warped ? VecX(wd.transpose() * b.col(j)) : VecX(b.col(j));
                    VecX pb(3 * n), px(3 * n), expected(3 * n);
                    for (int r = 0; r < 3 * n; ++r) pb[r] = bw[perm[r]];
                    px = rounded.solve(pb);
                    for (int r = 0; r < 3 * n; ++r) expected[perm[r]] = px[r];
                    if (warped) expected = wd * expected;
                    VecX x(a.rows());
                    for (Eigen::Index e = 0; e < x.size(); ++e) x[e] = nm[width * e + j];
                    // float: 2^-24 ~ 6e-8 a rounding, a few dozen of them along a row's passes
                    CHECK_LT((x - expected).norm() / expected.norm(), kFloatPassBound);
                    if (!warped)  // (the halves' rounding: far above double round-off)
                        CHECK((x - plain.solve(VecX(b.col(j)))).norm() / expected.norm() > 1e-6);
                }
            }
    }
    simd_level_override() = -1;
}

TEST(float_passes_on_the_float_panels_match_their_double_arithmetic) {
    // The 4- and 8-lane passes on the float panels run in float arithmetic where the CPU has
    // AVX2 (BlockLDLT::float_passes); at the baseline level the same panels are used in double
    // arithmetic, which applies the exact inverse of L_f L_f^T. The float passes must match it
    // to float round-off, and differ from it (the float kernels did run).
    if (detected_simd_level() == 0) return;
    const SpMat a = system_matrix(7, 5, 4, 11);
    const int n = static_cast<int>(a.rows() / 3);
    const BlockLDLT f = factored(a, true, true);  // (the half copy keeps the float one too)
    CHECK(f.has_single());
    std::mt19937 rng(21);
    std::normal_distribution<double> g(0, 1);
    const std::vector<Mat3> w = random_rotations(n, rng);
    for (int width : {4, 8})
        for (bool warped : {false, true}) {
            MatX b(a.rows(), width);
            for (int i = 0; i < b.size(); ++i) b.data()[i] = g(rng);
            std::vector<double> reference = node_major(b, width);
            simd_level_override() = 0;
            f.solve_node_major(reference.data(), width, warped ? &w : nullptr, Panels::Single);
            for (int level = 1; level <= detected_simd_level(); ++level) {
                simd_level_override() = level;
                std::vector<double> x = node_major(b, width);
                f.solve_node_major(x.data(), width, warped ? &w : nullptr, Panels::Single);
                CHECK_LT(max_relative_difference(x, reference), kFloatPassBound);
                CHECK(x != reference);
            }
        }
    simd_level_override() = -1;
}

TEST(supernodal_and_up_looking_factors_agree_and_refactorize) {
    const SpMat a1 = system_matrix(6, 4, 4, 21), a2 = system_matrix(6, 4, 4, 22);
    BlockLDLT up, sn;
    sn.set_supernodal(true);
    up.analyze(a1);
    sn.analyze(a1);
    std::mt19937 rng(23);
    std::normal_distribution<double> g(0, 1);
    int level = 0;
    for (const SpMat* a : {&a1, &a2, &a1, &a2}) {  // same pattern, new values: analysis reused
        simd_level_override() = level++ % (detected_simd_level() + 1);  // the update kernels too
        up.factorize(*a);
        sn.factorize(*a);
        MatX b(a->rows(), 5);
        for (int i = 0; i < b.size(); ++i) b.data()[i] = g(rng);
        MatX xu = b, xs = b;
        up.solve(xu);
        sn.solve(xs);
        CHECK_LT((xu - xs).cwiseAbs().maxCoeff() / xu.cwiseAbs().maxCoeff(), 1e-12);
        CHECK_LT((MatX(*a * xs) - b).norm() / b.norm(), 1e-12);
    }
    simd_level_override() = -1;
}

TEST(supernodal_factor_rejects_an_indefinite_matrix) {
    SpMat a = system_matrix(3, 3, 3, 7);
    for (int i = 0; i < a.rows(); ++i) a.coeffRef(i, i) -= 1e6;
    BlockLDLT f;
    f.set_supernodal(true);
    f.analyze(a);
    bool thrown = false;
    try {
        f.factorize(a);
    } catch (const NumericalError&) {
        thrown = true;
    }
    CHECK(thrown);
}

TEST(node_major_product_matches_the_sparse_product_at_every_simd_level) {
    const SpMat a = system_matrix(5, 4, 3, 31);
    CHECK(has_node_block_pattern(a));
    std::mt19937 rng(32);
    std::normal_distribution<double> g(0, 1);
    for (int level = 0; level <= detected_simd_level(); ++level) {
        simd_level_override() = level;
        for (int width : {1, 4, 8}) {
            MatX x(a.rows(), width);
            for (int i = 0; i < x.size(); ++i) x.data()[i] = g(rng);
            std::vector<double> nx = node_major(x, width), ny(nx.size());
            multiply_node_major(a, nx.data(), ny.data(), width);
            const MatX y = a * x;
            CHECK_LT(max_abs_diff(ny, y, width) / y.cwiseAbs().maxCoeff(), 1e-14);
            // in two ranges of nodes (the CG's product in two halves): the same bits, and each
            // range writes its own rows only
            const int n = static_cast<int>(a.rows() / 3), cut = n / 3;
            std::vector<double> halves(nx.size(), std::nan(""));
            multiply_node_major(a, nx.data(), halves.data(), width, 0, cut);
            for (size_t e = static_cast<size_t>(3) * width * cut; e < halves.size(); ++e) CHECK(std::isnan(halves[e]));
            multiply_node_major(a, nx.data(), halves.data(), width, cut, n);
            CHECK(halves == ny);
        }
    }
    simd_level_override() = -1;
    SpMat scalar(6, 6);  // not made of node blocks
    scalar.insert(0, 1) = 1;
    scalar.insert(1, 0) = 1;
    scalar.makeCompressed();
    CHECK(!has_node_block_pattern(scalar));
}

TEST(sparse_right_hand_sides_give_the_columns_of_the_inverse_in_both_forms) {
    // The forward passes skip nodes (up-looking) and supernodes whose values are all still zero.
    // Unit columns (the contact responses) touch only their elimination-tree paths: each
    // solve must still be the column of A^-1, at every SIMD level and width, with a unit
    // column of the first node, of the last and of nodes in between, alone and mixed with a
    // dense column.
    const SpMat a = system_matrix(7, 5, 4, 21);
    const MatX inverse = MatX(a).ldlt().solve(MatX::Identity(a.rows(), a.rows()));
    const double scale = inverse.cwiseAbs().maxCoeff();
    const int n3 = static_cast<int>(a.rows());
    std::mt19937 rng(22);
    std::normal_distribution<double> g(0, 1);
    VecX dense(n3);
    for (int i = 0; i < n3; ++i) dense[i] = g(rng);
    const VecX dense_solution = MatX(a).ldlt().solve(dense);
    for (bool supernodal : {false, true}) {
        const BlockLDLT f = factored(a, supernodal);
        for (int level = 0; level <= detected_simd_level(); ++level) {
            simd_level_override() = level;
            for (int width : {1, 4, 8}) {
                const std::vector<int> units = {0, n3 - 1, n3 / 2, 7, n3 / 3 + 1, 2 * n3 / 3, 40, n3 - 5};
                for (bool with_dense : {false, true}) {
                    MatX b = MatX::Zero(n3, width);
                    std::vector<int> col_unit(width, -1);
                    for (int j = 0; j < width; ++j) {
                        if (with_dense && j == width - 1) b.col(j) = dense;
                        else b(col_unit[j] = units[j % units.size()], j) = 1.0;
                    }
                    std::vector<double> nm = node_major(b, width);
                    f.solve_node_major(nm.data(), width, nullptr);
                    for (int j = 0; j < width; ++j) {
                        const VecX exact = col_unit[j] >= 0 ? VecX(inverse.col(col_unit[j])) : dense_solution;
                        double err = 0;
                        for (int e = 0; e < n3; ++e) err = std::max(err, std::abs(nm[width * e + j] - exact[e]));
                        CHECK_LT(err / std::max(scale, exact.cwiseAbs().maxCoeff()), 1e-12);
                    }
                }
            }
        }
        simd_level_override() = -1;
    }
}

TEST(solves_asked_for_some_nodes_give_those_rows_of_the_inverse_in_both_forms) {
    // With wanted nodes the backward pass runs over them and their elimination-tree ancestors
    // only (the contact responses need the inverse at a few touched nodes). Their rows must be
    // those of A^-1 b, for unit and dense columns, at every SIMD level and width, with and
    // without a warp; the wanted sets include a single node, the first and last nodes, and
    // nodes spread over the mesh; widths past one pass.
    const SpMat a = system_matrix(7, 5, 4, 23);
    const int n3 = static_cast<int>(a.rows()), n = n3 / 3;
    std::mt19937 rng(24);
    std::normal_distribution<double> g(0, 1);
    const std::vector<Mat3> warp = random_rotations(n, rng);
    const MatX wb = block_diagonal(warp);  // the warp as a matrix: x = W A^-1 W^T b
    const MatX inverse = MatX(a).ldlt().solve(MatX::Identity(n3, n3));
    const MatX warped_inverse = wb * inverse * wb.transpose();
    const std::vector<std::vector<int>> wanted_sets = {{n / 2}, {0, n - 1}, {3, 17, n / 3, 2 * n / 3, n - 7}};
    for (bool supernodal : {false, true}) {
        const BlockLDLT f = factored(a, supernodal);
        for (int level = 0; level <= detected_simd_level(); ++level) {
            simd_level_override() = level;
            // up to 8 columns a pass (up-looking), 16 or 32 (supernodal): padded widths, and
            // more columns than one pass takes
            for (int width : {1, 5, 8, 13, 32, 40}) {
                MatX b = MatX::Zero(n3, width);
                for (int j = 0; j < width; ++j) {
                    if (j % 2) b(std::min(n3 - 1, 3 * j * j + j), j) = 1.0;  // unit columns
                    else for (int e = 0; e < n3; ++e) b(e, j) = g(rng);
                }
                for (bool warped : {false, true}) {
                    const MatX exact = (warped ? warped_inverse : inverse) * b;
                    for (const auto& wanted : wanted_sets) {
                        MatX x = b;
                        f.solve(x, warped ? &warp : nullptr, &wanted);
                        for (int node : wanted)
                            for (int j = 0; j < width; ++j) {
                                const double scale = std::max(1.0, exact.col(j).cwiseAbs().maxCoeff());
                                CHECK_LT((x.block(3 * node, j, 3, 1) - exact.block(3 * node, j, 3, 1)).cwiseAbs().maxCoeff() / scale, 1e-12);
                            }
                    }
                }
            }
        }
        simd_level_override() = -1;
        // the rows not asked for are skipped, not computed: a single leaf node's request must
        // leave some row of a dense right-hand side's solution unsolved
        MatX b = MatX::Constant(n3, 1, 1.0), x = b;
        const std::vector<int> one = {0};
        f.solve(x, nullptr, &one);
        CHECK((x - inverse * b).cwiseAbs().maxCoeff() > 1e-6 * (inverse * b).cwiseAbs().maxCoeff());
    }
}

TEST(unit_solves_at_asked_rows_give_those_entries_of_the_inverse_in_both_forms) {
    // solve_units (the contact responses' path): unit right-hand sides placed straight in the
    // factor's node order and only the asked rows read back. Every entry must be A^-1's, at
    // every SIMD level, in both forms, for counts within one pass, padded, and past one pass;
    // the rows are a scattered set (not sorted, some of a node only) and the units among them.
    const SpMat a = system_matrix(7, 5, 4, 25);
    const int n3 = static_cast<int>(a.rows());
    const MatX inverse = MatX(a).ldlt().solve(MatX::Identity(n3, n3));
    const double scale = inverse.cwiseAbs().maxCoeff();
    std::vector<int> rows = {n3 - 1, 0, 1, 2, 3 * 17 + 1, n3 / 2, n3 / 3, 2 * n3 / 3 + 2, 100, 101, 59};
    std::vector<int> units;
    for (int j = 0; j < 80; ++j) units.push_back((37 * j + 5) % n3);
    std::vector<int> nodes;
    for (int r : rows) nodes.push_back(r / 3);
    for (int u : units) nodes.push_back(u / 3);
    std::sort(nodes.begin(), nodes.end());
    nodes.erase(std::unique(nodes.begin(), nodes.end()), nodes.end());
    for (bool supernodal : {false, true}) {
        const BlockLDLT f = factored(a, supernodal);
        for (int level = 0; level <= detected_simd_level(); ++level) {
            simd_level_override() = level;
            // (past one pass: several of one width, where only the nodes a pass can touch are
            // cleared between them, and a narrower last one)
            for (int k : {1, 3, 8, 13, 32, 40, 72}) {
                const long ld = static_cast<long>(rows.size()) + 2;  // a leading dimension past the rows
                std::vector<double> out(ld * k, 7.0);
                f.solve_units(units.data(), k, rows, nodes, out.data(), ld);
                for (int j = 0; j < k; ++j)
                    for (size_t r = 0; r < rows.size(); ++r)
                        CHECK_LT(std::abs(out[r + j * ld] - inverse(rows[r], units[j])) / scale, 1e-12);
                for (int j = 0; j < k; ++j) CHECK(out[rows.size() + j * ld] == 7.0);  // nothing written past the rows
            }
        }
        simd_level_override() = -1;
    }
}

TEST(unit_solves_leave_nothing_behind_for_the_next_call_on_any_factor) {
    // solve_units keeps its right-hand sides zero between calls (each pass clears what it left
    // nonzero) instead of clearing 3n x w values per call. Calls on two factors of different
    // sizes, with few wanted nodes, widths that change, and a call refused for a unit outside
    // the wanted nodes in between: every entry must still be A^-1's (a value left behind by an
    // earlier call would add to a later call's right-hand side).
    const SpMat a = system_matrix(7, 5, 4, 25), b = system_matrix(4, 4, 6, 7);
    struct Case {
        const SpMat* m;
        MatX inverse;
        double scale;
    };
    std::vector<Case> cases;
    for (const SpMat* m : {&a, &b}) {
        const int n3 = static_cast<int>(m->rows());
        MatX inverse = MatX(*m).ldlt().solve(MatX::Identity(n3, n3));
        const double scale = inverse.cwiseAbs().maxCoeff();
        cases.push_back({m, inverse, scale});
    }
    for (bool supernodal : {false, true}) {
        const BlockLDLT fa = factored(a, supernodal), fb = factored(b, supernodal);
        const BlockLDLT* factors[2] = {&fa, &fb};
        for (int call = 0; call < 24; ++call) {
            const int which = (call * 7 / 3) % 2;
            const Case& c = cases[which];
            const int n3 = static_cast<int>(c.m->rows());
            // a few nodes, different each call: their units and rows
            std::vector<int> nodes, units, rows;
            for (int q = 0; q < 2 + call % 4; ++q) nodes.push_back((11 * call + 17 * q + 3) % (n3 / 3));
            std::sort(nodes.begin(), nodes.end());
            nodes.erase(std::unique(nodes.begin(), nodes.end()), nodes.end());
            for (int node : nodes)
                for (int d = 0; d < 3; ++d) {
                    units.push_back(3 * node + d);
                    rows.push_back(3 * node + (d + call) % 3);
                }
            const int k = std::min(static_cast<int>(units.size()), 1 + (5 * call) % 12);
            const long ld = static_cast<long>(rows.size());
            if (call % 5 == 2) {
                // a unit outside the wanted nodes and their elimination-tree ancestors: refused
                // mid-call (its last unit). Nodes that are such ancestors are solved for anyway
                // (their values are cleared after the pass): those calls must be right.
                bool thrown = false;
                for (int node = 0; node < n3 / 3 && !thrown; ++node) {
                    if (std::binary_search(nodes.begin(), nodes.end(), node)) continue;
                    std::vector<int> stray(units.begin(), units.begin() + k);
                    stray[k - 1] = 3 * node + 1;
                    std::vector<double> out(ld * k, 7.0);
                    try {
                        factors[which]->solve_units(stray.data(), k, rows, nodes, out.data(), ld);
                        for (size_t r = 0; r < rows.size(); ++r)
                            CHECK_LT(std::abs(out[r + (k - 1) * ld] - c.inverse(rows[r], stray[k - 1])) / c.scale, 1e-12);
                    } catch (const std::logic_error&) {
                        thrown = true;
                    }
                }
                CHECK(thrown);
            }
            std::vector<double> out(ld * k, 7.0);
            factors[which]->solve_units(units.data(), k, rows, nodes, out.data(), ld);
            for (int j = 0; j < k; ++j)
                for (size_t r = 0; r < rows.size(); ++r)
                    CHECK_LT(std::abs(out[r + j * ld] - c.inverse(rows[r], units[j])) / c.scale, 1e-12);
        }
    }
}

TEST(panel_kernels_match_dense_products_and_cholesky_at_every_simd_level) {
    // the supernodal factorization's dense kernels on panels of every shape the blocking splits
    // differently (row and column remainders of the 24 x 8 register blocks, several column
    // blocks), against Eigen's dense product and LLT
    std::mt19937 rng(31);
    std::normal_distribution<double> g(0, 1);
    for (int level = 0; level <= detected_simd_level(); ++level) {
        simd_level_override() = level;
        for (int m : {1, 3, 8, 9, 17, 24, 25, 40, 51})
            for (int below : {0, 1, 7, 30}) {
                const int ld = m + below;
                MatX r(ld, m + 4);
                for (int i = 0; i < r.size(); ++i) r.data()[i] = g(rng);
                MatX full = r * r.transpose();  // ld x ld, SPD
                MatX panel = full.leftCols(m);
                for (int c = 0; c < m; ++c)  // only the lower part is read: poison the upper
                    for (int i = 0; i < c; ++i) panel(i, c) = std::nan("");
                CHECK(panel_cholesky(panel.data(), ld, m));
                const MatX l11 = MatX(full.topLeftCorner(m, m).llt().matrixL());
                const MatX l21 = full.bottomLeftCorner(below, m) * l11.transpose().inverse();
                const double scale = l11.cwiseAbs().maxCoeff();
                CHECK_LT((MatX(panel.topRows(m).triangularView<Eigen::Lower>()) - l11).cwiseAbs().maxCoeff(), 1e-12 * scale);
                if (below > 0) CHECK_LT((panel.bottomRows(below) - l21).cwiseAbs().maxCoeff(), 1e-10 * scale);
                // the update: C = A A(0:n)^T, checked on its lower part by 3x3 node blocks
                for (int n : {1, std::min(ld, 3), std::min(ld, 8), m}) {  // (n <= the rows, ld)
                    const int k = 1 + (m * 7 + n) % 23, lda = ld + 2;
                    MatX a(lda, k);
                    for (int i = 0; i < a.size(); ++i) a.data()[i] = g(rng);
                    MatX c = MatX::Constant(ld, n, 5.0);
                    panel_outer_product(a.data(), lda, ld, n, k, c.data());
                    const MatX exact = a.topRows(ld) * a.topRows(n).transpose();
                    for (int j = 0; j < n; ++j)
                        for (int i = j - j % 3; i < ld; ++i) CHECK_LT(std::abs(c(i, j) - exact(i, j)), 1e-12 * (1 + std::abs(exact(i, j))));
                }
            }
        // not positive definite: refused
        MatX bad = MatX::Identity(10, 10);
        bad(6, 6) = -1.0;
        CHECK(!panel_cholesky(bad.data(), 10, 10));
    }
    simd_level_override() = -1;
}

TEST(supernodal_factor_in_two_parts_is_the_same_side_by_side_or_not) {
    // a factor large enough to be split in two parts (whole subtrees) and the rest: the parts
    // run on two threads at once, one after the other, or inside factorize(), and the rest's
    // large supernodes take their updates in two shares, side by side or not, and the factor
    // (its solves) is the same bit for bit, and solves A
    const SpMat a = system_matrix(12, 8, 6, 41);
    BlockLDLT f;
    f.set_supernodal(true);
    f.analyze(a);
    CHECK(f.factor_parts() == 2);
    CHECK(f.rest_shares() > 0);
    std::mt19937 rng(42);
    std::normal_distribution<double> g(0, 1);
    MatX b(a.rows(), 3);
    for (int i = 0; i < b.size(); ++i) b.data()[i] = g(rng);
    f.factorize(a);
    MatX plain = b;
    f.solve(plain);
    CHECK_LT((MatX(a * plain) - b).norm() / b.norm(), 1e-12);
    for (int mode = 0; mode < 3; ++mode) {
        if (mode == 0) {
            f.factorize_part(a, 1);
            f.factorize_part(a, 0);
        } else if (mode == 1) {
            std::thread other([&] { f.factorize_part(a, 1); });
            f.factorize_part(a, 0);
            other.join();
        }
        f.factorize(a, mode == 2 ? Beside(side_by_side) : Beside());
        MatX x = b;
        f.solve(x);
        CHECK(x == plain);
    }
    // a part done for an earlier matrix is not reused after discard_parts()
    const SpMat a2 = system_matrix(12, 8, 6, 43);
    f.factorize_part(a, 0);
    f.discard_parts();
    f.factorize(a2);
    MatX x2 = b;
    f.solve(x2);
    CHECK_LT((MatX(a2 * x2) - b).norm() / b.norm(), 1e-12);
}

TEST(the_factors_single_and_half_copies_made_in_two_shares_side_by_side_are_the_same) {
    // BlockLDLT::make_single: the copies of the panels in single and half precision, in two
    // shares of the supernodes when factorize() is given `beside`. Two factors of the same
    // matrix, one made without `beside` and one with both shares on two threads: their passes
    // through each copy give the same bits (a share that missed a supernode would leave zeros
    // there), and the single copy's pass is the double one's to float round-off.
    const SpMat a = system_matrix(12, 8, 6, 47);
    BlockLDLT plain, shared;
    for (BlockLDLT* f : {&plain, &shared}) {
        f->set_supernodal(true);
        f->set_keep_single(true);
        f->set_keep_half(true);
        f->analyze(a);
    }
    plain.factorize(a);
    shared.factorize(a, side_by_side);
    CHECK(plain.has_single() && shared.has_single());
    CHECK(plain.has_half() == shared.has_half());
    std::mt19937 rng(48);
    std::normal_distribution<double> g(0, 1);
    MatX b(a.rows(), 1);
    for (int i = 0; i < b.size(); ++i) b.data()[i] = g(rng);
    std::vector<double> exact = node_major(b, 1);
    plain.solve_node_major(exact.data(), 1, nullptr, Panels::Double);
    std::vector<Panels> copies = {Panels::Single};
    if (plain.has_half()) copies.push_back(Panels::Half);
    for (Panels panels : copies) {
        std::vector<double> x = node_major(b, 1), y = x;
        plain.solve_node_major(x.data(), 1, nullptr, panels);
        shared.solve_node_major(y.data(), 1, nullptr, panels);
        CHECK(x == y);
        if (panels == Panels::Single) CHECK_LT(max_relative_difference(x, exact), 1e-4);
    }
}

TEST(a_solve_over_the_two_parts_side_by_side_is_the_plain_solve_to_round_off) {
    // solve_node_major_split: the parts' passes as two jobs, on two threads or one after the
    // other. The same bits either way, and the plain pass's result to round-off (only the rest's
    // rows sum the parts' contributions in another order), for dense and sparse right-hand
    // sides (the forward pass skips supernodes still zero), every copy of the panels, with and
    // without a warp. A factor without parts: the plain pass itself.
    const SpMat a = system_matrix(12, 8, 6, 41);
    const int n = static_cast<int>(a.rows() / 3);
    const BlockLDLT f = factored(a, true, true);
    CHECK(f.factor_parts() == 2);
    std::mt19937 rng(44);
    std::normal_distribution<double> g(0, 1);
    const std::vector<Mat3> w = random_rotations(n, rng);
    std::vector<Panels> copies = {Panels::Double, Panels::Single};
    if (f.has_half()) copies.push_back(Panels::Half);
    for (Panels panels : copies)
        for (int width : {1, 8})
            for (bool warped : {false, true})
                for (bool sparse : {false, true}) {
                    MatX b = MatX::Zero(a.rows(), width);
                    if (sparse) {
                        for (int node : {3, n / 2, n - 5})
                            for (int e = 0; e < 3 * width; ++e) b(3 * node + e % 3, e / 3) = g(rng);
                    } else {
                        for (int i = 0; i < b.size(); ++i) b.data()[i] = g(rng);
                    }
                    std::vector<double> plain = node_major(b, width), seq = plain, thr = plain;
                    f.solve_node_major(plain.data(), width, warped ? &w : nullptr, panels);
                    f.solve_node_major_split(seq.data(), width, warped ? &w : nullptr, panels, one_after_the_other);
                    f.solve_node_major_split(thr.data(), width, warped ? &w : nullptr, panels, side_by_side);
                    CHECK(seq == thr);
                    // the passes in float arithmetic (BlockLDLT::float_passes, where the CPU has AVX2)
                    const bool in_float = detected_simd_level() > 0 && (panels == Panels::Half ||
                                                                         (panels == Panels::Single && width > 1));
                    CHECK_LT(max_relative_difference(seq, plain), in_float ? kFloatPassBound : 1e-13);
                }
    const SpMat small = system_matrix(4, 3, 3, 45);
    const BlockLDLT s = factored(small, true);
    CHECK(s.factor_parts() == 0);
    MatX b(small.rows(), 1);
    for (int i = 0; i < b.size(); ++i) b.data()[i] = g(rng);
    std::vector<double> plain = node_major(b, 1), split = plain;
    s.solve_node_major(plain.data(), 1, nullptr);
    s.solve_node_major_split(split.data(), 1, nullptr, Panels::Double, side_by_side);
    CHECK(split == plain);
}
