// Sparse LDL^T factorization of a symmetric positive definite matrix made of 3x3 node
// blocks (the deformable system At), with D block-diagonal and L unit block-lower-
// triangular. Same algorithm as Davis's LDL (up-looking, elimination tree), with each scalar
// replaced by a 3x3 block: index work drops ninefold and the inner products become small
// fixed-size matrix products the compiler unrolls. Fill-reducing AMD ordering on the node
// graph. The pattern is analysed once; factorize() is called each step.
// Solves take several right-hand sides at once: one pass over L serves them all, and the
// passes are memory bound, so k right-hand sides cost far less than k single solves.
#pragma once
#include <vector>

#include "common/types.h"

namespace hh {

class BlockLDLT {
public:
    // A: 3n x 3n, column-major, both triangles stored, pattern closed under 3x3 node blocks.
    void analyze(const SpMat& a);
    void factorize(const SpMat& a);
    VecX solve(const VecX& b) const;
    // In place, every column of b a right-hand side.
    void solve(MatX& b) const;
    // Solves with the warped matrix W A W^T (W block-diagonal, a 3x3 block per node, e.g. the
    // rotation of each node since the factorization): x = W A^-1 W^T b. warp null: W = I.
    void solve(MatX& b, const std::vector<Mat3>* warp) const;
    // The same on node-major storage: x holds n nodes x 3 x w values (w = 1, 4 or 8; node i's
    // 3 x w block at x + 3 w i, row-major), in the matrix's own node order.
    void solve_node_major(double* x, int w, const std::vector<Mat3>* warp) const;
    int nodes() const { return n_; }
    // Scalar floating-point operations of one factorization (from the symbolic analysis).
    double factor_flops() const { return factor_flops_; }
    bool analysed() const { return n_ > 0; }
    long block_nonzeros() const { return static_cast<long>(li_.size()); }

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
    double factor_flops_ = 0;
    mutable std::vector<double> work_, packed_;
    // workspaces of factorize()
    std::vector<Mat3> y_;
    std::vector<int> flag_, pattern_;
};

}  // namespace hh
