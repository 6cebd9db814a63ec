#include "solver/rigid_system.h"

namespace hh {

void RigidSystem::solve() {
    Eigen::FullPivLU<Mat6> lu(A);
    if (!lu.isInvertible())
        throw NumericalError("the handle's 6x6 system is singular: check the handle mass and inertia");
    s = lu.solve(r);
}

}  // namespace hh
