// The contact solver's view of a skeleton hand (SkeletonSystem::apply_inverse*): the velocity
// response A^-1 rhs of Eq. 7 for B bones to impulses on the flesh, from the step's own solve
// (Eqs. 12-13 with its factor of A_t, its columns X = A_t^-1 A_th and the LU of S), as
// HandSystem's for the palm handle: one A_t pass per right-hand side, then
//   v_h = S^-1 (rhs_h - A_ht A_t^-1 rhs_t),   v_t = A_t^-1 rhs_t - X v_h.
#include <algorithm>

#include "solver/block_ldlt.h"  // kWidestSolve
#include "solver/skeleton_system.h"

namespace hh {

namespace {
// A_ht y for one flesh vector y (3n): each bone's rows touch only its nodes (Eq. 9)
VecX aht_times(const SkeletonSystem& sys, const double* y) {
    VecX out = VecX::Zero(6 * sys.n_bones());
    for (int b = 0; b < sys.n_bones(); ++b)
        for (size_t j = 0; j < sys.nodes[b]->size(); ++j)
            out.segment<6>(6 * b) += sys.Aht[b][j] * Eigen::Map<const Vec3>(y + 3 * (*sys.nodes[b])[j]);
    return out;
}
// A_th v for the bones' velocities v (6B): each bone's columns touch only its nodes
VecX ath_times(const SkeletonSystem& sys, const VecX& v) {
    VecX out = VecX::Zero(sys.tool.A.rows());
    for (int b = 0; b < sys.n_bones(); ++b)
        for (size_t j = 0; j < sys.nodes[b]->size(); ++j)
            out.segment<3>(3 * (*sys.nodes[b])[j]) += sys.Ath[b][j] * v.segment<6>(6 * b);
    return out;
}
}  // namespace

VecX SkeletonSystem::apply_inverse(const VecX& rhs) const {
    MatX out;
    apply_inverse_many(rhs, out);
    return out.col(0);
}

void SkeletonSystem::apply_inverse_many(const MatX& rhs, MatX& out, const std::vector<int>* rows) const {
    const Eigen::Index n3 = tool.A.rows(), nh = 6 * n_bones(), k = rhs.cols();
    out.resize(rows ? static_cast<Eigen::Index>(rows->size()) : nh + n3, k);
    // with asked rows the A_t passes need the flesh only at their nodes and at every bone's nodes
    // (A_ht reads those; none when all are prescribed, A_ht = 0): the factor's backward pass skips the rest
    std::vector<int> wanted;
    if (rows) {
        for (int row : *rows)
            if (row >= nh) wanted.push_back(static_cast<int>((row - nh) / 3));
        if (!prescribed_)
            for (const std::vector<int>* bone : nodes) wanted.insert(wanted.end(), bone->begin(), bone->end());
        std::sort(wanted.begin(), wanted.end());
        wanted.erase(std::unique(wanted.begin(), wanted.end()), wanted.end());
    }
    MatX flesh;
    for (Eigen::Index first = 0; first < k; first += kWidestSolve) {
        const Eigen::Index w = std::min<Eigen::Index>(kWidestSolve, k - first);
        MatX vh(nh, w);
        if (prescribed_) {  // v_h = rhs_h, v_t = A_t^-1 (rhs_t - A_th v_h): no columns A_t^-1 A_th
            vh = rhs.block(0, first, nh, w);
            MatX rt = rhs.block(nh, first, n3, w);
            for (Eigen::Index j = 0; j < w; ++j)
                if (!vh.col(j).isZero(0)) rt.col(j) -= ath_times(*this, vh.col(j));
            tool.solve_response(rt, flesh, rows ? &wanted : nullptr);
        } else {
            tool.solve_response(rhs.block(nh, first, n3, w), flesh, rows ? &wanted : nullptr);
            for (Eigen::Index j = 0; j < w; ++j)
                vh.col(j) = schur_lu_.solve(VecX(rhs.col(first + j).head(nh) - aht_times(*this, flesh.col(j).data())));
        }
        if (!rows) {
            out.block(0, first, nh, w) = vh;
            if (prescribed_) out.block(nh, first, n3, w) = flesh;
            else out.block(nh, first, n3, w).noalias() = flesh - response_ * vh;  // Eq. 12
            continue;
        }
        for (size_t i = 0; i < rows->size(); ++i) {
            const int row = (*rows)[i];
            const Eigen::Index at = static_cast<Eigen::Index>(i);
            if (row < nh) out.block(at, first, 1, w) = vh.row(row);
            else if (prescribed_) out.block(at, first, 1, w) = flesh.row(row - nh);
            else out.block(at, first, 1, w) = flesh.row(row - nh) - response_.row(row - nh) * vh;
        }
    }
    if (!out.allFinite()) throw NumericalError("the skeleton hand's contact response is not finite: reduce the time step");
}

}  // namespace hh
