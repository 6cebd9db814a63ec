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

CouplingModel linearize_coupling(const World& world, int hand) {
    if (hand < 0 || hand >= static_cast<int>(world.bodies.size()) || world.bodies[hand]->kind != BodyKind::Hand)
        throw InvalidArgument("linearize_coupling: not the hand's body index");
    const Body& b = *world.bodies[hand];
    const Model& m = *b.hand_model;
    const Data& d = *b.hand;
    if (!d.device.prescribed)
        throw InvalidArgument("the coupling model needs the handle driven to a prescribed pose (the proxy)");
    const double dt = world.settings.dt;
    const CouplingBlocks& cb = d.coupling;
    const std::vector<int>& nodes = m.handle.nodes;
    const MatX& response = d.hand.flesh_response();  // At^-1 Ath, a column per handle velocity
    auto aht_times = [&](const VecX& flesh) {
        Vec6 out = Vec6::Zero();
        for (std::size_t j = 0; j < nodes.size(); ++j) out += cb.aht[j] * flesh.segment<3>(3 * nodes[j]);
        return out;
    };
    // A_s - Aht At^-1 Ath with the true Aht (the step zeroed it in the system it solved)
    Mat6 schur = cb.ah;
    for (int i = 0; i < 6; ++i) schur.col(i) -= aht_times(response.col(i));

    CouplingModel out;
    // Held rows: the normal of every contact that pushed, and the tangents of those that stuck
    // inside the cone. A contact that slid keeps sliding the same way, so its friction impulse
    // follows its normal one: its normal row's impulse acts along n + (lambda_t / lambda_n).
    const int nc = static_cast<int>(world.contact_lambda.size() / 3);
    if (nc > 0 && world.contact_bodies.count(hand)) {
        const VecX& lambda = world.contact_lambda;
        std::vector<int> held, rows;   // held constraint rows; every row an impulse acts on
        std::vector<int> sliding;      // per held row: the contact when it is a sliding normal, else -1
        double scale = 0;
        for (int c = 0; c < nc; ++c) scale = std::max(scale, lambda[3 * c]);
        for (int c = 0; c < nc; ++c) {
            const double ln = lambda[3 * c];
            if (!(ln > 1e-9 * scale)) continue;
            const double lt = std::hypot(lambda[3 * c + 1], lambda[3 * c + 2]);
            const bool sticks = lt < (1 - 1e-6) * world.contact_friction[c] * ln;
            held.push_back(3 * c);
            sliding.push_back(sticks || lt == 0 ? -1 : c);
            if (sticks) {
                held.push_back(3 * c + 1);
                sliding.push_back(-1);
                held.push_back(3 * c + 2);
                sliding.push_back(-1);
            }
            for (int k = 0; k < 3; ++k)
                if (k == 0 || sticks || lt > 0) rows.push_back(3 * c + k);
        }
        const int na = static_cast<int>(held.size()), nr = static_cast<int>(rows.size());
        std::vector<int> where(3 * nc, -1);
        for (int r = 0; r < nr; ++r) where[rows[r]] = r;
        // G: held impulses -> impulses on every row
        MatX g = MatX::Zero(nr, na);
        for (int a = 0; a < na; ++a) {
            g(where[held[a]], a) = 1;
            if (sliding[a] >= 0) {
                const int c = sliding[a];
                g(where[3 * c + 1], a) = lambda[3 * c + 1] / lambda[3 * c];
                g(where[3 * c + 2], a) = lambda[3 * c + 2] / lambda[3 * c];
            }
        }
        MatX hr = MatX::Zero(na, 6), hl = MatX::Zero(6, nr);
        const MatX w_rows = world.contact_delassus(rows);  // the step's W on those rows (unsymmetrized)
        MatX wa(na, na);
        for (int a = 0; a < na; ++a) wa.row(a) = w_rows.row(where[held[a]]) * g;
        bool touches_hand = false;
        for (int r = 0; r < nr; ++r) {
            // the row's response A^-1 J^T e_r read at the handle nodes (its handle part is zero:
            // the handle is prescribed) through Ath^T and Aht; the world forms both from At's
            // symmetry without those rows (World::contact_handle_terms)
            Vec6 hr_row, aht_col;
            if (!world.contact_handle_terms(hand, rows[r], hr_row, aht_col)) continue;
            touches_hand = true;
            hl.col(r) = aht_col;  // Aht At^-1 J^T e_r
            for (int a = 0; a < na; ++a)
                if (held[a] == rows[r]) hr.row(a) = hr_row.transpose();  // (J At^-1 Ath) of the row
        }
        if (touches_hand && na > 0) {
            // Redundant contacts make W_a singular; a compliance of 1e-9 of its largest
            // diagonal entry picks the least-norm impulses without changing the response.
            const double reg = 1e-9 * wa.diagonal().cwiseAbs().maxCoeff() + 1e-300;
            wa.diagonal().array() += reg;
            schur += (hl * g) * wa.partialPivLu().solve(hr);
            out.held_rows = na;
        }
    }
    out.stiffness = -schur / (dt * dt);
    out.x_h = d.h.x_com;
    out.q_h = d.h.q;
    out.v_h = d.h.v_com;
    out.omega_h = d.h.omega;
    Vec3 f, t;
    coupling_wrench(m, d, f, t);
    out.wrench << f, t;
    out.valid = out.stiffness.allFinite() && out.wrench.allFinite();
    if (!out.valid) throw NumericalError("the coupling model has non-finite entries");
    return out;
}

}  // namespace hh
