// Shared Eigen types and the error type that every C entry point turns into a status.
#pragma once
#include <Eigen/Dense>
#include <Eigen/Sparse>
#include <stdexcept>
#include <string>

namespace hh {

using Vec3 = Eigen::Vector3d;
using Vec4 = Eigen::Vector4d;  // quaternions as (x, y, z, s), the paper's Appendix A order
using Vec6 = Eigen::Matrix<double, 6, 1>;
using Mat3 = Eigen::Matrix3d;
using Mat6 = Eigen::Matrix<double, 6, 6>;
using Mat34 = Eigen::Matrix<double, 3, 4>;
using Mat43 = Eigen::Matrix<double, 4, 3>;
using Mat36 = Eigen::Matrix<double, 3, 6>;
using Mat63 = Eigen::Matrix<double, 6, 3>;
using Mat12 = Eigen::Matrix<double, 12, 12>;
using VecX = Eigen::VectorXd;
using MatX = Eigen::MatrixXd;
using SpMat = Eigen::SparseMatrix<double>;  // column-major

// Bad input from the user: the message names the problem and the fix.
struct InvalidArgument : std::runtime_error {
    using std::runtime_error::runtime_error;
};
// A solve that failed or produced non-finite numbers.
struct NumericalError : std::runtime_error {
    using std::runtime_error::runtime_error;
};

// Cross-product matrix: skew(a) * b == a.cross(b).
inline Mat3 skew(const Vec3& a) {
    Mat3 m;
    m << 0, -a.z(), a.y(), a.z(), 0, -a.x(), -a.y(), a.x(), 0;
    return m;
}

}  // namespace hh
