// The proxy handle of the haptic loop (Section 3, Fig. 2 middle and bottom): a rigid body with
// the handle's mass and inertia, pulled by the linearized coupling force F*_c of the hand and
// by a two-way viscoelastic virtual coupling to the device frame (Colgate et al. 1995). Each
// haptic step is one implicit (backward Euler) step of its 6 DOF, linear in the new velocity;
// the feedback sent to the device is the virtual coupling's reaction. Fixed-size maths only:
// a step never allocates.
#pragma once
#include "coupling/springs.h"
#include "device/feedback.h"
#include "haptics/coupling_model.h"
#include "rigid/handle.h"
#include "sim/keyframes.h"

namespace hh {

// The virtual coupling's gains: the coupling.* rows of the parameter table; a
// default-constructed one holds the table's defaults.
struct VirtualCoupling {
    VirtualCoupling();
    VirtualCoupling(double stiffness, double damping, double angular_stiffness, double angular_damping)
        : stiffness(stiffness), damping(damping), angular_stiffness(angular_stiffness), angular_damping(angular_damping) {}
    double stiffness;          // N/m
    double damping;            // N s/m
    double angular_stiffness;  // N m/rad
    double angular_damping;    // N m s/rad
};

// Throws InvalidArgument, naming the fix, unless the coupling stays passive when sampled at
// `rate` (Hz): damping >= stiffness x period / 2, linear and angular (Colgate & Schenkel 1997).
void check_passive(const VirtualCoupling& coupling, double rate);

class ProxyHandle {
public:
    double mass = 0;
    Mat3 inertia_body = Mat3::Identity();  // about the centre of mass, body axes = world at rest
    HandleState state;

    // One step of dt ending at time t + dt. With the model off (`linearized` false), the proxy
    // is not simulated: it sits on the model's handle pose, the last one the visual loop
    // computed (the comparison without handle-space linearization). The hand's weight is in
    // F_c (gravity acts on the flesh the springs hold), so no gravity acts on the proxy.
    Feedback step(double dt, double t, const CouplingModel& model, bool linearized, const Pose& device,
                  const VirtualCoupling& coupling);
};

// The virtual coupling's wrench on the proxy from the device (force, torque).
Vec6 coupling_on_proxy(const HandleState& proxy, const Pose& device, const VirtualCoupling& c);

}  // namespace hh
