// A device whose pose the host pushes (HID 6-DoF input decoded in Python, Blender's viewport
// target empty). The pose crosses threads through a triple buffer: push never waits for the
// haptic loop and the haptic loop never waits for the host. Input only. The velocity is the
// difference of the last two poses over the haptic time between them.
#pragma once
#include "device/device.h"
#include "common/triple_buffer.h"

namespace hh {

class ExternalDevice : public Device {
public:
    explicit ExternalDevice(const Pose& start) : buffer_(start), pose_(start) {}
    const char* name() const override { return "external"; }
    bool outputs_force() const override { return false; }
    void push(const Pose& p) {  // host thread
        buffer_.back() = p;
        buffer_.publish();
    }
    bool read(double t, Pose& out) noexcept override {
        if (buffer_.fetch()) {
            const Pose& p = buffer_.front();
            const double dt = t - t_last_;
            if (dt > 0 && seen_) {
                pose_.velocity = (p.position - pose_.position) / dt;
            }
            pose_.position = p.position;
            pose_.quaternion = p.quaternion;
            t_last_ = t;
            seen_ = true;
        } else if (t - t_last_ > 0.1) {
            pose_.velocity.setZero();  // no news for a while: the target is at rest
        }
        out = pose_;
        return true;
    }

private:
    TripleBuffer<Pose> buffer_;
    Pose pose_;
    double t_last_ = 0;
    bool seen_ = false;
};

}  // namespace hh
