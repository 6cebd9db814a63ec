// The haptic device as the haptic loop sees it (ARCHITECTURE: device/): a pose to read each
// step and a feedback wrench to command. Backends: a simulated user (simulated_arm), playback
// of a recorded trajectory (playback), a pose pushed by the host (external: HID input devices
// and Blender's viewport target), and OpenHaptics devices loaded at run time (openhaptics).
// read() and command() run on the haptic thread: they never allocate, lock or throw.
#pragma once
#include <cstdio>

#include "device/feedback.h"
#include "sim/keyframes.h"

namespace hh {

class Device {
public:
    virtual ~Device() = default;
    virtual const char* name() const = 0;
    // The device frame at time t (s, the haptic loop's clock), world frame, SI units. False
    // when the device is gone; error() then says why.
    virtual bool read(double t, Pose& out) noexcept = 0;
    // The feedback of the step that just read; devices without force output ignore it.
    virtual void command(const Feedback&) noexcept {}
    virtual bool outputs_force() const { return true; }

    // A device whose driver runs its own servo loop (OpenHaptics) calls tick(user) from it at
    // its own rate instead of the session's haptic thread. start_servo throws InvalidArgument
    // with a message naming the problem when the driver cannot start.
    virtual bool has_servo_loop() const { return false; }
    virtual void start_servo(void (*)(void*), void*) {}
    virtual void stop_servo() noexcept {}

    const char* error() const { return error_; }
    double max_force = 1e9;   // N: feedback is clamped to this norm before command()
    double max_torque = 1e9;  // N m

protected:
    void fail(const char* what, double t) noexcept { std::snprintf(error_, sizeof error_, "%s (t = %.3f s)", what, t); }
    char error_[256] = {0};
};

}  // namespace hh
