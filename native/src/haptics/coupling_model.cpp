#include "haptics/coupling_model.h"

#include <algorithm>
#include <cmath>

#include "haptics/held_contacts.h"
#include "rigid/quaternion.h"
#include "sim/world.h"

namespace hh {

Vec6 motion_displacement(double tau, const HandleState& ref, const Vec3& a, const Vec3& alpha, const Vec3& x,
                         const Vec4& q) {
    const Vec3 x_ref = ref.x_com + tau * ref.v_com + 0.5 * tau * tau * a;
    const Vec4 q_ref = quat_multiply(quat_from_rotation_vector(tau * ref.omega + 0.5 * tau * tau * alpha), ref.q);
    Vec6 d;
    d.head<3>() = x - x_ref;
    d.tail<3>() = quat_to_rotation_vector(quat_multiply(q, quat_conjugate(q_ref)));
    return d;
}

Vec6 CouplingModel::displacement(double t, const Vec3& x, const Vec4& q) const {
    const double tau = std::min(std::max(t - time, 0.0), horizon);
    HandleState ref;
    ref.x_com = x_h;
    ref.q = q_h;
    ref.v_com = v_h;
    ref.omega = omega_h;
    return motion_displacement(tau, ref, a_h, alpha_h, x, q);
}

Vec6 CouplingModel::evaluate(double t, const Vec3& x, const Vec4& q) const {
    return wrench + stiffness * displacement(t, x, q);
}

CouplingModel hand_coupling_model(const Model& m, const Data& d, const Mat6& held) {
    if (!d.device.prescribed || d.end_aht.size() != m.handle.nodes.size())
        throw InvalidArgument(
            "the coupling model needs the last step taken with the handle driven to a prescribed pose (the proxy)");
    const double dt = m.params.dt;
    const double k = m.params.spring_stiffness, damping = m.params.spring_damping;
    const std::vector<int>& nodes = m.handle.nodes;
    // The springs' wrench at the end of the step and its partial derivatives there (Eq. 11 at
    // the end state): with respect to the handle's end pose (dx, dtheta) and its end velocity.
    Mat6 pose = Mat6::Zero(), velocity = Mat6::Zero();
    Vec6 wrench = Vec6::Zero();
    for (std::size_t j = 0; j < nodes.size(); ++j) {
        const Vec3 x_a = d.x.segment<3>(3 * nodes[j]), v_a = d.v.segment<3>(3 * nodes[j]);
        const SpringJacobian jac = spring_jacobian(k, damping, x_a, v_a, m.handle.r_body[j], d.h);
        pose += jac.dfh_dxh;
        velocity += jac.dfh_dvh;
        const SpringForce f = spring_force(k, damping, x_a, v_a, m.handle.r_body[j], d.h);
        wrench.head<3>() += f.on_handle;
        wrench.tail<3>() += f.torque;
    }
    // The flesh's part: its end velocity moves by -A_t^-1 Ath dv_h (Eq. 12) and its positions by dt
    // times that; the wrench sees them through Aht at the end pose, -(Aht / dt) dv_t.
    const MatX& response = d.hand.flesh_response();
    Mat6 flesh = Mat6::Zero();
    for (std::size_t j = 0; j < nodes.size(); ++j) flesh += d.end_aht[j] * response.middleRows<3>(3 * nodes[j]);
    // dv_h / d(dx, dtheta): dx = dt dv_com; the end turn exp(dt (omega - omega_frame)) of the
    // frame's turned pose (sim/step.cpp, integrate) moves by J_l^-1 of that relative turn
    Mat6 chain = Mat6::Identity() / dt;
    chain.bottomRightCorner<3, 3>() = left_jacobian_inverse(dt * (d.h.omega - d.frame.omega)) / dt;
    CouplingModel out;
    out.stiffness = pose + (velocity + (flesh - held) / dt) * chain;
    out.wrench = wrench;
    out.x_h = d.h.x_com;
    out.q_h = d.h.q;
    out.v_h = d.h.v_com;
    out.omega_h = d.h.omega;
    out.valid = out.stiffness.allFinite() && out.wrench.allFinite();
    if (!out.valid) throw NumericalError("the coupling model has non-finite entries");
    return out;
}

namespace {

// What the contacts held change in the flesh part of the model (H_l M^-1 N H_r,
// haptics/held_contacts.h): the held rows' impulses' change as the handle's end velocity
// changes, seen through Aht at the end pose.
Mat6 held_contacts(const World& world, int hand, int& held_rows) {
    held_rows = 0;
    const HeldContacts held = held_contacts_of(world, hand);
    const int nr = held.n_rows();
    if (nr == 0) return Mat6::Zero();
    MatX hr = MatX::Zero(nr, 6), hl = MatX::Zero(6, nr);
    bool touches_hand = false;
    for (int r = 0; r < nr; ++r) {
        // the row's response A^-1 J^T e_r read at the handle nodes (its handle part is zero:
        // the handle is prescribed) through Ath^T and Aht; the world forms both from At's
        // symmetry without those rows (World::contact_handle_terms)
        Vec6 hr_row, aht_col;
        if (!world.contact_handle_terms(hand, held.rows[r], hr_row, aht_col)) continue;
        touches_hand = true;
        hr.row(r) = hr_row.transpose();  // J A_t^-1 Ath: the row's free velocity is -that dv_h
        hl.col(r) = aht_col;             // Aht A_t^-1 J^T e_r
    }
    if (!touches_hand) return Mat6::Zero();
    held_rows = carrying_rows(world, held);
    return held_contact_term(world, held, hr, hl);
}

}  // namespace

CouplingModel linearize_coupling(const World& world, int hand) {
    if (hand < 0 || hand >= static_cast<int>(world.bodies.size()) || world.bodies[hand]->kind != BodyKind::Hand)
        throw InvalidArgument("linearize_coupling: not the hand's body index");
    const Body& b = *world.bodies[hand];
    if (b.skeleton())
        throw InvalidArgument("the handle-space model with contacts held takes a hand with one handle; this hand has " +
                              std::to_string(b.hand_model->n_bones()) +
                              " bones (a skeleton): take the bones' model, hh_world_bone_coupling_model");
    if (!b.hand->device.prescribed)
        throw InvalidArgument("the coupling model needs the handle driven to a prescribed pose (the proxy)");
    int held_rows = 0;
    const Mat6 held = held_contacts(world, hand, held_rows);
    CouplingModel out = hand_coupling_model(*b.hand_model, *b.hand, held);
    out.held_rows = held_rows;
    return out;
}

}  // namespace hh
