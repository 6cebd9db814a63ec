#include "haptics/bone_coupling_model.h"

#include <algorithm>

#include "haptics/held_contacts.h"
#include "rigid/quaternion.h"
#include "sim/world.h"

namespace hh {

Vec6 BoneCouplingModel::displacement(int b, double t, const Vec3& x, const Vec4& q) const {
    const double tau = std::min(std::max(t - time, 0.0), horizon);
    return motion_displacement(tau, ends[b], accelerations[b].head<3>(), accelerations[b].tail<3>(), x, q);
}

namespace {

// What the model reads of the hand after its step: per bone its nodes, its springs' Aht at the
// bone's end pose (Eq. 8; Aht_e) and Ath (Eq. 10, the step's), and the step's A_t^-1 Ath (3n x 6B).
// The palm handle's hand (one bone) keeps them in data.hand, a skeleton's in data.skeleton.
struct HandTerms {
    const Model& m;
    const Data& d;
    DeformableSystem& tool;  // (its step's factor, only read: solve_response)
    const MatX& columns;
    std::vector<std::vector<Mat63>> aht_e;
    int nb;
    const HandleModel& bone(int b) const { return m.skeleton.bones[b]; }
    const Mat36& ath(int b, int j) const { return nb == 1 ? d.hand.Ath[j] : d.skeleton.Ath[b][j]; }
};

HandTerms hand_terms(const Body& body) {
    const Model& m = *body.hand_model;
    const Data& d = *body.hand;
    const int nb = m.n_bones();
    HandTerms t{m, d, body.hand->tool, body.skeleton() ? d.skeleton.flesh_response() : d.hand.flesh_response(), {}, nb};
    const double k = m.params.spring_stiffness, damping = m.params.spring_damping, dt = m.params.dt;
    t.aht_e.resize(nb);
    for (int b = 0; b < nb; ++b) {
        const Mat3 end_rotation = quat_to_matrix(bone_state(d, b).q);
        for (const Vec3& r : t.bone(b).r_body) t.aht_e[b].push_back(handle_flesh_block(k, damping, dt, end_rotation * r));
    }
    return t;
}

void require_prescribed_step(const Body& body, const HandTerms& t) {
    const bool prescribed = body.skeleton() ? t.d.bones_prescribed : t.d.end_aht.size() == t.bone(0).nodes.size();
    if (!prescribed || t.columns.cols() != 6 * t.nb || t.columns.rows() != t.tool.A.rows())
        throw InvalidArgument("the bones' coupling model needs the world's last step taken with every bone prescribed "
                              "(hh_world_set_bone_targets with HH_BONE_PRESCRIBED for all of them, then hh_world_step)");
}

// A flesh matrix (3n x k) with bone b's blocks at its nodes, for every bone: Aht_e^T or Ath
template <class Block>
MatX bone_columns(const HandTerms& t, const Block& block) {
    MatX out = MatX::Zero(t.tool.A.rows(), 6 * t.nb);
    for (int b = 0; b < t.nb; ++b)
        for (size_t j = 0; j < t.bone(b).nodes.size(); ++j)
            out.block<3, 6>(3 * t.bone(b).nodes[j], 6 * b) = block(b, static_cast<int>(j));
    return out;
}

// The rows of the flesh unknowns `flesh` (3n indices) of the response operator the contacts saw
// (DeformableSystem::solve_response) applied to the columns
MatX response_at(const HandTerms& t, const MatX& columns, const std::vector<int>& flesh) {
    std::vector<int> nodes;
    for (int u : flesh) nodes.push_back(u / 3);
    std::sort(nodes.begin(), nodes.end());
    nodes.erase(std::unique(nodes.begin(), nodes.end()), nodes.end());
    MatX solved;
    t.tool.solve_response(columns, solved, &nodes);
    MatX out(static_cast<Eigen::Index>(flesh.size()), columns.cols());
    for (size_t i = 0; i < flesh.size(); ++i) out.row(static_cast<Eigen::Index>(i)) = solved.row(flesh[i]);
    return out;
}

// H_l M^-1 N H_r of the held contacts (haptics/held_contacts.h) with 6B handle columns:
// H_r = J A_t^-1 Ath (the step's columns at the contacts; with the reused factor, whose contact
// responses are its warped operator, solved through it as every contact response was) and
// H_l = Aht_e A_t^-1 J^T (solves: `how`).
MatX held_term(const World& world, int hand, const HandTerms& t, HeldSolves how, int& held_rows) {
    const int nh = 6 * t.nb;
    held_rows = 0;
    const HeldContacts held = held_contacts_of(world, hand);
    const int nr = held.n_rows();
    if (nr == 0) return MatX::Zero(nh, nh);
    const World::ContactBody& cb = world.contact_bodies.at(hand);
    std::vector<int> flesh;  // the touched flesh unknowns (3n indices)
    for (int u : cb.touched) flesh.push_back(u - nh);
    const bool own = t.tool.solver() != DeformableSolver::ReusedCholesky;
    MatX ath_at;  // A_t^-1 Ath at the touched unknowns
    if (own) {
        ath_at.resize(static_cast<Eigen::Index>(flesh.size()), nh);
        for (size_t i = 0; i < flesh.size(); ++i) ath_at.row(static_cast<Eigen::Index>(i)) = t.columns.row(flesh[i]);
    } else {
        ath_at = response_at(t, bone_columns(t, [&](int b, int j) { return t.ath(b, j); }), flesh);
    }
    // the held rows the hand takes part in, and their local rows (rows of G)
    std::vector<int> mine, local;
    for (int r = 0; r < nr; ++r) {
        const int row = held.rows[r];
        if (row < static_cast<int>(cb.local_row.size()) && cb.local_row[row] >= 0) {
            mine.push_back(r);
            local.push_back(cb.local_row[row]);
        }
    }
    if (mine.empty()) return MatX::Zero(nh, nh);
    const Eigen::SparseMatrix<double, Eigen::RowMajor>& g = cb.G;
    MatX hr = MatX::Zero(nr, nh), hl = MatX::Zero(nh, nr);
    for (size_t a = 0; a < mine.size(); ++a)
        for (Eigen::SparseMatrix<double, Eigen::RowMajor>::InnerIterator it(g, local[a]); it; ++it)
            hr.row(mine[a]) += it.value() * ath_at.row(it.col());
    const bool by_bones = how == HeldSolves::BoneColumns || (how == HeldSolves::Fewer && nh <= static_cast<int>(mine.size()));
    if (by_bones) {  // A_t^-1 Aht_e^T at the contacts, through J
        const MatX at = response_at(t, bone_columns(t, [&](int b, int j) { return t.aht_e[b][j].transpose(); }), flesh);
        for (size_t a = 0; a < mine.size(); ++a)
            for (Eigen::SparseMatrix<double, Eigen::RowMajor>::InnerIterator it(g, local[a]); it; ++it)
                hl.col(mine[a]) += it.value() * at.row(it.col()).transpose();
    } else {  // A_t^-1 J^T e_r at the bones' nodes, through Aht_e
        MatX rhs = MatX::Zero(t.tool.A.rows(), static_cast<Eigen::Index>(mine.size()));
        for (size_t a = 0; a < mine.size(); ++a)
            for (Eigen::SparseMatrix<double, Eigen::RowMajor>::InnerIterator it(g, local[a]); it; ++it)
                rhs(flesh[it.col()], static_cast<Eigen::Index>(a)) += it.value();
        std::vector<int> bone_flesh;
        for (int b = 0; b < t.nb; ++b)
            for (int i : t.bone(b).nodes)
                for (int k = 0; k < 3; ++k) bone_flesh.push_back(3 * i + k);
        const MatX at = response_at(t, rhs, bone_flesh);  // rows in bone_flesh's order
        Eigen::Index row = 0;
        for (int b = 0; b < t.nb; ++b)
            for (size_t j = 0; j < t.bone(b).nodes.size(); ++j, row += 3)
                for (size_t a = 0; a < mine.size(); ++a)
                    hl.block<6, 1>(6 * b, mine[a]) += t.aht_e[b][j] * at.block<3, 1>(row, static_cast<Eigen::Index>(a));
    }
    held_rows = carrying_rows(world, held);
    return held_contact_term(world, held, hr, hl);
}

}  // namespace

BoneCouplingModel linearize_bone_coupling(const World& world, int hand, HeldSolves how) {
    if (hand < 0 || hand >= static_cast<int>(world.bodies.size()) || world.bodies[hand]->kind != BodyKind::Hand)
        throw InvalidArgument("the bones' coupling model: body " + std::to_string(hand) +
                              " is not the hand: give the index hh_world_add_hand returned");
    const Body& body = *world.bodies[hand];
    const HandTerms t = hand_terms(body);
    require_prescribed_step(body, t);
    const Model& m = t.m;
    const Data& d = t.d;
    const int nb = t.nb, nh = 6 * nb;
    const double dt = m.params.dt, k = m.params.spring_stiffness, damping = m.params.spring_damping;
    BoneCouplingModel out;
    out.wrench = VecX::Zero(nh);
    MatX flesh = MatX::Zero(nh, nh);  // Aht_e A_t^-1 Ath: bone b's rows read its nodes of the columns
    std::vector<Mat6> pose(nb, Mat6::Zero()), velocity(nb, Mat6::Zero());
    for (int b = 0; b < nb; ++b) {
        const HandleModel& bone = t.bone(b);
        const HandleState& h = bone_state(d, b);
        for (size_t j = 0; j < bone.nodes.size(); ++j) {
            const Vec3 x_a = d.x.segment<3>(3 * bone.nodes[j]), v_a = d.v.segment<3>(3 * bone.nodes[j]);
            const SpringJacobian jac = spring_jacobian(k, damping, x_a, v_a, bone.r_body[j], h);
            pose[b] += jac.dfh_dxh;
            velocity[b] += jac.dfh_dvh;
            const SpringForce f = spring_force(k, damping, x_a, v_a, bone.r_body[j], h);
            out.wrench.segment<3>(6 * b) += f.on_handle;
            out.wrench.segment<3>(6 * b + 3) += f.torque;
            flesh.middleRows<6>(6 * b).noalias() += t.aht_e[b][j] * t.columns.middleRows<3>(3 * bone.nodes[j]);
        }
        out.ends.push_back(h);
    }
    MatX inner = (flesh - held_term(world, hand, t, how, out.held_rows)) / dt;
    out.stiffness.resize(nh, nh);
    for (int c = 0; c < nb; ++c) {
        inner.block<6, 6>(6 * c, 6 * c) += velocity[c];
        // dv_c / d(dx_c, dtheta_c): dx = dt dv; the end turn exp(dt (omega_c - omega_frame)) of
        // the frame's turned pose moves by J_l^-1 of that relative turn
        Mat6 chain = Mat6::Identity() / dt;
        chain.bottomRightCorner<3, 3>() = left_jacobian_inverse(dt * (bone_state(d, c).omega - d.frame.omega)) / dt;
        out.stiffness.middleCols<6>(6 * c) = inner.middleCols<6>(6 * c) * chain;
    }
    for (int b = 0; b < nb; ++b) out.stiffness.block<6, 6>(6 * b, 6 * b) += pose[b];
    out.accelerations.assign(nb, Vec6::Zero());
    out.valid = out.stiffness.allFinite() && out.wrench.allFinite();
    if (!out.valid) throw NumericalError("the bones' coupling model has non-finite entries");
    return out;
}

}  // namespace hh
