#include "device/simulated_arm.h"

#include <cmath>

#include "params/table.h"
#include "rigid/quaternion.h"

namespace hh {

ArmParams::ArmParams()
    : ArmParams(params::default_of("haptics.arm.mass"), params::default_of("haptics.arm.stiffness"),
                params::default_of("haptics.arm.damping"), HUGE_VAL) {}

namespace {
Vec3 clamped(const Vec3& v, double limit) {
    const double n = v.norm();
    return n > limit ? Vec3(v * (limit / n)) : v;
}
}  // namespace

void SimulatedArm::move_toward(const Pose& goal, double dt) noexcept {
    // Backward Euler on m v' = k (x* - x - dt v') + b (v* - v') + F (stable at any arm
    // stiffness), the arm's pull k (..) + b (..) then bounded, and the speed: the target's
    // velocity is a person's intention, so it is bounded too.
    const double m = p_.mass, k = p_.stiffness, b = p_.damping;
    const Vec3 v_goal = clamped(goal.velocity, p_.max_speed);
    const Vec3& x = pose_.position;
    const Vec3& v = pose_.velocity;
    Vec3 v_new = (m * v + dt * (k * (goal.position - x) + b * v_goal + force_)) / (m + dt * b + dt * dt * k);
    const Vec3 pull = m * (v_new - v) / dt - force_;
    if (pull.norm() > p_.max_pull) v_new = v + dt * (clamped(pull, p_.max_pull) + force_) / m;
    pose_.velocity = clamped(v_new, p_.max_speed);
    pose_.position += dt * pose_.velocity;
}

void SimulatedArm::turn_toward(const Pose& goal, double dt) noexcept {
    const Vec3 turn = quat_to_rotation_vector(quat_multiply(goal.quaternion, quat_conjugate(pose_.quaternion)));
    const double angle = turn.norm(), reach = p_.max_angular_speed * dt;
    if (angle <= reach) {  // the script is within the wrist's reach: follow it exactly
        pose_.quaternion = goal.quaternion;
        pose_.angular_velocity = clamped(goal.angular_velocity, p_.max_angular_speed);
        return;
    }
    pose_.angular_velocity = turn * (p_.max_angular_speed / angle);
    pose_.quaternion = quat_multiply(quat_from_rotation_vector(dt * pose_.angular_velocity), pose_.quaternion).normalized();
}

bool SimulatedArm::gone(double t) noexcept {
    if (t < p_.fail_at) return false;
    fail("the simulated device was told to disconnect", t);
    return true;
}

bool SimulatedArm::read_script(double t, Pose& out) noexcept {
    if (gone(t)) return false;
    out = target_.at(t);
    return true;
}

bool SimulatedArm::read(double t, Pose& out) noexcept {
    if (gone(t)) return false;
    const Pose goal = target_.at(t);
    if (!started_) {
        started_ = true;
        pose_.position = goal.position;
        pose_.velocity = clamped(goal.velocity, p_.max_speed);
        pose_.quaternion = goal.quaternion;
        pose_.angular_velocity = clamped(goal.angular_velocity, p_.max_angular_speed);
    } else if (t > t_) {
        move_toward(goal, t - t_);
        turn_toward(goal, t - t_);
    }
    t_ = t;
    out = pose_;
    return true;
}

}  // namespace hh
