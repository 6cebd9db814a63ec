// The C ABI of a skeleton hand in a world (docs/skeleton.md, Section 7): its bones' targets and
// states, where the last step's contact forces acted on its nodes (a finger's share of a pinch),
// and the bones' handle-space model with contacts held (Section 6). Same rules as
// world_capi.cpp: guard() around every body.
#include <cstring>
#include <string>
#include <vector>

#include "capi/bone_targets.h"
#include "capi/guard.h"
#include "haptics/bone_coupling_model.h"
#include "sim/skeleton_step.h"

using hh::capi::guard;
using hh::capi::require;
using hh::capi::require_size;

namespace {

hh::Body& hand_at(hh_world* world, int hand_body, int n_bones) {
    require(world != nullptr, "null world");
    require(!world->in_live_session(),
            "a live haptic session is stepping this world: read it through the session, or stop the session first");
    require(hand_body >= 0 && hand_body < static_cast<int>(world->w.bodies.size()) &&
                world->w.bodies[hand_body]->kind == hh::BodyKind::Hand,
            "body " + std::to_string(hand_body) + " is not the hand: give the index hh_world_add_hand returned");
    hh::Body& b = *world->w.bodies[hand_body];
    require_size(n_bones, b.hand_model->n_bones(), "the hand's bones");
    return b;
}

// The force (N) each contact of the last step put on the body's flesh nodes, through the
// surface vertices it acted on and their weights in the tets (J^T lambda / dt, node by node)
void node_contact_forces(const hh::World& w, int body, double* out, int n_nodes) {
    std::memset(out, 0, sizeof(double) * 3 * static_cast<size_t>(n_nodes));
    const hh::Body& b = *w.bodies[body];
    for (size_t c = 0; c < w.contacts.size(); ++c) {
        const hh::Contact& k = w.contacts[c];
        const hh::Vec3 impulse = w.contact_lambda[3 * c] * k.normal + w.contact_lambda[3 * c + 1] * k.tangent1 +
                                 w.contact_lambda[3 * c + 2] * k.tangent2;
        for (int s = 0; s < 2; ++s) {
            const hh::ContactSide& side = s == 0 ? k.a : k.b;
            if (side.body != body) continue;
            const hh::Vec3 f = (s == 0 ? 1.0 : -1.0) * impulse / w.settings.dt;
            for (int v = 0; v < side.count; ++v)
                for (int q = 0; q < 4; ++q) {
                    const int node = b.surface.nodes[side.vertex[v]][q];
                    const double weight = side.weight[v] * b.surface.weights[side.vertex[v]][q];
                    if (weight != 0)
                        for (int d = 0; d < 3; ++d) out[3 * node + d] += weight * f[d];
                }
        }
    }
}

}  // namespace

extern "C" {

int hh_world_set_bone_targets(hh_world* world, int hand_body, int n_bones, const int* modes, const double* positions,
                              const double* quaternions, const double* velocities, const double* angular_velocities) {
    return guard([&] {
        hh::Body& b = hand_at(world, hand_body, n_bones);
        const std::vector<hh::DeviceFrame> targets =
            hh::capi::bone_targets(*b.hand, n_bones, modes, positions, quaternions, velocities, angular_velocities);
        for (int i = 0; i < n_bones; ++i) hh::bone_target(*b.hand, i) = targets[i];
        return HH_OK;
    });
}

int hh_world_bone_states(const hh_world* world, int hand_body, int n_bones, double* positions, double* quaternions,
                         double* wrenches) {
    return guard([&] {
        const hh::Body& b = hand_at(const_cast<hh_world*>(world), hand_body, n_bones);
        for (int i = 0; i < n_bones; ++i) {
            const hh::HandleState& h = hh::bone_state(*b.hand, i);
            hh::capi::put3(h.x_com, positions ? positions + 3 * i : nullptr);
            if (quaternions) std::memcpy(quaternions + 4 * i, h.q.data(), 4 * sizeof(double));
        }
        if (wrenches) {
            const std::vector<hh::Vec6> w = hh::bone_wrenches(*b.hand_model, *b.hand);
            for (int i = 0; i < n_bones; ++i) std::memcpy(wrenches + 6 * i, w[i].data(), 6 * sizeof(double));
        }
        return HH_OK;
    });
}

int hh_world_bone_velocities(const hh_world* world, int hand_body, int n_bones, double* velocities,
                             double* angular_velocities) {
    return guard([&] {
        const hh::Body& b = hand_at(const_cast<hh_world*>(world), hand_body, n_bones);
        for (int i = 0; i < n_bones; ++i) {
            const hh::HandleState& h = hh::bone_state(*b.hand, i);
            hh::capi::put3(h.v_com, velocities ? velocities + 3 * i : nullptr);
            hh::capi::put3(h.omega, angular_velocities ? angular_velocities + 3 * i : nullptr);
        }
        return HH_OK;
    });
}

int hh_world_set_bone_states(hh_world* world, int hand_body, int n_bones, const double* positions,
                             const double* quaternions, const double* velocities, const double* angular_velocities) {
    return guard([&] {
        hh::Body& b = hand_at(world, hand_body, n_bones);
        const std::vector<hh::HandleState> states =
            hh::capi::bone_states(*b.hand, n_bones, positions, quaternions, velocities, angular_velocities);
        for (int i = 0; i < n_bones; ++i) hh::bone_state(*b.hand, i) = states[i];
        b.carried_impulse.resize(0);  // (the last step's impulses were on another state)
        return HH_OK;
    });
}

int hh_world_bone_coupling_model(const hh_world* world, int hand_body, int n_bones, double* wrench0,
                                 double* stiffness, int* held_rows) {
    return guard([&] {
        const hh::Body& b = hand_at(const_cast<hh_world*>(world), hand_body, n_bones);
        require(wrench0 && stiffness, "hh_world_bone_coupling_model: null output");
        const int nh = 6 * n_bones;
        if (!b.skeleton()) {  // one bone: the palm handle's model, exactly
            const hh::CouplingModel m = hh::linearize_coupling(world->w, hand_body);
            std::memcpy(wrench0, m.wrench.data(), 6 * sizeof(double));
            Eigen::Map<Eigen::Matrix<double, 6, 6, Eigen::RowMajor>> out(stiffness);
            out = m.stiffness;
            if (held_rows) *held_rows = m.held_rows;
            return HH_OK;
        }
        const hh::BoneCouplingModel m = hh::linearize_bone_coupling(world->w, hand_body);
        std::memcpy(wrench0, m.wrench.data(), nh * sizeof(double));
        Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>> out(stiffness, nh, nh);
        out = m.stiffness;
        if (held_rows) *held_rows = m.held_rows;
        return HH_OK;
    });
}

int hh_world_node_contact_forces(const hh_world* world, int body, double* out, int n_nodes) {
    return guard([&] {
        require(world != nullptr && out != nullptr, "hh_world_node_contact_forces: null pointer");
        require(!world->in_live_session(),
                "a live haptic session is stepping this world: read it through the session, or stop the session first");
        require(body >= 0 && body < static_cast<int>(world->w.bodies.size()),
                "body index " + std::to_string(body) + " does not exist in this world");
        const hh::Body& b = *world->w.bodies[body];
        require(b.kind == hh::BodyKind::Hand || b.kind == hh::BodyKind::Soft,
                "contact forces per node exist for the hand and soft bodies: give one of their indices");
        require_size(n_nodes, static_cast<int>(b.points.size()), "the body's nodes");
        node_contact_forces(world->w, body, out, n_nodes);
        return HH_OK;
    });
}

}  // extern "C"
