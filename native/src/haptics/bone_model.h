// The handle-space model of a hand of B bones alone (docs/skeleton.md, Section 6, without
// contacts): after a step with every bone driven to the pose its end-of-step velocity reaches
// (prescribed, as the visual loop drives a handle to its proxy), the bones' springs' wrenches at
// the end of the step as a linear function of the bones' end velocities v_h (6B) about v_h = 0:
//   W(v_h) = wrench0 + response v_h,
// the exact derivative of that step (hh_coupling_linear_model block for block).
#pragma once
#include <memory>

#include "sim/data.h"

namespace hh {

// A copy of d with every bone prescribed to the pose its end velocity vh (6B: v_b, omega_b)
// reaches from the step's frame (the hand's turn about the root), stepped once.
std::unique_ptr<Data> driven_bones(const Model& m, const Data& d, const VecX& vh);

// W(vh): every bone's springs' wrench (force, torque about its centre) at the end of that step.
VecX bone_response(const Model& m, const Data& d, const VecX& vh);

struct BoneLinearModel {
    VecX wrench0;  // 6B
    MatX response; // 6B x 6B, d W / d v_h
};
BoneLinearModel bone_linear_model(const Model& m, const Data& d);

}  // namespace hh
