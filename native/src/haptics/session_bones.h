// The part of a haptic session (haptics/session.h) that a skeleton hand of B > 1 bones adds
// (docs/skeleton.md, Section 6): the B proxies, what the loops hand each other through triple
// buffers sized once (the visual loop's snapshot of the bones' model, the haptic loop's sample
// of the proxies and device frames), the haptic step's work arrays, and the feedback groups.
#pragma once
#include <vector>

#include "common/triple_buffer.h"
#include "haptics/bone_proxies.h"
#include "haptics/session.h"

namespace hh {

// What the haptic loop tells the visual loop: every proxy, device frame and feedback of a step.
struct BoneSample {
    double time = 0;
    std::vector<HandleState> proxies;
    std::vector<Pose> devices;
    std::vector<Feedback> feedback, groups;  // per bone, per group (up to one per bone)
    Feedback commanded;                      // what the device was commanded: the root's, or a wrist glove's sum
};

// The model of a step not linearized (or none yet): the bones where they are, no wrench.
BoneCouplingModel resting_bone_model(const Data& d, int n_bones);

struct Session::Bones {
    Bones(const Model& m, const Data& d, const VirtualCoupling& coupling, double h);
    int n;
    BoneProxies proxies;                // the haptic thread's
    TripleBuffer<BoneSnapshot> models;  // visual -> haptic
    TripleBuffer<BoneSample> samples;   // haptic -> visual
    FeedbackGroups groups;              // set while stopped, read by the haptic thread
    // haptic side: the frames read and the feedback of the step (sized once)
    std::vector<Pose> devices;
    std::vector<Feedback> feedback, group_out;
    // visual side: the newest sample, the last model
    BoneSample sample;
    BoneCouplingModel last_model;
    // A snapshot of last_model for haptic steps of h, published (the visual loop's, or while stopped)
    void publish_model(double h);
};

}  // namespace hh
