// The simulated glove user: one simulated arm (device/simulated_arm.h) per bone of a skeleton
// hand, each following its bone's scripted poses and pushed by its bone's feedback force, so the
// feedback changes the motion finger by finger as it would a person's. Each arm is a person's,
// bounded in pull, speed and turning rate: a script that jumps is followed as a hand could.
// A frame may instead be posed: it follows its script exactly and feels nothing (a finger posed
// by animation while a palm device on the wrist carries the hand, or a glove that renders the
// palm's wrench only).
#pragma once
#include <cstdio>
#include <vector>

#include "device/simulated_arm.h"

namespace hh {

class SimulatedGlove : public Device {
public:
    // posed[b] != 0: bone b's frame is posed (empty: none is)
    explicit SimulatedGlove(std::vector<SimulatedArm> arms, std::vector<char> posed = {})
        : arms_(std::move(arms)), posed_(std::move(posed)) {
        posed_.resize(arms_.size(), 0);
    }
    const char* name() const override { return "simulated glove"; }
    bool read(double t, Pose&) noexcept override { return frames_only(t); }
    int frames() const override { return static_cast<int>(arms_.size()); }
    bool read_frames(double t, Pose* out, int n) noexcept override {
        if (n != frames()) return read(t, out[0]);
        for (int b = 0; b < n; ++b)
            if (!(posed_[b] ? arms_[b].read_script(t, out[b]) : arms_[b].read(t, out[b]))) {
                std::snprintf(error_, sizeof error_, "bone %d's finger: %.200s", b, arms_[b].error());
                return false;
            }
        return true;
    }
    void command_frames(const Feedback* bones, int n, const Feedback*, int) noexcept override {
        for (int b = 0; b < n && b < frames(); ++b)
            if (!posed_[b]) arms_[b].command(bones[b]);
    }

private:
    std::vector<SimulatedArm> arms_;
    std::vector<char> posed_;
};

}  // namespace hh
