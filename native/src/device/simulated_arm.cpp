#include "device/simulated_arm.h"

namespace hh {

bool SimulatedArm::read(double t, Pose& out) noexcept {
    if (t >= p_.fail_at) {
        fail("the simulated device was told to disconnect", t);
        return false;
    }
    const Pose goal = target_.at(t);
    if (!started_) {
        started_ = true;
        x_ = goal.position;
        v_ = goal.velocity;
    } else {
        // semi-implicit Euler over the time since the last read: m a = k (x* - x) + b (v* - v) + F
        const double dt = t - t_;
        if (dt > 0) {
            const Vec3 a = (p_.stiffness * (goal.position - x_) + p_.damping * (goal.velocity - v_) + force_) / p_.mass;
            v_ += dt * a;
            x_ += dt * v_;
        }
    }
    t_ = t;
    out.position = x_;
    out.velocity = v_;
    out.quaternion = goal.quaternion;
    out.angular_velocity = goal.angular_velocity;
    return true;
}

}  // namespace hh
