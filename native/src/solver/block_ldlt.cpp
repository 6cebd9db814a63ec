#include "solver/block_ldlt.h"

#include <Eigen/OrderingMethods>
#include <algorithm>
#include <numeric>

namespace hh {

void BlockLDLT::analyze(const SpMat& a) {
    n_ = static_cast<int>(a.cols() / 3);
    const int* outer = a.outerIndexPtr();
    const int* inner = a.innerIndexPtr();
    auto offset = [&](int row, int col) {
        const int* begin = inner + outer[col];
        const int* end = inner + outer[col + 1];
        const int* it = std::lower_bound(begin, end, row);
        if (it == end || *it != row) throw std::logic_error("BlockLDLT: pattern is not made of 3x3 blocks");
        return static_cast<int>(it - inner);
    };
    // node graph: block (i, k) present when scalar (3i, 3k) is
    std::vector<Eigen::Triplet<double>> trip;
    for (int k = 0; k < n_; ++k)
        for (int p = outer[3 * k]; p < outer[3 * k + 1]; ++p)
            if (inner[p] % 3 == 0) trip.emplace_back(inner[p] / 3, k, 1.0);
    SpMat graph(n_, n_);
    graph.setFromTriplets(trip.begin(), trip.end());
    Eigen::PermutationMatrix<Eigen::Dynamic, Eigen::Dynamic, int> perm;
    Eigen::AMDOrdering<int> amd;
    amd(graph, perm);  // eliminate old node perm.indices()[new] at step new
    order_.assign(perm.indices().data(), perm.indices().data() + n_);
    inverse_.assign(n_, 0);
    for (int k = 0; k < n_; ++k) inverse_[order_[k]] = k;

    column_.assign(n_, {});
    for (int k = 0; k < n_; ++k) {
        const int old_k = order_[k];
        for (SpMat::InnerIterator it(graph, old_k); it; ++it) {
            const int old_i = static_cast<int>(it.row());
            const int i = inverse_[old_i];
            if (i > k) continue;
            BlockRef ref;
            ref.row = i;
            for (int r = 0; r < 3; ++r)
                for (int c = 0; c < 3; ++c) ref.offsets[3 * r + c] = offset(3 * old_i + r, 3 * old_k + c);
            column_[k].push_back(ref);
        }
    }
    // elimination tree and column counts of L (Davis, LDL symbolic)
    parent_.assign(n_, -1);
    lnz_.assign(n_, 0);
    flag_.assign(n_, -1);
    for (int k = 0; k < n_; ++k) {
        flag_[k] = k;
        for (const BlockRef& ref : column_[k])
            for (int i = ref.row; i < k && flag_[i] != k; i = parent_[i]) {
                if (parent_[i] == -1) parent_[i] = k;
                ++lnz_[i];
                flag_[i] = k;
            }
    }
    factor_flops_ = 0;
    for (int k = 0; k < n_; ++k) factor_flops_ += 54.0 * lnz_[k] * (lnz_[k] + 1) / 2 + 54.0 * lnz_[k];
    lp_.assign(n_ + 1, 0);
    for (int k = 0; k < n_; ++k) lp_[k + 1] = lp_[k] + lnz_[k];
    li_.assign(lp_[n_], 0);
    lx_.assign(lp_[n_], Mat3::Zero());
    d_inverse_.assign(n_, Mat3::Identity());
    y_.assign(n_, Mat3::Zero());
    pattern_.assign(n_, 0);
}

void BlockLDLT::factorize(const SpMat& a) {
    const double* values = a.valuePtr();
    std::fill(flag_.begin(), flag_.end(), -1);
    std::fill(lnz_.begin(), lnz_.end(), 0);
    for (int k = 0; k < n_; ++k) {
        // scatter column k of the permuted A (upper part) into y, and find the pattern of
        // row k of L by walking up the elimination tree
        y_[k].setZero();
        int top = n_;
        flag_[k] = k;
        for (const BlockRef& ref : column_[k]) {
            Mat3& yi = y_[ref.row];
            for (int e = 0; e < 9; ++e) yi(e / 3, e % 3) += values[ref.offsets[e]];
            int len = 0;
            for (int i = ref.row; flag_[i] != k; i = parent_[i]) {
                pattern_[len++] = i;
                flag_[i] = k;
            }
            while (len > 0) pattern_[--top] = pattern_[--len];
        }
        Mat3 dk = y_[k];
        y_[k].setZero();
        for (; top < n_; ++top) {
            const int i = pattern_[top];
            const Mat3 yi = y_[i];
            y_[i].setZero();
            const int end = lp_[i] + lnz_[i];
            for (int p = lp_[i]; p < end; ++p) y_[li_[p]].noalias() -= lx_[p] * yi;
            const Mat3 lki = yi.transpose() * d_inverse_[i];  // L(k, i) = Y_i^T D_i^-1
            dk.noalias() -= lki * yi;
            li_[end] = k;
            lx_[end] = lki;
            ++lnz_[i];
        }
        const Mat3 dsym = 0.5 * (dk + dk.transpose());
        Eigen::LLT<Mat3> llt(dsym);
        if (llt.info() != Eigen::Success || !dsym.allFinite())
            throw NumericalError(
                "the deformable system At is not positive definite (block LDL^T failed): check for "
                "inverted elements, negative parameters or a far too large time step");
        d_inverse_[k] = llt.solve(Mat3::Identity());
    }
}

namespace {

// L D L^T x = b on the permuted right-hand sides, K at a time, stored node-major so that a
// node's 3 x K values are contiguous: every 3x3 block of L is loaded once for all K.
struct Factor {
    int n;
    const int *lp, *lnz, *li;
    const double *lx, *d_inverse;  // 3x3 blocks, column-major, 9 doubles each
};

// Four doubles as one value (GCC/Clang vector extension): explicit SIMD the compiler maps to
// one AVX register or two SSE registers; aligned(8) allows unaligned loads and stores.
typedef double V4 __attribute__((vector_size(32), aligned(8)));

template <int K>
__attribute__((always_inline)) inline void solve_permuted(const Factor& f, double* x) {
    static_assert(K % 4 == 0, "right-hand sides in groups of four");
    constexpr int N = K / 4;  // vectors per row of a node's 3 x K block
    V4* xv = reinterpret_cast<V4*>(x);
    for (int i = 0; i < f.n; ++i) {  // L z = b
        V4 xi[3 * N];
        for (int e = 0; e < 3 * N; ++e) xi[e] = xv[3 * N * i + e];
        for (int p = f.lp[i], end = f.lp[i] + f.lnz[i]; p < end; ++p) {
            const double* l = f.lx + 9 * p;
            V4* xr = xv + 3 * N * f.li[p];
            for (int r = 0; r < 3; ++r)
                for (int j = 0; j < N; ++j) xr[r * N + j] -= l[r] * xi[j] + l[3 + r] * xi[N + j] + l[6 + r] * xi[2 * N + j];
        }
    }
    for (int i = 0; i < f.n; ++i) {  // z <- D^-1 z
        V4* xi = xv + 3 * N * i;
        const double* d = f.d_inverse + 9 * i;
        V4 t[3 * N];
        for (int r = 0; r < 3; ++r)
            for (int j = 0; j < N; ++j) t[r * N + j] = d[r] * xi[j] + d[3 + r] * xi[N + j] + d[6 + r] * xi[2 * N + j];
        for (int e = 0; e < 3 * N; ++e) xi[e] = t[e];
    }
    for (int i = f.n - 1; i >= 0; --i) {  // L^T x = z
        V4 t[3 * N];
        V4* xi = xv + 3 * N * i;
        for (int e = 0; e < 3 * N; ++e) t[e] = xi[e];
        for (int p = f.lp[i], end = f.lp[i] + f.lnz[i]; p < end; ++p) {
            const double* l = f.lx + 9 * p;
            const V4* xr = xv + 3 * N * f.li[p];
            for (int c = 0; c < 3; ++c)
                for (int j = 0; j < N; ++j)
                    t[c * N + j] -= l[3 * c] * xr[j] + l[3 * c + 1] * xr[N + j] + l[3 * c + 2] * xr[2 * N + j];
        }
        for (int e = 0; e < 3 * N; ++e) xi[e] = t[e];
    }
}

// One right-hand side: scalar code (a 3-vector per node does not fill a SIMD register).
template <>
inline void solve_permuted<1>(const Factor& f, double* x) {
    for (int i = 0; i < f.n; ++i) {
        const double x0 = x[3 * i], x1 = x[3 * i + 1], x2 = x[3 * i + 2];
        for (int p = f.lp[i], end = f.lp[i] + f.lnz[i]; p < end; ++p) {
            const double* l = f.lx + 9 * p;
            double* xr = x + 3 * f.li[p];
            for (int r = 0; r < 3; ++r) xr[r] -= l[r] * x0 + l[3 + r] * x1 + l[6 + r] * x2;
        }
    }
    for (int i = 0; i < f.n; ++i) {
        const double* d = f.d_inverse + 9 * i;
        const double x0 = x[3 * i], x1 = x[3 * i + 1], x2 = x[3 * i + 2];
        for (int r = 0; r < 3; ++r) x[3 * i + r] = d[r] * x0 + d[3 + r] * x1 + d[6 + r] * x2;
    }
    for (int i = f.n - 1; i >= 0; --i) {
        double t0 = x[3 * i], t1 = x[3 * i + 1], t2 = x[3 * i + 2];
        for (int p = f.lp[i], end = f.lp[i] + f.lnz[i]; p < end; ++p) {
            const double* l = f.lx + 9 * p;
            const double* xr = x + 3 * f.li[p];
            t0 -= l[0] * xr[0] + l[1] * xr[1] + l[2] * xr[2];
            t1 -= l[3] * xr[0] + l[4] * xr[1] + l[5] * xr[2];
            t2 -= l[6] * xr[0] + l[7] * xr[1] + l[8] * xr[2];
        }
        x[3 * i] = t0;
        x[3 * i + 1] = t1;
        x[3 * i + 2] = t2;
    }
}

// The same loops compiled for AVX2 + FMA, chosen at run time when the CPU has them: the
// library itself is built for the baseline x86-64 instruction set.
#if defined(__GNUC__) && defined(__x86_64__)
#define HH_HAVE_AVX2_KERNELS 1
template <int K>
__attribute__((target("avx2,fma"))) void solve_permuted_avx2(const Factor& f, double* x) {
    solve_permuted<K>(f, x);
}
bool cpu_has_avx2() {
    static const bool has = __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
    return has;
}
#endif

template <int K>
void solve_dispatch(const Factor& f, double* x) {
#ifdef HH_HAVE_AVX2_KERNELS
    if (cpu_has_avx2()) return solve_permuted_avx2<K>(f, x);
#endif
    solve_permuted<K>(f, x);
}

}  // namespace

void BlockLDLT::solve_node_major(double* b, int w, const std::vector<Mat3>* warp) const {
    if (w != 1 && w != 4 && w != 8) throw std::logic_error("BlockLDLT::solve_node_major: width must be 1, 4 or 8");
    work_.resize(static_cast<size_t>(3) * n_ * w);
    double* x = work_.data();
    for (int node = 0; node < n_; ++node) {  // x = P W^T b
        const int old = order_[node];
        const double* bn = b + 3 * w * old;
        double* xn = x + 3 * w * node;
        if (!warp) {
            std::copy(bn, bn + 3 * w, xn);
            continue;
        }
        const double* m = (*warp)[old].data();  // column-major: W^T(r, c) = m[3 r + c]
        for (int r = 0; r < 3; ++r)
            for (int j = 0; j < w; ++j) xn[r * w + j] = m[3 * r] * bn[j] + m[3 * r + 1] * bn[w + j] + m[3 * r + 2] * bn[2 * w + j];
    }
    const Factor f{n_, lp_.data(), lnz_.data(), li_.data(), lx_.empty() ? nullptr : lx_[0].data(), d_inverse_[0].data()};
    if (w == 1) solve_dispatch<1>(f, x);
    else if (w == 4) solve_dispatch<4>(f, x);
    else solve_dispatch<8>(f, x);
    for (int node = 0; node < n_; ++node) {  // b = W P^T x
        const int old = order_[node];
        const double* xn = x + 3 * w * node;
        double* bn = b + 3 * w * old;
        if (!warp) {
            std::copy(xn, xn + 3 * w, bn);
            continue;
        }
        const double* m = (*warp)[old].data();  // W(r, c) = m[r + 3 c]
        for (int r = 0; r < 3; ++r)
            for (int j = 0; j < w; ++j) bn[r * w + j] = m[r] * xn[j] + m[r + 3] * xn[w + j] + m[r + 6] * xn[2 * w + j];
    }
}

VecX BlockLDLT::solve(const VecX& b) const {
    MatX x = b;
    solve(x, nullptr);
    return x.col(0);
}

void BlockLDLT::solve(MatX& b) const { solve(b, nullptr); }

void BlockLDLT::solve(MatX& b, const std::vector<Mat3>* warp) const {
    if (b.rows() != 3 * n_) throw std::logic_error("BlockLDLT::solve: right-hand side of the wrong size");
    for (Eigen::Index first = 0; first < b.cols(); first += 8) {
        const int k = static_cast<int>(std::min<Eigen::Index>(8, b.cols() - first));
        const int w = k == 1 ? 1 : (k <= 4 ? 4 : 8);  // 2-3 and 5-7 right-hand sides are padded
        packed_.assign(static_cast<size_t>(3) * n_ * w, 0.0);
        for (int j = 0; j < k; ++j)
            for (int e = 0; e < 3 * n_; ++e) packed_[w * e + j] = b(e, first + j);
        solve_node_major(packed_.data(), w, warp);
        for (int j = 0; j < k; ++j)
            for (int e = 0; e < 3 * n_; ++e) b(e, first + j) = packed_[w * e + j];
    }
}

}  // namespace hh
