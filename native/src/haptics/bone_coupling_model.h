// The handle-space model of a hand of B bones in a world, contacts held (docs/skeleton.md,
// Section 6; docs/maths.md, "Handle-space linearization"): after a world step with every bone
// prescribed (each to its proxy's pose), every bone's springs' wrench at the end of the step as
// a linear function of displacements of the B prescribed poses,
//   W(delta) = wrench + stiffness delta,   delta = (dx_1, dtheta_1, ..., dx_B, dtheta_B),
// the exact derivative of that step, with the step's contacts held as the palm handle's model
// holds them (haptics/held_contacts.h). One bone is the palm handle's model (linearize_coupling).
#pragma once
#include <vector>

#include "haptics/coupling_model.h"

namespace hh {

struct BoneCouplingModel {
    bool valid = false;
    double time = 0;      // s, on the haptic loop's clock: when the bones were at their end poses
    double horizon = 0.1; // s: the reference motions are continued at most this long (CouplingModel)
    int held_rows = 0;    // contact constraint rows held in the model
    // per bone: its end pose and the velocity its reference moves on with, and the reference's
    // acceleration (a, alpha; the session sets it in free space, as for the palm handle)
    std::vector<HandleState> ends;
    std::vector<Vec6> accelerations;
    VecX wrench;     // 6B: each bone's springs' force and torque about its centre (N, N m)
    MatX stiffness;  // 6B x 6B: d wrench / d delta (N/m, N/rad, N m/m, N m/rad)

    int n_bones() const { return static_cast<int>(ends.size()); }
    // bone b's (dx, dtheta) of the pose (x, q) from its end motion continued to time t
    Vec6 displacement(int b, double t, const Vec3& x, const Vec4& q) const;
};

// How H_l = Aht_e A_t^-1 J^T is formed (one solve per column either way): through the 6B
// columns A_t^-1 Aht_e^T read at the contacts, or through the held rows' A_t^-1 J^T read at the
// bones' nodes. Fewer: whichever has fewer columns (the two are the same to round-off).
enum class HeldSolves { Fewer, BoneColumns, RowColumns };

// The model after the world's last step for its hand body `hand`, every bone of which must have
// been prescribed in that step:
//   K = P + (V + (Aht_e A_t^-1 Ath - H_l M^-1 N H_r) / dt) D / dt
// with P, V block diagonal (each bone's springs' Jacobians, Eq. 11, at the end of the step),
// Aht_e A_t^-1 Ath (6B x 6B) from the step's own Schur columns, and D = blockdiag(I, J_l^-1(phi_b))
// (phi_b bone b's turn relative to the step's frame). H_r reads the step's columns at the
// contacts; H_l costs min(6B, held rows) solves on the step's factor.
BoneCouplingModel linearize_bone_coupling(const World& world, int hand, HeldSolves how = HeldSolves::Fewer);

}  // namespace hh
