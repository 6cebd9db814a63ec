#include "solver/hand_system.h"

#include <Eigen/SparseLU>
#include <chrono>

namespace hh {

namespace {
double seconds_since(std::chrono::steady_clock::time_point t0) {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}
}  // namespace

Vec6 HandSystem::aht_times(const VecX& vt) const {
    Vec6 out = Vec6::Zero();
    for (size_t j = 0; j < coupled_nodes.size(); ++j) out += Aht[j] * vt.segment<3>(3 * coupled_nodes[j]);
    return out;
}

// Section 6 pseudocode. (The paper's listing writes "Handle.r = bt - Aht Tool.s"; Eq. 13
// has b_h there, which is what is implemented.)
void HandSystem::solve() {
    using clock = std::chrono::steady_clock;
    const Eigen::Index n3 = tool.A.rows();
    const Vec6 bh = r.head<6>();
    const VecX bt = r.tail(n3);
    t_deformable = 0;
    t_schur = 0;

    // Right-hand side of Eq. 13
    auto t0 = clock::now();
    tool.r = bt;
    tool.select_slot(0);
    tool.solve();
    t_deformable += seconds_since(t0);
    handle.r = bh - aht_times(tool.s);

    // Schur complement of Eq. 13, one column of Ath at a time
    temp_.resize(6);
    Mat6 aht_temp;
    for (int i = 0; i < 6; ++i) {
        tool.r.setZero();
        for (size_t j = 0; j < coupled_nodes.size(); ++j)
            tool.r.segment<3>(3 * coupled_nodes[j]) = Ath[j].col(i);
        t0 = clock::now();
        tool.select_slot(1 + i);
        tool.solve();
        t_deformable += seconds_since(t0);
        temp_[i] = tool.s;
        aht_temp.col(i) = aht_times(tool.s);
    }
    t0 = clock::now();
    aht_inverse_ath = aht_temp;
    handle.A = Ah - aht_temp;
    handle.solve();  // v_h
    const Vec6 vh = handle.s;
    t_schur += seconds_since(t0);

    // Eq. 12: the tool velocity
    tool.r = bt;
    for (size_t j = 0; j < coupled_nodes.size(); ++j)
        tool.r.segment<3>(3 * coupled_nodes[j]) -= Ath[j] * vh;
    t0 = clock::now();
    tool.select_slot(7);
    tool.solve();
    t_deformable += seconds_since(t0);

    s.resize(6 + n3);
    s.head<6>() = vh;
    s.tail(n3) = tool.s;
}

VecX HandSystem::apply_inverse(const VecX& rhs) {
    const Eigen::Index n3 = tool.A.rows();
    tool.r = rhs.tail(n3);
    tool.select_slot(8);
    tool.solve();
    const VecX s0 = tool.s;
    handle.r = rhs.head<6>() - aht_times(s0);
    handle.solve();  // handle.A still holds the Schur complement
    VecX out(6 + n3);
    out.head<6>() = handle.s;
    out.tail(n3) = s0;
    for (int i = 0; i < 6; ++i) out.tail(n3) -= temp_[i] * handle.s[i];
    return out;
}

VecX solve_monolithic(const HandSystem& system, const VecX& rhs) {
    const SpMat& at = system.tool.A;
    const Eigen::Index n3 = at.rows();
    std::vector<Eigen::Triplet<double>> trip;
    trip.reserve(at.nonZeros() + 36 + system.coupled_nodes.size() * 36);
    for (int i = 0; i < 6; ++i)
        for (int j = 0; j < 6; ++j) trip.emplace_back(i, j, system.Ah(i, j));
    for (Eigen::Index c = 0; c < at.outerSize(); ++c)
        for (SpMat::InnerIterator it(at, c); it; ++it) trip.emplace_back(6 + it.row(), 6 + it.col(), it.value());
    for (size_t j = 0; j < system.coupled_nodes.size(); ++j) {
        const int base = 6 + 3 * system.coupled_nodes[j];
        for (int a = 0; a < 3; ++a)
            for (int b = 0; b < 6; ++b) {
                trip.emplace_back(base + a, b, system.Ath[j](a, b));
                trip.emplace_back(b, base + a, system.Aht[j](b, a));
            }
    }
    SpMat a(6 + n3, 6 + n3);
    a.setFromTriplets(trip.begin(), trip.end());
    Eigen::SparseLU<SpMat> lu;
    lu.compute(a);
    if (lu.info() != Eigen::Success) throw NumericalError("monolithic reference: sparse LU failed");
    VecX x = lu.solve(rhs);
    if (!x.allFinite()) throw NumericalError("monolithic reference produced non-finite values");
    return x;
}

}  // namespace hh
