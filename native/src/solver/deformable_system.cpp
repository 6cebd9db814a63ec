#include "solver/deformable_system.h"

#include <Eigen/IterativeLinearSolvers>
#include <algorithm>
#include <atomic>
#include <cmath>

#include "fem/corotational.h"
#include "rigid/quaternion.h"
#include "solver/block_ldlt.h"

namespace hh {

namespace {

// Width of a node-major block of k right-hand sides (the kernels take 1, 4 or 8).
int padded_width(int k) { return k == 1 ? 1 : (k <= 4 ? 4 : 8); }

// The nodes of some unknowns, added to `nodes`, sorted, each once
std::vector<int> nodes_of(const std::vector<int>& unknowns, std::vector<int> nodes = {}) {
    for (int u : unknowns) nodes.push_back(u / 3);
    std::sort(nodes.begin(), nodes.end());
    nodes.erase(std::unique(nodes.begin(), nodes.end()), nodes.end());
    return nodes;
}

// The fresh columns' unit solves for response_blocks: `units` are the fresh column nodes'
// unknowns in the factor's elimination order, `row_nodes` the rows: the first
// `every_batch_rows` (kept from before, or rows only), then the fresh columns' own in
// elimination order. A batch of units is solved at the first rows and at the fresh columns'
// rows from its first node on only; a fresh column's row before that is, by Af^-1's symmetry,
// the transpose of that row's own column, which an earlier batch solved at this batch's rows.
// A batch's backward pass then reaches only the nodes eliminated after its first one and their
// ancestors, not every row's.
// In two jobs of whole batches, side by side when `beside` lets them, the same batches either
// way: as few batches as kWidestSolve allows (at least two from two nodes on), of about equal
// width. A batch's pass costs about a pass over the factor's part above its rows (the handle's
// coupled nodes among them: ~1.1 ms on the ~17000-tet hand for one node's three units) plus
// its width; the hand touches a few new nodes a step, 6-15 units that took one batch on one
// thread beside an idle one (measured alternating in one run, those calls 15-25% shorter;
// ~0.1 ms a 10x bunny frame). The two jobs take the batches in turn from a shared counter
// rather than half each: batches differ in cost and the other thread may join late, and with
// fixed halves a renewal frame of the 10x bunny had one thread on the hand's responses for
// 13.7 ms, the other for 5.8 ms and then idle. A batch's columns are the same whichever thread
// solves it.
struct FreshColumns {
    const BlockLDLT& factor;
    const std::vector<int>& units;
    const std::vector<int>& row_nodes;
    const std::vector<int>& row_slot;
    const std::vector<int>& column_slot;
    Eigen::Index every_batch_rows;

    // the units' columns into b from column first_column on, at every row
    void solve(MatX& b, Eigen::Index first_column, const Beside& beside) const {
        const int k = static_cast<int>(units.size());
        const int batches = k < 6 ? 1 : std::max(2, (k + kWidestSolve - 1) / kWidestSolve);
        const int width = (k + batches - 1) / batches;
        std::vector<Eigen::Index> from(static_cast<size_t>(batches));  // each batch's first fresh column's row
        for (int batch = 0; batch < batches; ++batch) from[batch] = first_fresh_row(units[std::min(batch * width, k - 1)] / 3);
        std::atomic<int> next{0};
        auto take_batches = [&] {
            for (int batch = next++; batch < batches && batch * width < k; batch = next++)
                solve_batch(b, first_column, batch * width, std::min(width, k - batch * width), from[batch]);
        };
        if (beside && batches > 1)
            beside(take_batches, take_batches);
        else
            take_batches();
        for (int j = 0; j < k; ++j) {  // the fresh columns' rows before each batch's first, by symmetry
            const Eigen::Index row_of_j = 3 * row_slot[units[j] / 3] + units[j] % 3;
            for (Eigen::Index q = every_batch_rows; q < every_batch_rows + from[j / width]; ++q)
                for (int d = 0; d < 3; ++d)
                    b(3 * q + d, first_column + j) = b(row_of_j, 3 * column_slot[row_nodes[q]] + d);
        }
    }
    // how many of the fresh columns' rows the factor eliminates before this node
    Eigen::Index first_fresh_row(int node) const {
        Eigen::Index q = every_batch_rows;
        while (q < static_cast<Eigen::Index>(row_nodes.size()) && factor.position(row_nodes[q]) < factor.position(node)) ++q;
        return q - every_batch_rows;
    }
    // units [first, first + w) at the first rows and the fresh columns' rows from `from` on
    void solve_batch(MatX& b, Eigen::Index first_column, int first, int w, Eigen::Index from) const {
        std::vector<int> rows, wanted;
        const Eigen::Index total = static_cast<Eigen::Index>(row_nodes.size());
        auto add = [&](Eigen::Index q) {
            wanted.push_back(row_nodes[q]);
            for (int d = 0; d < 3; ++d) rows.push_back(3 * row_nodes[q] + d);
        };
        for (Eigen::Index q = 0; q < every_batch_rows; ++q) add(q);
        for (Eigen::Index q = every_batch_rows + from; q < total; ++q) add(q);
        std::sort(wanted.begin(), wanted.end());
        MatX out(static_cast<Eigen::Index>(rows.size()), w);
        factor.solve_units(units.data() + first, w, rows, wanted, out.data(), out.rows());
        const Eigen::Index kept = 3 * every_batch_rows;
        b.block(0, first_column + first, kept, w) = out.topRows(kept);
        b.block(3 * (every_batch_rows + from), first_column + first, out.rows() - kept, w) = out.bottomRows(out.rows() - kept);
    }
};

// The reused factor's kept blocks between some nodes (DeformableSystem::response_blocks), read
// as the response operator's: W_a (Af^-1)_ab W_b^T
struct KeptBlocks {
    const double* data = nullptr;
    long ld = 0;
    const std::vector<int>* row_slot = nullptr;
    const std::vector<int>* column_slot = nullptr;
    const std::vector<Mat3>* warp = nullptr;
    bool read(DeformableSystem& sys, const std::vector<int>& nodes, const Beside& beside) {
        return sys.response_blocks(nodes, nodes, data, ld, row_slot, column_slot, warp, beside);
    }
    Mat3 rot(int node) const { return warp ? (*warp)[node] : Mat3::Identity(); }
    // (Af^-1)_ab, unwarped
    Eigen::Map<const Mat3, 0, Eigen::OuterStride<>> block(int a, int b) const {
        const double* column = data + 3 * static_cast<long>((*column_slot)[b]) * ld;
        return {column + 3 * static_cast<long>((*row_slot)[a]), 3, 3, Eigen::OuterStride<>(ld)};
    }
};

// Y = A X on node-major storage for any symmetric pattern (the fallback of the block kernel):
// column c of the compressed-column storage is row c, a dot product with X's rows.
template <int W>
void multiply_scalar(const SpMat& a, const double* x, double* y) {
    const int* outer = a.outerIndexPtr();
    const int* inner = a.innerIndexPtr();
    const double* values = a.valuePtr();
    for (Eigen::Index c = 0; c < a.outerSize(); ++c) {
        double acc[W] = {};
        for (int p = outer[c]; p < outer[c + 1]; ++p) {
            const double v = values[p];
            const double* xr = x + static_cast<size_t>(W) * inner[p];
            for (int j = 0; j < W; ++j) acc[j] += v * xr[j];
        }
        std::copy(acc, acc + W, y + static_cast<size_t>(W) * c);
    }
}
void multiply_any(const SpMat& a, bool blocks, const double* x, double* y, int w) {
    if (blocks) return multiply_node_major(a, x, y, w);
    if (w == 1) multiply_scalar<1>(a, x, y);
    else if (w == 4) multiply_scalar<4>(a, x, y);
    else multiply_scalar<8>(a, x, y);
}
// Lane-wise kernels on node-major blocks of W lanes (W fixed so that the compiler vectorizes).
template <int W>
void lane_dot_w(const double* u, const double* v, size_t rows, double* out) {
    double acc[W] = {};
    for (size_t e = 0; e < rows; ++e)
        for (int l = 0; l < W; ++l) acc[l] += u[W * e + l] * v[W * e + l];
    std::copy(acc, acc + W, out);
}
template <int W>
void p_update_w(double* p, const double* z, const double* beta, size_t rows) {  // p = z + beta p
    for (size_t e = 0; e < rows; ++e)
        for (int l = 0; l < W; ++l) p[W * e + l] = z[W * e + l] + beta[l] * p[W * e + l];
}
template <int W>  // x += alpha p, r -= alpha q, out = |r|^2 per lane
void xr_update_w(double* x, double* r, const double* p, const double* q, const double* alpha, size_t rows, double* out) {
    double acc[W] = {};
    for (size_t e = 0; e < rows; ++e)
        for (int l = 0; l < W; ++l) {
            x[W * e + l] += alpha[l] * p[W * e + l];
            r[W * e + l] -= alpha[l] * q[W * e + l];
            acc[l] += r[W * e + l] * r[W * e + l];
        }
    std::copy(acc, acc + W, out);
}
void lane_dot(int w, const double* u, const double* v, size_t rows, double* out) {
    if (w == 1) lane_dot_w<1>(u, v, rows, out);
    else if (w == 4) lane_dot_w<4>(u, v, rows, out);
    else lane_dot_w<8>(u, v, rows, out);
}
void p_update(int w, double* p, const double* z, const double* beta, size_t rows) {
    if (w == 1) p_update_w<1>(p, z, beta, rows);
    else if (w == 4) p_update_w<4>(p, z, beta, rows);
    else p_update_w<8>(p, z, beta, rows);
}
void xr_update(int w, double* x, double* r, const double* p, const double* q, const double* alpha, size_t rows, double* out) {
    if (w == 1) xr_update_w<1>(x, r, p, q, alpha, rows, out);
    else if (w == 4) xr_update_w<4>(x, r, p, q, alpha, rows, out);
    else xr_update_w<8>(x, r, p, q, alpha, rows, out);
}
}  // namespace

struct DeformableSystem::Impl {
    DeformableSolver solver = DeformableSolver::Cholesky;
    double cg_tolerance = 1e-10;
    int cg_max_iterations = 2000;
    // The pattern of At never changes, so the symbolic analysis (AMD ordering, elimination
    // tree) is done once and only the numeric factorization is repeated.
    BlockLDLT cholesky;
    Eigen::ConjugateGradient<SpMat, Eigen::Lower | Eigen::Upper, Eigen::DiagonalPreconditioner<double>> cg;
    std::vector<VecX> warm;
    std::vector<VecX> warm2;  // ReusedCholesky: the solutions before those in warm
    std::vector<double> tolerance_scale;  // per slot, ReusedCholesky
    std::vector<double> reference_norm;   // per slot, the next solve only (set_reference_norm); 0: none
    struct ReferenceScope {  // (a solve's: the references are cleared however it ends)
        std::vector<double>& r;
        ~ReferenceScope() { std::fill(r.begin(), r.end(), 0.0); }
    };
    // the norm a slot's relative residual is measured against: its right-hand side's, or the
    // reference set for this solve when larger
    double residual_norm(int slot, double rhs_norm) const {
        return slot < static_cast<int>(reference_norm.size()) ? std::max(rhs_norm, reference_norm[slot]) : rhs_norm;
    }

    // ReusedCholesky
    bool have_factor = false;        // cholesky holds the factor of some earlier At
    bool factor_current = false;     // ... of this step's At
    std::vector<Vec4> node_q;        // nodes' rotations this step (warm starts of the polar decomposition)
    std::vector<Mat3> node_r, node_r_factor, warp;  // this step's, at the factorization, and R R_factor^T
    bool have_rotations = false;
    bool block_pattern = false;  // At's pattern suits the block kernel of multiply_node_major
    FactorForms forms;
    // The panels a preconditioner pass of `width` lanes reads: the narrowest copy the factor
    // keeps (see pcg_block). The half copy's rounding bounds an iteration's contraction at ~5e-4
    // even on an exact factor, so a wider block asked for a relative residual below 1e-8 (from
    // warm starts 1e-4 to 1e-5 off, two iterations instead of one) reads the float copy: its
    // iterations cost several one-lane passes each.
    Panels pass_panels(int width, double tolerance) const {
        if (forms.preconditioner == Panels::Half && cholesky.has_half() && (width == 1 || tolerance >= 1e-8))
            return Panels::Half;
        return forms.preconditioner != Panels::Double && cholesky.has_single() ? Panels::Single : Panels::Double;
    }
    // Cost bookkeeping of the refactorization policy, in work units (one unit: a one-lane pass
    // over the factor), counted, not timed: the policy does not depend on the machine's load,
    // so runs repeat exactly.
    double factor_units = 0;         // a factorization
    double epoch_units = 0;          // solves since the last factorization, its own step included
    int epoch_steps = 0;             // steps since the last factorization, its own included
    double step_units = 0;           // solves of the current step
    bool renew = false;              // refactor at the start of the next step
    static double pass_units(int width) {  // one preconditioner pass (or direct solve) of width 1, 4, 8
        return width == 1 ? 1.0 : width == 4 ? 1.9 : 2.5;  // measured ratios
    }
    void add_units(double units) {
        step_units += units;
        epoch_units += units;
    }
    void count_pass(int width) { add_units(pass_units(width)); }
    // Af^-1's blocks kept since the last factorization (response_blocks): node k's three
    // columns at 3 column_slot[k] of block_matrix, node i's three rows at 3 row_slot[i] (its
    // capacity grows by doubling)
    std::vector<int> row_slot, column_slot;  // per node; -1: not kept
    std::vector<int> row_nodes, column_nodes;  // per slot
    MatX block_matrix;
    void drop_blocks() {
        for (int node : row_nodes) row_slot[node] = -1;
        for (int node : column_nodes) column_slot[node] = -1;
        row_nodes.clear();
        column_nodes.clear();
    }
    // PCG workspaces (node-major blocks): one per group of columns that may be solved side by
    // side (solve_many_split)
    struct PcgWork {
        std::vector<double> nb, nx, nr, nz, np, nq;
    };
    PcgWork pcg_work[2];
    // what a pcg_block call counts, added to the system's counters once its group is done
    struct PcgTally {
        int iterations = 0;
        double max_residual = 0, units = 0;
        bool stale = false;  // a lane reached reuse_iteration_limit where the factor could not be renewed
    };

    // whether the next factor() call is this step's (or, before matrix_changed closed the last
    // step's bookkeeping, the step about to start): no factor yet, or the policy renews it
    bool renewing() const { return !have_factor || renew || step_costs_a_renewal(); }
    // the policy's test on the step that ended (see matrix_changed)
    bool step_costs_a_renewal() const {
        return step_units > 0 && epoch_steps > 1 && step_units > (renewal_units() + epoch_units) / epoch_steps;
    }
    // What a renewal costs: the factorization, and the response columns kept since the last one,
    // which the contact build then solves again on the new factor (response_blocks), each about
    // this much of a one-lane pass (a column in a batch of 32 at the touched rows; the grasping
    // hand's renewal at the end of its closing solves 312 columns again, ~4.6 ms on one core).
    // Leaving them out renewed the factor in the grasp's hold to save a CG iteration a step, a
    // step of ~20 ms for ~0.3 ms a step.
    static constexpr double kKeptColumnUnits = 0.022;
    double renewal_units() const { return factor_units + kKeptColumnUnits * 3 * static_cast<double>(column_nodes.size()); }
    void analyse(DeformableSystem& sys) {
        if (!cholesky.analysed()) {
            // many preconditioner passes per factorization: the supernodal form's dense panel
            // kernels (and its single-precision copy) pay off
            cholesky.set_supernodal(forms.reused_supernodal);
            cholesky.set_keep_single(forms.preconditioner != Panels::Double);
            cholesky.set_keep_half(forms.preconditioner == Panels::Half);
            cholesky.analyze(sys.A);
            block_pattern = has_node_block_pattern(sys.A);
            // a factorization against a one-lane pass over its result: flops against stored
            // entries; measured 7.9 flops per entry-pass with the AVX-512 update kernel (20837
            // tets: 101 ms vs 1.43 ms), 4.8 without it (175 ms vs 1.5 ms). Fixed per machine,
            // so the policy stays independent of the load.
            const double flops_per_entry_pass = detected_simd_level() >= 2 && cholesky.supernodal() ? 7.9 : 4.8;
            factor_units = cholesky.factor_flops() /
                           (flops_per_entry_pass * 9.0 * std::max(1L, cholesky.block_nonzeros() + cholesky.nodes()));
        }
    }
    // beside: the rest's shares of updates as two jobs for it (BlockLDLT::factorize)
    void factor(DeformableSystem& sys, const Beside& beside = Beside()) {
        analyse(sys);
        cholesky.factorize(sys.A, beside);  // (the rest, after factorize_part's parts when they ran)
        ++sys.factorizations;
        have_factor = factor_current = true;
        drop_blocks();  // of the former factor
        if (have_rotations) node_r_factor = node_r;
        else node_r_factor.clear();  // no warp until the next factorization
        warp_valid = false;
        epoch_units = 0;
        epoch_steps = 1;
        renew = false;
    }
    // the response operator's warp (DeformableSystem::solve_response): none on the step's own factor
    const std::vector<Mat3>* response_warp() { return factor_current ? nullptr : current_warp(); }
    // (made once per step and factor: after the first call, calls only read it, so solves on
    // two threads may ask for it at once, World::solve_free's carried impulses beside b_t)
    const std::vector<Mat3>* current_warp() {
        if (!have_rotations || node_r_factor.size() != node_r.size()) return nullptr;
        if (warp_valid) return &warp;
        warp.resize(node_r.size());
        for (size_t i = 0; i < node_r.size(); ++i) warp[i] = node_r[i] * node_r_factor[i].transpose();
        warp_valid = true;
        return &warp;
    }
    bool warp_valid = false;  // warp is R R_factor^T of this step's rotations and factor
    // Cholesky (a factorization every step): the up-looking block LDL^T is the cheaper on small
    // meshes, the supernodal form's dense panel kernels on large ones, where the factorization's
    // flops dwarf its index work. Step time measured up-looking / supernodal: 1599 tets (3.8e6
    // flops) 1.07 / 1.45 ms, 5154 tets (2.6e7) 5.07 / 5.73 ms, 20837 tets (1.5e9) 205 / 133 ms.
    // Since relaxed supernodes and AVX-512 panel kernels (factorization alone, up-looking /
    // supernodal): 1700 tets (4.6e6) 0.65 / 0.43 ms, 4101 tets (1.9e7) 2.4 / 1.7 ms, 17208 tets
    // (4.6e8) 55 / 26 ms; in the contact scenes the supernodal solves cost a little more, so the
    // paper's hands (1700 tets: as fast either way) stay up-looking, the 10x bunny scene's 4101-
    // and 2594-tet bodies gain ~2 ms a frame on one thread. (FactorForms::per_step forces one.)
    static constexpr double kSupernodalFlops = 1e7;
    void analyze_per_step(const SpMat& a) {
        using PerStep = FactorForms::PerStep;
        cholesky.analyze(a);
        const bool big = cholesky.factor_flops() > kSupernodalFlops;
        if (forms.per_step == PerStep::Supernodal || (forms.per_step == PerStep::Auto && big)) {
            cholesky = BlockLDLT();
            cholesky.set_supernodal(true);
            cholesky.analyze(a);
        }
    }
    // split > 0: columns [0, split) and [split, k) as two groups that `beside` may run side by side
    // after_second: run on the second group's thread once it is done (solve_many_split)
    void pcg(DeformableSystem& sys, const MatX& b, MatX& x, int first_slot, int split = 0, const Beside* beside = nullptr,
             const std::function<void()>* after_second = nullptr);
    // may_renew: a lane at reuse_iteration_limit renews the factor on the spot and the block
    // restarts; else (a group solved beside another, which reads the factor) the block stops
    // and reports the factor stale. pass_beside: the one-lane passes through the factor's two
    // parts, and the products with At in two halves of its rows, as two jobs for it
    // (BlockLDLT::solve_node_major_split; see pcg)
    struct PcgBlock;
    void pcg_block(DeformableSystem& sys, const MatX& b, MatX& x, int first_slot, int first, int count, PcgWork& ws,
                   PcgTally& tally, const std::vector<Mat3>* w, bool may_renew, const Beside* pass_beside = nullptr);
};

DeformableSystem::DeformableSystem() : impl_(new Impl) {}
DeformableSystem::~DeformableSystem() = default;

void DeformableSystem::configure(DeformableSolver solver, double cg_tolerance, int cg_max_iterations) {
    Impl& m = *impl_;
    if (solver == m.solver && cg_tolerance == m.cg_tolerance && cg_max_iterations == m.cg_max_iterations) return;
    if (solver != m.solver) {  // (each solver analyses in its own forms: analyse, analyze_per_step)
        m.cholesky = BlockLDLT();
        m.drop_blocks();
    }
    m.solver = solver;
    m.cg_tolerance = cg_tolerance;
    m.cg_max_iterations = cg_max_iterations;
    m.have_factor = m.factor_current = false;
    factor_valid_ = false;
}

void DeformableSystem::analyse_ahead() {
    Impl& m = *impl_;
    if (A.rows() == 0 || m.cholesky.analysed()) return;
    if (m.solver == DeformableSolver::Cholesky) m.analyze_per_step(A);
    else if (m.solver == DeformableSolver::ReusedCholesky) m.analyse(*this);
}

DeformableSolver DeformableSystem::solver() const { return impl_->solver; }

void DeformableSystem::set_factor_forms(const FactorForms& forms) {
    Impl& m = *impl_;
    m.forms = forms;
    m.cholesky = BlockLDLT();  // (analysed again, in the new forms, by the next solve)
    m.have_factor = m.factor_current = false;
    m.drop_blocks();
    factor_valid_ = false;
}

const FactorForms& DeformableSystem::factor_forms() const { return impl_->forms; }

void DeformableSystem::matrix_changed() {
    Impl& m = *impl_;
    factor_valid_ = false;
    m.cholesky.discard_parts();
    m.factor_current = false;
    m.have_rotations = false;
    m.warp_valid = false;
    if (m.solver != DeformableSolver::ReusedCholesky || !m.have_factor) return;
    // Close the bookkeeping of the step that ended: the mean cost per step since the last
    // factorization, (renewal + solves) / steps, decreases while a step costs less than that
    // mean; once a step costs more, renewing the factor lowers the mean again.
    if (m.step_units > 0) {
        if (m.step_costs_a_renewal()) m.renew = true;
        ++m.epoch_steps;
    }
    m.step_units = 0;
}

void DeformableSystem::set_element_rotations(const std::vector<Eigen::Vector4i>& tets, const std::vector<Mat3>& rotations) {
    Impl& m = *impl_;
    if (m.solver != DeformableSolver::ReusedCholesky) return;
    const int n = static_cast<int>(A.rows() / 3);
    std::vector<Mat3> sum(n, Mat3::Zero());
    for (size_t e = 0; e < tets.size() && e < rotations.size(); ++e)
        for (int a = 0; a < 4; ++a) sum[tets[e][a]] += rotations[e];
    if (static_cast<int>(m.node_q.size()) != n) m.node_q.assign(n, quat_identity());
    m.node_r.resize(n);
    for (int i = 0; i < n; ++i) m.node_r[i] = polar_rotation(sum[i], m.node_q[i]);
    m.have_rotations = true;
    m.warp_valid = false;
}

void DeformableSystem::select_slot(int slot) { slot_ = slot; }

void DeformableSystem::set_tolerance_scale(int slot, double scale) {
    std::vector<double>& t = impl_->tolerance_scale;
    if (static_cast<int>(t.size()) <= slot) t.resize(slot + 1, 1.0);
    t[slot] = scale;
}

void DeformableSystem::set_reference_norm(int slot, double norm) {
    std::vector<double>& t = impl_->reference_norm;
    if (static_cast<int>(t.size()) <= slot) t.resize(slot + 1, 0.0);
    t[slot] = std::isfinite(norm) && norm > 0 ? norm : 0.0;
}

void DeformableSystem::solve() {
    MatX b = r, x;
    solve_many(b, x, slot_);
    s = x.col(0);
}

void DeformableSystem::solve_response(const MatX& b, MatX& x, const std::vector<int>* wanted_nodes) {
    Impl& m = *impl_;
    if (m.solver != DeformableSolver::ReusedCholesky || !m.have_factor) return solve_many(b, x, 8, wanted_nodes);
    // (not counted by the refactorization policy: their cost does not grow with the factor's age)
    x = b;
    m.cholesky.solve(x, m.response_warp(), wanted_nodes);
    if (!wanted_nodes && !x.allFinite())
        throw NumericalError("the deformable solve produced non-finite values: reduce the time step");
}

void DeformableSystem::solve_response_single(const VecX& b, VecX& x) { solve_response_column(b, x, true, Beside()); }

void DeformableSystem::solve_response_split(const VecX& b, VecX& x, const Beside& beside) {
    solve_response_column(b, x, false, beside);
}

// One column through the reused factor itself (node-major storage is the plain vector); the
// other solvers, or a factor without the panels asked for: solve_response.
void DeformableSystem::solve_response_column(const VecX& b, VecX& x, bool single, const Beside& beside) {
    Impl& m = *impl_;
    if (m.solver != DeformableSolver::ReusedCholesky || !m.have_factor || (single && !m.cholesky.has_single())) {
        MatX xm;
        solve_response(b, xm);
        x = xm.col(0);
        return;
    }
    x = b;
    m.cholesky.solve_node_major_split(x.data(), 1, m.response_warp(), single ? Panels::Single : Panels::Double, beside);  // (without beside: the plain pass)
    if (!x.allFinite()) throw NumericalError("the deformable solve produced non-finite values: reduce the time step");
}

int DeformableSystem::fresh_response_unknowns(const std::vector<int>& unknowns) const {
    const Impl& m = *impl_;
    if (m.solver != DeformableSolver::ReusedCholesky || !m.have_factor) return -1;
    int fresh = 0;
    for (int node : nodes_of(unknowns))
        fresh += node < 0 || node >= static_cast<int>(m.column_slot.size()) || m.column_slot[node] < 0 ? 3 : 0;
    return fresh;
}

bool DeformableSystem::response_at(const std::vector<int>& unknowns, const VecX& f, VecX& out, const Beside& beside) {
    Impl& m = *impl_;
    if (m.solver != DeformableSolver::ReusedCholesky || !m.have_factor || f.size() != A.rows()) return false;
    std::vector<int> loaded;  // f's nodes
    for (Eigen::Index i = 0; i < f.size() / 3; ++i)
        if (!f.segment<3>(3 * i).isZero(0)) loaded.push_back(static_cast<int>(i));
    KeptBlocks kept;
    if (!kept.read(*this, nodes_of(unknowns, loaded), beside)) return false;
    // W_b^T f_b once per loaded node, then per asked node a: W_a sum_b (Af^-1)_ab (W_b^T f_b)
    std::vector<Vec3> turned(loaded.size());
    for (size_t j = 0; j < loaded.size(); ++j) turned[j] = kept.rot(loaded[j]).transpose() * f.segment<3>(3 * loaded[j]);
    out.resize(static_cast<Eigen::Index>(unknowns.size()));
    int last = -1;
    Vec3 at = Vec3::Zero();
    for (size_t i = 0; i < unknowns.size(); ++i) {
        const int a = unknowns[i] / 3;
        if (a != last) {
            Vec3 sum = Vec3::Zero();
            for (size_t j = 0; j < loaded.size(); ++j) sum += kept.block(a, loaded[j]) * turned[j];
            at = kept.rot(a) * sum;
            last = a;
        }
        out[static_cast<Eigen::Index>(i)] = at[unknowns[i] % 3];
    }
    return true;
}

bool DeformableSystem::response_units(const std::vector<int>& unknowns, MatX& out, const Beside& beside) {
    // the unknowns' nodes, each once, and per node its unknowns (index in `unknowns`, direction)
    const std::vector<int> nodes = nodes_of(unknowns);
    KeptBlocks kept;
    if (!kept.read(*this, nodes, beside)) return false;
    std::vector<std::vector<std::pair<int, int>>> of_node(nodes.size());
    for (size_t j = 0; j < unknowns.size(); ++j) {
        const size_t a = static_cast<size_t>(std::lower_bound(nodes.begin(), nodes.end(), unknowns[j] / 3) - nodes.begin());
        of_node[a].emplace_back(static_cast<int>(j), unknowns[j] % 3);
    }
    const Eigen::Index k = static_cast<Eigen::Index>(unknowns.size());
    out.resize(k, k);
    // per pair of nodes the operator's 3x3 block W_i (Af^-1)_ik W_k^T, then its entries; the
    // operator is symmetric, so each pair once, its transpose for (k, i)
    for (size_t b = 0; b < nodes.size(); ++b) {
        const Mat3 wk = kept.rot(nodes[b]);
        for (size_t a = b; a < nodes.size(); ++a) {
            const Mat3 response = kept.rot(nodes[a]) * kept.block(nodes[a], nodes[b]) * wk.transpose();
            for (const auto& r : of_node[a])
                for (const auto& c : of_node[b]) out(r.first, c.first) = out(c.first, r.first) = response(r.second, c.second);
        }
    }
    return true;
}

bool DeformableSystem::response_blocks(const std::vector<int>& columns, const std::vector<int>& rows, const double*& data,
                                       long& ld, const std::vector<int>*& row_slot, const std::vector<int>*& column_slot,
                                       const std::vector<Mat3>*& warp, const Beside& beside) {
    Impl& m = *impl_;
    if (m.solver != DeformableSolver::ReusedCholesky || !m.have_factor) return false;
    const int n = m.cholesky.nodes();
    if (static_cast<int>(m.row_slot.size()) != n) {
        m.row_slot.assign(static_cast<size_t>(n), -1);
        m.column_slot.assign(static_cast<size_t>(n), -1);
        m.row_nodes.clear();
        m.column_nodes.clear();
    }
    auto each_once = [&](std::vector<int> v) {  // sorted
        std::sort(v.begin(), v.end());
        v.erase(std::unique(v.begin(), v.end()), v.end());
        if (!v.empty() && (v.front() < 0 || v.back() >= n)) throw InvalidArgument("DeformableSystem::response_blocks: a node out of range");
        return v;
    };
    const std::vector<int> asked_columns = each_once(columns);
    std::vector<int> asked_rows = rows;
    asked_rows.insert(asked_rows.end(), columns.begin(), columns.end());
    asked_rows = each_once(std::move(asked_rows));
    // at most 64 MB of blocks (~960 nodes of rows and columns each): past that, start over
    const size_t budget = size_t(64) << 20;
    auto bytes = [](size_t r, size_t c) { return 9 * r * c * sizeof(double); };
    if (bytes(asked_rows.size(), asked_columns.size()) > budget) return false;
    std::vector<int> fresh_rows, fresh_columns;
    for (int node : asked_rows)
        if (m.row_slot[node] < 0) fresh_rows.push_back(node);
    for (int node : asked_columns)
        if (m.column_slot[node] < 0) fresh_columns.push_back(node);
    // a fresh row that is not a fresh column has no values at the kept columns: start over
    bool restart = bytes(m.row_nodes.size() + fresh_rows.size(), m.column_nodes.size() + fresh_columns.size()) > budget;
    for (int node : fresh_rows) restart |= !std::binary_search(fresh_columns.begin(), fresh_columns.end(), node);
    if (restart) {
        m.drop_blocks();
        fresh_rows = asked_rows;
        fresh_columns = asked_columns;
    }
    if (!fresh_rows.empty() || !fresh_columns.empty()) {
        const Eigen::Index kept_rows = static_cast<Eigen::Index>(m.row_nodes.size());
        const Eigen::Index kept_columns = static_cast<Eigen::Index>(m.column_nodes.size());
        const Eigen::Index total_rows = kept_rows + static_cast<Eigen::Index>(fresh_rows.size());
        const Eigen::Index total_columns = kept_columns + static_cast<Eigen::Index>(fresh_columns.size());
        MatX& b = m.block_matrix;
        if (b.rows() < 3 * total_rows || b.cols() < 3 * total_columns) {
            const Eigen::Index r = std::max<Eigen::Index>(3 * total_rows, std::max<Eigen::Index>(96, b.rows() < 3 * total_rows ? 2 * b.rows() : b.rows()));
            const Eigen::Index c = std::max<Eigen::Index>(3 * total_columns, std::max<Eigen::Index>(96, b.cols() < 3 * total_columns ? 2 * b.cols() : b.cols()));
            MatX grown(r, c);
            grown.topLeftCorner(3 * kept_rows, 3 * kept_columns) = b.topLeftCorner(3 * kept_rows, 3 * kept_columns);
            b.swap(grown);
        }
        // the fresh columns' units in the factor's elimination order (a batch's units then
        // share their paths to the root); the fresh rows that are not fresh columns (rows only,
        // like the handle's coupled nodes), then the others in that order (FreshColumns)
        auto eliminated_first = [&](int x, int y) { return m.cholesky.position(x) < m.cholesky.position(y); };
        std::sort(fresh_columns.begin(), fresh_columns.end(), eliminated_first);
        for (int node : fresh_columns) {
            m.column_slot[node] = static_cast<int>(m.column_nodes.size());
            m.column_nodes.push_back(node);
        }
        auto fresh_column = [&](int node) { return m.column_slot[node] >= kept_columns; };
        std::sort(fresh_rows.begin(), fresh_rows.end(), [&](int x, int y) {
            return fresh_column(x) != fresh_column(y) ? fresh_column(y) : eliminated_first(x, y);
        });
        for (int node : fresh_rows) {
            m.row_slot[node] = static_cast<int>(m.row_nodes.size());
            m.row_nodes.push_back(node);
        }
        const Eigen::Index every_batch_rows =
            kept_rows + std::count_if(fresh_rows.begin(), fresh_rows.end(), [&](int node) { return !fresh_column(node); });
        std::vector<int> units;
        for (int node : fresh_columns)
            for (int d = 0; d < 3; ++d) units.push_back(3 * node + d);
        if (!units.empty()) {
            const FreshColumns fresh{m.cholesky, units, m.row_nodes, m.row_slot, m.column_slot, every_batch_rows};
            fresh.solve(b, 3 * kept_columns, beside);
            if (!b.block(0, 3 * kept_columns, 3 * total_rows, 3 * (total_columns - kept_columns)).allFinite())
                throw NumericalError("the deformable solve produced non-finite values: reduce the time step");
        }
        // the fresh rows at the kept columns, by symmetry (each fresh row is a fresh column)
        for (int node : fresh_rows) {
            if (kept_columns == 0) break;
            const Eigen::Index r = 3 * m.row_slot[node], c = 3 * m.column_slot[node];
            for (Eigen::Index k = 0; k < kept_columns; ++k) {
                const Eigen::Index at = 3 * m.row_slot[m.column_nodes[k]];
                b.block<3, 3>(r, 3 * k) = b.block<3, 3>(at, c).transpose();
            }
        }
    }
    data = m.block_matrix.data();
    ld = static_cast<long>(m.block_matrix.rows());
    row_slot = &m.row_slot;
    column_slot = &m.column_slot;
    warp = m.response_warp();
    return true;
}

bool DeformableSystem::prepare_concurrent_solves() {
    Impl& m = *impl_;
    if (m.solver != DeformableSolver::Cholesky) return false;
    if (!factor_valid_) {
        if (!m.cholesky.analysed()) m.analyze_per_step(A);
        m.cholesky.factorize(A);
        ++factorizations;
        factor_valid_ = true;
    }
    return true;
}

bool DeformableSystem::solve_units(const int* units, int k, const std::vector<int>& rows, double* out, long ld) {
    if (!prepare_concurrent_solves()) return false;
    std::vector<int> nodes;  // of the rows and the units (ascending, each once)
    nodes.reserve(rows.size() + k);
    for (int r : rows) nodes.push_back(r / 3);
    for (int j = 0; j < k; ++j) nodes.push_back(units[j] / 3);
    std::sort(nodes.begin(), nodes.end());
    nodes.erase(std::unique(nodes.begin(), nodes.end()), nodes.end());
    impl_->cholesky.solve_units(units, k, rows, nodes, out, ld);
    return true;
}

int DeformableSystem::factor_parts() {
    Impl& m = *impl_;
    if (m.solver == DeformableSolver::ReusedCholesky) {
        // only a step that renews the factor has parts to run (then the first solve finishes
        // the factorization and its bookkeeping, Impl::factor)
        if (!m.renewing()) return 0;
        m.analyse(*this);
        return m.cholesky.factor_parts();
    }
    if (m.solver != DeformableSolver::Cholesky) return 0;
    if (!m.cholesky.analysed()) m.analyze_per_step(A);
    return m.cholesky.factor_parts();
}

void DeformableSystem::factorize_part(int part) { impl_->cholesky.factorize_part(A, part); }

int DeformableSystem::elimination_position(int node) const {
    const Impl& m = *impl_;
    if (m.solver != DeformableSolver::Cholesky || !factor_valid_ || !m.cholesky.analysed()) return -1;
    return m.cholesky.position(node);
}

void DeformableSystem::solve_many_split(const MatX& b, MatX& x, int first_slot, int split, const Beside& beside,
                                        const std::function<void()>& after_second) {
    Impl& m = *impl_;
    if (m.solver != DeformableSolver::ReusedCholesky) {
        solve_many(b, x, first_slot);
        return;
    }
    const Impl::ReferenceScope references{m.reference_norm};
    m.pcg(*this, b, x, first_slot, split, &beside, after_second ? &after_second : nullptr);
    if (!x.allFinite()) throw NumericalError("the deformable solve produced non-finite values: reduce the time step");
}

void DeformableSystem::solve_many(const MatX& b, MatX& x, int first_slot, const std::vector<int>* wanted_nodes) {
    Impl& m = *impl_;
    // set_reference_norm holds for this solve only, however it ends
    const Impl::ReferenceScope references{m.reference_norm};
    if (prepare_concurrent_solves()) {
        x = b;
        m.cholesky.solve(x, nullptr, wanted_nodes);
    } else if (m.solver == DeformableSolver::ConjugateGradient) {
        if (!factor_valid_) {
            m.cg.setTolerance(m.cg_tolerance);
            m.cg.setMaxIterations(m.cg_max_iterations);
            m.cg.compute(A);
            factor_valid_ = true;
        }
        x.resize(b.rows(), b.cols());
        for (Eigen::Index j = 0; j < b.cols(); ++j) {
            const int slot = first_slot + static_cast<int>(j);
            if (static_cast<int>(m.warm.size()) <= slot) m.warm.resize(slot + 1);
            VecX& guess = m.warm[slot];
            if (guess.size() != b.rows()) guess = VecX::Zero(b.rows());
            const double bn = b.col(j).norm();
            const double widen = bn > 0 ? m.residual_norm(slot, bn) / bn : 1.0;  // (set_reference_norm)
            m.cg.setTolerance(m.cg_tolerance * widen);
            x.col(j) = m.cg.solveWithGuess(b.col(j), guess);
            guess = x.col(j);
            iterations += static_cast<int>(m.cg.iterations());
            // Eigen's relative residual estimate; Cholesky is exact to round-off so it costs no check
            max_residual = std::max(max_residual, m.cg.error() / widen);
        }
    } else {
        m.pcg(*this, b, x, first_slot);
    }
    if (!wanted_nodes && !x.allFinite())  // (with wanted nodes the caller checks its rows)
        throw NumericalError("the deformable solve produced non-finite values: reduce the time step");
}


// Conjugate gradient on up to 8 columns of b at once, preconditioned by the (warped) reused
// factor. The iterates live in node-major blocks (node i's 3 x w values together, w = 1, 4 or 8
// lanes), so that each iteration is one batched pass over the factor and one over At; a
// converged column leaves its lane, and the block narrows (8 -> 4 -> 1) when it can.
void DeformableSystem::Impl::pcg(DeformableSystem& sys, const MatX& b, MatX& x, int first_slot, int split, const Beside* beside,
                                 const std::function<void()>* after_second) {
    const int n3 = static_cast<int>(sys.A.rows());
    const int k = static_cast<int>(b.cols());
    static const Beside none;
    const Beside& two = beside ? *beside : none;  // (empty: one job after the other)
    if (!have_factor || renew) factor(sys, two);
    x.resize(n3, k);
    for (int j = 0; j < k; ++j) {
        const int slot = first_slot + j;
        if (static_cast<int>(warm.size()) <= slot) warm.resize(slot + 1);
        if (warm[slot].size() != n3) warm[slot] = VecX::Zero(n3);
        if (static_cast<int>(warm2.size()) <= slot) warm2.resize(slot + 1);
        if (warm2[slot].size() != n3) warm2[slot] = VecX::Zero(n3);
    }
    if (factor_current) {  // the factor is this step's: a direct solve
        x = b;
        cholesky.solve(x, nullptr, two);  // (its parts side by side)
        for (int first = 0; first < k; first += 8) count_pass(padded_width(std::min(8, k - first)));
        for (int j = 0; j < k; ++j) {
            warm2[first_slot + j].swap(warm[first_slot + j]);
            warm[first_slot + j] = x.col(j);
        }
        return;
    }
    PcgTally tally[2];
    if (split > 0 && split < k) {
        const std::vector<Mat3>* w = current_warp();  // (once: the groups only read it)
        // The first group's one-lane iterations (b_t's, the hand's free solve) give `beside` two
        // jobs each for the pass through the factor (its two parts) and for the product with At
        // (two halves of the rows): a thread that is free (the second group done, or never
        // taken by the other thread) takes the second job, else this thread runs both, the same
        // arithmetic either way. The second group's 8-lane passes keep the other
        // thread busy in the machine's fast states and the two groups end together; in slow
        // ones b_t's passes slowed ~2.5x against the block's ~1.6x (a memory-latency-bound
        // pass; 10x bunny, 17006-tet hand: b_t 26-28 ms against the columns' 11) and the
        // other thread idled behind b_t, 3-5 ms a frame on average (up to ~13 in a frame); it
        // now takes ~1.2 ms a frame of b_t's work there.
        auto group = [&](int g) {
            const int begin = g == 0 ? 0 : split, end = g == 0 ? split : k;
            for (int first = begin; first < end; first += 8)
                pcg_block(sys, b, x, first_slot, first, std::min(8, end - first), pcg_work[g], tally[g], w, false,
                          g == 0 ? beside : nullptr);
        };
        auto second = [&] {
            group(1);
            if (after_second) (*after_second)();
        };
        if (two) two([&] { group(0); }, second);
        else {
            group(0);
            second();
        }
    } else {
        for (int first = 0; first < k; first += 8)  // (a block's renewal changes the next one's warp)
            pcg_block(sys, b, x, first_slot, first, std::min(8, k - first), pcg_work[0], tally[0], current_warp(), true);
    }
    for (const PcgTally& t : tally) {
        sys.iterations += t.iterations;
        sys.max_residual = std::max(sys.max_residual, t.max_residual);
        add_units(t.units);
    }
    if (tally[0].stale || tally[1].stale) {
        // (split groups only) the factor is too stale: renewed now, and every column solved on it
        factor(sys, two);
        x = b;
        cholesky.solve(x, nullptr, two);
        for (int first = 0; first < k; first += 8) count_pass(padded_width(std::min(8, k - first)));
    }
    for (int j = 0; j < k; ++j) {
        warm2[first_slot + j].swap(warm[first_slot + j]);
        warm[first_slot + j] = x.col(j);
    }
}

// One block of up to 8 columns of pcg, in the steps of one preconditioned CG iteration.
//
// Every pass through the factor reads its narrowest copy (pass_panels): the passes are memory
// bound, and in the world two groups of lanes stream the factor at once (solve_many_split),
// b_t's one-lane passes beside the Schur columns' 8-lane ones. The half-precision copy is a
// quarter of the double traffic; its rounding (2^-11 of each column's largest entry) limits
// CG's contraction to ~5e-4 an iteration on an exact factor, far below what the staleness of a
// reused one allows (0.2-0.3 an iteration on the ~17000-tet hand). The passes' arithmetic is
// float where the CPU has AVX2 (BlockLDLT::float_passes; the residuals and products with At stay
// double, and CG's flexible beta takes the float round-off like any change of preconditioner).
// The preconditioner is the stale warped factor anyway.
struct DeformableSystem::Impl::PcgBlock {
    Impl& m;
    DeformableSystem& sys;
    const MatX& b;
    MatX& x;
    const int first_slot, first, count;
    std::vector<double>&nb, &nx, &nr, &nz, &np, &nq;  // node-major blocks of wd lanes (PcgWork)
    PcgTally& tally;
    const std::vector<Mat3>* w;  // the warp (null after a renewal)
    const bool may_renew;
    const Beside* pass_beside;
    const int n3;
    std::vector<int> lanes;  // lanes[l] = column of b held in lane l (-1: an idle lane, all zeros)
    int wd = 0;              // the block's width: 1, 4 or 8 lanes
    std::vector<double> bnorm, rnorm;  // per column: |b|, and the norm its relative residual is measured against
    double tightest = 1;  // the block's smallest tolerance (pass_panels)
    double rnorm2[8], rz_new[8], pq[8], qz[8];
    std::vector<double> rz, cross;  // per column (lanes move when the block narrows)
    std::vector<int> its;
    bool restarted = false, fresh = true;

    PcgBlock(Impl& m, DeformableSystem& sys, const MatX& b, MatX& x, int first_slot, int first, int count, PcgWork& ws,
             PcgTally& tally, const std::vector<Mat3>* w, bool may_renew, const Beside* pass_beside)
        : m(m), sys(sys), b(b), x(x), first_slot(first_slot), first(first), count(count), nb(ws.nb), nx(ws.nx), nr(ws.nr),
          nz(ws.nz), np(ws.np), nq(ws.nq), tally(tally), w(w), may_renew(may_renew), pass_beside(pass_beside),
          n3(static_cast<int>(sys.A.rows())), bnorm(count, 0.0), rnorm(count, 0.0), rz(count, 0.0), cross(count, 0.0),
          its(count, 0) {}

    void run() {
        if (!take_lanes()) return;
        start();
        for (;;) {
            compact();
            bool any = false;
            for (int c : lanes) any |= c >= 0;
            if (!any) break;
            precondition();
            update_directions();
            multiply_directions();
            const int worst = step_lanes();
            if (worst >= sys.reuse_iteration_limit && !restarted) {
                if (!may_renew) {
                    // (another group may be reading the factor: pcg renews it once both are done,
                    // and solves this block's columns again on it)
                    tally.stale = true;
                    break;
                }
                renew();
            }
        }
    }

private:
    double tol_of(int col) const {
        const int slot = first_slot + col;
        const double scale = slot < static_cast<int>(m.tolerance_scale.size()) ? m.tolerance_scale[slot] : 1.0;
        return m.cg_tolerance * scale;
    }
    double lane_norm_b(int l) const { return rnorm[lanes[l] - first]; }
    // per-lane sums over node-major blocks
    void lane_dot(const std::vector<double>& u, const std::vector<double>& v, double* out) const {
        hh::lane_dot(wd, u.data(), v.data(), static_cast<size_t>(n3), out);
    }
    // node-major loads, a whole row of lanes at a time (lane-by-lane strided writes touched a
    // cache line per entry and lane)
    template <class ColumnOf>
    void load(ColumnOf column_of, std::vector<double>& to) const {
        const double* from[8] = {};
        for (int l = 0; l < wd; ++l)
            if (lanes[l] >= 0) from[l] = column_of(lanes[l]);
        for (int e = 0; e < n3; ++e)
            for (int l = 0; l < wd; ++l) to[static_cast<size_t>(wd) * e + l] = from[l] ? from[l][e] : 0.0;
    }
    void residual() {  // r = b - A x
        multiply_any(sys.A, m.block_pattern, nx.data(), nq.data(), wd);
        const size_t total = static_cast<size_t>(n3) * wd;
        for (size_t e = 0; e < total; ++e) nr[e] = nb[e] - nq[e];
    }
    // A finished lane is left as it is: its alpha and beta stay 0 from then on, so its x and r
    // no longer change and p = M^-1 r stays finite; the lanes never mix, so it cannot disturb
    // the others, and compact() drops it when the block narrows. (Zeroing it would touch a cache
    // line per entry in four vectors.)
    void finish_lane(int l, double rel) {
        const int col = lanes[l];
        for (int e = 0; e < n3; ++e) x(e, col) = nx[static_cast<size_t>(wd) * e + l];
        tally.max_residual = std::max(tally.max_residual, rel);
        lanes[l] = -1;
    }
    // narrow the block when the live lanes fit in a smaller width
    void compact() {
        int live = 0;
        for (int c : lanes) live += c >= 0;
        const int nw = padded_width(std::max(live, 1));
        if (nw >= wd) return;
        std::vector<int> keep;
        for (int l = 0; l < wd; ++l)
            if (lanes[l] >= 0) keep.push_back(l);
        for (std::vector<double>* v : {&nb, &nx, &nr, &np}) {
            std::vector<double>& a = *v;
            for (int e = 0; e < n3; ++e)  // in place: the new layout never overtakes the old
                for (int k = 0; k < nw; ++k)
                    a[static_cast<size_t>(nw) * e + k] = k < static_cast<int>(keep.size()) ? a[static_cast<size_t>(wd) * e + keep[k]] : 0.0;
        }
        std::vector<int> nl(nw, -1);
        for (size_t k = 0; k < keep.size(); ++k) nl[k] = lanes[keep[k]];
        lanes.swap(nl);
        wd = nw;
    }

    // The block's columns with a nonzero right-hand side as lanes (the others' solutions are 0),
    // their norms, and b and the slots' last two solutions in node-major blocks. False when no
    // column is left.
    bool take_lanes() {
        for (int j = 0; j < count; ++j) {
            const int col = first + j;
            bnorm[j] = b.col(col).norm();
            if (bnorm[j] == 0) x.col(col).setZero();
            else lanes.push_back(col);
        }
        if (lanes.empty()) return false;
        wd = padded_width(static_cast<int>(lanes.size()));
        lanes.resize(wd, -1);
        // the norms the lanes' relative residuals are measured against (set_reference_norm)
        for (int j = 0; j < count; ++j) rnorm[j] = m.residual_norm(first_slot + first + j, bnorm[j]);
        for (int c : lanes)
            if (c >= 0) tightest = std::min(tightest, tol_of(c));
        const size_t size = static_cast<size_t>(n3) * 8;
        for (std::vector<double>* v : {&nb, &nx, &nr, &nz, &np, &nq}) v->resize(size);
        load([&](int col) { return b.col(col).data(); }, nb);
        load([&](int col) { return m.warm[first_slot + col].data(); }, nx);
        load([&](int col) { return m.warm2[first_slot + col].data(); }, np);
        return true;
    }

    // Initial guess: the Galerkin (A-norm optimal) combination c1 h1 + c2 h2 of the slot's last
    // two solutions h1, h2: it contains the plain warm start (1, 0), the linear extrapolation
    // (2, -1) and zero, so it is never worse than any of them in the A-norm. Lanes already within
    // their tolerance finish.
    void start() {
        const size_t total = static_cast<size_t>(n3) * wd;
        multiply_any(sys.A, m.block_pattern, nx.data(), nq.data(), wd);  // A h1
        multiply_any(sys.A, m.block_pattern, np.data(), nz.data(), wd);  // A h2 (h2 loaded in np)
        double a11[8], a12[8], a22[8], b1[8], b2[8];
        lane_dot(nx, nq, a11);
        lane_dot(nx, nz, a12);
        lane_dot(np, nz, a22);
        lane_dot(nx, nb, b1);
        lane_dot(np, nb, b2);
        double c1[8] = {}, c2[8] = {};
        for (int l = 0; l < wd; ++l) {
            if (lanes[l] < 0) continue;
            const double det = a11[l] * a22[l] - a12[l] * a12[l];
            if (a11[l] > 0 && a22[l] > 0 && det > 1e-10 * a11[l] * a22[l]) {
                c1[l] = (a22[l] * b1[l] - a12[l] * b2[l]) / det;
                c2[l] = (a11[l] * b2[l] - a12[l] * b1[l]) / det;
            } else if (a11[l] > 0) {
                c1[l] = b1[l] / a11[l];
            }
        }
        for (size_t e = 0; e < total; e += wd)
            for (int l = 0; l < wd; ++l) {
                nx[e + l] = c1[l] * nx[e + l] + c2[l] * np[e + l];
                nr[e + l] = nb[e + l] - c1[l] * nq[e + l] - c2[l] * nz[e + l];
            }
        std::fill(np.begin(), np.begin() + total, 0.0);
        lane_dot(nr, nr, rnorm2);
        for (int l = 0; l < wd; ++l) {
            if (lanes[l] < 0) continue;
            const double bn = lane_norm_b(l);
            if (std::sqrt(rnorm2[l]) <= tol_of(lanes[l]) * bn) finish_lane(l, std::sqrt(rnorm2[l]) / bn);
        }
    }

    // z = M^-1 r: a pass through the (warped) factor; one lane's in two jobs for pass_beside
    void precondition() {
        const size_t total = static_cast<size_t>(n3) * wd;
        std::copy(nr.begin(), nr.begin() + total, nz.begin());
        if (wd == 1 && pass_beside && *pass_beside)
            m.cholesky.solve_node_major_split(nz.data(), 1, w, m.pass_panels(1, tightest), *pass_beside);
        else
            m.cholesky.solve_node_major(nz.data(), wd, w, m.pass_panels(wd, tightest));
        tally.units += pass_units(wd);
    }

    // p = z + beta p. Polak-Ribiere (flexible) CG: beta = r_new . (z_new - z_old) / (r_old . z_old),
    // with r_new . z_old = r_old . z_old - alpha q . z_old. It equals Fletcher-Reeves for a fixed
    // preconditioner and stays robust were the preconditioner to change between iterations
    // (single and double passes were mixed once; the renewal restarts).
    void update_directions() {
        lane_dot(nr, nz, rz_new);
        double beta[8] = {};
        for (int l = 0; l < wd; ++l) {
            if (lanes[l] < 0) continue;
            const int j = lanes[l] - first;
            beta[l] = fresh ? 0.0 : std::max(0.0, (rz_new[l] - cross[j]) / rz[j]);
            rz[j] = rz_new[l];
        }
        p_update(wd, np.data(), nz.data(), beta, static_cast<size_t>(n3));
        fresh = false;
    }

    // q = A p; one lane's in two jobs for pass_beside (the nodes' rows in two halves)
    void multiply_directions() {
        if (wd == 1 && m.block_pattern && pass_beside && *pass_beside) {
            const int n = n3 / 3;
            (*pass_beside)([&] { multiply_node_major(sys.A, np.data(), nq.data(), 1, 0, n / 2); },
                           [&] { multiply_node_major(sys.A, np.data(), nq.data(), 1, n / 2, n); });
        } else {
            multiply_any(sys.A, m.block_pattern, np.data(), nq.data(), wd);
        }
    }

    // x += alpha p, r -= alpha q; the lanes within their tolerance (or out of iterations)
    // finish. Returns the most iterations a lane still running has taken.
    int step_lanes() {
        lane_dot(np, nq, pq);
        lane_dot(nq, nz, qz);
        double alpha[8] = {};
        for (int l = 0; l < wd; ++l) {
            if (lanes[l] < 0) continue;
            const int j = lanes[l] - first;
            alpha[l] = pq[l] == 0 ? 0.0 : rz[j] / pq[l];
            cross[j] = rz[j] - alpha[l] * qz[l];
        }
        double acc[8] = {};
        xr_update(wd, nx.data(), nr.data(), np.data(), nq.data(), alpha, static_cast<size_t>(n3), acc);
        int worst = 0;
        for (int l = 0; l < wd; ++l) {
            if (lanes[l] < 0) continue;
            const int j = lanes[l] - first;
            ++its[j];
            ++tally.iterations;
            const double rel = std::sqrt(acc[l]) / rnorm[j];
            if (rel <= tol_of(lanes[l])) finish_lane(l, rel);
            else if (its[j] >= std::max(m.cg_max_iterations, sys.reuse_iteration_limit + 5)) finish_lane(l, rel);  // give up
            else worst = std::max(worst, its[j]);
        }
        return worst;
    }

    // The factor is too stale: renewed with this step's At, and CG restarted from the current
    // iterates (with the exact factor one or two iterations reach the tolerance)
    void renew() {
        m.add_units(tally.units);  // (the passes so far count in the closing epoch, as the step's)
        tally.units = 0;
        m.factor(sys);
        w = nullptr;
        restarted = true;
        fresh = true;
        residual();
    }
};

void DeformableSystem::Impl::pcg_block(DeformableSystem& sys, const MatX& b, MatX& x, int first_slot, int first, int count,
                                       PcgWork& ws, PcgTally& tally, const std::vector<Mat3>* w, bool may_renew,
                                       const Beside* pass_beside) {
    PcgBlock(*this, sys, b, x, first_slot, first, count, ws, tally, w, may_renew, pass_beside).run();
}

}  // namespace hh
