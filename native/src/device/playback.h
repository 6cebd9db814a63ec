// Replays a recorded device trajectory (timed poses, e.g. a previous session's haptic log or
// a capture from another tracker). Input only: the feedback changes nothing in it.
#pragma once
#include "device/device.h"

namespace hh {

class Playback : public Device {
public:
    Playback(Keyframes recording, double fail_at) : recording_(std::move(recording)), fail_at_(fail_at) {}
    const char* name() const override { return "playback"; }
    bool outputs_force() const override { return false; }
    bool read(double t, Pose& out) noexcept override {
        if (t >= fail_at_) {
            fail("the playback device was told to disconnect", t);
            return false;
        }
        out = recording_.at(t);
        return true;
    }

private:
    Keyframes recording_;
    double fail_at_;
};

}  // namespace hh
