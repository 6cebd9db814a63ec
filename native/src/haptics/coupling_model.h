// Handle-space linearization of the coupling force (Section 3; Garre & Otaduy 2009): after a
// visual-loop step in which the handle was driven to a prescribed pose, the springs' wrench
// on the handle as a linear function of where the handle is, with the contacts that were
// active in the step held (normal rows of contacts that pushed, tangent rows of those that
// stuck). The haptic loop evaluates it at 1 kHz for the proxy handle.
#pragma once
#include "common/types.h"
#include "coupling/springs.h"

namespace hh {

class World;

struct CouplingModel {
    bool valid = false;
    double time = 0;  // s, on the haptic loop's clock: when the handle was at (x_h, q_h)
    // the handle at the end of the visual step and the velocity it was driven with
    Vec3 x_h = Vec3::Zero();
    Vec4 q_h = Vec4(0, 0, 0, 1);
    Vec3 v_h = Vec3::Zero();
    Vec3 omega_h = Vec3::Zero();
    // the reference motion's acceleration (the session sets it in free space, see session.cpp)
    Vec3 a_h = Vec3::Zero();
    Vec3 alpha_h = Vec3::Zero();
    Vec6 wrench = Vec6::Zero();     // F_c0: springs' force and torque on the handle (N, N m)
    Mat6 stiffness = Mat6::Zero();  // dF_c/d(dx, dtheta) (N/m, N/rad, N m/m, N m/rad)
    int held_rows = 0;              // contact constraint rows held in the model
    // s: the reference motion is continued at most this long after `time`; a visual loop that
    // falls behind (a heavy scene, a debugger) must not make it run away
    double horizon = 0.1;

    // F*_c at the proxy pose (x, q) at time t: the displacement is taken from the handle's
    // motion continued with velocity v_h (and acceleration a_h), so a proxy moving on with the
    // hand feels F_c0.
    Vec6 evaluate(double t, const Vec3& x, const Vec4& q) const;
    // (dx, dtheta) of the pose (x, q) from that continued handle motion at time t.
    Vec6 displacement(double t, const Vec3& x, const Vec4& q) const;
};

// (dx, dtheta) of the pose (x, q) from the reference pose `ref` moved on for tau with its
// velocity (v_com, omega) and the acceleration (a, alpha): CouplingModel::displacement's rule,
// one bone's of BoneCouplingModel's (haptics/bone_coupling_model.h).
Vec6 motion_displacement(double tau, const HandleState& ref, const Vec3& a, const Vec3& alpha, const Vec3& x,
                         const Vec4& q);

// The model after the world's last step for its hand body `hand`, whose handle must have
// been prescribed (DeviceFrame::prescribed): the exact derivative of that step's end-of-step
// wrench with respect to the prescribed pose (docs/haptics.md, docs/maths.md),
//   K = dF/dx_h + (dF/dv_h + (Aht_e A_t^-1 Ath - H_l M^-1 N H_r) / dt) D / dt,
// every spring Jacobian at the end of the step (Aht_e: Aht at the end pose), D = diag(I,
// J_l^-1(phi)) the end velocity's change with the pose (phi the handle's turn relative to the
// step's frame), and the contacts that pushed held (H_r = J A_t^-1 Ath, H_l = Aht_e A_t^-1 J^T,
// M and N: sticking and sliding rows, held_contacts in coupling_model.cpp). Costs no solve
// beyond the step's own: A_t^-1 Ath are the Schur complement's columns and A_t^-1 J^T the
// contact solve's.
CouplingModel linearize_coupling(const World& world, int hand);

// The same for a hand alone (no world) after data's last step with a prescribed handle; held:
// the contacts' term H_l M^-1 N H_r (zero without contact).
struct Model;
struct Data;
CouplingModel hand_coupling_model(const Model& m, const Data& d, const Mat6& held);

}  // namespace hh
