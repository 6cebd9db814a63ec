// Dense kernels of the supernodal factorization (BlockLDLT::factorize_supernodal) on
// column-major panels. With AVX-512 they are this file's register-blocked kernels; with AVX2 its
// kernel for the small outer products and Eigen's for the rest; otherwise Eigen's (the library is
// built for baseline x86-64, where Eigen's dense code is SSE2).
#pragma once

namespace hh {

// C (m x n, leading dimension m) = A(0:m, 0:k) A(0:n, 0:k)^T for a column-major A with leading
// dimension lda (n <= m): a descendant's update of a supernode. Only C's lower part by 3x3
// node blocks is specified (rows from each column's node block down; C is symmetric on top).
void panel_outer_product(const double* a, int lda, int m, int n, int k, double* c);

// In place, a supernode's panel P (ld x m, column-major, ld >= m): its top m x m block is
// symmetric positive definite (lower triangle read), the rest the rows below. Afterwards P
// holds L's columns, [L11; L21] with P11 = L11 L11^T and L21 = P21 L11^-T (the entries above
// L11's diagonal are left unspecified). False when a pivot is not positive or not finite.
bool panel_cholesky(double* p, int ld, int m);

}  // namespace hh
