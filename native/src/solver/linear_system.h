// The black-box interface of Section 6: every dynamic body formulates a linear system
// A s = r for its implicit step; callers set r, call solve(), and read s. The complete hand
// (HandSystem) implements the same interface on top of a deformable and a rigid one.
#pragma once
#include "common/types.h"

namespace hh {

class LinearSystem {
public:
    virtual ~LinearSystem() = default;
    virtual void solve() = 0;  // s = A^-1 r
    VecX r;
    VecX s;
};

}  // namespace hh
