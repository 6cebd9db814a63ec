#include "sim/keyframes.h"

#include <algorithm>
#include <cmath>
#include <sstream>

#include "rigid/quaternion.h"

namespace hh {

Keyframes::Keyframes(const double* times, const double* positions, const double* quaternions, int n) {
    if (n < 1 || !times || !positions) throw InvalidArgument("a trajectory needs at least one timed pose");
    for (int k = 0; k < n; ++k) {
        const Vec3 p(positions[3 * k], positions[3 * k + 1], positions[3 * k + 2]);
        Vec4 q(0, 0, 0, 1);
        if (quaternions) q = Vec4(quaternions[4 * k], quaternions[4 * k + 1], quaternions[4 * k + 2], quaternions[4 * k + 3]);
        if (!std::isfinite(times[k]) || !p.allFinite() || !q.allFinite())
            throw InvalidArgument("trajectory pose " + std::to_string(k) +
                                  " has a NaN or infinite time, position or quaternion: give finite numbers");
        if (q.norm() < 1e-12)
            throw InvalidArgument("trajectory pose " + std::to_string(k) +
                                  " has a zero quaternion: use (x, y, z, s) with s = 1 for no rotation");
        if (k > 0 && !(times[k] > times[k - 1])) {
            std::ostringstream msg;
            msg << "trajectory pose " << k << " has t = " << times[k] << " s after " << times[k - 1]
                << " s: times must increase strictly; give each pose a later time than the one before";
            throw InvalidArgument(msg.str());
        }
        if (k > 0 && q.dot(quaternions_.back()) < 0) q = -q;  // shortest arc between poses
        times_.push_back(times[k]);
        positions_.push_back(p);
        quaternions_.push_back(q.normalized());
    }
}

Pose Keyframes::at(double t) const {
    Pose out;
    if (times_.empty()) return out;
    if (t <= times_.front() || times_.size() == 1) {
        out.position = positions_.front();
        out.quaternion = quaternions_.front();
        return out;
    }
    if (t >= times_.back()) {
        out.position = positions_.back();
        out.quaternion = quaternions_.back();
        return out;
    }
    const std::size_t k = static_cast<std::size_t>(std::upper_bound(times_.begin(), times_.end(), t) - times_.begin()) - 1;
    const double span = times_[k + 1] - times_[k];
    const double a = (t - times_[k]) / span;
    out.position = (1 - a) * positions_[k] + a * positions_[k + 1];
    out.velocity = (positions_[k + 1] - positions_[k]) / span;
    // slerp as q_k rotated by a fraction of the relative rotation: constant angular velocity
    const Vec3 theta = quat_to_rotation_vector(quat_multiply(quaternions_[k + 1], quat_conjugate(quaternions_[k])));
    out.quaternion = quat_multiply(quat_from_rotation_vector(a * theta), quaternions_[k]).normalized();
    out.angular_velocity = theta / span;
    return out;
}

}  // namespace hh
