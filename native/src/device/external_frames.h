// A glove of several frames whose poses the host pushes (one pose per bone of a skeleton hand:
// a tracked glove's joints retargeted to the bones, docs/skeleton.md Section 6) and whose
// feedback the host reads, per bone and per group of bones, for the glove's actuators. Poses
// and feedback cross threads through triple buffers sized once: the host never waits for the
// haptic loop and the haptic loop never waits for the host or allocates. Each frame's velocity
// is the difference of its last two poses (device/pushed_pose.h).
//
// Until the first poses arrive the frames hold the start poses (the bones', so the hand stays
// where it is); a host that pushes none within `timeout` seconds of the first read fails the
// session with a message, as the one-frame external device does.
#pragma once
#include <cstdio>
#include <vector>

#include "common/triple_buffer.h"
#include "device/device.h"
#include "device/pushed_pose.h"

namespace hh {

// What the haptic step commanded last: its time and the feedback per bone and per group.
struct FramesFeedback {
    double time = 0;
    std::vector<Feedback> bones, groups;
};

class ExternalFrames : public Device {
public:
    // start: the frames until the host pushes any; n_groups: how many group wrenches it keeps
    ExternalFrames(const std::vector<Pose>& start, int n_groups, double timeout)
        : poses_(start), feedback_(FramesFeedback{0, std::vector<Feedback>(start.size()), std::vector<Feedback>(n_groups)}),
          frames_(start.size()), timeout_(timeout) {
        for (size_t b = 0; b < start.size(); ++b) frames_[b].pose = start[b];
    }
    const char* name() const override { return "external"; }
    bool read(double t, Pose&) noexcept override { return frames_only(t); }
    int frames() const override { return static_cast<int>(frames_.size()); }
    bool read_frames(double t, Pose* out, int n) noexcept override {
        if (n != frames()) return read(t, out[0]);
        if (t_first_ < 0) t_first_ = t;
        if (poses_.fetch()) {
            for (int b = 0; b < n; ++b) frames_[b].take(poses_.front()[b], t);
        } else if (!frames_[0].seen && t - t_first_ > timeout_) {
            return never_connected(t);
        } else {
            for (PushedPose& f : frames_) f.rest_if_stale(t);  // no news for a while: at rest
        }
        for (int b = 0; b < n; ++b) out[b] = frames_[b].pose;
        t_now_ = t;
        return true;
    }
    void command_frames(const Feedback* bones, int n, const Feedback* groups, int n_groups) noexcept override {
        FramesFeedback& f = feedback_.back();
        f.time = t_now_;
        for (int b = 0; b < n && b < static_cast<int>(f.bones.size()); ++b) f.bones[b] = bones[b];
        for (int g = 0; g < n_groups && g < static_cast<int>(f.groups.size()); ++g) f.groups[g] = groups[g];
        feedback_.publish();
    }

    // Host thread: the frames' poses (n = frames(), positions and unit quaternions checked by the caller)
    void push(const Pose* poses, int n) {
        for (int b = 0; b < n; ++b) poses_.back()[b] = poses[b];
        poses_.publish();
    }
    // Host thread: the newest feedback (fetch, then feedback()); true when it changed
    bool fetch_feedback() { return feedback_.fetch(); }
    const FramesFeedback& feedback() const { return feedback_.front(); }
    int groups() const { return static_cast<int>(feedback_.front().groups.size()); }

private:
    bool never_connected(double t) noexcept {
        char what[200];
        std::snprintf(what, sizeof what,
                      "the external glove sent no poses within %.3g s of the start: push its frames "
                      "(NativeSession.push_device_frames), or raise haptics.external_timeout",
                      timeout_);
        fail(what, t);
        return false;
    }

    TripleBuffer<std::vector<Pose>> poses_;
    TripleBuffer<FramesFeedback> feedback_;
    std::vector<PushedPose> frames_;
    double timeout_;
    double t_first_ = -1, t_now_ = 0;
};

}  // namespace hh
