// Co-rotational elasticity: invariance to rigid motion, agreement with linear FEM for small
// strains, symmetric element stiffness, lumped masses that add up to the body's mass.
#include <algorithm>
#include <array>
#include <map>
#include <random>

#include "box_mesh.h"
#include "check.h"
#include "common/simd.h"
#include "fem/corotational.h"
#include "fem/element_order.h"
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

TEST(fused_assembly_equals_forces_plus_warped_stiffness) {
    // assemble_corotational (the per-step path) against add_elastic_forces + add_warped_stiffness
    // on a box rotated, stretched and sheared, over several steps of warm-started rotations,
    // including an inverted element (in the first SIMD batch), at every SIMD level the CPU has:
    // the batched element pass (4 or 8 lanes, the last elements scalar) must agree with the
    // scalar one to round-off. The box has 5 x 3 x 3 x 6 = 270 tets: not a multiple of 4 or 8.
    const TetMesh mesh = to_mesh(make_box(5, 3, 3, 0.01));
    const CorotationalElements el = precompute_elements(mesh, flesh);
    const StiffnessPattern pat = build_stiffness_pattern(mesh);
    for (int level = 0; level <= detected_simd_level(); ++level) {
    simd_level_override() = level;
    std::mt19937 rng(41);
    std::normal_distribution<double> n(0, 1);
    ElementRotations fused, reference;
    for (int step = 0; step < 4; ++step) {
        const Mat3 r = quat_to_matrix(quat_from_rotation_vector(Vec3(0.3 * step, 0.2, -0.1 * step)));
        Mat3 stretch = Mat3::Identity();
        stretch(0, 0) = 1.0 + 0.05 * step;
        stretch(0, 1) = 0.03;
        VecX x(mesh.rest.size());
        for (int i = 0; i < mesh.n_nodes; ++i)
            x.segment<3>(3 * i) = r * stretch * mesh.rest.segment<3>(3 * i) + 1e-4 * Vec3(n(rng), n(rng), n(rng));
        if (step == 3) {  // invert element 0 by pushing its node 0 through the opposite face
            const auto& t = mesh.tets[0];
            const Vec3 c = (x.segment<3>(3 * t[1]) + x.segment<3>(3 * t[2]) + x.segment<3>(3 * t[3])) / 3;
            x.segment<3>(3 * t[0]) = c + 0.5 * (c - x.segment<3>(3 * t[0]));
        }
        VecX f1 = VecX::Zero(x.size()), f2 = VecX::Zero(x.size());
        SpMat k1 = pat.matrix, k2 = pat.matrix;
        const double e1 = assemble_corotational(mesh, el, x, f1, fused, pat, 0.7, k1.valuePtr());
        const double e2 = add_elastic_forces(mesh, el, x, f2, &reference);
        add_warped_stiffness(el, reference.r, pat, 0.7, k2.valuePtr());
        CHECK_LT((f1 - f2).cwiseAbs().maxCoeff() / f2.cwiseAbs().maxCoeff(), 1e-12);
        CHECK_LT(std::abs(e1 - e2) / std::abs(e2), 1e-12);
        const double kscale = Eigen::Map<const VecX>(k2.valuePtr(), k2.nonZeros()).cwiseAbs().maxCoeff();
        CHECK(kscale > 0);
        CHECK_LT((MatX(k1) - MatX(k2)).cwiseAbs().maxCoeff() / kscale, 1e-13);
        for (size_t e = 0; e < mesh.tets.size(); ++e) CHECK_LT((fused.r[e] - reference.r[e]).cwiseAbs().maxCoeff(), 1e-12);
    }
    }
    simd_level_override() = -1;
}

TEST(spatial_element_order_keeps_every_element_and_the_forces) {
    // order_elements_spatially permutes the elements with their data: the same tets (as node
    // sets) with the same volumes and rest inverses, consecutive elements mostly sharing nodes,
    // and the assembled forces and matrix equal to the user's order up to summation round-off
    // the user's order: the box's tets shuffled (a tetrahedralizer's order is far from local)
    TetMesh user = to_mesh(make_box(6, 4, 3, 0.01));
    std::mt19937 shuffle_rng(7);
    std::shuffle(user.tets.begin(), user.tets.end(), shuffle_rng);
    const CorotationalElements user_el = precompute_elements(user, flesh);
    TetMesh sorted = user;
    CorotationalElements sorted_el = user_el;
    order_elements_spatially(sorted, sorted_el);
    CHECK(sorted.tets.size() == user.tets.size());
    std::map<std::array<int, 4>, size_t> where;
    for (size_t e = 0; e < user.tets.size(); ++e) {
        std::array<int, 4> key{user.tets[e][0], user.tets[e][1], user.tets[e][2], user.tets[e][3]};
        where[key] = e;
    }
    int shared = 0;
    for (size_t e = 0; e < sorted.tets.size(); ++e) {
        std::array<int, 4> key{sorted.tets[e][0], sorted.tets[e][1], sorted.tets[e][2], sorted.tets[e][3]};
        const auto it = where.find(key);
        CHECK(it != where.end());
        if (it == where.end()) continue;
        CHECK(sorted_el.volume[e] == user_el.volume[it->second]);
        CHECK((sorted_el.rest_inverse[e] - user_el.rest_inverse[it->second]).cwiseAbs().maxCoeff() == 0);
        where.erase(it);  // each user element used once
        if (e > 0) {
            bool any = false;
            for (int a = 0; a < 4; ++a)
                for (int b = 0; b < 4; ++b) any = any || sorted.tets[e][a] == sorted.tets[e - 1][b];
            shared += any;
        }
    }
    CHECK(where.empty());
    int shared_user = 0;  // the same count in the shuffled order
    for (size_t e = 1; e < user.tets.size(); ++e) {
        bool any = false;
        for (int a = 0; a < 4; ++a)
            for (int b = 0; b < 4; ++b) any = any || user.tets[e][a] == user.tets[e - 1][b];
        shared_user += any;
    }
    // along the Morton curve most neighbours in the order are neighbours in space
    CHECK_LT(0.75 * (sorted.tets.size() - 1), static_cast<double>(shared));
    CHECK_LT(2.0 * shared_user, static_cast<double>(shared));
    const StiffnessPattern pu = build_stiffness_pattern(user), ps = build_stiffness_pattern(sorted);
    const Mat3 r = quat_to_matrix(quat_from_rotation_vector(Vec3(0.4, -0.2, 0.3)));
    VecX x(user.rest.size());
    for (int i = 0; i < user.n_nodes; ++i) x.segment<3>(3 * i) = r * (1.1 * user.rest.segment<3>(3 * i));
    VecX fu = VecX::Zero(x.size()), fs = VecX::Zero(x.size());
    SpMat ku = pu.matrix, ks = ps.matrix;
    ElementRotations ru, rs;
    assemble_corotational(user, user_el, x, fu, ru, pu, 0.5, ku.valuePtr());
    assemble_corotational(sorted, sorted_el, x, fs, rs, ps, 0.5, ks.valuePtr());
    CHECK_LT((fu - fs).cwiseAbs().maxCoeff() / fu.cwiseAbs().maxCoeff(), 1e-12);
    CHECK_LT((MatX(ku) - MatX(ks)).cwiseAbs().maxCoeff() / MatX(ku).cwiseAbs().maxCoeff(), 1e-12);
}

TEST(element_pass_in_parts_equals_the_whole_pass_bit_for_bit) {
    // split_element_pass: A and B share no node, every element is in one part, A and B about
    // equal; the parts run in turn (A's and B's nodes zeroed by their own part) give exactly
    // the whole pass over the same order, as the sums into each entry come in the same order
    TetMesh mesh = to_mesh(make_box(9, 6, 5, 0.01));
    CorotationalElements el = precompute_elements(mesh, flesh);
    order_elements_spatially(mesh, el);
    const ElementPassParts parts = split_element_pass(mesh, el, mesh.n_nodes);
    const size_t m = mesh.tets.size();
    CHECK(parts.end[2] == m);
    CHECK(parts.end[0] <= parts.end[1] && parts.end[1] <= parts.end[2]);
    const double a = static_cast<double>(parts.end[0]), b = static_cast<double>(parts.end[1] - parts.end[0]);
    CHECK_LT(std::abs(a - b), 0.1 * m);         // balanced
    CHECK_LT(static_cast<double>(m - parts.end[1]), 0.4 * m);  // the seam is the smaller part
    std::vector<int> owner(mesh.n_nodes, -1);
    for (int k = 0; k < 2; ++k)
        for (int i : parts.owned_nodes[k]) {
            CHECK(owner[i] == -1);
            owner[i] = k;
        }
    for (int i = 0; i < mesh.n_nodes; ++i) CHECK(owner[i] >= 0);
    for (size_t e = 0; e < parts.end[1]; ++e)
        for (int k = 0; k < 4; ++k) CHECK(owner[mesh.tets[e][k]] == (e < parts.end[0] ? 0 : 1));
    const StiffnessPattern pattern = build_stiffness_pattern(mesh);
    const Mat3 r = quat_to_matrix(quat_from_rotation_vector(Vec3(0.3, 0.5, -0.2)));
    VecX x(mesh.rest.size());
    for (int i = 0; i < mesh.n_nodes; ++i) x.segment<3>(3 * i) = r * (Vec3(1.05, 0.97, 1.02).asDiagonal() * mesh.rest.segment<3>(3 * i));
    VecX f_whole = VecX::Zero(x.size());
    SpMat k_whole = pattern.matrix;
    ElementRotations r_whole;
    const double e_whole = assemble_corotational(mesh, el, x, f_whole, r_whole, pattern, 0.5, k_whole.valuePtr());
    // the parts, on garbage-filled outputs: each part must zero what it owns
    VecX f_parts = VecX::Constant(x.size(), 7.0);
    SpMat k_parts = pattern.matrix;
    std::fill(k_parts.valuePtr(), k_parts.valuePtr() + k_parts.nonZeros(), 3.0);
    ElementRotations r_parts;
    size_rotations(r_parts, m);
    double e_parts = 0;
    for (int part = 0; part < 3; ++part) {
        if (part < 2)
            for (int i : parts.owned_nodes[part]) {
                std::fill(k_parts.valuePtr() + k_parts.outerIndexPtr()[3 * i], k_parts.valuePtr() + k_parts.outerIndexPtr()[3 * i + 3], 0.0);
                f_parts.segment<3>(3 * i).setZero();
            }
        e_parts += assemble_corotational(mesh, el, x, f_parts, r_parts, pattern, 0.5, k_parts.valuePtr(),
                                         part == 0 ? 0 : parts.end[part - 1], parts.end[part]);
    }
    CHECK((f_whole - f_parts).cwiseAbs().maxCoeff() == 0);
    CHECK(std::equal(k_whole.valuePtr(), k_whole.valuePtr() + k_whole.nonZeros(), k_parts.valuePtr()));
    CHECK_LT(std::abs(e_whole - e_parts), 1e-12 * std::abs(e_whole));  // (the energy's sum is split in three)
}

TEST(polar_rotation_is_the_rotation_of_the_polar_decomposition) {
    // against the SVD, from cold (identity) and warm starts, small and large rotations
    std::mt19937 rng(43);
    std::normal_distribution<double> n(0, 1);
    for (int trial = 0; trial < 200; ++trial) {
        const Mat3 r = quat_to_matrix(Vec4(n(rng), n(rng), n(rng), n(rng)).normalized());
        Mat3 s = Mat3::Identity();
        for (int i = 0; i < 3; ++i)
            for (int j = 0; j <= i; ++j) s(i, j) = s(j, i) = s(i, j) + 0.2 * n(rng);
        s = s * s.transpose() + 0.1 * Mat3::Identity();  // symmetric positive definite stretch
        const Mat3 f = r * s;
        Eigen::JacobiSVD<Mat3> svd(f, Eigen::ComputeFullU | Eigen::ComputeFullV);
        const Mat3 expected = svd.matrixU() * svd.matrixV().transpose();
        Vec4 cold = quat_identity();
        Vec4 warm = quat_multiply(quat_from_rotation_vector(Vec3(0.01 * n(rng), 0.01 * n(rng), 0.01 * n(rng))), quat_from_matrix(expected));
        // from identity the first steps may be the scaled (non-Newton) ones: ~1e-9 left, as before
        CHECK_LT((polar_rotation(f, cold) - expected).cwiseAbs().maxCoeff(), 1e-8);
        CHECK_LT((polar_rotation(f, warm) - expected).cwiseAbs().maxCoeff(), 1e-12);
        CHECK_LT(std::abs(warm.norm() - 1), 1e-14);
    }
}

namespace {
// An SVD independent of the engine's (Eigen's two-sided Jacobi): one-sided Jacobi (Hestenes
// 1958), plane rotations V from the right until the columns of A = F V are orthogonal; then
// sigma_i = |a_i| and u_i = a_i / sigma_i (so det U V^T has the sign of det F).
void hestenes_svd(const Mat3& f, Mat3& u, Vec3& sigma, Mat3& v) {
    Mat3 a = f;
    v.setIdentity();
    for (int sweep = 0; sweep < 60; ++sweep) {
        double off = 0;
        for (int p = 0; p < 2; ++p)
            for (int q = p + 1; q < 3; ++q) {
                const double alpha = a.col(p).squaredNorm(), beta = a.col(q).squaredNorm(), gamma = a.col(p).dot(a.col(q));
                if (gamma == 0) continue;
                off = std::max(off, std::abs(gamma) / std::sqrt(alpha * beta));
                const double zeta = (beta - alpha) / (2 * gamma);
                const double t = (zeta >= 0 ? 1.0 : -1.0) / (std::abs(zeta) + std::sqrt(1 + zeta * zeta));
                const double c = 1 / std::sqrt(1 + t * t), s = c * t;
                const Vec3 ap = a.col(p), aq = a.col(q), vp = v.col(p), vq = v.col(q);
                a.col(p) = c * ap - s * aq;
                a.col(q) = s * ap + c * aq;
                v.col(p) = c * vp - s * vq;
                v.col(q) = s * vp + c * vq;
            }
        if (off < 1e-15) break;
    }
    for (int i = 0; i < 3; ++i) {
        sigma[i] = a.col(i).norm();
        u.col(i) = a.col(i) / sigma[i];
    }
}

// The proper rotation maximizing trace(R^T F): U V^T, with the direction of the smallest
// singular value flipped when F is inverted.
Mat3 reference_rotation(const Mat3& f) {
    Mat3 u, v;
    Vec3 sigma;
    hestenes_svd(f, u, sigma, v);
    if (f.determinant() < 0) {
        int k = 0;
        sigma.minCoeff(&k);
        u.col(k) = -u.col(k);
    }
    return u * v.transpose();
}

Mat3 random_rotation(std::mt19937& rng) {
    std::normal_distribution<double> n(0, 1);
    return quat_to_matrix(Vec4(n(rng), n(rng), n(rng), n(rng)).normalized());
}

// A large deformation F = R1 diag(s) R2^T, stretches 0.2..3, inverted (one s negative) one
// time in three, with the rotation well defined: the two singular values that decide it (the
// pair sums for a proper F, s2 - |s3| for an inverted one) at least 0.05 apart.
Mat3 random_large_deformation(std::mt19937& rng) {
    std::uniform_real_distribution<double> u(0, 1);
    for (;;) {
        Vec3 s;
        for (int i = 0; i < 3; ++i) s[i] = 0.2 * std::pow(15.0, u(rng));
        Vec3 sorted = s;
        std::sort(sorted.data(), sorted.data() + 3);
        const bool inverted = u(rng) < 1.0 / 3;
        if (inverted && sorted[1] - sorted[0] < 0.05) continue;
        if (inverted) s[std::min_element(s.data(), s.data() + 3) - s.data()] *= -1;
        return random_rotation(rng) * s.asDiagonal() * random_rotation(rng).transpose();
    }
}

// Disjoint tets (each its own four nodes, 1 cm legs) whose deformation gradients are fs.
TetMesh separate_tets(const std::vector<Mat3>& fs, VecX& x) {
    TetMesh mesh;
    mesh.n_nodes = 4 * static_cast<int>(fs.size());
    mesh.rest = VecX::Zero(3 * mesh.n_nodes);
    x = VecX::Zero(3 * mesh.n_nodes);
    for (size_t e = 0; e < fs.size(); ++e) {
        const Vec3 origin(0.05 * (e % 40), 0.05 * (e / 40), 0);
        const int n0 = 4 * static_cast<int>(e);
        for (int a = 0; a < 4; ++a) {
            const Vec3 leg = a == 0 ? Vec3::Zero() : Vec3(0.01 * Vec3::Unit(a - 1));
            mesh.rest.segment<3>(3 * (n0 + a)) = origin + leg;
            x.segment<3>(3 * (n0 + a)) = Vec3(0.3, -0.2, 0.1) + fs[e] * leg;
        }
        mesh.tets.emplace_back(n0, n0 + 1, n0 + 2, n0 + 3);
    }
    return mesh;
}
}  // namespace

TEST(polar_rotation_is_right_for_any_large_deformation_from_any_start) {
    // Thousands of random large deformations (stretch 0.2..3, a third inverted, every rotation)
    // and pure rotations up to 180 degrees, each from four starts: the identity, a random
    // rotation, the answer itself, and the worst: a saddle of trace(R^T F) (the answer turned
    // by 180 degrees about a singular direction, where the gradient is zero). Through the
    // element pass at every SIMD level the CPU has (lanes and the scalar tail) and through
    // polar_rotation itself, against the independent one-sided Jacobi SVD above.
    std::mt19937 rng(2011);
    std::normal_distribution<double> n(0, 1);
    std::vector<Mat3> fs;
    for (int k = 0; k < 1500; ++k) fs.push_back(random_large_deformation(rng));
    for (int k = 0; k < 500; ++k) {  // rotated, barely deformed: the hand after a state jump
        Mat3 noise;
        for (int i = 0; i < 9; ++i) noise(i) = 0.05 * n(rng);
        fs.push_back(random_rotation(rng) * (Mat3::Identity() + noise));
    }
    fs.push_back(quat_to_matrix(quat_from_rotation_vector(Vec3(M_PI, 0, 0))));  // exactly 180 degrees
    std::vector<Mat3> expected;
    for (const Mat3& f : fs) expected.push_back(reference_rotation(f));
    auto start = [&](size_t e, int kind) -> Vec4 {
        if (kind == 0) return quat_identity();
        if (kind == 1) return quat_from_matrix(random_rotation(rng));
        if (kind == 2) return quat_from_matrix(expected[e]);
        Mat3 u, v;
        Vec3 sigma;
        hestenes_svd(fs[e], u, sigma, v);
        const Vec3 axis = v.col(static_cast<int>(e % 3));  // turned about a singular direction
        return quat_from_matrix(expected[e] * quat_to_matrix(quat_from_rotation_vector(M_PI * axis)));
    };
    VecX x;
    const TetMesh mesh = separate_tets(fs, x);
    const CorotationalElements el = precompute_elements(mesh, flesh);
    const StiffnessPattern pat = build_stiffness_pattern(mesh);
    int checked = 0;
    double worst = 0;
    for (int kind = 0; kind < 4; ++kind)
        for (int level = -1; level <= detected_simd_level(); ++level) {  // -1: polar_rotation itself
            if (level >= 0) simd_level_override() = level;
            ElementRotations rot;
            size_rotations(rot, fs.size());
            for (size_t e = 0; e < fs.size(); ++e) rot.q[e] = start(e, kind);
            if (level >= 0) {
                VecX f = VecX::Zero(x.size());
                SpMat k = pat.matrix;
                assemble_corotational(mesh, el, x, f, rot, pat, 1.0, k.valuePtr(), 0, fs.size());
            } else {
                for (size_t e = 0; e < fs.size(); ++e)
                    rot.r[e] = polar_rotation(deformation_gradient(mesh, el, static_cast<int>(e), x), rot.q[e]);
            }
            for (size_t e = 0; e < fs.size(); ++e) {
                const double err = (rot.r[e] - expected[e]).cwiseAbs().maxCoeff();
                worst = std::max(worst, err);
                CHECK_LT(err, 1e-8);
                CHECK_LT((quat_to_matrix(rot.q[e]) - rot.r[e]).cwiseAbs().maxCoeff(), 1e-12);  // the warm start kept
                ++checked;
            }
        }
    simd_level_override() = -1;
    CHECK(checked >= 4 * 2 * 2001);
    std::printf("  %d rotations, largest error %.2g\n", checked, worst);
}
