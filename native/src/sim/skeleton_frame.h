// The step's rigid frame (sim/step_frame.h) for a hand of B bones: the hand's own rotation
// over the step at its start-of-step angular velocity, R = exp(dt omega) (hand_motion, every
// bone counted with its mass, inertia and spin), about the root's centre when a target holds
// it, else the whole hand's centre of mass. Every bone is carried by it as the palm handle is: centre c + R (x_b - c),
// orientation R q_b, velocity omega x R (x_b - c), angular velocity omega. With one bone this is
// update_step_frame; the one-bone step uses that and never comes here.
#pragma once
#include <vector>

#include "sim/data.h"

namespace hh {

// Fills f (f.handle: the root carried) and carried[b] for every bone.
void update_skeleton_frame(const Model& model, const Data& data, StepFrame& f, std::vector<HandleState>& carried);

// (v_h, v_t) of the step from those relative to the frame (data.skeleton's solution), as
// frame_velocities: plus the frame's velocities at the advanced state, and with a free root the
// turn of the whole hand about c that keeps its angular momentum.
VecX skeleton_frame_velocities(const Model& model, const StepFrame& f, const std::vector<HandleState>& carried,
                               const VecX& relative);

}  // namespace hh
