// The haptic loop's proxies of a skeleton hand (docs/skeleton.md, Section 6): one proxy per bone,
// with the bone's mass and inertia (Eq. 3), each held by its own two-way virtual coupling to its
// own device frame (a glove's), and all pulled by the bones' linearized coupling wrenches
// F*_c = W0 + K delta (haptics/bone_coupling_model.h), which couple them through the flesh and
// the held contacts. Each haptic step is one backward Euler step of the 6B unknowns, linear in
// the new velocities v' (every force linearized about the present state), as the palm proxy's
// (haptics/proxy.h):
//   (M - h^2 K + h^2 Kc + h Dc) v' = M v - h (0, w x I w) + h (F*_c(x, q at t + h) + Fc(x, v = 0) + Dc v_d)
// with the inertias taken at the model's bone orientations: the matrix then changes only with
// the model, so the visual loop inverts it with each model (prepare) and the 1 kHz step is two
// products with 6B x 6B matrices and per-bone vector work. It allocates nothing and takes no lock.
#pragma once
#include <vector>

#include "device/feedback.h"
#include "haptics/bone_coupling_model.h"
#include "haptics/proxy.h"
#include "sim/model.h"

namespace hh {

// What the visual loop hands the haptic loop after each step: the bones' model, the proxies'
// inertias (world frame, at the model's end orientations) and the step's matrix inverted.
struct BoneSnapshot {
    BoneCouplingModel model;
    std::vector<Mat3> inertia;
    MatX step_inverse;  // (M - h^2 K + h^2 Kc + h Dc)^-1, 6B x 6B
};

class BoneProxies {
public:
    // The proxies of the model's bones at their present states, every one coupled to its
    // device frame with `coupling` (the session's gains).
    BoneProxies(const Model& m, const std::vector<HandleState>& bones, const VirtualCoupling& coupling);
    int n() const { return static_cast<int>(state.size()); }
    std::vector<double> mass;
    std::vector<Mat3> inertia_body;  // about the centre of mass, body axes = world at rest
    std::vector<HandleState> state;
    VirtualCoupling coupling;

    // The snapshot of `model` for steps of h (sizes it: the visual loop's side, which may allocate)
    void prepare(BoneSnapshot& s, double h) const;
    // One step of h ending at t + h, the device frames devices[n()]; each bone's feedback (its
    // coupling's reaction on the user) into out[n()]. With `linearized` off the proxies sit on the
    // model's bone poses (the comparison without handle-space linearization).
    void step(double h, double t, const BoneSnapshot& s, bool linearized, const Pose* devices, Feedback* out) noexcept;

private:
    VecX rhs_, v_, force_, delta_;  // 6B each, sized once
};

// Groups of bones whose feedback is summed (a glove's actuators: the wrist, each digit): each
// bone's group (0 .. n-1, or -1: in none) and each group's first bone, whose device frame is the
// point the group's torque is taken about. Throws InvalidArgument, naming the fix, for a group
// number out of range or a group without a bone.
struct FeedbackGroups {
    FeedbackGroups() = default;
    FeedbackGroups(std::vector<int> group_of_bone, int n_groups);
    std::vector<int> of_bone, first;
    int n() const { return static_cast<int>(first.size()); }
};

// Each group's feedback from its bones': the sum of the forces, and of the torques about the
// group's point (each bone's force acting at its own device frame), into out[groups.n()].
void group_feedback(const FeedbackGroups& groups, const Pose* devices, const Feedback* bones, Feedback* out) noexcept;

}  // namespace hh
