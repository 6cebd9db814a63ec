// The C ABI of the skeleton of many handles (docs/skeleton.md, Section 7). Every entry point
// runs through guard(): nothing thrown reaches the caller.
#include <algorithm>
#include <cstring>
#include <string>
#include <vector>

#include "haptic_hand.h"
#include "params/table.h"
#include "haptics/bone_model.h"
#include "sim/skeleton_step.h"

#include "capi/bone_targets.h"
#include "capi/guard.h"

using hh::capi::guard;
using hh::capi::require;
using hh::capi::require_size;
using hh::capi::vec3;

namespace {

// The C description as BoneDesc rows (checked for null arrays and offsets here; the bones'
// own rules in hh::check_skeleton).
std::vector<hh::BoneDesc> bone_descs(const hh_skeleton_desc* s) {
    require(s != nullptr, "the skeleton description is null");
    require(s->struct_size == static_cast<int>(sizeof(hh_skeleton_desc)),
            "hh_skeleton_desc has the wrong size (struct_size " + std::to_string(s->struct_size) + ", expected " +
                std::to_string(sizeof(hh_skeleton_desc)) + "): rebuild the bindings against this haptic_hand.h");
    require(s->n_bones >= 1, "a skeleton needs at least one bone");
    require(s->parents && s->heads && s->tails && s->radii, "the skeleton's parents, heads, tails and radii must not be null");
    require((s->set_offsets == nullptr) == (s->set_nodes == nullptr),
            "the skeleton's set_offsets and set_nodes must both be given or both be null");
    std::vector<hh::BoneDesc> out(s->n_bones);
    for (int b = 0; b < s->n_bones; ++b) {
        hh::BoneDesc& d = out[b];
        d.name = s->names && s->names[b] ? std::string(s->names[b]) : "bone " + std::to_string(b);
        d.parent = s->parents[b];
        d.head = vec3(s->heads + 3 * b);
        d.tail = vec3(s->tails + 3 * b);
        d.radius = s->radii[b];
        d.drive_scale = s->drive_scales ? s->drive_scales[b] : 1.0;
        if (s->axes)
            for (int r = 0; r < 3; ++r)
                for (int c = 0; c < 3; ++c) d.axes(r, c) = s->axes[9 * b + 3 * r + c];
        if (s->limit_min) d.limit_min = vec3(s->limit_min + 3 * b);
        if (s->limit_max) d.limit_max = vec3(s->limit_max + 3 * b);
        if (!s->set_offsets) continue;
        const int first = s->set_offsets[b], last = s->set_offsets[b + 1];
        require(first >= 0 && last >= first, "bone '" + d.name + "': its set_offsets must be non-negative and non-decreasing");
        d.explicit_set = last > first;
        d.nodes.assign(s->set_nodes + first, s->set_nodes + last);
    }
    return out;
}

void require_bones(const hh_model* model, int n_bones, const char* what) {
    require(model != nullptr, std::string(what) + ": null model");
    require_size(n_bones, model->m.n_bones(), what);
}

}  // namespace

extern "C" {

int hh_skeleton_capture(const double* rest_positions, int n_nodes, const hh_skeleton_desc* skeleton, int* out_node_bone,
                        int* out_counts) {
    return guard([&] {
        require(rest_positions && out_node_bone && out_counts && n_nodes >= 0, "hh_skeleton_capture: bad arguments");
        const std::vector<hh::BoneDesc> bones = bone_descs(skeleton);
        const hh::VecX rest = Eigen::Map<const hh::VecX>(rest_positions, 3 * n_nodes);
        const std::vector<int> owner = hh::capture_skeleton(rest, bones);
        std::copy(owner.begin(), owner.end(), out_node_bone);
        std::fill(out_counts, out_counts + bones.size(), 0);
        for (int b : owner)
            if (b >= 0) ++out_counts[b];
        return HH_OK;
    });
}

int hh_model_create_skeleton(const double* rest_positions, int n_nodes, const int* tets, int n_tets,
                             const hh_params* params, const hh_skeleton_desc* skeleton, hh_model** out_model) {
    return guard([&] {
        require(out_model && params, "hh_model_create_skeleton: null params or output pointer");
        *out_model = nullptr;
        const std::vector<hh::BoneDesc> bones = bone_descs(skeleton);
        *out_model = new hh_model{hh::build_skeleton_model(rest_positions, n_nodes, tets, n_tets, *params, bones)};
        return HH_OK;
    });
}

int hh_model_bone_count(const hh_model* model, int* out_n_bones) {
    return guard([&] {
        require(model && out_n_bones, "hh_model_bone_count: null pointer");
        *out_n_bones = model->m.n_bones();
        return HH_OK;
    });
}

int hh_model_bone_info(const hh_model* model, int bone, hh_bone_info* out) {
    return guard([&] {
        require(model && out, "hh_model_bone_info: null pointer");
        require(out->struct_size == static_cast<int>(sizeof(hh_bone_info)),
                "hh_bone_info has the wrong size: rebuild the bindings against this haptic_hand.h");
        require(bone >= 0 && bone < model->m.n_bones(), "hh_model_bone_info: bone " + std::to_string(bone) +
                                                            " is outside 0.." + std::to_string(model->m.n_bones() - 1));
        const hh::HandleModel& h = model->m.skeleton.bones[bone];
        out->parent = model->m.skeleton.parents[bone];
        out->n_nodes = static_cast<int>(h.nodes.size());
        out->mass = h.mass;
        hh::capi::put3(h.rest_com, out->com);
        for (int i = 0; i < 3; ++i)
            for (int j = 0; j < 3; ++j) out->inertia[3 * i + j] = h.inertia_body(i, j);
        const hh::Vec4 drive = hh::bone_drive(model->m, bone);
        for (int i = 0; i < 4; ++i) out->drive[i] = drive[i];
        return HH_OK;
    });
}

int hh_model_bone_nodes(const hh_model* model, int bone, int* out_nodes, int capacity, int* out_count) {
    return guard([&] {
        require(model && out_count, "hh_model_bone_nodes: null pointer");
        require(bone >= 0 && bone < model->m.n_bones(), "hh_model_bone_nodes: bone " + std::to_string(bone) +
                                                            " is outside 0.." + std::to_string(model->m.n_bones() - 1));
        const std::vector<int>& nodes = model->m.skeleton.bones[bone].nodes;
        *out_count = static_cast<int>(nodes.size());
        require(capacity >= *out_count && (out_nodes || *out_count == 0),
                "hh_model_bone_nodes: capacity " + std::to_string(capacity) + " is below the bone's " +
                    std::to_string(*out_count) + " nodes");
        std::copy(nodes.begin(), nodes.end(), out_nodes);
        return HH_OK;
    });
}

int hh_model_node_bones(const hh_model* model, int* out_node_bone, int n_nodes) {
    return guard([&] {
        require(model && out_node_bone, "hh_model_node_bones: null pointer");
        require_size(n_nodes, model->m.mesh.n_nodes, "node bones");
        std::copy(model->m.skeleton.node_bone.begin(), model->m.skeleton.node_bone.end(), out_node_bone);
        return HH_OK;
    });
}

int hh_get_bone_states(const hh_model* model, const hh_data* data, int n_bones, double* positions, double* quaternions,
                       double* velocities, double* angular_velocities) {
    return guard([&] {
        require_bones(model, n_bones, "bone states");
        require(data != nullptr, "hh_get_bone_states: null data");
        for (int b = 0; b < n_bones; ++b) {
            const hh::HandleState& h = hh::bone_state(data->d, b);
            if (positions) hh::capi::put3(h.x_com, positions + 3 * b);
            if (quaternions) std::memcpy(quaternions + 4 * b, h.q.data(), 4 * sizeof(double));
            if (velocities) hh::capi::put3(h.v_com, velocities + 3 * b);
            if (angular_velocities) hh::capi::put3(h.omega, angular_velocities + 3 * b);
        }
        return HH_OK;
    });
}

int hh_set_bone_states(const hh_model* model, hh_data* data, int n_bones, const double* positions,
                       const double* quaternions, const double* velocities, const double* angular_velocities) {
    return guard([&] {
        require_bones(model, n_bones, "bone states");
        require(data != nullptr, "hh_set_bone_states: null data");
        const std::vector<hh::HandleState> states =
            hh::capi::bone_states(data->d, n_bones, positions, quaternions, velocities, angular_velocities);
        for (int b = 0; b < n_bones; ++b) hh::bone_state(data->d, b) = states[b];
        return HH_OK;
    });
}

int hh_set_bone_targets(const hh_model* model, hh_data* data, int n_bones, const int* modes, const double* positions,
                        const double* quaternions, const double* velocities, const double* angular_velocities) {
    return guard([&] {
        require_bones(model, n_bones, "bone targets");
        require(data != nullptr, "hh_set_bone_targets: null data");
        const std::vector<hh::DeviceFrame> targets =
            hh::capi::bone_targets(data->d, n_bones, modes, positions, quaternions, velocities, angular_velocities);
        for (int b = 0; b < n_bones; ++b) hh::bone_target(data->d, b) = targets[b];
        return HH_OK;
    });
}

int hh_bone_wrenches(const hh_model* model, const hh_data* data, int n_bones, double* out) {
    return guard([&] {
        require_bones(model, n_bones, "bone wrenches");
        require(data && out, "hh_bone_wrenches: null pointer");
        const std::vector<hh::Vec6> w = hh::bone_wrenches(model->m, data->d);
        for (int b = 0; b < n_bones; ++b) std::memcpy(out + 6 * b, w[b].data(), 6 * sizeof(double));
        return HH_OK;
    });
}

int hh_bone_linear_model(const hh_model* model, const hh_data* data, int n_bones, double* wrench0, double* response) {
    return guard([&] {
        require_bones(model, n_bones, "bone linear model");
        require(data && wrench0 && response, "hh_bone_linear_model: null pointer");
        const hh::BoneLinearModel bm = hh::bone_linear_model(model->m, data->d);
        const int n = 6 * n_bones;
        std::copy(bm.wrench0.data(), bm.wrench0.data() + n, wrench0);
        Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>>(response, n, n) = bm.response;
        return HH_OK;
    });
}

int hh_bone_response(const hh_model* model, const hh_data* data, int n_bones, const double* velocities, double* out) {
    return guard([&] {
        require_bones(model, n_bones, "bone response");
        require(data && velocities && out, "hh_bone_response: null pointer");
        const hh::VecX w = hh::bone_response(model->m, data->d, Eigen::Map<const hh::VecX>(velocities, 6 * n_bones));
        std::copy(w.data(), w.data() + 6 * n_bones, out);
        return HH_OK;
    });
}

}  // extern "C"
