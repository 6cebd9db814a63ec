#include "solver/panel_kernels.h"

#include <Eigen/Cholesky>
#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <cstddef>

#include "common/simd.h"

#if defined(__GNUC__) && defined(__x86_64__)
#include <immintrin.h>
#define HH_PANEL_AVX512 1
#define HH_AVX512_TARGET __attribute__((target("avx512f,avx512vl,avx2,fma")))
#endif

namespace hh {

namespace {
using Panel = Eigen::Map<Eigen::MatrixXd, 0, Eigen::OuterStride<>>;
using ConstPanel = Eigen::Map<const Eigen::MatrixXd, 0, Eigen::OuterStride<>>;

#ifdef HH_PANEL_AVX512
// C(0:rows, 0:NC) = (or -=) A(0:rows, 0:k) B(0:NC, 0:k)^T, rows <= 8 RB: RB x NC accumulators of
// 8 doubles (24 of the 32 registers at 3 x 8), each step of k one load of A's RB vectors and NC
// broadcasts of B for RB x NC fused multiply-adds. The rows past `rows` are masked off.
template <int RB, int NC, bool Assign>
HH_AVX512_TARGET __attribute__((always_inline)) inline void nt_block(const double* a, int lda, const double* b, int ldb, int k,
                                                                    double* c, int ldc, int rows) {
    __m512d acc[RB][NC];
    __mmask8 mask[RB];
    for (int r = 0; r < RB; ++r) {
        const int left = rows - 8 * r;
        mask[r] = left >= 8 ? __mmask8(0xFF) : __mmask8((1u << left) - 1);
        for (int q = 0; q < NC; ++q) acc[r][q] = _mm512_setzero_pd();
    }
    for (int p = 0; p < k; ++p) {
        const double* ap = a + static_cast<std::size_t>(p) * lda;
        const double* bp = b + static_cast<std::size_t>(p) * ldb;
        __m512d av[RB];
        for (int r = 0; r < RB; ++r) av[r] = _mm512_maskz_loadu_pd(mask[r], ap + 8 * r);
        for (int q = 0; q < NC; ++q) {
            const __m512d bq = _mm512_set1_pd(bp[q]);
            for (int r = 0; r < RB; ++r) acc[r][q] = _mm512_fmadd_pd(av[r], bq, acc[r][q]);
        }
    }
    for (int q = 0; q < NC; ++q)
        for (int r = 0; r < RB; ++r) {
            double* cp = c + static_cast<std::size_t>(q) * ldc + 8 * r;
            const __m512d v = Assign ? acc[r][q] : _mm512_sub_pd(_mm512_maskz_loadu_pd(mask[r], cp), acc[r][q]);
            _mm512_mask_storeu_pd(cp, mask[r], v);
        }
}

template <int RB, bool Assign>
HH_AVX512_TARGET inline void nt_rows(const double* a, int lda, const double* b, int ldb, int k, double* c, int ldc, int rows, int nc) {
    switch (nc) {
        case 1: return nt_block<RB, 1, Assign>(a, lda, b, ldb, k, c, ldc, rows);
        case 2: return nt_block<RB, 2, Assign>(a, lda, b, ldb, k, c, ldc, rows);
        case 3: return nt_block<RB, 3, Assign>(a, lda, b, ldb, k, c, ldc, rows);
        case 4: return nt_block<RB, 4, Assign>(a, lda, b, ldb, k, c, ldc, rows);
        case 5: return nt_block<RB, 5, Assign>(a, lda, b, ldb, k, c, ldc, rows);
        case 6: return nt_block<RB, 6, Assign>(a, lda, b, ldb, k, c, ldc, rows);
        case 7: return nt_block<RB, 7, Assign>(a, lda, b, ldb, k, c, ldc, rows);
        default: return nt_block<RB, 8, Assign>(a, lda, b, ldb, k, c, ldc, rows);
    }
}

// C (m x n, ldc) = (or -=) A (m x k, lda) B (n x k, ldb)^T, all column-major: blocks of 24 rows
// by 8 columns (B's 8 columns stay in L1 while A's rows stream past them). lower: only the rows
// from each column's 3x3 node block down (the rest of C is left as it was).
template <bool Assign>
HH_AVX512_TARGET void nt_product(const double* a, int lda, const double* b, int ldb, int m, int n, int k, double* c, int ldc,
                                 bool lower = false) {
    for (int j = 0; j < n; j += 8) {
        const int nc = std::min(8, n - j);
        for (int i = lower ? j - j % 3 : 0; i < m; i += 24) {
            const int rows = std::min(24, m - i);
            double* cij = c + i + static_cast<std::size_t>(j) * ldc;
            if (rows > 16) nt_rows<3, Assign>(a + i, lda, b + j, ldb, k, cij, ldc, rows, nc);
            else if (rows > 8) nt_rows<2, Assign>(a + i, lda, b + j, ldb, k, cij, ldc, rows, nc);
            else nt_rows<1, Assign>(a + i, lda, b + j, ldb, k, cij, ldc, rows, nc);
        }
    }
}

// X (rows x NB, ld) = X L^-T for the NB x NB lower triangle L (at l, leading dimension ld; inv:
// 1 / its diagonal), 8 rows at a time held in NB registers.
template <int NB>
HH_AVX512_TARGET void solve_block_rows(double* x, int rows, const double* l, int ld, const double* inv) {
    for (int i = 0; i < rows; i += 8) {
        const int left = rows - i;
        const __mmask8 mask = left >= 8 ? __mmask8(0xFF) : __mmask8((1u << left) - 1);
        __m512d v[NB];
        for (int c = 0; c < NB; ++c) v[c] = _mm512_maskz_loadu_pd(mask, x + i + static_cast<std::size_t>(c) * ld);
        for (int c = 0; c < NB; ++c) {
            for (int d = 0; d < c; ++d) v[c] = _mm512_fnmadd_pd(v[d], _mm512_set1_pd(l[c + static_cast<std::size_t>(d) * ld]), v[c]);
            v[c] = _mm512_mul_pd(v[c], _mm512_set1_pd(inv[c]));
        }
        for (int c = 0; c < NB; ++c) _mm512_mask_storeu_pd(x + i + static_cast<std::size_t>(c) * ld, mask, v[c]);
    }
}

// Left-looking by blocks of 8 columns: each block takes the update of the columns before it
// (one product over all its rows, the bulk of the flops), then factors its 8 x 8 diagonal
// block and solves the rows below against it.
HH_AVX512_TARGET bool panel_cholesky_avx512(double* p, int ld, int m) {
    for (int j0 = 0; j0 < m; j0 += 8) {
        const int nb = std::min(8, m - j0);
        double* pj = p + j0 + static_cast<std::size_t>(j0) * ld;  // P(j0, j0)
        if (j0 > 0) nt_product<false>(p + j0, ld, p + j0, ld, ld - j0, nb, j0, pj, ld);
        double inv[8];
        for (int c = 0; c < nb; ++c) {
            double* col = pj + static_cast<std::size_t>(c) * ld;
            double d = col[c];
            for (int e = 0; e < c; ++e) d -= pj[c + static_cast<std::size_t>(e) * ld] * pj[c + static_cast<std::size_t>(e) * ld];
            if (!(d > 0) || !std::isfinite(d)) return false;
            d = std::sqrt(d);
            col[c] = d;
            inv[c] = 1.0 / d;
            for (int r = c + 1; r < nb; ++r) {
                double v = col[r];
                for (int e = 0; e < c; ++e) v -= pj[r + static_cast<std::size_t>(e) * ld] * pj[c + static_cast<std::size_t>(e) * ld];
                col[r] = v * inv[c];
            }
        }
        const int below = ld - j0 - nb;
        if (below <= 0) continue;
        double* x = pj + nb;
        switch (nb) {
            case 1: solve_block_rows<1>(x, below, pj, ld, inv); break;
            case 2: solve_block_rows<2>(x, below, pj, ld, inv); break;
            case 3: solve_block_rows<3>(x, below, pj, ld, inv); break;
            case 4: solve_block_rows<4>(x, below, pj, ld, inv); break;
            case 5: solve_block_rows<5>(x, below, pj, ld, inv); break;
            case 6: solve_block_rows<6>(x, below, pj, ld, inv); break;
            case 7: solve_block_rows<7>(x, below, pj, ld, inv); break;
            default: solve_block_rows<8>(x, below, pj, ld, inv); break;
        }
    }
    return true;
}
#endif

// Entries of A up to which the AVX2 product below serves panel_outer_product (256 KB)
constexpr long kSmallProduct = 32768;

// The same product with AVX2 and FMA: blocks of 12 rows by 4 columns, 12 accumulators of 4
// doubles (with 3 of A's vectors and a broadcast of B: the 16 registers), the last rows of a
// column through a masked load and a scalar store.
#define HH_AVX2_TARGET __attribute__((target("avx2,fma")))
template <int RB, int NC>
HH_AVX2_TARGET __attribute__((always_inline)) inline void nt_block_avx2(const double* a, int lda, const double* b, int ldb, int k,
                                                                       double* c, int ldc, int rows) {
    __m256d acc[RB][NC];
    __m256i mask[RB];
    for (int r = 0; r < RB; ++r) {
        const int left = rows - 4 * r;
        mask[r] = _mm256_setr_epi64x(left > 0 ? -1 : 0, left > 1 ? -1 : 0, left > 2 ? -1 : 0, left > 3 ? -1 : 0);
        for (int q = 0; q < NC; ++q) acc[r][q] = _mm256_setzero_pd();
    }
    const bool full = rows == 4 * RB;
    for (int p = 0; p < k; ++p) {
        const double* ap = a + static_cast<std::size_t>(p) * lda;
        const double* bp = b + static_cast<std::size_t>(p) * ldb;
        __m256d av[RB];
        for (int r = 0; r < RB; ++r) av[r] = full ? _mm256_loadu_pd(ap + 4 * r) : _mm256_maskload_pd(ap + 4 * r, mask[r]);
        for (int q = 0; q < NC; ++q) {
            const __m256d bq = _mm256_broadcast_sd(bp + q);
            for (int r = 0; r < RB; ++r) acc[r][q] = _mm256_fmadd_pd(av[r], bq, acc[r][q]);
        }
    }
    for (int q = 0; q < NC; ++q)
        for (int r = 0; r < RB; ++r) {
            double* cp = c + static_cast<std::size_t>(q) * ldc + 4 * r;
            if (full || rows - 4 * r >= 4) {
                _mm256_storeu_pd(cp, acc[r][q]);
            } else {
                alignas(32) double v[4];
                _mm256_store_pd(v, acc[r][q]);
                for (int e = 0; e < rows - 4 * r; ++e) cp[e] = v[e];
            }
        }
}

template <int RB>
HH_AVX2_TARGET inline void nt_rows_avx2(const double* a, int lda, const double* b, int ldb, int k, double* c, int ldc, int rows, int nc) {
    switch (nc) {
        case 1: return nt_block_avx2<RB, 1>(a, lda, b, ldb, k, c, ldc, rows);
        case 2: return nt_block_avx2<RB, 2>(a, lda, b, ldb, k, c, ldc, rows);
        case 3: return nt_block_avx2<RB, 3>(a, lda, b, ldb, k, c, ldc, rows);
        default: return nt_block_avx2<RB, 4>(a, lda, b, ldb, k, c, ldc, rows);
    }
}

// C (m x n, ldc) = A (m x k) A(0:n, 0:k)^T, only the rows from each column's 3x3 node block down
HH_AVX2_TARGET void outer_product_avx2(const double* a, int lda, int m, int n, int k, double* c, int ldc) {
    for (int j = 0; j < n; j += 4) {
        const int nc = std::min(4, n - j);
        for (int i = j - j % 3; i < m; i += 12) {
            const int rows = std::min(12, m - i);
            double* cij = c + i + static_cast<std::size_t>(j) * ldc;
            if (rows > 8) nt_rows_avx2<3>(a + i, lda, a + j, lda, k, cij, ldc, rows, nc);
            else if (rows > 4) nt_rows_avx2<2>(a + i, lda, a + j, lda, k, cij, ldc, rows, nc);
            else nt_rows_avx2<1>(a + i, lda, a + j, lda, k, cij, ldc, rows, nc);
        }
    }
}

bool use_avx512() {
#ifdef HH_PANEL_AVX512
    return active_simd_level() == 2;
#else
    return false;
#endif
}
}  // namespace

// With AVX2, the small products by the 12 x 4 kernel above (the grasping hand's 2078-node
// factorization 8.3 -> 6.5 ms, one core), the large ones by Eigen's baseline product: a simple
// AVX2 kernel without cache blocking took 470 ms against Eigen's 320 for a 20837-tet hand.
void panel_outer_product(const double* a, int lda, int m, int n, int k, double* c) {
#ifdef HH_PANEL_AVX512
    if (use_avx512()) return nt_product<true>(a, lda, a, lda, m, n, k, c, m, true);
#endif
    // (AVX2: small products here, whose A stays in L2 while it is read once per 4 columns; Eigen's
    // packing and cache blocking for the large ones)
    if (active_simd_level() == 1 && static_cast<long>(m) * k <= kSmallProduct) return outer_product_avx2(a, lda, m, n, k, c, m);
    ConstPanel am(a, m, k, Eigen::OuterStride<>(lda));
    Eigen::Map<Eigen::MatrixXd>(c, m, n).noalias() = am * am.topRows(n).transpose();
}

bool panel_cholesky(double* p, int ld, int m) {
#ifdef HH_PANEL_AVX512
    if (use_avx512()) return panel_cholesky_avx512(p, ld, m);
#endif
    Panel diag(p, m, m, Eigen::OuterStride<>(ld));
    if (Eigen::internal::llt_inplace<double, Eigen::Lower>::blocked(diag) >= 0 || !diag.diagonal().allFinite()) return false;
    if (ld > m) {
        Panel below(p + m, ld - m, m, Eigen::OuterStride<>(ld));
        diag.triangularView<Eigen::Lower>().adjoint().solveInPlace<Eigen::OnTheRight>(below);
    }
    return true;
}

}  // namespace hh
