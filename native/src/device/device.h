// The haptic device as the haptic loop sees it (ARCHITECTURE: device/): a pose to read each
// step and a feedback wrench to command. Backends: a simulated user (simulated_arm), playback
// of a recorded trajectory (playback), a pose pushed by the host (external: HID input devices
// and Blender's viewport target), OpenHaptics devices loaded at run time (openhaptics), and
// gloves of one frame per bone of a skeleton hand: poses pushed by the host (external_frames)
// or a simulated glove user (simulated_glove). read() and command() (and the frames' forms)
// run on the haptic thread: they never allocate, lock or throw.
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

    // A device of several frames (a glove: one frame per bone of a skeleton hand, docs/skeleton.md
    // Section 6): how many, the frames at time t (out[n], n = frames()), and the feedback of the
    // step that read them, per bone (bones[n]) and per group of bones (groups[n_groups], summed,
    // haptics/bone_proxies.h). A one-frame device is read and commanded through read and command.
    virtual int frames() const { return 1; }
    virtual bool read_frames(double t, Pose* out, int n) noexcept { return n == 1 && read(t, out[0]); }
    virtual void command_frames(const Feedback* bones, int n, const Feedback* /*groups*/, int /*n_groups*/) noexcept {
        if (n == 1) command(bones[0]);
    }

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
    // read() of a device of several frames: a session reads it by read_frames
    bool frames_only(double t) noexcept {
        fail("this device has one frame per bone: it drives a skeleton hand's session", t);
        return false;
    }
    char error_[256] = {0};
};

}  // namespace hh
