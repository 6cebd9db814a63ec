// The simulated user: the end effector is a point mass held by the user's arm, modelled as a
// spring and damper pulling it toward a scripted target trajectory (Hogan's impedance view of
// the arm), and pushed by the force the device displays. So the feedback changes the motion
// as it would with a person holding the stylus: pushing into a wall, the hand stops short of
// the target and the arm's spring holds the force. Orientation follows the script exactly.
#pragma once
#include "device/device.h"

namespace hh {

struct ArmParams {
    double mass = 1.0;        // kg: hand and forearm as felt at the stylus
    double stiffness = 300;   // N/m: arm's grip on its intended position
    double damping = 20;      // N s/m
    double fail_at = 1e300;   // s: from this time on the device reports a disconnection (tests)
};

class SimulatedArm : public Device {
public:
    SimulatedArm(Keyframes target, const ArmParams& params) : target_(std::move(target)), p_(params) {}
    const char* name() const override { return "simulated"; }
    bool read(double t, Pose& out) noexcept override;
    void command(const Feedback& fb) noexcept override { force_ = fb.force; }

private:
    Keyframes target_;
    ArmParams p_;
    bool started_ = false;
    double t_ = 0;
    Vec3 x_ = Vec3::Zero(), v_ = Vec3::Zero(), force_ = Vec3::Zero();
};

}  // namespace hh
