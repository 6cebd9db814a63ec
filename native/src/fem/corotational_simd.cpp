#include "fem/corotational_simd.h"

// The lane helpers return vector values from always-inline functions only ever inlined into
// kernels compiled for AVX2 / AVX-512; GCC still warns about the ABI.
#pragma GCC diagnostic ignored "-Wpsabi"

#include <cmath>

#include "common/simd.h"
#include "rigid/quaternion.h"

namespace hh {

#if defined(__GNUC__) && defined(__x86_64__)
namespace {

template <int L> struct Lanes;
template <> struct Lanes<4> {
    typedef double V __attribute__((vector_size(32)));
    typedef long M __attribute__((vector_size(32)));
};
template <> struct Lanes<8> {
    typedef double V __attribute__((vector_size(64)));
    typedef long M __attribute__((vector_size(64)));
};

template <int L, typename M>
__attribute__((always_inline)) inline bool any(const M& m) {
    for (int l = 0; l < L; ++l)
        if (m[l]) return true;
    return false;
}

// R of unit quaternions (x, y, z, s), as rotation_of in corotational.cpp
template <typename V>
__attribute__((always_inline)) inline void rotation_of(const V (&q)[4], V (&r)[3][3]) {
    const V x = q[0], y = q[1], z = q[2], w = q[3];
    r[0][0] = 1 - 2 * (y * y + z * z);
    r[0][1] = 2 * (x * y - z * w);
    r[0][2] = 2 * (x * z + y * w);
    r[1][0] = 2 * (x * y + z * w);
    r[1][1] = 1 - 2 * (x * x + z * z);
    r[1][2] = 2 * (y * z - x * w);
    r[2][0] = 2 * (x * z - y * w);
    r[2][1] = 2 * (y * z + x * w);
    r[2][2] = 1 - 2 * (x * x + y * y);
}

// One batch of L elements starting at e0: the body of assemble_corotational's loop with every
// scalar replaced by L lanes, and polar_rotation's iteration run on all lanes with a mask of
// those not converged yet (each lane stops at the same test as the scalar loop).
template <int L>
__attribute__((always_inline)) inline void element_batch(const TetMesh& mesh, const CorotationalElements& el, const double* xs,
                                                         double* fs, ElementRotations& rot, const StiffnessPattern& pattern,
                                                         double scale, double* values, size_t e0, typename Lanes<L>::V& energy) {
    typedef typename Lanes<L>::V V;
    typedef typename Lanes<L>::M M;
    const double lambda = el.lambda, mu = el.mu;
    V ds[3][3], bm[3][3], grad[4][3], vol, q[4];
    for (int l = 0; l < L; ++l) {
        const size_t e = e0 + l;
        const auto& t = mesh.tets[e];
        const double* x0 = xs + 3 * t[0];
        for (int c = 0; c < 3; ++c) {
            const double* xc = xs + 3 * t[c + 1];
            for (int i = 0; i < 3; ++i) ds[i][c][l] = xc[i] - x0[i];
        }
        const double* b = el.rest_inverse[e].data();  // column-major
        for (int r = 0; r < 3; ++r)
            for (int c = 0; c < 3; ++c) bm[r][c][l] = b[3 * c + r];
        const double* g = el.gradients[e].data();  // 4 x 3, column-major
        for (int a = 0; a < 4; ++a)
            for (int j = 0; j < 3; ++j) grad[a][j][l] = g[4 * j + a];
        vol[l] = el.volume[e];
        for (int k = 0; k < 4; ++k) q[k][l] = rot.q[e][k];
    }
    V f[3][3];  // F = Ds Bm
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) f[i][j] = ds[i][0] * bm[0][j] + ds[i][1] * bm[1][j] + ds[i][2] * bm[2][j];

    // polar_rotation: guarded Newton ascent on trace(R^T F) from the warm start q (see
    // corotational.cpp). Every lane runs until it converges at a maximum or leaves the region
    // where the Hessian is positive definite; those that leave it, or do not converge within
    // the steps allowed, get the SVD, one lane at a time.
    M active = M{} == 0;  // all lanes
    M to_svd = M{};
    V r[3][3];
    rotation_of(q, r);
    for (int iter = 0; iter < kPolarNewtonSteps && any<L>(active); ++iter) {
        V torque[3];
        torque[0] = (r[1][0] * f[2][0] - r[2][0] * f[1][0]) + (r[1][1] * f[2][1] - r[2][1] * f[1][1]) + (r[1][2] * f[2][2] - r[2][2] * f[1][2]);
        torque[1] = (r[2][0] * f[0][0] - r[0][0] * f[2][0]) + (r[2][1] * f[0][1] - r[0][1] * f[2][1]) + (r[2][2] * f[0][2] - r[0][2] * f[2][2]);
        torque[2] = (r[0][0] * f[1][0] - r[1][0] * f[0][0]) + (r[0][1] * f[1][1] - r[1][1] * f[0][1]) + (r[0][2] * f[1][2] - r[1][2] * f[0][2]);
        V m[3][3];  // F R^T
        for (int i = 0; i < 3; ++i)
            for (int j = 0; j < 3; ++j) m[i][j] = f[i][0] * r[j][0] + f[i][1] * r[j][1] + f[i][2] * r[j][2];
        const V tr = m[0][0] + m[1][1] + m[2][2];
        const V h00 = tr - m[0][0], h11 = tr - m[1][1], h22 = tr - m[2][2];
        const V h01 = -0.5 * (m[0][1] + m[1][0]), h02 = -0.5 * (m[0][2] + m[2][0]), h12 = -0.5 * (m[1][2] + m[2][1]);
        const V c00 = h11 * h22 - h12 * h12, c01 = h02 * h12 - h01 * h22, c02 = h01 * h12 - h02 * h11;
        const V det = h00 * c00 + h01 * c01 + h02 * c02;
        const V c11 = h00 * h22 - h02 * h02, c12 = h01 * h02 - h00 * h12, c22 = h00 * h11 - h01 * h01;
        const M pd = (h00 > 0) & (c22 > 0) & (det > 0);  // false for NaN too
        to_svd = to_svd | (active & ~pd);
        active = active & pd;
        const V safe_det = pd ? det : V{} + 1.0;
        V omega[3];
        omega[0] = (c00 * torque[0] + c01 * torque[1] + c02 * torque[2]) / safe_det;
        omega[1] = (c01 * torque[0] + c11 * torque[1] + c12 * torque[2]) / safe_det;
        omega[2] = (c02 * torque[0] + c12 * torque[1] + c22 * torque[2]) / safe_det;
        const V angle2 = omega[0] * omega[0] + omega[1] * omega[1] + omega[2] * omega[2];
        if (!any<L>(active)) break;
        // exp(omega) as a quaternion: the series for small steps, sin/cos per lane otherwise
        const V s = 0.5 - angle2 / 48.0 + angle2 * angle2 / 3840.0;
        const V c = 1.0 - angle2 / 8.0 + angle2 * angle2 / 384.0;
        V dq[4] = {s * omega[0], s * omega[1], s * omega[2], c};
        for (int l = 0; l < L; ++l)
            if (active[l] && !(angle2[l] < 1e-4)) {
                const Vec4 big = quat_from_rotation_vector(Vec3(omega[0][l], omega[1][l], omega[2][l]));
                for (int k = 0; k < 4; ++k) dq[k][l] = big[k];
            }
        V qn[4];  // quat_multiply(dq, q)
        qn[0] = dq[3] * q[0] + q[3] * dq[0] + (dq[1] * q[2] - dq[2] * q[1]);
        qn[1] = dq[3] * q[1] + q[3] * dq[1] + (dq[2] * q[0] - dq[0] * q[2]);
        qn[2] = dq[3] * q[2] + q[3] * dq[2] + (dq[0] * q[1] - dq[1] * q[0]);
        qn[3] = dq[3] * q[3] - (dq[0] * q[0] + dq[1] * q[1] + dq[2] * q[2]);
        // 1/|qn|: a product of unit quaternions is unit to ~1e-16, where 1.5 - |qn|^2 / 2 is
        // 1/|qn| to ~1e-32 (no sqrt per lane); a lane further off takes the square root
        const V norm2 = qn[0] * qn[0] + qn[1] * qn[1] + qn[2] * qn[2] + qn[3] * qn[3];
        V inverse = 1.5 - 0.5 * norm2;
        const M off = (norm2 > 1 + 1e-6) | (norm2 < 1 - 1e-6);
        if (any<L>(off))
            for (int l = 0; l < L; ++l)
                if (off[l]) inverse[l] = norm2[l] > 0 ? 1.0 / std::sqrt(norm2[l]) : 1.0;
        for (int k = 0; k < 4; ++k) q[k] = active ? qn[k] * inverse : q[k];
        V rn[3][3];
        rotation_of(q, rn);
        for (int i = 0; i < 3; ++i)
            for (int j = 0; j < 3; ++j) r[i][j] = active ? rn[i][j] : r[i][j];
        active = active & (angle2 > kPolarConverged);  // a step below 1e-9 rad is the last, taken (corotational.cpp)
    }
    to_svd = to_svd | active;  // still moving after the steps allowed
    for (int l = 0; l < L; ++l) {
        const size_t e = e0 + l;
        if (to_svd[l]) {
            Mat3 fl;
            for (int i = 0; i < 3; ++i)
                for (int j = 0; j < 3; ++j) fl(i, j) = f[i][j][l];
            Vec4 ql(q[0][l], q[1][l], q[2][l], q[3][l]);
            const Mat3 rl = polar_rotation_svd(fl, ql);
            for (int k = 0; k < 4; ++k) q[k][l] = ql[k];
            for (int i = 0; i < 3; ++i)
                for (int j = 0; j < 3; ++j) r[i][j][l] = rl(i, j);
        }
        rot.q[e] = Vec4(q[0][l], q[1][l], q[2][l], q[3][l]);
        Mat3& re = rot.r[e];
        for (int i = 0; i < 3; ++i)
            for (int j = 0; j < 3; ++j) re(i, j) = r[i][j][l];
    }

    // small strain in the element's frame, stress, energy (as assemble_corotational)
    V eps[3][3];
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) {
            const V gij = r[0][i] * f[0][j] + r[1][i] * f[1][j] + r[2][i] * f[2][j];  // (R^T F)(i, j)
            eps[i][j] = gij;
        }
    for (int i = 0; i < 3; ++i)
        for (int j = i + 1; j < 3; ++j) eps[i][j] = eps[j][i] = 0.5 * (eps[i][j] + eps[j][i]);
    for (int i = 0; i < 3; ++i) eps[i][i] -= 1.0;
    const V tre = eps[0][0] + eps[1][1] + eps[2][2];
    V eps2 = V{};
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) eps2 += eps[i][j] * eps[i][j];
    energy += 0.5 * vol * (lambda * tre * tre + 2 * mu * eps2);
    V sigma[3][3];
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) sigma[i][j] = (2 * mu) * eps[i][j];
    for (int i = 0; i < 3; ++i) sigma[i][i] += lambda * tre;
    V p[3][3];  // V R sigma
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) p[i][j] = vol * (r[i][0] * sigma[0][j] + r[i][1] * sigma[1][j] + r[i][2] * sigma[2][j]);
    V force[4][3], gr[4][3];  // -(P g_a) and R g_a
    for (int a = 0; a < 4; ++a)
        for (int i = 0; i < 3; ++i) {
            force[a][i] = p[i][0] * grad[a][0] + p[i][1] * grad[a][1] + p[i][2] * grad[a][2];
            gr[a][i] = r[i][0] * grad[a][0] + r[i][1] * grad[a][1] + r[i][2] * grad[a][2];
        }
    // scale * R Ke R^T, block (a, b) = s (lambda g'_a g'_b^T + mu g'_b g'_a^T + mu (g_a . g_b) I)
    const V s = scale * vol, sl = s * lambda, sm = s * mu;
    V block[10][3][3];
    int k = 0;
    for (int a = 0; a < 4; ++a)
        for (int b = a; b < 4; ++b, ++k) {
            const V dot = sm * (grad[a][0] * grad[b][0] + grad[a][1] * grad[b][1] + grad[a][2] * grad[b][2]);
            for (int i = 0; i < 3; ++i)
                for (int j = 0; j < 3; ++j) block[k][i][j] = sl * gr[a][i] * gr[b][j] + sm * gr[b][i] * gr[a][j];
            for (int i = 0; i < 3; ++i) block[k][i][i] += dot;
        }
    // scatter element by element, in the scalar loop's order
    for (int l = 0; l < L; ++l) {
        const size_t e = e0 + l;
        const auto& t = mesh.tets[e];
        for (int a = 0; a < 4; ++a)
            for (int i = 0; i < 3; ++i) fs[3 * t[a] + i] -= force[a][i][l];
        const int* blocks = &pattern.element_blocks[e * 16];
        int kb = 0;
        for (int a = 0; a < 4; ++a)
            for (int b = a; b < 4; ++b, ++kb) {
                double* ab = values + blocks[4 * a + b];
                const int lb = pattern.column_length[t[b]];
                for (int j = 0; j < 3; ++j)
                    for (int i = 0; i < 3; ++i) ab[j * lb + i] += block[kb][i][j][l];
                if (a != b) {  // block (b, a) = block (a, b)^T
                    double* ba = values + blocks[4 * b + a];
                    const int la = pattern.column_length[t[a]];
                    for (int j = 0; j < 3; ++j)
                        for (int i = 0; i < 3; ++i) ba[j * la + i] += block[kb][j][i][l];
                }
            }
    }
}

template <int L>
__attribute__((always_inline)) inline size_t run_batches(const TetMesh& mesh, const CorotationalElements& el, const double* xs,
                                                         double* fs, ElementRotations& rot, const StiffnessPattern& pattern,
                                                         double scale, double* values, double& energy, size_t begin,
                                                         size_t end) {
    typename Lanes<L>::V sum = typename Lanes<L>::V{};
    const size_t whole = begin + (end - begin) / L * L;
    for (size_t e0 = begin; e0 < whole; e0 += L) element_batch<L>(mesh, el, xs, fs, rot, pattern, scale, values, e0, sum);
    for (int l = 0; l < L; ++l) energy += sum[l];
    return whole;
}

__attribute__((target("avx2,fma"))) size_t run_avx2(const TetMesh& mesh, const CorotationalElements& el, const double* xs,
                                                    double* fs, ElementRotations& rot, const StiffnessPattern& pattern,
                                                    double scale, double* values, double& energy, size_t begin, size_t end) {
    return run_batches<4>(mesh, el, xs, fs, rot, pattern, scale, values, energy, begin, end);
}

__attribute__((target("avx512f,avx512vl,avx512dq,avx2,fma"))) size_t run_avx512(const TetMesh& mesh, const CorotationalElements& el,
                                                                               const double* xs, double* fs, ElementRotations& rot,
                                                                               const StiffnessPattern& pattern, double scale,
                                                                               double* values, double& energy, size_t begin,
                                                                               size_t end) {
    return run_batches<8>(mesh, el, xs, fs, rot, pattern, scale, values, energy, begin, end);
}

}  // namespace
#endif

size_t assemble_corotational_simd(const TetMesh& mesh, const CorotationalElements& elements, const double* x, double* f,
                                  ElementRotations& rotations, const StiffnessPattern& pattern, double scale,
                                  double* values, double& energy, size_t begin, size_t end) {
#if defined(__GNUC__) && defined(__x86_64__)
    const int level = active_simd_level();
    if (level == 2) return run_avx512(mesh, elements, x, f, rotations, pattern, scale, values, energy, begin, end);
    if (level == 1) return run_avx2(mesh, elements, x, f, rotations, pattern, scale, values, energy, begin, end);
#else
    (void)mesh, (void)elements, (void)x, (void)f, (void)rotations, (void)pattern, (void)scale, (void)values, (void)energy;
    (void)end;
#endif
    return begin;
}

}  // namespace hh
