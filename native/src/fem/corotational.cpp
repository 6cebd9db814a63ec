#include "fem/corotational.h"

#include "fem/corotational_simd.h"
#include "rigid/quaternion.h"

#include <algorithm>
#include <cmath>
#include <sstream>

namespace hh {

namespace {
Vec3 node(const VecX& x, int i) { return x.segment<3>(3 * i); }

// Gradients of the four linear shape functions: rows of Bm for nodes 1..3, minus their sum
// for node 0.
Eigen::Matrix<double, 4, 3> shape_gradients(const Mat3& bm) {
    Eigen::Matrix<double, 4, 3> g;
    g.bottomRows<3>() = bm;
    g.row(0) = -bm.colwise().sum();
    return g;
}
}  // namespace

double tet_signed_volume(const Vec3& x0, const Vec3& x1, const Vec3& x2, const Vec3& x3) {
    Mat3 d;
    d << x1 - x0, x2 - x0, x3 - x0;
    return d.determinant() / 6.0;
}

CorotationalElements precompute_elements(const TetMesh& mesh, const Material& material) {
    const double e_mod = material.young_modulus, nu = material.poisson_ratio;
    const double lambda = e_mod * nu / ((1 + nu) * (1 - 2 * nu));
    const double mu = e_mod / (2 * (1 + nu));
    CorotationalElements out;
    const size_t m = mesh.tets.size();
    out.rest_inverse.resize(m);
    out.volume.resize(m);
    out.stiffness.resize(m);
    out.gradients.resize(m);
    out.lambda = lambda;
    out.mu = mu;
    for (size_t e = 0; e < m; ++e) {
        const auto& t = mesh.tets[e];
        const Vec3 x0 = node(mesh.rest, t[0]);
        Mat3 dm;
        dm << node(mesh.rest, t[1]) - x0, node(mesh.rest, t[2]) - x0, node(mesh.rest, t[3]) - x0;
        const double vol = dm.determinant() / 6.0;
        double longest = 0;
        for (int a = 0; a < 4; ++a)
            for (int b = a + 1; b < 4; ++b)
                longest = std::max(longest, (node(mesh.rest, t[a]) - node(mesh.rest, t[b])).norm());
        // "zero volume" relative to the element's own size, so units and scale do not matter
        if (!(vol > 1e-9 * longest * longest * longest)) {
            std::ostringstream msg;
            msg << "tetrahedron " << e << " (nodes " << t[0] << ", " << t[1] << ", " << t[2] << ", "
                << t[3] << ") has " << (vol < 0 ? "negative volume (inverted)" : "zero volume")
                << ": signed volume " << vol
                << " m^3; re-tetrahedralize the hand, or swap two of its vertices if it is "
                   "only wound the wrong way";
            throw InvalidArgument(msg.str());
        }
        const Mat3 bm = dm.inverse();
        out.rest_inverse[e] = bm;
        out.volume[e] = vol;
        // Linear elasticity: K_ab = V (lambda g_a g_b^T + mu g_b g_a^T + mu (g_a . g_b) I)
        const auto g = shape_gradients(bm);
        out.gradients[e] = g;
        Mat12 k;
        for (int a = 0; a < 4; ++a)
            for (int b = 0; b < 4; ++b) {
                const Vec3 ga = g.row(a).transpose(), gb = g.row(b).transpose();
                k.block<3, 3>(3 * a, 3 * b) =
                    vol * (lambda * ga * gb.transpose() + mu * gb * ga.transpose() +
                           mu * ga.dot(gb) * Mat3::Identity());
            }
        out.stiffness[e] = k;
    }
    return out;
}

VecX lumped_masses(const TetMesh& mesh, const CorotationalElements& elements, double density) {
    VecX m = VecX::Zero(mesh.n_nodes);
    for (size_t e = 0; e < mesh.tets.size(); ++e)
        for (int a = 0; a < 4; ++a) m[mesh.tets[e][a]] += 0.25 * density * elements.volume[e];
    return m;
}

Mat3 deformation_gradient(const TetMesh& mesh, const CorotationalElements& elements, int e, const VecX& x) {
    const auto& t = mesh.tets[e];
    const Vec3 x0 = node(x, t[0]);
    Mat3 ds;
    ds << node(x, t[1]) - x0, node(x, t[2]) - x0, node(x, t[3]) - x0;
    return ds * elements.rest_inverse[e];
}

namespace {
// R of a unit quaternion (x, y, z, s).
inline Mat3 rotation_of(const Vec4& q) {
    const double x = q[0], y = q[1], z = q[2], w = q[3];
    Mat3 r;
    r << 1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
         2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
         2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y);
    return r;
}
}  // namespace

Mat3 polar_rotation_svd(const Mat3& f, Vec4& q) {
    if (!f.allFinite()) return rotation_of(q);  // the step rejects non-finite states itself
    Eigen::JacobiSVD<Mat3> svd(f, Eigen::ComputeFullU | Eigen::ComputeFullV);
    Mat3 u = svd.matrixU();
    const Mat3 v = svd.matrixV();
    // Kabsch: the maximizer over proper rotations flips the smallest singular direction when
    // U V^T is a reflection (det F < 0, an inverted element: McAdams et al. 2011)
    if ((u * v.transpose()).determinant() < 0) u.col(2) = -u.col(2);
    const Mat3 r = u * v.transpose();
    q = quat_from_matrix(r);
    return r;
}

Mat3 polar_rotation(const Mat3& f, Vec4& q) {
    Mat3 r = rotation_of(q);
    for (int iter = 0; iter < kPolarNewtonSteps; ++iter) {
        // Newton ascent on trace(R^T F) over rotations R <- exp(omega) R: the gradient is
        // sum_i r_i x f_i (Mueller et al. 2016); with M = F R^T the Hessian is
        // H = trace(M) I - sym(M), solved by its adjugate.
        const Vec3 torque = r.col(0).cross(f.col(0)) + r.col(1).cross(f.col(1)) + r.col(2).cross(f.col(2));
        const Mat3 m = f * r.transpose();
        const double tr = m.trace();
        const double h00 = tr - m(0, 0), h11 = tr - m(1, 1), h22 = tr - m(2, 2);
        const double h01 = -0.5 * (m(0, 1) + m(1, 0)), h02 = -0.5 * (m(0, 2) + m(2, 0)), h12 = -0.5 * (m(1, 2) + m(2, 1));
        const double c00 = h11 * h22 - h12 * h12, c01 = h02 * h12 - h01 * h22, c02 = h01 * h12 - h02 * h11;
        const double det = h00 * c00 + h01 * c01 + h02 * c02;
        const double c11 = h00 * h22 - h02 * h02, c12 = h01 * h02 - h00 * h12, c22 = h00 * h11 - h01 * h01;
        // The guard: the maximum is the only critical point where H is positive definite
        // (leading minors), so Newton may go on only there; elsewhere (a warm start far from
        // the answer, a saddle, a degenerate F) the SVD decides.
        if (!(h00 > 0 && c22 > 0 && det > 0)) break;
        const Vec3 omega = Vec3(c00 * torque[0] + c01 * torque[1] + c02 * torque[2],
                                c01 * torque[0] + c11 * torque[1] + c12 * torque[2],
                                c02 * torque[0] + c12 * torque[1] + c22 * torque[2]) / det;
        const double angle2 = omega.squaredNorm();
        Vec4 dq;  // exp(omega) as a quaternion; a series for the small steps of a warm start
        if (angle2 < 1e-4) {
            const double s = 0.5 - angle2 / 48.0 + angle2 * angle2 / 3840.0;
            const double c = 1.0 - angle2 / 8.0 + angle2 * angle2 / 384.0;
            dq << s * omega, c;
        } else {
            dq = quat_from_rotation_vector(omega);
        }
        q = quat_multiply(dq, q);
        q.normalize();
        r = rotation_of(q);
        // A step below 1e-9 rad is the last: taken, quadratic convergence leaves ~1e-18, so the
        // rotation does not depend on where the warm start began (left out, it would by ~1e-9).
        if (angle2 <= kPolarConverged) return r;
    }
    return polar_rotation_svd(f, q);  // not converged at a maximum within the steps allowed
}

double add_elastic_forces(const TetMesh& mesh, const CorotationalElements& elements,
                          const VecX& x, VecX& f, ElementRotations* rotations) {
    const size_t m = mesh.tets.size();
    ElementRotations local;
    ElementRotations& rot = rotations ? *rotations : local;
    if (rot.q.size() != m) rot.q.assign(m, quat_identity());
    rot.r.resize(m);
    double energy = 0;
    Eigen::Matrix<double, 12, 1> u, fe;
    for (size_t e = 0; e < m; ++e) {
        const Mat3 r = polar_rotation(deformation_gradient(mesh, elements, static_cast<int>(e), x), rot.q[e]);
        rot.r[e] = r;
        const auto& t = mesh.tets[e];
        // displacement measured from node 0: Ke ignores translations, and dropping them
        // keeps round-off from a far-away body out of the energy
        const Vec3 x0 = node(x, t[0]), rest0 = node(mesh.rest, t[0]);
        for (int a = 0; a < 4; ++a)
            u.segment<3>(3 * a) = r.transpose() * (node(x, t[a]) - x0) - (node(mesh.rest, t[a]) - rest0);
        fe = elements.stiffness[e] * u;  // rest-frame force (negated below)
        energy += 0.5 * u.dot(fe);
        for (int a = 0; a < 4; ++a) f.segment<3>(3 * t[a]) -= r * fe.segment<3>(3 * a);
    }
    return energy;
}

StiffnessPattern build_stiffness_pattern(const TetMesh& mesh) {
    std::vector<Eigen::Triplet<double>> trip;
    trip.reserve(mesh.tets.size() * 144);
    for (const auto& t : mesh.tets)
        for (int a = 0; a < 4; ++a)
            for (int b = 0; b < 4; ++b)
                for (int i = 0; i < 3; ++i)
                    for (int j = 0; j < 3; ++j) trip.emplace_back(3 * t[a] + i, 3 * t[b] + j, 0.0);
    StiffnessPattern p;
    p.matrix.resize(3 * mesh.n_nodes, 3 * mesh.n_nodes);
    p.matrix.setFromTriplets(trip.begin(), trip.end());
    p.matrix.makeCompressed();
    const int* outer = p.matrix.outerIndexPtr();
    const int* inner = p.matrix.innerIndexPtr();
    auto offset = [&](int row, int col) {
        const int* begin = inner + outer[col];
        const int* end = inner + outer[col + 1];
        return static_cast<int>(std::lower_bound(begin, end, row) - inner);
    };
    p.element_offsets.resize(mesh.tets.size() * 144);
    for (size_t e = 0; e < mesh.tets.size(); ++e) {
        const auto& t = mesh.tets[e];
        for (int r = 0; r < 12; ++r)
            for (int c = 0; c < 12; ++c)
                p.element_offsets[e * 144 + r * 12 + c] = offset(3 * t[r / 3] + r % 3, 3 * t[c / 3] + c % 3);
    }
    p.column_length.resize(mesh.n_nodes);
    for (int n = 0; n < mesh.n_nodes; ++n) p.column_length[n] = outer[3 * n + 1] - outer[3 * n];
    p.element_blocks.resize(mesh.tets.size() * 16);
    for (size_t e = 0; e < mesh.tets.size(); ++e) {
        const auto& t = mesh.tets[e];
        for (int a = 0; a < 4; ++a)
            for (int b = 0; b < 4; ++b) {
                const int base = offset(3 * t[a], 3 * t[b]);
                p.element_blocks[e * 16 + 4 * a + b] = base;
                for (int i = 0; i < 3; ++i)  // the compact form's assumption, checked once
                    for (int j = 0; j < 3; ++j)
                        if (offset(3 * t[a] + i, 3 * t[b] + j) != base + j * p.column_length[t[b]] + i)
                            throw std::logic_error("build_stiffness_pattern: columns of a node do not share their pattern");
            }
    }
    p.node_block_offsets.resize(9 * mesh.n_nodes);
    for (int n = 0; n < mesh.n_nodes; ++n)
        for (int i = 0; i < 3; ++i)
            for (int j = 0; j < 3; ++j) p.node_block_offsets[9 * n + 3 * i + j] = offset(3 * n + i, 3 * n + j);
    return p;
}

void add_warped_stiffness(const CorotationalElements& elements, const std::vector<Mat3>& rotations,
                          const StiffnessPattern& pattern, double scale, double* values) {
    // R Ke R^T from the rotated shape-function gradients g'_a = R g_a: since dot products are
    // rotation invariant, (R K R^T)_ab = V (lambda g'_a g'_b^T + mu g'_b g'_a^T + mu (g_a . g_b) I),
    // five times fewer operations than rotating each 3x3 block of Ke.
    const double lambda = elements.lambda, mu = elements.mu;
    for (size_t e = 0; e < elements.gradients.size(); ++e) {
        const Mat3& r = rotations[e];
        const auto& g = elements.gradients[e];
        Eigen::Matrix<double, 3, 4> gr;  // columns g'_a
        for (int a = 0; a < 4; ++a) gr.col(a) = r * g.row(a).transpose();
        const double s = scale * elements.volume[e];
        const int* off = &pattern.element_offsets[e * 144];
        for (int a = 0; a < 4; ++a)
            for (int b = a; b < 4; ++b) {
                Mat3 block = (s * lambda) * gr.col(a) * gr.col(b).transpose() + (s * mu) * gr.col(b) * gr.col(a).transpose();
                block.diagonal().array() += s * mu * g.row(a).dot(g.row(b));
                for (int i = 0; i < 3; ++i)
                    for (int j = 0; j < 3; ++j) {
                        values[off[(3 * a + i) * 12 + 3 * b + j]] += block(i, j);
                        if (a != b) values[off[(3 * b + j) * 12 + 3 * a + i]] += block(i, j);
                    }
            }
    }
}

void size_rotations(ElementRotations& rot, size_t m) {
    if (rot.q.size() != m) rot.q.assign(m, quat_identity());
    rot.r.resize(m);
}

double assemble_corotational(const TetMesh& mesh, const CorotationalElements& elements, const VecX& x, VecX& f,
                             ElementRotations& rot, const StiffnessPattern& pattern, double scale, double* values) {
    size_rotations(rot, mesh.tets.size());
    return assemble_corotational(mesh, elements, x, f, rot, pattern, scale, values, 0, mesh.tets.size());
}

double assemble_corotational(const TetMesh& mesh, const CorotationalElements& elements, const VecX& x, VecX& f,
                             ElementRotations& rot, const StiffnessPattern& pattern, double scale, double* values,
                             size_t begin, size_t end) {
    const double lambda = elements.lambda, mu = elements.mu;
    const double* xs = x.data();
    double* fs = f.data();
    double energy = 0;
    // whole batches of 4 or 8 elements on SIMD lanes when the CPU has them, the rest here
    const size_t first = assemble_corotational_simd(mesh, elements, xs, fs, rot, pattern, scale, values, energy, begin, end);
    for (size_t e = first; e < end; ++e) {
        const auto& t = mesh.tets[e];
        const Vec3 x0 = Eigen::Map<const Vec3>(xs + 3 * t[0]);
        Mat3 ds;
        ds << Eigen::Map<const Vec3>(xs + 3 * t[1]) - x0, Eigen::Map<const Vec3>(xs + 3 * t[2]) - x0,
            Eigen::Map<const Vec3>(xs + 3 * t[3]) - x0;
        const Mat3 fdef = ds * elements.rest_inverse[e];
        const Mat3 r = polar_rotation(fdef, rot.q[e]);
        rot.r[e] = r;
        const double vol = elements.volume[e];
        // small strain in the element's frame and the stress
        const Mat3 g = r.transpose() * fdef;
        Mat3 eps = 0.5 * (g + g.transpose());
        eps.diagonal().array() -= 1.0;
        const double tr = eps.trace();
        Mat3 sigma = (2 * mu) * eps;
        sigma.diagonal().array() += lambda * tr;
        energy += 0.5 * vol * (lambda * tr * tr + 2 * mu * eps.squaredNorm());
        const Mat3 p = vol * (r * sigma);
        const auto& gr0 = elements.gradients[e];  // rows g_a
        Eigen::Matrix<double, 3, 4> gr;           // columns R g_a
        for (int a = 0; a < 4; ++a) {
            const Vec3 ga = gr0.row(a).transpose();
            gr.col(a) = r * ga;
            Eigen::Map<Vec3>(fs + 3 * t[a]) -= p * ga;
        }
        // scale * R Ke R^T, block (a, b) = s (lambda g'_a g'_b^T + mu g'_b g'_a^T + mu (g_a . g_b) I)
        const double s = scale * vol;
        const int* blocks = &pattern.element_blocks[e * 16];
        for (int a = 0; a < 4; ++a)
            for (int b = a; b < 4; ++b) {
                Mat3 block = (s * lambda) * gr.col(a) * gr.col(b).transpose() + (s * mu) * gr.col(b) * gr.col(a).transpose();
                block.diagonal().array() += s * mu * gr0.row(a).dot(gr0.row(b));
                double* ab = values + blocks[4 * a + b];
                const int lb = pattern.column_length[t[b]];
                for (int j = 0; j < 3; ++j)
                    for (int i = 0; i < 3; ++i) ab[j * lb + i] += block(i, j);
                if (a != b) {  // block (b, a) = block (a, b)^T
                    double* ba = values + blocks[4 * b + a];
                    const int la = pattern.column_length[t[a]];
                    for (int j = 0; j < 3; ++j)
                        for (int i = 0; i < 3; ++i) ba[j * la + i] += block(j, i);
                }
            }
    }
    return energy;
}

}  // namespace hh
