// The simulated user: the end effector is a point mass held by the user's arm, modelled as a
// spring and damper pulling it toward a scripted target trajectory (Hogan's impedance view of
// the arm), and pushed by the force the device displays. So the feedback changes the motion
// as it would with a person holding the stylus: pushing into a wall, the hand stops short of
// the target and the arm's spring holds the force. The arm is a person's: its pull, its speed
// and its turning rate are bounded, so a script that jumps (a teleport, a typo in a keyframe)
// is followed as fast as a hand could, never in one step. Orientation follows the script
// exactly while it turns slower than the arm can.
#pragma once
#include "device/device.h"

namespace hh {

// The simulated user's arm: mass, stiffness and damping are the haptics.arm.* rows of the
// parameter table (a default-constructed one holds their defaults).
struct ArmParams {
    ArmParams();
    ArmParams(double mass, double stiffness, double damping, double fail_at)
        : mass(mass), stiffness(stiffness), damping(damping), fail_at(fail_at) {}
    double mass;       // kg: hand and forearm as felt at the stylus
    double stiffness;  // N/m: arm's grip on its intended position
    double damping;    // N s/m
    double fail_at;    // s: from this time on the device reports a disconnection (tests)
    // A person's limits: part of the simulated user, not of the scene (fixed, so that every
    // trajectory, however violent, is followed the way a human arm could)
    double max_speed = 3.0;           // m/s: a fast reach of the hand
    double max_pull = 100.0;          // N: the arm's own force on the end effector
    double max_angular_speed = 10.0;  // rad/s: a fast turn of the wrist
};

class SimulatedArm : public Device {
public:
    SimulatedArm(Keyframes target, const ArmParams& params) : target_(std::move(target)), p_(params) {}
    const char* name() const override { return "simulated"; }
    bool read(double t, Pose& out) noexcept override;
    // The script itself at time t, never pushed: a frame posed by animation (a glove's finger
    // while a palm device carries the hand, device/simulated_glove.h)
    bool read_script(double t, Pose& out) noexcept;
    void command(const Feedback& fb) noexcept override { force_ = fb.force; }

private:
    bool gone(double t) noexcept;  // told to disconnect by now (fail_at): error() says so
    void move_toward(const Pose& goal, double dt) noexcept;
    void turn_toward(const Pose& goal, double dt) noexcept;
    Keyframes target_;
    ArmParams p_;
    bool started_ = false;
    double t_ = 0;
    Pose pose_;  // the end effector
    Vec3 force_ = Vec3::Zero();
};

}  // namespace hh
