// A skeleton hand driven from one device on the wrist, the fingers posed (docs/skeleton.md,
// Section 6): a one-frame device (OpenHaptics, playback, the host-pushed external device, the
// simulated arm) gives the root's frame, and every other bone's frame is the root's carried by
// that bone's scripted pose relative to the root, rel_b(t) = T_root,anim(t)^-1 T_b,anim(t):
// T_b = T_wrist rel_b. The fingers are posed rigidly on the device in the user's hand, so what
// a finger touches pushes the stylus: the wrist device is commanded the whole hand's wrench, the
// sum of every bone's feedback with each force's moment about the wrist frame's point, clamped to
// the device's limits (max_force, max_torque: the session sets them to its own and the wrapped
// device's, the lower of each). read_frames and command_frames never allocate, lock or throw:
// the frames' positions of the step are kept in an array sized once.
#pragma once
#include <cstdio>
#include <memory>
#include <vector>

#include "device/device.h"
#include "rigid/quaternion.h"

namespace hh {

class WristGlove : public Device {
public:
    // fingers[b - 1]: bone b's pose relative to the root over time, in the root's frame
    WristGlove(std::unique_ptr<Device> wrist, std::vector<Keyframes> fingers)
        : wrist_(std::move(wrist)), fingers_(std::move(fingers)), at_(fingers_.size() + 1, Vec3::Zero()) {
        max_force = wrist_->max_force;
        max_torque = wrist_->max_torque;
    }
    const char* name() const override { return wrist_->name(); }
    bool read(double t, Pose&) noexcept override { return frames_only(t); }
    int frames() const override { return static_cast<int>(fingers_.size()) + 1; }
    bool outputs_force() const override { return wrist_->outputs_force(); }

    bool read_frames(double t, Pose* out, int n) noexcept override {
        if (n != frames()) return read(t, out[0]);
        if (!wrist_->read(t, out[0])) {
            std::snprintf(error_, sizeof error_, "%s", wrist_->error());
            return false;
        }
        const Pose& w = out[0];
        const Mat3 r = quat_to_matrix(w.quaternion);
        at_[0] = w.position;
        for (int b = 1; b < n; ++b) {
            const Pose rel = fingers_[b - 1].at(t);
            const Vec3 arm = r * rel.position;  // p_b - p_0
            Pose& f = out[b];
            f.position = w.position + arm;
            f.quaternion = quat_multiply(w.quaternion, rel.quaternion).normalized();
            // the rigid motion of the wrist carrying the finger, plus the finger's own motion on it
            f.velocity = w.velocity + w.angular_velocity.cross(arm) + r * rel.velocity;
            f.angular_velocity = w.angular_velocity + r * rel.angular_velocity;
            at_[b] = f.position;
        }
        return true;
    }

    // The whole hand's wrench on the wrist frame: forces summed, torques summed with each force's
    // moment about the wrist frame's point (tau += (p_b - p_0) x f_b), then clamped.
    void command_frames(const Feedback* bones, int n, const Feedback*, int) noexcept override {
        Feedback sum;
        for (int b = 0; b < n && b < frames(); ++b) {
            sum.force += bones[b].force;
            sum.torque += bones[b].torque + (at_[b] - at_[0]).cross(bones[b].force);
        }
        const double fn = sum.force.norm(), tn = sum.torque.norm();
        if (fn > max_force) sum.force *= max_force / fn;
        if (tn > max_torque) sum.torque *= max_torque / tn;
        commanded_ = sum;
        wrist_->command(sum);
    }
    // what the last step commanded the wrist device
    const Feedback& commanded() const { return commanded_; }

    bool has_servo_loop() const override { return wrist_->has_servo_loop(); }
    void start_servo(void (*tick)(void*), void* user) override { wrist_->start_servo(tick, user); }
    void stop_servo() noexcept override { wrist_->stop_servo(); }

    Device& wrist() { return *wrist_; }
    // the wrist device back (the session re-poses the fingers on it)
    std::unique_ptr<Device> release_wrist() { return std::move(wrist_); }

private:
    std::unique_ptr<Device> wrist_;
    std::vector<Keyframes> fingers_;
    std::vector<Vec3> at_;  // every frame's position read this step: the moments' lever arms
    Feedback commanded_;
};

}  // namespace hh
