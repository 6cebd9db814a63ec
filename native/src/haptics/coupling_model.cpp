#include "haptics/coupling_model.h"

#include <algorithm>
#include <cmath>

#include "rigid/quaternion.h"
#include "sim/world.h"

namespace hh {

Vec6 CouplingModel::displacement(double t, const Vec3& x, const Vec4& q) const {
    const double tau = std::min(std::max(t - time, 0.0), horizon);
    const Vec3 x_ref = x_h + tau * v_h + 0.5 * tau * tau * a_h;
    const Vec4 q_ref = quat_multiply(quat_from_rotation_vector(tau * omega_h + 0.5 * tau * tau * alpha_h), q_h);
    Vec6 d;
    d.head<3>() = x - x_ref;
    d.tail<3>() = quat_to_rotation_vector(quat_multiply(q, quat_conjugate(q_ref)));
    return d;
}

Vec6 CouplingModel::evaluate(double t, const Vec3& x, const Vec4& q) const {
    return wrench + stiffness * displacement(t, x, q);
}

namespace {

// J_l(phi)^-1: the derivative of log(exp(d) exp(phi)) with respect to d at d = 0 (rotation
// vectors), so that a turn d of the end pose changes the step's relative turn phi by J_l^-1 d.
Mat3 left_jacobian_inverse(const Vec3& phi) {
    const double a = phi.norm();
    const Mat3 k = skew(phi);
    // 1/a^2 - (1 + cos a) / (2 a sin a), by its series below 1e-4 rad
    const double c = a < 1e-4 ? 1.0 / 12.0 + a * a / 720.0 : 1.0 / (a * a) - (1 + std::cos(a)) / (2 * a * std::sin(a));
    return Mat3::Identity() - 0.5 * k + c * k * k;
}

}  // namespace

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

// What the contacts held change in the flesh part of the model (H_l M^-1 N H_r, docs/haptics.md):
// the rows of the hand's group's contacts that pushed, their impulses' change dlambda as the
// handle's end velocity changes, seen through Aht at the end pose. Sticking contacts keep
// their tangential velocity zero; sliding ones keep lambda_t = -mu lambda_n u_t/|u_t|, with
// mu = |lambda_t| / lambda_n, so their friction follows the normal impulse and turns with the
// sliding velocity.
Mat6 held_contacts(const World& world, int hand, int& held_rows) {
    held_rows = 0;
    const int nc = static_cast<int>(world.contact_lambda.size() / 3);
    if (nc == 0 || !world.contact_bodies.count(hand)) return Mat6::Zero();
    const VecX& lambda = world.contact_lambda;
    const VecX& u = world.contact_velocity;
    // the contacts of the hand's groups
    std::vector<char> group(world.contact_groups.size(), 0);
    for (int row : world.contact_bodies.at(hand).rows) group[world.contact_group_of[row / 3]] = 1;
    double scale = 0;
    for (int c = 0; c < nc; ++c) scale = std::max(scale, lambda[3 * c]);
    // a contact slides when its tangential velocity is well above the sweeps' tolerance
    const double slip = 10 * world.settings.tolerance;
    std::vector<int> rows;     // 3 per held contact
    std::vector<char> slides;  // per held contact
    for (int c = 0; c < nc; ++c) {
        if (!group[world.contact_group_of[c]] || !(lambda[3 * c] > 1e-9 * scale)) continue;
        // (a frictionless contact slides whatever its velocity: it holds no tangential impulse)
        slides.push_back(std::hypot(u[3 * c + 1], u[3 * c + 2]) > slip || world.contact_friction[c] == 0);
        for (int k = 0; k < 3; ++k) rows.push_back(3 * c + k);
    }
    const int nr = static_cast<int>(rows.size());
    if (nr == 0) return Mat6::Zero();
    MatX hr = MatX::Zero(nr, 6), hl = MatX::Zero(6, nr);
    bool touches_hand = false;
    for (int r = 0; r < nr; ++r) {
        // the row's response A^-1 J^T e_r read at the handle nodes (its handle part is zero:
        // the handle is prescribed) through Ath^T and Aht; the world forms both from At's
        // symmetry without those rows (World::contact_handle_terms)
        Vec6 hr_row, aht_col;
        if (!world.contact_handle_terms(hand, rows[r], hr_row, aht_col)) continue;
        touches_hand = true;
        hr.row(r) = hr_row.transpose();  // J A_t^-1 Ath: the row's free velocity is -that dv_h
        hl.col(r) = aht_col;             // Aht A_t^-1 J^T e_r
    }
    if (!touches_hand) return Mat6::Zero();
    // M dlambda = N H_r dv_h: normal and sticking rows keep their velocity (W dlambda = H_r dv_h);
    // a sliding contact's tangent rows, with s = mu lambda_n / |u_t| and P the projection off
    // u_t: dlambda_t + mu u^ dlambda_n + s P (W dlambda - H_r dv_h)_t = 0
    const MatX w = world.contact_delassus(rows);  // the step's W on those rows (unsymmetrized)
    MatX mat = w, rhs_map = MatX::Identity(nr, nr);
    // Redundant contacts make W singular; a compliance of 1e-9 of its largest diagonal entry
    // picks the least-norm impulses without changing the response.
    const double reg = 1e-9 * w.diagonal().cwiseAbs().maxCoeff() + 1e-300;
    for (int a = 0; a < nr; ++a) mat(a, a) += reg;
    for (int h = 0; h < nr / 3; ++h) {
        if (!slides[h]) continue;
        const int c = rows[3 * h] / 3, n = 3 * h;
        const Eigen::Vector2d ut(u[3 * c + 1], u[3 * c + 2]);
        const double speed = ut.norm();
        const Eigen::Vector2d dir = speed > 0 ? Eigen::Vector2d(ut / speed) : Eigen::Vector2d::Zero();
        const double mu = std::hypot(lambda[3 * c + 1], lambda[3 * c + 2]) / lambda[3 * c];
        const double s = speed > 0 ? mu * lambda[3 * c] / speed : 0.0;
        const Eigen::Matrix2d p = Eigen::Matrix2d::Identity() - dir * dir.transpose();
        mat.middleRows<2>(n + 1) = s * p * w.middleRows<2>(n + 1);
        mat.block<2, 2>(n + 1, n + 1) += Eigen::Matrix2d::Identity();
        mat.block<2, 1>(n + 1, n) += mu * dir;
        rhs_map.block<2, 2>(n + 1, n + 1) = s * p;
    }
    // (rows that carry impulse: the normal ones, the tangents of contacts with friction)
    for (int h = 0; h < nr / 3; ++h) held_rows += world.contact_friction[rows[3 * h] / 3] == 0 ? 1 : 3;
    return hl * mat.partialPivLu().solve(rhs_map * hr);
}

}  // namespace

CouplingModel linearize_coupling(const World& world, int hand) {
    if (hand < 0 || hand >= static_cast<int>(world.bodies.size()) || world.bodies[hand]->kind != BodyKind::Hand)
        throw InvalidArgument("linearize_coupling: not the hand's body index");
    const Body& b = *world.bodies[hand];
    if (b.skeleton())
        throw InvalidArgument("the handle-space model with contacts held takes a hand with one handle; this hand has " +
                              std::to_string(b.hand_model->n_bones()) +
                              " bones (a skeleton): its model with contacts held is not built yet");
    if (!b.hand->device.prescribed)
        throw InvalidArgument("the coupling model needs the handle driven to a prescribed pose (the proxy)");
    int held_rows = 0;
    const Mat6 held = held_contacts(world, hand, held_rows);
    CouplingModel out = hand_coupling_model(*b.hand_model, *b.hand, held);
    out.held_rows = held_rows;
    return out;
}

}  // namespace hh
