// The C ABI: every entry point runs its body through guard(), which turns any exception into
// a status code and a thread-local message, so nothing thrown ever reaches Blender.
#include <cmath>
#include <cstring>
#include <memory>
#include <new>
#include <string>

#include "haptic_hand.h"
#include "haptics/bone_model.h"
#include "haptics/coupling_model.h"
#include "sim/skeleton_step.h"
#include "rigid/quaternion.h"

#include "capi/guard.h"

using hh::capi::guard;
using hh::capi::put3;
using hh::capi::require;
using hh::capi::require_size;
using hh::capi::vec3;

extern "C" {

const char* hh_last_error(void) { return hh::capi::last_error().c_str(); }
int hh_api_version(void) { return HH_API_VERSION; }

int hh_model_create(const double* rest_positions, int n_nodes, const int* tets, int n_tets,
                    const hh_params* params, hh_model** out_model) {
    return guard([&] {
        require(out_model && params, "hh_model_create: null params or output pointer");
        *out_model = nullptr;
        // the palm handle is one bone: joints between bones would be silently ignored
        require(params->joint_stiffness == 0 && params->joint_damping == 0 && params->joint_limit_stiffness == 0 &&
                    params->joint_limit_damping == 0,
                "joint_stiffness, joint_damping and the joint limits tie a skeleton's bones to their parents, and "
                "this model has the palm handle (one bone): set them to 0, or create the model with "
                "hh_model_create_skeleton");
        auto* m = new hh_model{hh::build_model(rest_positions, n_nodes, tets, n_tets, *params)};
        *out_model = m;
        return HH_OK;
    });
}

void hh_model_free(hh_model* model) { delete model; }

int hh_model_info_get(const hh_model* model, hh_model_info* out) {
    return guard([&] {
        require(model && out, "hh_model_info_get: null pointer");
        const hh::Model& m = model->m;
        out->n_nodes = m.mesh.n_nodes;
        out->n_tets = static_cast<int>(m.mesh.tets.size());
        out->n_handle_nodes = static_cast<int>(m.handle.nodes.size());
        out->total_mass = m.masses.sum();
        out->handle_mass = m.handle.mass;
        put3(m.handle.rest_com, out->handle_com);
        for (int i = 0; i < 3; ++i)
            for (int j = 0; j < 3; ++j) out->handle_inertia[3 * i + j] = m.handle.inertia_body(i, j);
        out->min_tet_volume = *std::min_element(m.elements.volume.begin(), m.elements.volume.end());
        out->max_tet_volume = *std::max_element(m.elements.volume.begin(), m.elements.volume.end());
        return HH_OK;
    });
}

int hh_model_handle_nodes(const hh_model* model, int* out_nodes, int capacity) {
    return guard([&] {
        require(model && out_nodes, "hh_model_handle_nodes: null pointer");
        require_size(capacity, static_cast<int>(model->m.handle.nodes.size()), "handle nodes");
        std::copy(model->m.handle.nodes.begin(), model->m.handle.nodes.end(), out_nodes);
        return HH_OK;
    });
}

int hh_model_lumped_masses(const hh_model* model, double* out_masses, int n_nodes) {
    return guard([&] {
        require(model && out_masses, "hh_model_lumped_masses: null pointer");
        require_size(n_nodes, model->m.mesh.n_nodes, "lumped masses");
        std::copy(model->m.masses.data(), model->m.masses.data() + n_nodes, out_masses);
        return HH_OK;
    });
}

int hh_model_params(const hh_model* model, hh_params* out) {
    return guard([&] {
        require(model && out, "hh_model_params: null pointer");
        *out = model->m.params;
        return HH_OK;
    });
}

int hh_count_captured(const double* rest_positions, int n_nodes, const double seed[3], double radius,
                      int* out_count) {
    return guard([&] {
        require(rest_positions && seed && out_count && n_nodes >= 0, "hh_count_captured: bad arguments");
        const hh::VecX rest = Eigen::Map<const hh::VecX>(rest_positions, 3 * n_nodes);
        *out_count = static_cast<int>(hh::capture_nodes(rest, vec3(seed), radius).size());
        return HH_OK;
    });
}

int hh_check_handle(const double* rest_positions, int n_nodes, const double seed[3], double radius, int* out_count) {
    return guard([&] {
        require(rest_positions && seed && out_count && n_nodes >= 0, "hh_check_handle: bad arguments");
        const hh::VecX rest = Eigen::Map<const hh::VecX>(rest_positions, 3 * n_nodes);
        *out_count = static_cast<int>(hh::capture_nodes(rest, vec3(seed), radius).size());
        hh::check_capture(*out_count, n_nodes, radius);
        return HH_OK;
    });
}

int hh_data_create(const hh_model* model, hh_data** out_data) {
    return guard([&] {
        require(model && out_data, "hh_data_create: null pointer");
        *out_data = new hh_data(model->m);
        return HH_OK;
    });
}

void hh_data_free(hh_data* data) { delete data; }

int hh_data_reset(const hh_model* model, hh_data* data) {
    return guard([&] {
        require(model && data, "hh_data_reset: null pointer");
        hh::reset(model->m, data->d);
        return HH_OK;
    });
}

int hh_get_state(const hh_model* model, const hh_data* data, double* x, double* v, int n_nodes,
                 double handle_position[3], double handle_quaternion[4], double handle_velocity[3],
                 double handle_angular_velocity[3]) {
    return guard([&] {
        require(model && data, "hh_get_state: null pointer");
        require_size(n_nodes, model->m.mesh.n_nodes, "state");
        const hh::Data& d = data->d;
        if (x) std::copy(d.x.data(), d.x.data() + 3 * n_nodes, x);
        if (v) std::copy(d.v.data(), d.v.data() + 3 * n_nodes, v);
        put3(d.h.x_com, handle_position);
        if (handle_quaternion) std::memcpy(handle_quaternion, d.h.q.data(), 4 * sizeof(double));
        put3(d.h.v_com, handle_velocity);
        put3(d.h.omega, handle_angular_velocity);
        return HH_OK;
    });
}

int hh_set_state(const hh_model* model, hh_data* data, const double* x, const double* v, int n_nodes,
                 const double handle_position[3], const double handle_quaternion[4],
                 const double handle_velocity[3], const double handle_angular_velocity[3]) {
    return guard([&] {
        require(model && data, "hh_set_state: null pointer");
        require_size(n_nodes, model->m.mesh.n_nodes, "state");
        hh::Data& d = data->d;
        hh::VecX nx = x ? hh::VecX(Eigen::Map<const hh::VecX>(x, 3 * n_nodes)) : d.x;
        hh::VecX nv = v ? hh::VecX(Eigen::Map<const hh::VecX>(v, 3 * n_nodes)) : d.v;
        hh::HandleState h = d.h;
        if (handle_position) h.x_com = vec3(handle_position);
        if (handle_quaternion) {
            h.q = hh::Vec4(handle_quaternion[0], handle_quaternion[1], handle_quaternion[2], handle_quaternion[3]);
            require(h.q.allFinite() && h.q.norm() > 1e-12, "handle quaternion must be finite and non-zero");
            h.q.normalize();
        }
        if (handle_velocity) h.v_com = vec3(handle_velocity);
        if (handle_angular_velocity) h.omega = vec3(handle_angular_velocity);
        require(nx.allFinite() && nv.allFinite() && h.x_com.allFinite() && h.v_com.allFinite() && h.omega.allFinite(),
                "hh_set_state: state contains NaN or infinite values");
        d.x = nx;
        d.v = nv;
        d.h = h;
        d.end_aht.clear();  // (no coupling model of the last step for another state: hh_coupling_model)
        return HH_OK;
    });
}

int hh_set_device(hh_data* data, int enabled, const double position[3], const double quaternion[4],
                  const double velocity[3], const double angular_velocity[3]) {
    return guard([&] {
        require(data, "hh_set_device: null data");
        data->d.device = hh::capi::updated_device(data->d.device, enabled, position, quaternion, velocity,
                                                  angular_velocity);
        return HH_OK;
    });
}

int hh_set_solver(hh_model* model, int solver, double cg_tolerance, int cg_max_iterations) {
    return guard([&] {
        require(model, "hh_set_solver: null model");
        hh_params p = model->m.params;
        p.solver = solver;
        p.cg_tolerance = cg_tolerance;
        p.cg_max_iterations = cg_max_iterations;
        hh::validate_params(p);
        model->m.params = p;
        return HH_OK;
    });
}

static int do_step(const hh_model* model, hh_data* data, hh_step_stats* out_stats, bool monolithic) {
    return guard([&] {
        require(model && data, "hh_step: null pointer");
        hh::configure_solver(model->m, data->d);  // picks up hh_set_solver changes
        const hh::VecX x0 = data->d.x, v0 = data->d.v;
        const hh::HandleState h0 = data->d.h;
        try {
            hh::step(model->m, data->d, monolithic);
        } catch (...) {
            // a failed step leaves the previous state, so the caller keeps a usable simulation
            data->d.x = x0;
            data->d.v = v0;
            data->d.h = h0;
            throw;
        }
        if (!data->d.x.allFinite() || !data->d.v.allFinite()) {
            data->d.x = x0;
            data->d.v = v0;
            data->d.h = h0;
            throw hh::NumericalError("the step produced non-finite positions: reduce the time step or the stiffness");
        }
        if (out_stats) *out_stats = data->d.stats;
        return HH_OK;
    });
}

int hh_step(const hh_model* model, hh_data* data, hh_step_stats* out_stats) {
    return do_step(model, data, out_stats, false);
}

int hh_step_monolithic(const hh_model* model, hh_data* data, hh_step_stats* out_stats) {
    return do_step(model, data, out_stats, true);
}

int hh_compare_solvers(const hh_model* model, const hh_data* data, double* out_relative_difference) {
    return guard([&] {
        require(model && data && out_relative_difference, "hh_compare_solvers: null pointer");
        hh::Data work(model->m);
        work.x = data->d.x;
        work.v = data->d.v;
        work.h = data->d.h;
        work.device = data->d.device;
        hh::VecX schur, mono;
        if (model->m.n_bones() > 1) {  // a skeleton (docs/skeleton.md): its B-bone system
            work.bones = data->d.bones;
            work.targets = data->d.targets;
            hh::formulate_skeleton(model->m, work);
            work.skeleton.solve();
            schur = work.skeleton.s;
            mono = hh::solve_monolithic(work.skeleton, work.skeleton.r);
        } else {
            hh::formulate(model->m, work);
            work.hand.solve();
            schur = work.hand.s;
            mono = hh::solve_monolithic(work.hand, work.hand.r);
        }
        const double scale = mono.cwiseAbs().maxCoeff();
        const double diff = (schur - mono).cwiseAbs().maxCoeff();
        *out_relative_difference = scale > 0 ? diff / scale : diff;
        return HH_OK;
    });
}

int hh_coupling_linear_model(const hh_model* model, const hh_data* data, double wrench0[6], double response[36]) {
    return guard([&] {
        require(model && data && wrench0 && response, "hh_coupling_linear_model: null pointer");
        hh::capi::require_one_bone(model->m, "hh_coupling_linear_model");
        // the palm handle is the one bone of hh_bone_linear_model (haptics/bone_model.h)
        const hh::BoneLinearModel lm = hh::bone_linear_model(model->m, data->d);
        for (int i = 0; i < 6; ++i) {
            wrench0[i] = lm.wrench0[i];
            for (int j = 0; j < 6; ++j) response[6 * i + j] = lm.response(i, j);
        }
        return HH_OK;
    });
}

int hh_coupling_response(const hh_model* model, const hh_data* data, const double handle_velocity[6], double wrench[6]) {
    return guard([&] {
        require(model && data && handle_velocity && wrench, "hh_coupling_response: null pointer");
        hh::capi::require_one_bone(model->m, "hh_coupling_response");
        const hh::Model& m = model->m;
        hh::Vec6 vh;
        for (int i = 0; i < 6; ++i) vh[i] = handle_velocity[i];
        require(vh.allFinite(), "handle velocity must be finite");
        const hh::VecX w = hh::bone_response(m, data->d, vh);
        for (int i = 0; i < 6; ++i) wrench[i] = w[i];
        return HH_OK;
    });
}

int hh_coupling_model(const hh_model* model, const hh_data* data, double wrench0[6], double stiffness[36]) {
    return guard([&] {
        require(model && data && wrench0 && stiffness, "hh_coupling_model: null pointer");
        hh::capi::require_one_bone(model->m, "hh_coupling_model");
        const hh::CouplingModel cm = hh::hand_coupling_model(model->m, data->d, hh::Mat6::Zero());
        for (int i = 0; i < 6; ++i) {
            wrench0[i] = cm.wrench[i];
            for (int j = 0; j < 6; ++j) stiffness[6 * i + j] = cm.stiffness(i, j);
        }
        return HH_OK;
    });
}

int hh_coupling_wrench(const hh_model* model, const hh_data* data, double force[3], double torque[3]) {
    return guard([&] {
        require(model && data, "hh_coupling_wrench: null pointer");
        hh::Vec3 f, t;
        hh::coupling_wrench(model->m, data->d, f, t);
        put3(f, force);
        put3(t, torque);
        return HH_OK;
    });
}

int hh_energies(const hh_model* model, const hh_data* data, double* kinetic, double* elastic, double* spring) {
    return guard([&] {
        require(model && data, "hh_energies: null pointer");
        const hh::Model& m = model->m;
        const hh::Data& d = data->d;
        double ke = 0;
        for (int i = 0; i < m.mesh.n_nodes; ++i) ke += 0.5 * m.masses[i] * d.v.segment<3>(3 * i).squaredNorm();
        ke += 0.5 * m.handle.mass * d.h.v_com.squaredNorm();
        ke += 0.5 * d.h.omega.dot(hh::handle_world_inertia(m, d.h) * d.h.omega);
        for (int b = 1; b < m.n_bones(); ++b) {  // a skeleton's other bones (docs/skeleton.md)
            const hh::HandleState& h = hh::bone_state(d, b);
            const hh::Mat3 rb = hh::quat_to_matrix(h.q);
            ke += 0.5 * m.skeleton.bones[b].mass * h.v_com.squaredNorm();
            ke += 0.5 * h.omega.dot(rb * m.skeleton.bones[b].inertia_body * rb.transpose() * h.omega);
        }
        hh::VecX f = hh::VecX::Zero(d.x.size());
        const double ee = hh::add_elastic_forces(m.mesh, m.elements, d.x, f, nullptr);
        double se = 0;
        const hh::Mat3 r = hh::quat_to_matrix(d.h.q);
        for (size_t j = 0; j < m.handle.nodes.size(); ++j) {
            const hh::Vec3 e = d.x.segment<3>(3 * m.handle.nodes[j]) - d.h.x_com - r * m.handle.r_body[j];
            se += 0.5 * m.params.spring_stiffness * e.squaredNorm();
        }
        for (int b = 1; b < m.n_bones(); ++b) {
            const hh::HandleModel& bone = m.skeleton.bones[b];
            const hh::HandleState& h = hh::bone_state(d, b);
            const hh::Mat3 rb = hh::quat_to_matrix(h.q);
            for (size_t j = 0; j < bone.nodes.size(); ++j) {
                const hh::Vec3 e = d.x.segment<3>(3 * bone.nodes[j]) - h.x_com - rb * bone.r_body[j];
                se += 0.5 * m.params.spring_stiffness * e.squaredNorm();
            }
        }
        se += hh::joint_energy(m, d);  // the ball joints' springs (docs/skeleton.md Section 5)
        if (kinetic) *kinetic = ke;
        if (elastic) *elastic = ee;
        if (spring) *spring = se;
        return HH_OK;
    });
}

int hh_linear_momentum(const hh_model* model, const hh_data* data, double out[3]) {
    return guard([&] {
        require(model && data && out, "hh_linear_momentum: null pointer");
        const hh::Model& m = model->m;
        hh::Vec3 p = m.handle.mass * data->d.h.v_com;
        for (int i = 0; i < m.mesh.n_nodes; ++i) p += m.masses[i] * data->d.v.segment<3>(3 * i);
        for (int b = 1; b < m.n_bones(); ++b) p += m.skeleton.bones[b].mass * hh::bone_state(data->d, b).v_com;
        put3(p, out);
        return HH_OK;
    });
}

}  // extern "C"
