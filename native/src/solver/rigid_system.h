// The rigid handle's linear system: Ah is a dense 6x6 matrix (Eq. 7), generally not
// symmetric once the springs' torque terms enter, solved by LU with partial pivoting.
#pragma once
#include "solver/linear_system.h"

namespace hh {

class RigidSystem : public LinearSystem {
public:
    RigidSystem() { r = VecX::Zero(6); s = VecX::Zero(6); }
    Mat6 A = Mat6::Identity();
    void solve() override;
};

}  // namespace hh
