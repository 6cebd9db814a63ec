// A pose the host pushes to the haptic loop (external devices): the pose itself and its
// velocity, the difference of the last two poses over the haptic time between them; a pose
// with no news for 0.1 s is at rest.
#pragma once
#include "sim/keyframes.h"

namespace hh {

struct PushedPose {
    Pose pose;
    double t_last = 0;
    bool seen = false;

    void take(const Pose& p, double t) noexcept {
        const double dt = t - t_last;
        if (dt > 0 && seen) pose.velocity = (p.position - pose.position) / dt;
        pose.position = p.position;
        pose.quaternion = p.quaternion;
        t_last = t;
        seen = true;
    }
    void rest_if_stale(double t) noexcept {
        if (t - t_last > 0.1) pose.velocity.setZero();
    }
};

}  // namespace hh
