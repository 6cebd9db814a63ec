#include "solver/skeleton_system.h"

#include <Eigen/SparseLU>
#include <algorithm>
#include <chrono>

#include "common/clock.h"

namespace hh {

void SkeletonSystem::resize(int n_bones) {
    Ah.assign(n_bones, Mat6::Zero());
    nodes.assign(n_bones, nullptr);
    Ath.resize(n_bones);
    Aht.resize(n_bones);
    links.clear();
}

// Whether every bone's rows are v_b = target (Ah = I, A_ht = 0, no joint links: a prescribed
// bone's, sim/skeleton_step.cpp), so that v_h = b_h and S = I.
bool SkeletonSystem::all_prescribed() const {
    if (!links.empty()) return false;
    for (int b = 0; b < n_bones(); ++b) {
        if (Ah[b] != Mat6::Identity()) return false;
        for (const Mat63& block : Aht[b])
            if (!block.isZero(0)) return false;
    }
    return true;
}

void SkeletonSystem::solve() {
    const Eigen::Index nh = 6 * n_bones();
    t_deformable = 0;
    t_schur = 0;
    response_ready_ = false;
    // As HandSystem::solve: with an iterative tool solver the columns are solved
    // min(1, 100 / cond(S)) times tighter than b_t, cond(S) (now 6B x 6B) from the last step.
    const double scale = schur_condition_ > 0 ? std::min(1.0, std::max(1e-4, 100.0 / schur_condition_)) : 1e-3;
    for (Eigen::Index i = 1; i <= nh; ++i) tool.set_tolerance_scale(static_cast<int>(i), scale);
    if (all_prescribed()) solve_prescribed();
    else solve_schur();
    if (!s.allFinite()) throw NumericalError("the skeleton's step is not finite: reduce the time step");
    tool.s = s.tail(tool.A.rows());
}

// The bones' columns of A_th as a flesh matrix (3n x 6B): bone b's six columns are non-zero only
// at its nodes
void SkeletonSystem::ath_columns(MatX& out, Eigen::Index first_col) const {
    for (int b = 0; b < n_bones(); ++b)
        for (size_t j = 0; j < nodes[b]->size(); ++j)
            out.block<3, 6>(3 * (*nodes[b])[j], first_col + 6 * b) = Ath[b][j];
}

// Every bone prescribed: v_h = b_h is known, so Eq. 12 is one flesh solve,
// v_t = A_t^-1 (b_t - A_th v_h), instead of 1 + 6B columns (the 16-bone grasp: 1 against 97).
// S = I; the columns A_t^-1 A_th are solved only if flesh_response() asks for them.
void SkeletonSystem::solve_prescribed() {
    using clock = std::chrono::steady_clock;
    const Eigen::Index n3 = tool.A.rows(), nh = 6 * n_bones();
    auto t0 = clock::now();
    schur.setIdentity(nh, nh);
    schur_lu_.compute(schur);
    if (tool.solver() != DeformableSolver::Cholesky) schur_condition_ = 1;  // (as solve_schur's SVD of S = I)
    s.resize(nh + n3);
    s.head(nh) = r.head(nh);
    rhs_ = r.tail(n3);
    for (int b = 0; b < n_bones(); ++b)
        for (size_t j = 0; j < nodes[b]->size(); ++j)
            rhs_.col(0).segment<3>(3 * (*nodes[b])[j]) -= Ath[b][j] * s.segment<6>(6 * b);
    t_schur += seconds_since(t0);
    t0 = clock::now();
    tool.solve_many(rhs_, solved_, 0);
    t_deformable += seconds_since(t0);
    columns = 1;
    s.tail(n3) = solved_.col(0);
    prescribed_ = true;
}

const MatX& SkeletonSystem::flesh_response() const {
    if (response_ready_ || !prescribed_) return response_;  // (before any solve: empty)
    MatX ath = MatX::Zero(tool.A.rows(), 6 * n_bones());
    ath_columns(ath, 0);
    tool.solve_many(ath, response_, 1);  // slots 1..6B, as solve_schur's
    response_ready_ = true;
    return response_;
}

void SkeletonSystem::solve_schur() {
    using clock = std::chrono::steady_clock;
    const Eigen::Index n3 = tool.A.rows();
    const int nb = n_bones();
    const Eigen::Index nh = 6 * nb;
    prescribed_ = false;

    // b_t and the 6B columns of A_th
    rhs_.setZero(n3, 1 + nh);
    rhs_.col(0) = r.tail(n3);
    ath_columns(rhs_, 1);
    auto t0 = clock::now();
    tool.solve_many(rhs_, solved_, 0);  // one factor of A_t for all 1 + 6B right-hand sides
    t_deformable += seconds_since(t0);
    columns = static_cast<int>(1 + nh);

    // S = A_h - A_ht A_t^-1 A_th and b_h - A_ht A_t^-1 b_t (Eq. 13): bone b's rows of A_ht
    // touch only its nodes' rows of the solved columns
    t0 = clock::now();
    schur.setZero(nh, nh);
    for (int b = 0; b < nb; ++b) schur.block<6, 6>(6 * b, 6 * b) = Ah[b];
    for (const Link& l : links) schur.block<6, 6>(6 * l.row, 6 * l.col) += l.block;
    VecX rh = r.head(nh);
    // column by column, so each solved column is read in order (nodes ascending) with fixed-size
    // 6x3 products (by 3 x 6B row blocks, striding across all the columns, the 16-bone hand's
    // Schur part took 0.63 ms a step against 0.41 now, bench/bench_skeleton.py)
    for (Eigen::Index c = 0; c <= nh; ++c) {
        const double* col = solved_.col(c).data();
        for (int b = 0; b < nb; ++b) {
            Vec6 sum = Vec6::Zero();
            for (size_t j = 0; j < nodes[b]->size(); ++j)
                sum.noalias() += Aht[b][j] * Eigen::Map<const Vec3>(col + 3 * (*nodes[b])[j]);
            if (c == 0) rh.segment<6>(6 * b) -= sum;
            else schur.block<6, 1>(6 * b, c - 1) -= sum;
        }
    }
    if (tool.solver() != DeformableSolver::Cholesky) {
        const VecX sv = Eigen::JacobiSVD<MatX>(schur).singularValues();
        schur_condition_ = sv[nh - 1] > 0 ? sv[0] / sv[nh - 1] : 1e16;
    }
    // Partial pivoting suffices: S is dominated by its diagonal blocks (each bone's mass,
    // inertia and springs; a prescribed bone's identity), and a singular S shows as a non-finite
    // step below.
    schur_lu_.compute(schur);
    const VecX vh = schur_lu_.solve(rh);
    t_schur += seconds_since(t0);

    // Eq. 12: v_t = A_t^-1 b_t - (A_t^-1 A_th) v_h
    s.resize(nh + n3);
    s.head(nh) = vh;
    response_ = solved_.rightCols(nh);
    response_ready_ = true;
    s.tail(n3) = solved_.col(0) - response_ * vh;
}

VecX solve_monolithic(const SkeletonSystem& system, const VecX& rhs) {
    const SpMat& at = system.tool.A;
    const int nb = system.n_bones();
    const Eigen::Index nh = 6 * nb, n3 = at.rows();
    std::vector<Eigen::Triplet<double>> trip;
    trip.reserve(at.nonZeros() + 36 * (nb + system.links.size()));
    for (const SkeletonSystem::Link& l : system.links)
        for (int i = 0; i < 6; ++i)
            for (int j = 0; j < 6; ++j) trip.emplace_back(6 * l.row + i, 6 * l.col + j, l.block(i, j));
    for (int b = 0; b < nb; ++b) {
        for (int i = 0; i < 6; ++i)
            for (int j = 0; j < 6; ++j) trip.emplace_back(6 * b + i, 6 * b + j, system.Ah[b](i, j));
        for (size_t q = 0; q < system.nodes[b]->size(); ++q) {
            const Eigen::Index base = nh + 3 * (*system.nodes[b])[q];
            for (int a = 0; a < 3; ++a)
                for (int c = 0; c < 6; ++c) {
                    trip.emplace_back(base + a, 6 * b + c, system.Ath[b][q](a, c));
                    trip.emplace_back(6 * b + c, base + a, system.Aht[b][q](c, a));
                }
        }
    }
    for (Eigen::Index c = 0; c < at.outerSize(); ++c)
        for (SpMat::InnerIterator it(at, c); it; ++it) trip.emplace_back(nh + it.row(), nh + it.col(), it.value());
    SpMat a(nh + n3, nh + n3);
    a.setFromTriplets(trip.begin(), trip.end());
    Eigen::SparseLU<SpMat> lu;
    lu.compute(a);
    if (lu.info() != Eigen::Success) throw NumericalError("monolithic reference: sparse LU failed");
    VecX x = lu.solve(rhs);
    if (!x.allFinite()) throw NumericalError("monolithic reference produced non-finite values");
    return x;
}

}  // namespace hh
