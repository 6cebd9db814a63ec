#include "solver/hand_system.h"
#include "solver/block_ldlt.h"
#include "common/clock.h"
#include "common/simd.h"

#include <Eigen/SparseLU>
#include <algorithm>
#include <chrono>
#if defined(__GNUC__) && defined(__x86_64__)
#include <immintrin.h>
#endif

namespace hh {

Vec6 HandSystem::aht_times(const VecX& vt) const {
    Vec6 out = Vec6::Zero();
    for (size_t j = 0; j < coupled_nodes.size(); ++j) out += Aht[j] * vt.segment<3>(3 * coupled_nodes[j]);
    return out;
}

// Section 6 pseudocode. (The paper's listing writes "Handle.r = bt - Aht Tool.s"; Eq. 13
// has b_h there, which is what is implemented.) The seven solves with At that do not depend on
// each other (b_t and the 6 columns of Ath) go to the tool as one batch; the pseudocode's last
// solve, A_t^-1 (b_t - Ath v_h), is the same combination of the solved columns,
// A_t^-1 b_t - (A_t^-1 Ath) v_h, so it costs no eighth solve.
void HandSystem::solve() {
    using clock = std::chrono::steady_clock;
    const Eigen::Index n3 = tool.A.rows();
    const Vec6 bh = r.head<6>();
    t_deformable = 0;
    t_schur = 0;
    std::fill(aht_prepared_.begin(), aht_prepared_.end(), 0);  // (a new step's At and Aht)

    // Right-hand sides: b_t (Eq. 13) and the columns of Ath (Schur complement)
    rhs_.setZero(n3, 7);
    rhs_.col(0) = r.tail(n3);
    for (size_t j = 0; j < coupled_nodes.size(); ++j)
        rhs_.block<3, 6>(3 * coupled_nodes[j], 1) = Ath[j];
    auto t0 = clock::now();
    // S = Ah - Aht A_t^-1 Ath can be worse conditioned than At (a stiff handle on light flesh):
    // a relative error e in the columns A_t^-1 Ath moves v_h by about cond(S) e. With an
    // iterative tool solver they are solved min(1, 100 / cond(S)) times tighter than b_t, cond(S)
    // from the last step (a box hand, cond(S) ~ 3e4: at 1e-10 v_h was 1.5e-8 off, at 3.6e-13
    // ~5e-11; the 1600-tet hand with default parameters: cond(S) ~ 120, so ~1e-10 suffices).
    const double scale = schur_condition_ > 0 ? std::min(1.0, std::max(1e-4, 100.0 / schur_condition_)) : 1e-3;
    for (int i = 1; i <= 6; ++i) tool.set_tolerance_scale(i, scale);
    VecX carried_flesh;       // A_t^-1 carried_t (the tool's response operator, single precision)
    int carried_factor = -1;  // tool.factorizations when it was solved
    auto carried_pass = [&] {
        carried_factor = tool.factorizations;
        tool.solve_response_single(carried.tail(n3), carried_flesh);
    };
    if (beside && carried.size()) {
        tool.solve_many_split(rhs_, solved_, 0, 1, beside, carried_pass);
    } else if (beside) {
        tool.solve_many_split(rhs_, solved_, 0, 1, beside);
    } else {
        tool.solve_many(rhs_, solved_, 0);
    }
    // (not solved yet, or on a factor renewed since: the groups' stale path)
    if (carried.size() && carried_factor != tool.factorizations) carried_pass();
    t_deformable += seconds_since(t0);

    t0 = clock::now();
    handle.r = bh - aht_times(solved_.col(0));
    response_ = solved_.rightCols<6>();
    Mat6 aht_temp;
    for (int i = 0; i < 6; ++i) aht_temp.col(i) = aht_times(response_.col(i));
    aht_inverse_ath = aht_temp;
    handle.A = Ah - aht_temp;
    if (tool.solver() != DeformableSolver::Cholesky) {
        const Vec6 sv = Eigen::JacobiSVD<Mat6>(handle.A).singularValues();
        schur_condition_ = sv[5] > 0 ? sv[0] / sv[5] : 1e16;
    }
    handle.solve();  // v_h
    const Vec6 vh = handle.s;
    t_schur += seconds_since(t0);

    // Eq. 12: the tool velocity
    s.resize(6 + n3);
    s.head<6>() = vh;
    s.tail(n3) = solved_.col(0) - solved_.rightCols<6>() * vh;
    tool.s = s.tail(n3);
    if (carried.size()) {
        carried_response = finish_inverse(carried, carried_flesh);
        carried.resize(0);
    }
}

VecX HandSystem::apply_inverse(const VecX& rhs, bool single) {
    const Eigen::Index n3 = tool.A.rows();
    VecX s0;
    if (single) {
        tool.solve_response_single(rhs.tail(n3), s0);
    } else if (beside) {
        tool.solve_response_split(rhs.tail(n3), s0, beside);
    } else {
        MatX solved;
        tool.solve_response(rhs.tail(n3), solved);
        s0 = solved.col(0);
    }
    return finish_inverse(rhs, s0);
}

VecX HandSystem::finish_inverse(const VecX& rhs, const VecX& s0) {
    const Eigen::Index n3 = tool.A.rows();
    handle.r = rhs.head<6>() - aht_times(s0);
    handle.solve();  // handle.A still holds the Schur complement
    VecX out(6 + n3);
    out.head<6>() = handle.s;
    out.tail(n3) = s0;
    out.tail(n3) -= response_ * handle.s;
    return out;
}

void HandSystem::apply_inverse_many(const MatX& rhs, MatX& out, const std::vector<int>* rows) {
    const Eigen::Index n3 = tool.A.rows();
    const Eigen::Index k = rhs.cols();
    out.resize(rows ? static_cast<Eigen::Index>(rows->size()) : 6 + n3, k);
    Eigen::FullPivLU<Mat6> schur(handle.A);  // handle.A still holds the Schur complement
    // With asked rows, the tool solves only need the flesh at their nodes and at the coupled
    // nodes (Aht reads those, unless it is zero): the factor's backward pass skips the rest.
    const bool coupled = !aht_zero();
    std::vector<int> wanted;
    if (rows) {
        for (int row : *rows)
            if (row >= 6) wanted.push_back((row - 6) / 3);
        if (coupled) wanted.insert(wanted.end(), coupled_nodes.begin(), coupled_nodes.end());
    }
    MatX flesh;
    for (Eigen::Index first = 0; first < k; first += kWidestSolve) {  // (as many as a pass takes)
        const Eigen::Index w = std::min<Eigen::Index>(kWidestSolve, k - first);
        tool.solve_response(rhs.block(6, first, n3, w), flesh, rows ? &wanted : nullptr);
        Eigen::Matrix<double, 6, Eigen::Dynamic> vh(6, w);
        for (Eigen::Index j = 0; j < w; ++j)
            vh.col(j) = schur.solve(Vec6(rhs.col(first + j).head<6>() - (coupled ? aht_times(flesh.col(j)) : Vec6::Zero())));
        if (!rows) {
            out.block(0, first, 6, w) = vh;
            out.block(6, first, n3, w).noalias() = flesh - response_ * vh;  // Eq. 12 for every column
            continue;
        }
        MatX flesh_rows = MatX::Zero(static_cast<Eigen::Index>(rows->size()), w);
        for (size_t i = 0; i < rows->size(); ++i)
            if ((*rows)[i] >= 6) flesh_rows.row(i) = flesh.row((*rows)[i] - 6);
        eq12_on_rows(*rows, flesh_rows, vh, out.middleCols(first, w));
    }
}

bool HandSystem::aht_zero() const {
    for (const Mat63& block : Aht)
        if (!block.isZero(0)) return false;
    return true;
}

MatX HandSystem::response_at(const MatX& columns, const std::vector<int>& unknowns) {
    std::vector<int> nodes;
    for (int u : unknowns) nodes.push_back((u - 6) / 3);
    std::sort(nodes.begin(), nodes.end());
    nodes.erase(std::unique(nodes.begin(), nodes.end()), nodes.end());
    MatX solved;
    tool.solve_response(columns, solved, &nodes);
    MatX out(static_cast<Eigen::Index>(unknowns.size()), columns.cols());
    for (size_t i = 0; i < unknowns.size(); ++i) out.row(static_cast<Eigen::Index>(i)) = solved.row(unknowns[i] - 6);
    return out;
}

void HandSystem::prepare_unit_columns(const std::vector<int>& units) {
    if (aht_zero()) return;
    const Eigen::Index n3 = tool.A.rows();
    MatX aht_t = MatX::Zero(n3, 6);  // Aht^T, 3n x 6
    for (size_t q = 0; q < coupled_nodes.size(); ++q) aht_t.middleRows<3>(3 * coupled_nodes[q]) = Aht[q].transpose();
    std::vector<int> flesh;
    for (int u : units)
        if (u >= 6) flesh.push_back(u);
    // indexed by the flesh unknown (rows elsewhere unused)
    aht_response_.resize(n3, 6);
    aht_prepared_.resize(n3, 0);
    const MatX at = response_at(aht_t, flesh);
    for (size_t i = 0; i < flesh.size(); ++i) {
        aht_response_.row(flesh[i] - 6) = at.row(static_cast<Eigen::Index>(i));
        aht_prepared_[flesh[i] - 6] = 1;
    }
}

bool HandSystem::apply_inverse_unit_columns(const int* units, int k, const std::vector<int>& rows, Eigen::Ref<MatX> out) {
    // the flesh rows asked for (the handle's response to each unit comes from aht_response_)
    std::vector<int> flesh_rows_at;
    for (int row : rows)
        if (row >= 6) flesh_rows_at.push_back(row - 6);
    // unit columns on the flesh (a handle unknown's has no flesh part: zero)
    std::vector<int> flesh_units, column_of;
    for (int j = 0; j < k; ++j)
        if (units[j] >= 6) {
            flesh_units.push_back(units[j] - 6);
            column_of.push_back(j);
        }
    const bool coupled = !aht_zero();
    if (coupled && tool.solver() == DeformableSolver::Cholesky)
        for (int u : flesh_units)
            if (u >= static_cast<int>(aht_prepared_.size()) || !aht_prepared_[u])
                throw InvalidArgument("HandSystem::apply_inverse_unit_columns: unit not prepared (prepare_unit_columns)");
    MatX flesh_rows = MatX::Zero(static_cast<Eigen::Index>(rows.size()), k);
    MatX solved(static_cast<Eigen::Index>(flesh_rows_at.size()), static_cast<Eigen::Index>(flesh_units.size()));
    if (!flesh_units.empty() &&
        !tool.solve_units(flesh_units.data(), static_cast<int>(flesh_units.size()), flesh_rows_at, solved.data(), solved.rows()))
        return false;
    for (size_t q = 0; q < column_of.size(); ++q)
        for (size_t i = 0, f = 0; i < rows.size(); ++i)
            if (rows[i] >= 6) flesh_rows(static_cast<Eigen::Index>(i), column_of[q]) = solved(static_cast<Eigen::Index>(f++), static_cast<Eigen::Index>(q));
    Eigen::FullPivLU<Mat6> schur(handle.A);  // handle.A still holds the Schur complement
    Eigen::Matrix<double, 6, Eigen::Dynamic> vh(6, k);
    for (int j = 0; j < k; ++j) {
        Vec6 rh = Vec6::Zero();
        if (units[j] < 6) rh[units[j]] = 1.0;
        // Aht A_t^-1 e_u = (A_t^-1 Aht^T)^T e_u, At symmetric (prepare_unit_columns)
        if (units[j] >= 6 && coupled) rh -= aht_response_.row(units[j] - 6).transpose();
        vh.col(j) = schur.solve(rh);
    }
    eq12_on_rows(rows, flesh_rows, vh, out);
    return true;
}

void HandSystem::handle_columns(const std::vector<int>& unknowns, const std::vector<Mat63>& aht, MatX& out) {
    const Eigen::Index n3 = tool.A.rows();
    // A_t^-1 Ath is the step's own (solve()) unless the contacts see the reused factor's
    // operator instead of At^-1 (DeformableSystem::solve_response): then all twelve through it
    const bool own = tool.solver() != DeformableSolver::ReusedCholesky;
    MatX columns = MatX::Zero(n3, own ? 6 : 12);  // [aht^T] or [Ath | aht^T]
    for (size_t q = 0; q < coupled_nodes.size(); ++q) {
        if (!own) columns.block<3, 6>(3 * coupled_nodes[q], 0) = Ath[q];
        columns.block<3, 6>(3 * coupled_nodes[q], own ? 0 : 6) = aht[q].transpose();
    }
    const MatX solved = response_at(columns, unknowns);
    if (!own) {
        out = solved;
        return;
    }
    out.resize(static_cast<Eigen::Index>(unknowns.size()), 12);
    for (size_t i = 0; i < unknowns.size(); ++i) out.row(static_cast<Eigen::Index>(i)).head<6>() = response_.row(unknowns[i] - 6);
    out.rightCols<6>() = solved;
}

void HandSystem::eq12_on_rows(const std::vector<int>& rows, const MatX& flesh_rows,
                              const Eigen::Matrix<double, 6, Eigen::Dynamic>& vh, Eigen::Ref<MatX> out) const {
    // the rows of A_t^-1 Ath gathered (zero at handle rows), then one product for every row (a
    // product per row: 0.1-0.27 ms a pressed 10x bunny frame at 110-180 unknowns; now 0.04-0.09)
    const Eigen::Index nr = static_cast<Eigen::Index>(rows.size());
    Eigen::Matrix<double, Eigen::Dynamic, 6> at_rows(nr, 6);
    for (Eigen::Index i = 0; i < nr; ++i) {
        if (rows[i] < 6) at_rows.row(i).setZero();
        else at_rows.row(i) = response_.row(rows[i] - 6);
    }
    out = flesh_rows;
    out.noalias() -= at_rows * vh;
    for (Eigen::Index i = 0; i < nr; ++i)
        if (rows[i] < 6) out.row(i) = vh.row(rows[i]);
    if (!out.allFinite()) throw NumericalError("the contact response of the hand is not finite: reduce the time step");
}

namespace {
// m (6 x 3, column-major) = aw (6 x span, column-major) times c (span x 3, its columns ld
// apart): apply_inverse_units' M_k for one node. Eigen's general product, one call per node
// (packing aw each time), took ~10-20 us a node at span ~1500: 0.5-1.3 ms of a 10x bunny frame
// on the ~17000-tet hand, on the one thread then busy. Here the six rows of each column of aw
// are the SIMD lanes (4 + 2), and each entry sums over s in two partial sums (even and odd s)
// added at the end: 3-4x less time (AVX2; the plain form ~2.5x), measured both ways on the same
// calls in one run, the results within 2e-15 of Eigen's.
void aw_times_columns_baseline(const double* __restrict aw, long span, const double* __restrict c, long ld,
                               double* __restrict m) {
    double even[3][6] = {}, odd[3][6] = {};
    long s = 0;
    for (; s + 2 <= span; s += 2)
        for (int q = 0; q < 3; ++q)
            for (int r = 0; r < 6; ++r) {
                even[q][r] += aw[6 * s + r] * c[q * ld + s];
                odd[q][r] += aw[6 * s + 6 + r] * c[q * ld + s + 1];
            }
    for (; s < span; ++s)
        for (int q = 0; q < 3; ++q)
            for (int r = 0; r < 6; ++r) even[q][r] += aw[6 * s + r] * c[q * ld + s];
    for (int q = 0; q < 3; ++q)
        for (int r = 0; r < 6; ++r) m[6 * q + r] = even[q][r] + odd[q][r];
}

#if defined(__GNUC__) && defined(__x86_64__)
#define HH_HAVE_AW_AVX2 1
__attribute__((target("avx2,fma"))) void aw_times_columns_avx2(const double* __restrict aw, long span,
                                                               const double* __restrict c, long ld,
                                                               double* __restrict m) {
    __m256d lo[2][3];  // rows 0-3, per partial sum and column
    __m128d hi[2][3];  // rows 4-5
    for (int u = 0; u < 2; ++u)
        for (int q = 0; q < 3; ++q) {
            lo[u][q] = _mm256_setzero_pd();
            hi[u][q] = _mm_setzero_pd();
        }
    const double* c0 = c;
    const double* c1 = c + ld;
    const double* c2 = c + 2 * ld;
    // (loops, not a lambda: a lambda would not inherit the target and its intrinsics would not inline)
    for (long s = 0; s < span; s += 2)
        for (int u = 0; u < 2 && s + u < span; ++u) {
            const long at = s + u;
            const __m256d a03 = _mm256_loadu_pd(aw + 6 * at);
            const __m128d a45 = _mm_loadu_pd(aw + 6 * at + 4);
            const double b[3] = {c0[at], c1[at], c2[at]};
            for (int q = 0; q < 3; ++q) {
                lo[u][q] = _mm256_fmadd_pd(a03, _mm256_set1_pd(b[q]), lo[u][q]);
                hi[u][q] = _mm_fmadd_pd(a45, _mm_set1_pd(b[q]), hi[u][q]);
            }
        }
    for (int q = 0; q < 3; ++q) {
        _mm256_storeu_pd(m + 6 * q, _mm256_add_pd(lo[0][q], lo[1][q]));
        _mm_storeu_pd(m + 6 * q + 4, _mm_add_pd(hi[0][q], hi[1][q]));
    }
}
#endif

void aw_times_columns(const double* aw, long span, const double* c, long ld, double* m) {
#ifdef HH_HAVE_AW_AVX2
    if (active_simd_level() >= 1) return aw_times_columns_avx2(aw, span, c, ld, m);
#endif
    aw_times_columns_baseline(aw, span, c, ld, m);
}
}  // namespace

bool HandSystem::apply_inverse_units(const std::vector<int>& unknowns, const std::vector<int>& rows, MatX& out) {
    // the flesh nodes whose columns are read (the units') and where (the asked rows', and the
    // coupled ones for Aht x_t unless Aht is zero: a prescribed handle); handle unknowns 0-5
    // have no flesh part
    const bool coupled = !aht_zero();
    std::vector<int> columns, at;
    if (coupled) at = coupled_nodes;
    for (int u : unknowns)
        if (u >= 6) columns.push_back((u - 6) / 3);
    for (int row : rows)
        if (row >= 6) at.push_back((row - 6) / 3);
    const double* blocks = nullptr;
    long ld = 0;
    const std::vector<int>* row_slot = nullptr;
    const std::vector<int>* column_slot = nullptr;
    const std::vector<Mat3>* warp = nullptr;
    if (!tool.response_blocks(columns, at, blocks, ld, row_slot, column_slot, warp, beside)) return false;
    auto rot = [&](int node) -> Mat3 { return warp ? (*warp)[node] : Mat3::Identity(); };
    // Aht x_t for a unit at node k, direction d (x_t = W Af^-1 W^T e): sum_i Aht_i W_i
    // (Af^-1)_ik W_k^T e_d = M_k w with w = W_k^T e_d and M_k = sum_i (Aht_i W_i) (Af^-1)_ik, a
    // 6x3 matrix per node (not per unit), made as one product over the kept rows: AW (6 x the
    // rows up to the last coupled node's, Aht_i W_i at node i's rows, zero elsewhere) times the
    // node's three kept columns. (Summed per unit and coupled node, as before, over the
    // ~17000-tet hand's ~480 coupled nodes: on the same 10x bunny calls, alternating, 0.77-1.44
    // ms a call against 0.50-1.07 now, the results within 2e-16 of each other.)
    Eigen::Index span = 0;
    Eigen::Matrix<double, 6, Eigen::Dynamic> aw;
    if (coupled) {
        for (int node : coupled_nodes) span = std::max<Eigen::Index>(span, 3 * static_cast<Eigen::Index>((*row_slot)[node] + 1));
        aw.setZero(6, span);
        for (size_t q = 0; q < coupled_nodes.size(); ++q)
            aw.middleCols<3>(3 * static_cast<Eigen::Index>((*row_slot)[coupled_nodes[q]])) = Aht[q] * rot(coupled_nodes[q]);
    }
    Eigen::FullPivLU<Mat6> schur(handle.A);  // handle.A still holds the Schur complement
    const Eigen::Index nr = static_cast<Eigen::Index>(rows.size()), k = static_cast<Eigen::Index>(unknowns.size());
    MatX flesh_rows = MatX::Zero(nr, k);  // the flesh part at the asked rows
    Eigen::Matrix<double, 6, Eigen::Dynamic> vh(6, k);
    int m_node = -1;  // the node M was made for (a node's unknowns come together)
    Mat63 m = Mat63::Zero();
    for (size_t j = 0; j < unknowns.size(); ++j) {
        Vec6 rh = Vec6::Zero();
        if (unknowns[j] < 6) rh[unknowns[j]] = 1.0;
        // the flesh part x_t = W Af^-1 W^T e (e: unit at the unknown): Af^-1's columns of its
        // node times w = W_k^T e_d, then each asked row's node block rotated by W_i
        Vec3 w = Vec3::Zero();
        const double* c = nullptr;  // Af^-1's three columns of the unit's node
        Vec6 aht = Vec6::Zero();    // Aht x_t
        if (unknowns[j] >= 6) {
            const int node = (unknowns[j] - 6) / 3, d = (unknowns[j] - 6) % 3;
            w = rot(node).row(d).transpose();
            c = blocks + 3 * static_cast<long>((*column_slot)[node]) * ld;
            if (coupled) {
                if (node != m_node) {
                    aw_times_columns(aw.data(), span, c, ld, m.data());
                    m_node = node;
                }
                aht = m * w;
            }
        }
        auto flesh_block = [&](int node) -> Vec3 {  // x_t at node (3 values)
            if (!c) return Vec3::Zero();
            const long row = 3 * static_cast<long>((*row_slot)[node]);
            Vec3 y = Vec3::Zero();
            for (int q = 0; q < 3; ++q) y += w[q] * Eigen::Map<const Vec3>(c + q * ld + row);
            return rot(node) * y;
        };
        vh.col(j) = schur.solve(Vec6(rh - aht));
        int last = -1;
        Vec3 at_last = Vec3::Zero();
        for (size_t i = 0; i < rows.size(); ++i) {
            if (rows[i] < 6) continue;
            const int node = (rows[i] - 6) / 3;
            if (node != last) {  // (a node's rows come together)
                at_last = flesh_block(node);
                last = node;
            }
            flesh_rows(i, j) = at_last[(rows[i] - 6) % 3];
        }
    }
    out.resize(nr, k);
    eq12_on_rows(rows, flesh_rows, vh, out);
    return true;
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
