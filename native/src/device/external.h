// A device whose pose the host pushes (HID 6-DoF input decoded in Python, Blender's viewport
// target empty). The pose crosses threads through a triple buffer: push never waits for the
// haptic loop and the haptic loop never waits for the host. Input only. The velocity is the
// difference of the last two poses over the haptic time between them.
//
// Until the first pose arrives the device holds the start pose (the handle's, so the hand
// stays where it is); a host that never pushes one within `timeout` seconds of the first read
// is a driver that never connected, and the device reports it rather than holding forever.
#pragma once
#include <cstdio>

#include "device/device.h"
#include "device/pushed_pose.h"
#include "common/triple_buffer.h"

namespace hh {

class ExternalDevice : public Device {
public:
    ExternalDevice(const Pose& start, double timeout) : buffer_(start), timeout_(timeout) { pose_.pose = start; }
    const char* name() const override { return "external"; }
    bool outputs_force() const override { return false; }
    void push(const Pose& p) {  // host thread
        buffer_.back() = p;
        buffer_.publish();
    }
    bool read(double t, Pose& out) noexcept override {
        if (t_first_ < 0) t_first_ = t;
        if (buffer_.fetch()) {
            pose_.take(buffer_.front(), t);
        } else if (!pose_.seen && t - t_first_ > timeout_) {
            return never_connected(t);
        } else {
            pose_.rest_if_stale(t);  // no news for a while: the target is at rest
        }
        out = pose_.pose;
        return true;
    }

private:
    bool never_connected(double t) noexcept {
        char what[200];
        std::snprintf(what, sizeof what,
                      "the external device sent no pose within %.3g s of the start: push poses "
                      "(LiveSession.set_device_pose, or move the target empty), or raise "
                      "haptics.external_timeout",
                      timeout_);
        fail(what, t);
        return false;
    }

    TripleBuffer<Pose> buffer_;
    PushedPose pose_;
    double timeout_;
    double t_first_ = -1;
};

}  // namespace hh
