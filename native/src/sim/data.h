// The mutable part of a simulation (MuJoCo's mjData in spirit): state, device frame, and
// the workspaces of the linear systems.
#pragma once
#include <vector>

#include "sim/flesh_step.h"
#include "sim/model.h"
#include "sim/step_frame.h"
#include "solver/hand_system.h"
#include "solver/skeleton_system.h"

namespace hh {

struct DeviceFrame {
    bool enabled = false;
    // The handle follows this pose exactly (kinematically) instead of through the virtual
    // coupling: the visual loop's handle driven to the haptic loop's proxy (Section 3).
    bool prescribed = false;
    Vec3 position = Vec3::Zero();
    Vec4 quaternion = Vec4(0, 0, 0, 1);
    Vec3 velocity = Vec3::Zero();
    Vec3 angular_velocity = Vec3::Zero();
};

// FleshState holds x_t, v_t of Eq. 1 and the element rotations.
struct Data : FleshState {
    explicit Data(const Model& model);
    HandleState h;   // Eq. 1: x_h = (x_com, q_h), v_h = (v_com, omega_h)
    DeviceFrame device;

    DeformableSystem tool;
    RigidSystem rigid;
    HandSystem hand{tool, rigid};
    CouplingBlocks coupling;
    // The step's rigid frame (formulate_begin): Eq. 7 is linearized about the state it carries
    // the hand to and data.hand solves for the velocities relative to frame's, (v_h, v_t) - (the
    // frame's), which integrate() takes back.
    StepFrame frame;
    // With a prescribed handle: Aht's blocks at the handle's end-of-step pose, where the coupling
    // model differentiates the springs' wrench (haptics/coupling_model.cpp); else empty.
    std::vector<Mat63> end_aht;
    hh_step_stats stats{};

    // A skeleton of B > 1 bones (docs/skeleton.md): the states and targets of bones 1..B-1 at
    // index b - 1 (the root's are h and device, so every single-handle entry point addresses the
    // root), each bone's state carried by the step's frame, its coupling blocks, and the coupled
    // system of Eq. 7 for B bones. Empty with one bone: the step is today's (data.hand).
    std::vector<HandleState> bones;
    std::vector<DeviceFrame> targets;
    std::vector<HandleState> carried;
    std::vector<CouplingBlocks> bone_coupling;
    SkeletonSystem skeleton{tool};
    // Whether the last step of B > 1 bones had every bone prescribed: the step the B-bone
    // coupling model differentiates (haptics/bone_coupling_model.h)
    bool bones_prescribed = false;
};

// Bone b's state and target (bone 0: h and device).
inline HandleState& bone_state(Data& d, int b) { return b == 0 ? d.h : d.bones[b - 1]; }
inline const HandleState& bone_state(const Data& d, int b) { return b == 0 ? d.h : d.bones[b - 1]; }
inline DeviceFrame& bone_target(Data& d, int b) { return b == 0 ? d.device : d.targets[b - 1]; }
inline const DeviceFrame& bone_target(const Data& d, int b) { return b == 0 ? d.device : d.targets[b - 1]; }

void reset(const Model& model, Data& data);
void configure_solver(const Model& model, Data& data);

// Fills data.hand (Ah, At, Aht, Ath, r) with the system of Eq. 7 for one step of dt. In
// stages (the world runs parts 0 and 1 of the element pass on two threads, formulate_flesh):
// formulate_begin, formulate_pass for parts 0, 1, 2, formulate_end.
void formulate(const Model& model, Data& data);
void formulate_begin(const Model& model, Data& data);
void formulate_pass(const Model& model, Data& data, int part);
void formulate_end(const Model& model, Data& data);
// (v_h, v_t) of the step from data.hand's solution of Eq. 7 relative to the step's frame
// (frame_velocities, sim/step_frame.h).
VecX step_velocities(const Model& model, const Data& data, const VecX& relative);
// Advances x, v and the handle to the end of the step with velocities s = (v_h, v_t): every
// node and the handle by the step's rigid frame (data.frame), then by dt times its velocity
// relative to the frame's (the handle's turn on the exponential map of that relative part).
void integrate(const Model& model, Data& data, const VecX& s);
// One step: formulate, solve by Schur complement (or the monolithic reference), integrate.
void step(const Model& model, Data& data, bool monolithic);

Mat3 handle_world_inertia(const Model& model, const HandleState& h);

// Total force and torque (about x_com) the springs apply on the handle.
void coupling_wrench(const Model& model, const Data& data, Vec3& force, Vec3& torque);

}  // namespace hh
