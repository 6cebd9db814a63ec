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

VecX BlockLDLT::solve(const VecX& b) const {
    VecX x(3 * n_);
    for (int k = 0; k < n_; ++k) x.segment<3>(3 * k) = b.segment<3>(3 * order_[k]);
    for (int i = 0; i < n_; ++i) {  // L z = b
        const Vec3 xi = x.segment<3>(3 * i);
        for (int p = lp_[i]; p < lp_[i] + lnz_[i]; ++p) x.segment<3>(3 * li_[p]).noalias() -= lx_[p] * xi;
    }
    for (int i = 0; i < n_; ++i) x.segment<3>(3 * i) = d_inverse_[i] * x.segment<3>(3 * i).eval();
    for (int i = n_ - 1; i >= 0; --i) {  // L^T x = z
        Vec3 xi = x.segment<3>(3 * i);
        for (int p = lp_[i]; p < lp_[i] + lnz_[i]; ++p) xi.noalias() -= lx_[p].transpose() * x.segment<3>(3 * li_[p]);
        x.segment<3>(3 * i) = xi;
    }
    VecX out(3 * n_);
    for (int k = 0; k < n_; ++k) out.segment<3>(3 * order_[k]) = x.segment<3>(3 * k);
    return out;
}

}  // namespace hh
