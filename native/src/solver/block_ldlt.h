// Sparse LDL^T factorization of a symmetric positive definite matrix made of 3x3 node
// blocks (the deformable system At), with D block-diagonal and L unit block-lower-
// triangular. Same algorithm as Davis's LDL (up-looking, elimination tree), with each scalar
// replaced by a 3x3 block: index work drops ninefold and the inner products become small
// fixed-size matrix products the compiler unrolls. Fill-reducing AMD ordering on the node
// graph. The pattern is analysed once; factorize() is called each step.
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
    // workspaces of factorize()
    std::vector<Mat3> y_;
    std::vector<int> flag_, pattern_;
};

}  // namespace hh
