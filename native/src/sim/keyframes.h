// A scripted rigid motion: timed poses, linear in position and slerp in orientation between
// them, held before the first and after the last. Scripts the simulated user's target, the
// playback device and kinematic bodies. Evaluating it never allocates (the haptic loop uses it).
#pragma once
#include <vector>

#include "common/types.h"

namespace hh {

struct Pose {
    Vec3 position = Vec3::Zero();
    Vec4 quaternion = Vec4(0, 0, 0, 1);
    Vec3 velocity = Vec3::Zero();          // m/s
    Vec3 angular_velocity = Vec3::Zero();  // rad/s, world frame
};

class Keyframes {
public:
    Keyframes() = default;
    // Throws InvalidArgument unless times are finite and strictly increasing, and every
    // position and quaternion is finite (quaternions are normalized, never zero).
    Keyframes(const double* times, const double* positions, const double* quaternions, int n);
    bool empty() const { return times_.empty(); }
    double end_time() const { return times_.empty() ? 0 : times_.back(); }
    // The pose at time t with the velocity of the segment it lies on (zero when held).
    Pose at(double t) const;

private:
    std::vector<double> times_;
    std::vector<Vec3> positions_;
    std::vector<Vec4> quaternions_;
};

}  // namespace hh
