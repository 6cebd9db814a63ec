// One implicit step of a hand of B > 1 bones (docs/skeleton.md, Sections 2-4): Eq. 7 with a
// 6x6 block per bone, each bone's springs (Eqs. 4-5, 8-11) on its own nodes, each bone's virtual
// coupling to its target (free, coupled or prescribed), linearized about the state the step's
// rigid frame carries the hand to (sim/skeleton_frame.h), solved by SkeletonSystem's Schur
// complement or the monolithic reference, and integrated per bone as the palm handle is.
#pragma once
#include <vector>

#include "sim/data.h"

namespace hh {

// Fills data.skeleton (A_h per bone, A_t, A_ht, A_th, r) for one step of dt: begin (the step's
// rigid frame and the element rotations carried by it; what the world's contact setup reads,
// so it runs before the step's tasks), then end (the element pass, A_t, b_t, every bone's blocks).
void formulate_skeleton(const Model& model, Data& data);
void formulate_skeleton_begin(const Model& model, Data& data);
void formulate_skeleton_end(const Model& model, Data& data);
// Advances the flesh and every bone with the step's velocities s = (v_h, v_t) (integrate()'s rule).
void integrate_skeleton(const Model& model, Data& data, const VecX& s);
void step_skeleton(const Model& model, Data& data, bool monolithic);

// Each bone's springs' wrench (force, torque about its centre of mass) at the current state:
// W_b = sum over N_b of (F_B, R r_B x F_B), Eq. 5.
std::vector<Vec6> bone_wrenches(const Model& model, const Data& data);

// The ball joints' and angular limits' elastic energy, sum of k |e|^2 / 2 and of k/2 times each
// limit's squared overshoot (docs/skeleton.md Section 5; 0 without them).
double joint_energy(const Model& model, const Data& data);

}  // namespace hh
