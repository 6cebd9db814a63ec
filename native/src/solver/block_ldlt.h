// Sparse LDL^T factorization of a symmetric positive definite matrix made of 3x3 node
// blocks (the deformable system At), with D block-diagonal and L unit block-lower-
// triangular. Same algorithm as Davis's LDL (up-looking, elimination tree), with each scalar
// replaced by a 3x3 block: index work drops ninefold and the inner products become small
// fixed-size matrix products the compiler unrolls. Fill-reducing AMD ordering on the node
// graph. The pattern is analysed once; factorize() is called each step.
// Solves take several right-hand sides at once: one pass over L serves them all, and the
// passes are memory bound, so k right-hand sides cost far less than k single solves.
#pragma once
#include <algorithm>
#include <vector>

#include "common/beside.h"
#include "common/simd.h"
#include "common/types.h"
#include "solver/half.h"
#include "solver/panels.h"

namespace hh {

// Most right-hand sides one solve pass takes (supernodal form with AVX-512; with AVX2 16, the
// up-looking form 8: BlockLDLT::widest_pass), and the batches the callers hand to a solve.
constexpr int kWidestSolve = 32;

class BlockLDLT {
public:
    // A: 3n x 3n, column-major, both triangles stored, pattern closed under 3x3 node blocks.
    void analyze(const SpMat& a);
    // Before analyze(): the up-looking block LDL^T (the default: fastest to factor for the
    // sizes here) or the supernodal L L^T (dense panels: faster solves, a single-precision copy
    // that halves their memory traffic; for a factor reused over many solves).
    void set_supernodal(bool on) {
        if (on != supernodal_ && n_ > 0) throw std::logic_error("BlockLDLT::set_supernodal: call it before analyze()");
        supernodal_ = on;
    }
    bool supernodal() const { return supernodal_; }
    int supernodes() const { return static_cast<int>(sn_start_.size()) - 1; }
    // beside (supernodal form with parts): the rest's large supernodes receive their
    // descendants' updates in two shares of their columns, as two jobs for it (the same factor,
    // bit for bit, whether they run side by side or not, and with or without `beside`); the
    // single- and half-precision copies are made in two shares of the supernodes too.
    void factorize(const SpMat& a, const Beside& beside = nullptr);
    // Supernodal form: the factorization in parts that may run side by side. The analysis splits
    // the supernodes into two sets of whole subtrees of the elimination tree (balanced by their
    // estimated flops) and the rest (their ancestors); factor_parts() is 2 then (large factors
    // only), else 0. factorize_part(a, 0) and (a, 1) touch disjoint data and may run on two
    // threads at once; factorize(a) then does the rest (and any part not done yet). The result
    // is the same, bit for bit, whether the parts ran side by side, one after the other, or
    // inside factorize().
    int factor_parts() const { return factor_parts_; }
    void factorize_part(const SpMat& a, int part);
    // Supernodes of the rest whose updates go in two shares (see factorize).
    int rest_shares() const { return static_cast<int>(std::count_if(sn_split_.begin(), sn_split_.end(), [](int s) { return s > 0; })); }
    // Forget parts done for an earlier matrix (the values changed since).
    void discard_parts() { part_done_[0] = part_done_[1] = false; }
    VecX solve(const VecX& b) const;
    // In place, every column of b a right-hand side.
    void solve(MatX& b) const;
    // Solves with the warped matrix W A W^T (W block-diagonal, a 3x3 block per node, e.g. the
    // rotation of each node since the factorization): x = W A^-1 W^T b. warp null: W = I.
    void solve(MatX& b, const std::vector<Mat3>* warp) const;
    // The same, but only the rows of the wanted nodes (original numbering) are asked for: the
    // backward pass runs over them and their elimination-tree ancestors only, and every other
    // row of b is left holding unspecified values. For the contact responses, which need the
    // inverse at a few touched nodes: with unit right-hand sides the forward pass already skips
    // all but the paths above them, so a column costs its paths instead of all of L.
    void solve(MatX& b, const std::vector<Mat3>* warp, const std::vector<int>* wanted_nodes) const;
    // solve(b, warp) with each pass through the factor's two parts as two jobs for `beside`
    // (solve_node_major_split).
    void solve(MatX& b, const std::vector<Mat3>* warp, const Beside& beside) const;
    // Columns of A^-1 for unit right-hand sides: out[r + j ld] = (A^-1)(rows[r], units[j]) for
    // j < k (scalar unknowns, original numbering), without the full-length columns. The nodes of
    // `rows` and of `units` must be among wanted_nodes (the backward pass visits them and their
    // ancestors only; the other rows are never computed; a unit elsewhere is refused with
    // std::logic_error). The contact responses' solves.
    // The units go in batches of a pass's lanes (widest_pass; 16 up-looking); first_batch and batch_step: only the batches
    // first_batch, first_batch + batch_step, ... (calls for different batches may run on two
    // threads at once: each batch's columns are its own, and come out the same either way).
    void solve_units(const int* units, int k, const std::vector<int>& rows, const std::vector<int>& wanted_nodes,
                     double* out, long ld, int first_batch = 0, int batch_step = 1) const;
    // The same on node-major storage: x holds n nodes x 3 x w values (w = 1, 4 or 8; node i's
    // 3 x w block at x + 3 w i, row-major), in the matrix's own node order. Panels::Single:
    // with the single-precision copy of the factor (half the memory traffic; a matrix within
    // float round-off of A: a preconditioner, not a solve). Panels::Half: the half-precision
    // copy (a quarter of the traffic; within 2^-11 per entry: a preconditioner only), or the
    // single one on a CPU without half conversions (solver/half.h) or at SIMD level 0. Where
    // the CPU has AVX2 the passes on the half copy (1, 4 or 8 lanes) and on the single one (4
    // or 8) run in float arithmetic (float_passes); else in double.
    void solve_node_major(double* x, int w, const std::vector<Mat3>* warp, Panels panels = Panels::Double) const;
    // The same with the factor's two parts (factor_parts() == 2) as two jobs for `beside`: the
    // forward pass over each part's subtrees (each into its own copy of the rest's rows, added
    // in a fixed order afterwards), the rest's forward and backward passes, then the backward
    // pass over each part. The parts share no rows but the rest's, which the backward passes only
    // read. The result is the same whether `beside` runs the jobs side by side or one after the
    // other, and within round-off of solve_node_major's (the rest's rows sum the parts'
    // contributions in another order). For a pass nothing else waits beside: with the other
    // thread idle, ~0.7 of its time on the ~17000-tet hand (a quarter of the factor is the rest).
    // Without parts or `beside`: solve_node_major.
    void solve_node_major_split(double* x, int w, const std::vector<Mat3>* warp, Panels panels, const Beside& beside) const;
    // Keep a single-precision copy of L and D^-1 with every factorization (for preconditioning).
    void set_keep_single(bool keep) { keep_single_ = keep; if (keep && !single_valid_ && n_ > 0 && factored_) make_single(); }
    bool has_single() const { return single_valid_; }
    // Supernodal form: keep a half-precision copy of the panels (solver/half.h) where the CPU
    // converts halves, and the single-precision one (its fallback) with every factorization.
    void set_keep_half(bool keep) {
        keep_half_ = keep;
        if (keep && !half_valid_ && n_ > 0 && factored_) make_single();
    }
    bool has_half() const { return half_valid_; }
    int nodes() const { return n_; }
    // After analyze(): the step at which the node (original numbering) is eliminated.
    int position(int node) const { return inverse_[node]; }
    // Scalar floating-point operations of one factorization (from the symbolic analysis).
    double factor_flops() const { return factor_flops_; }
    bool analysed() const { return n_ > 0; }
    long block_nonzeros() const { return static_cast<long>(li_.size()); }
    // debugging / statistics
    const std::vector<int>& column_counts() const { return lnz_; }
    const std::vector<int>& column_rows() const { return li_; }
    const std::vector<int>& column_starts() const { return lp_; }
    const std::vector<int>& etree() const { return parent_; }

private:
    struct BlockRef {
        int row;          // permuted node index (<= the column's)
        int offsets[9];   // of the block's entries in A's value array, row-major
    };
    int n_ = 0;                          // nodes
    std::vector<int> order_;             // order_[new] = old node
    std::vector<int> inverse_;           // inverse_[old] = new node
    std::vector<std::vector<BlockRef>> column_;  // upper pattern of permuted A, by column
    std::vector<int> parent_, lp_, lnz_, li_;    // elimination tree, L's column pointers and rows
    std::vector<Mat3> lx_, d_inverse_;
    std::vector<float> lx_single_, d_inverse_single_;  // 9 per block, column-major
    // Supernodal form: A = L L^T with scalar L stored as dense panels, one per
    // supernode (consecutive nodes sharing their column structure): supernode s covers nodes
    // [sn_start_[s], sn_start_[s+1]); its rows (nodes) are sn_rows_[sn_rows_ptr_[s] ..), its own
    // nodes first; its panel is 3 rows x 3 width values, column-major, at sn_val_ptr_[s].
    bool supernodal_ = false;
    std::vector<int> sn_start_, sn_rows_ptr_, sn_rows_, node_sn_;
    std::vector<size_t> sn_val_ptr_;
    std::vector<double> sn_val_;
    std::vector<float> sn_val_single_;
    std::vector<Half> sn_val_half_;         // the panels' values over their column's scale
    std::vector<float> sn_scale_;           // per scalar column (as sn_diag_inverse_): its largest magnitude
    std::vector<int> sn_diag_ptr_;          // 3 width per supernode
    std::vector<double> sn_diag_inverse_;   // 1 / L(c, c) of every scalar column
    std::vector<std::vector<BlockRef>> lower_;  // lower pattern of permuted A by column (row >= column)
    std::vector<int> link_head_, link_next_, sn_pos_;
    // the two parts: per supernode its part (0, 1, or 2: the rest, after both); per part a
    // workspace, and the supernodes whose next update goes to the rest (linked afterwards)
    std::vector<unsigned char> sn_part_;
    struct PartWork {
        std::vector<int> relmap;
        std::vector<double> update;
        std::vector<int> pending;
        std::vector<int> descendants;  // factor_supernode's: those whose updates it takes
    };
    // per supernode of the rest: 0, or the first column (scalar) of its second share of updates
    std::vector<int> sn_split_;
    static constexpr double kSplitUpdateFlops = 2e6;  // below it one share (a share costs a hand-over)
    PartWork part_work_[2];
    int factor_parts_ = 0;
    bool part_done_[2] = {false, false};  // (one flag per part: the parts may run at once)
    void analyze_supernodes();
    void split_supernodes();
    void factorize_supernodal(const SpMat& a, const Beside& beside);
    void factor_supernode(const double* values, int j, int part, const Beside* beside);
    void factorize_up_looking(const SpMat& a);
    // part: only the supernodes of that part (0, 1, or 2: the rest), and only the passes asked
    // (forward, backward); -1: every supernode, both passes
    // the solves on MatX: columns packed node-major, kWidestSolve a pass; beside: split passes
    void solve_packed(MatX& b, const std::vector<Mat3>* warp, const std::vector<int>* wanted_nodes, const Beside* beside) const;
    void pack_columns(const MatX& b, Eigen::Index first, int k, int w, double* packed) const;
    void unpack_columns(const double* packed, int w, MatX& b, Eigen::Index first, int k) const;
    // lanes of a double pass on MatX columns and of solve_units' passes (see solve_packed)
    int widest_pass() const;
    // (T: double, or float for the one-lane half passes: float_passes)
    // path: null, or per supernode whether the forward pass visits it (solve_units: the batch's
    // units and their ancestors; the others hold zeros, which it then need not scan for)
    template <typename T>
    void solve_supernodal(T* x, int w, Panels panels, const unsigned char* wanted, int part = -1, bool forward = true,
                          bool backward = true, const unsigned char* path = nullptr) const;
    // solve_units' path for units[0 .. k) into scratch (see solve_supernodal)
    const unsigned char* unit_path(const int* units, int k) const;
    // whether a pass of w lanes on these panels runs in float arithmetic (one lane on the half
    // panels, where the CPU converts halves: see supernodal_solve_half_float)
    bool float_passes(int w, Panels panels) const;
    void check_panels(int w, Panels panels) const;
    // path: as solve_supernodal's, per node on the up-looking factor
    void solve_in_order(double* x, int w, Panels panels, const unsigned char* wanted, const unsigned char* path = nullptr) const;
    void solve_node_major(double* x, int w, const std::vector<Mat3>* warp, Panels panels, const unsigned char* wanted) const;
    const unsigned char* wanted_mask(const std::vector<int>& nodes) const;
    bool keep_single_ = false, single_valid_ = false, factored_ = false;
    bool keep_half_ = false, half_valid_ = false;
    void make_single(const Beside& beside = nullptr);
    double factor_flops_ = 0;
    // workspaces of factorize()
    std::vector<Mat3> y_;
    std::vector<int> flag_, pattern_;
};

// y = A x on node-major storage (x, y: 3n rows x w values, w = 1, 4 or 8) for a symmetric A,
// 3n x 3n, both triangles stored, whose three columns of a node share one row pattern made
// of whole 3x3 blocks (has_node_block_pattern). AVX2 / AVX-512 kernels chosen at run time.
void multiply_node_major(const SpMat& a, const double* x, double* y, int w);
// The same for the rows of nodes [first_node, end_node) only (y's other rows untouched): two
// ranges give the same values as the whole product, each node's rows from its own column.
void multiply_node_major(const SpMat& a, const double* x, double* y, int w, int first_node, int end_node);
bool has_node_block_pattern(const SpMat& a);

}  // namespace hh
