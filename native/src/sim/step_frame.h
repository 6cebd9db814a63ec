// The rigid motion a step advances the whole hand by (docs/maths.md, "Rotation-consistent
// integration"): the hand's own rotation over the step at its start-of-step angular velocity,
// R = exp(dt omega), about a centre c. The step linearizes Eq. 7 about the state this motion
// carries the hand to, and solves for the velocities relative to it: a hand that turns rigidly
// with its handle then turns exactly (its springs and flesh are not stretched by the chord of
// the turn, r (1 - cos omega dt)), its velocities turn with it, and its momentum is kept.
#pragma once
#include "coupling/springs.h"
#include "rigid/quaternion.h"
#include "sim/model.h"

namespace hh {

struct StepFrame {
    double dt = 0;
    Vec3 center = Vec3::Zero();  // c: the handle's centre of mass when the handle is held (a
                                 // device couples or prescribes it), else the hand's (flesh and handle)
    Vec3 omega = Vec3::Zero();   // the hand's angular velocity at the start of the step (TurnFit)
    Vec4 turn = Vec4(0, 0, 0, 1);  // exp(dt omega)
    Mat3 rotation = Mat3::Identity();
    // (I - dt [omega]x) R - I: what turning by R adds to the straight step dt omega x R r of the
    // frame's velocity at the advanced position (second order in dt omega)
    Mat3 remainder = Mat3::Zero();
    // The advanced state: flesh positions c + R (x - c), and the velocity the frame gives them
    // there, omega x R (x - c); the handle carried along (x_com, q turned by R; v_com the
    // frame's velocity at its centre, omega).
    VecX x, v;
    HandleState handle;
    // The frame's second-order remainder (what turning by R adds to the straight step of the
    // frame's velocity) summed over the masses: zero when c is the hand's centre of mass; with
    // c at the handle it is the flesh's, and the handle takes its reaction (Eq. 7's b_h).
    Vec3 imbalance = Vec3::Zero();

    // A free handle (no device): the inverse inertia of the whole hand about c at the advanced
    // state, and the sum of m (v - omega x (x - c)) x v_frame at the start of the step, for the
    // angular momentum the frame's velocities would add (frame_velocities).
    bool free = false;
    Mat3 inertia_inverse = Mat3::Zero();
    Vec3 start_moment = Vec3::Zero();

    // (v_h, v_t) of the frame at the advanced state, the velocities the step solves relative to
    Vec6 handle_velocity() const {
        Vec6 out;
        out << handle.v_com, handle.omega;
        return out;
    }
};

// The angular velocity of the rigid turn about c that best fits a hand's velocities: the least
// squares fit, weighted by mass, of v - v_c = omega x (x - c) over its flesh nodes and handles
// (a handle with its inertia and its own spin): omega = I_c^-1 sum m (x - c) x (v - v_c). A hand
// turning rigidly gives its handle's angular velocity; a handle spun alone (a device's sudden
// turn, a state set by hand) leaves the frame with the flesh, where the linearization belongs:
// a frame at the handle's angular velocity while the flesh stood still turned the stiff springs'
// linearization point away from where the step ends, and the step gained energy.
struct TurnFit {
    Mat3 inertia = Mat3::Zero();
    Vec3 momentum = Vec3::Zero();
    void add_point(double m, const Vec3& r, const Vec3& v_relative);
    void add_body(double m, const Mat3& world_inertia, const Vec3& r, const Vec3& v_relative, const Vec3& omega);
    Vec3 omega() const;
};

// The frame's centre and angular velocity for a hand whose bone b (0: the palm handle or the
// root) has the state bone(b): c the root's centre when a device holds it (the hand turns about
// the device's pose), else the hand's centre of mass (moving on a straight line); omega the
// TurnFit about c.
struct FrameMotion {
    Vec3 center, omega;
};
template <class Bones>
FrameMotion hand_motion(const Model& model, const VecX& x, const VecX& v, bool held, const Bones& bone) {
    const int n = model.mesh.n_nodes, nb = model.n_bones();
    FrameMotion out;
    Vec3 v_center = bone(0).v_com;
    out.center = bone(0).x_com;
    if (!held) {
        Vec3 sum = Vec3::Zero(), p = Vec3::Zero();
        double mass = 0;
        for (int b = 0; b < nb; ++b) {
            sum += model.skeleton.bones[b].mass * bone(b).x_com;
            p += model.skeleton.bones[b].mass * bone(b).v_com;
            mass += model.skeleton.bones[b].mass;
        }
        for (int i = 0; i < n; ++i) {
            sum += model.masses[i] * x.segment<3>(3 * i);
            p += model.masses[i] * v.segment<3>(3 * i);
            mass += model.masses[i];
        }
        out.center = sum / mass;
        v_center = p / mass;
    }
    TurnFit fit;
    for (int b = 0; b < nb; ++b) {
        const HandleState& h = bone(b);
        const Mat3 turned = quat_to_matrix(h.q);
        fit.add_body(model.skeleton.bones[b].mass, turned * model.skeleton.bones[b].inertia_body * turned.transpose(),
                     h.x_com - out.center, h.v_com - v_center, h.omega);
    }
    for (int i = 0; i < n; ++i)
        fit.add_point(model.masses[i], x.segment<3>(3 * i) - out.center, v.segment<3>(3 * i) - v_center);
    out.omega = fit.omega();
    return out;
}

// The frame of the step from the current state (x, v, the handle, whether a device holds it).
void update_step_frame(const Model& model, const VecX& x, const VecX& v, const HandleState& h, bool held, StepFrame& f);

// Where a point at x (start of the step) ends beyond x + dt v for the velocity v it is given:
// remainder (x - c). A contact on the hand closes its gap by this much more (World).
Vec3 turn_remainder(const StepFrame& f, const Vec3& x);

// The inertia term of the step relative to the frame, per flesh node: m (v - omega x (x - c)
// - dt omega x (omega x R (x - c))): the velocity relative to the frame at the start and the
// frame's centrifugal impulse at the advanced position (the centripetal force the flesh's
// stress supplies to turn with the frame). For the handle's centre the same with its mass,
// minus the imbalance.
Vec3 relative_momentum(const StepFrame& f, double mass, const Vec3& x, const Vec3& v);

// The step's velocities (v_h, v_t) from those relative to the frame, w (data.hand's solution):
// w plus the frame's velocities at the advanced state. A node that moved relative to the frame
// by dt (w - u) (u its relative velocity at the start) then carries the frame's velocity of the
// advanced position, not its own: the symmetric system of Eq. 7 has no Coriolis coupling, and
// the hand's angular momentum grows by dt sum m (w - u) x v_frame (a spinning hand that stretches
// under its centrifugal load would gain energy). With a free handle that excess is taken out as
// a rigid turn of the whole hand about c (momentum unchanged); a device holding the handle takes it.
// (In a world, of the free solve's velocities: the contact impulses' own share is left.)
VecX frame_velocities(const Model& model, const StepFrame& f, const VecX& relative);

}  // namespace hh
