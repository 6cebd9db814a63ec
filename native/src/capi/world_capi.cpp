// The C ABI of worlds (scenes with contact). Same rules as capi.cpp: guard() around every body.
#include <cmath>
#include <memory>

#include "capi/guard.h"
#include "rigid/quaternion.h"

using hh::capi::guard;
using hh::capi::put3;
using hh::capi::require;
using hh::capi::require_size;
using hh::capi::vec3;

namespace {

void require_idle(const hh_world* world) {
    require(world != nullptr, "null world");
    require(!world->in_live_session.load(std::memory_order_acquire),
            "a live haptic session is stepping this world: read it through the session, or stop the session first");
}

hh::Body& body_at(hh_world* world, int body) {
    require_idle(world);
    require(body >= 0 && body < static_cast<int>(world->w.bodies.size()),
            "body index " + std::to_string(body) + " does not exist in this world");
    return *world->w.bodies[body];
}
const hh::Body& body_at(const hh_world* world, int body) { return body_at(const_cast<hh_world*>(world), body); }

void require_finite_positive(double value, const char* name, const char* rule) {
    require(std::isfinite(value) && value > 0, std::string(name) + " = " + std::to_string(value) +
                                                   " is invalid: it must be " + rule);
}

void set_surface(hh::CollisionSurface& s, const int* nodes, const double* weights, int n_vertices, const int* faces,
                 int n_faces) {
    require(n_vertices > 0 && n_faces > 0 && nodes && weights && faces,
            "a collision surface needs vertices and triangles");
    s.nodes.resize(n_vertices);
    s.weights.resize(n_vertices);
    for (int v = 0; v < n_vertices; ++v) {
        s.nodes[v] = Eigen::Vector4i(nodes[4 * v], nodes[4 * v + 1], nodes[4 * v + 2], nodes[4 * v + 3]);
        s.weights[v] = hh::Vec4(weights[4 * v], weights[4 * v + 1], weights[4 * v + 2], weights[4 * v + 3]);
        require(s.weights[v].allFinite(), "collision surface weights must be finite");
    }
    s.triangles.resize(n_faces);
    for (int t = 0; t < n_faces; ++t) s.triangles[t] = Eigen::Vector3i(faces[3 * t], faces[3 * t + 1], faces[3 * t + 2]);
}

void require_friction(double friction) {
    require(std::isfinite(friction) && friction >= 0,
            "friction = " + std::to_string(friction) + " is invalid: it must be zero or positive");
}

}  // namespace

extern "C" {

void hh_default_world_params(hh_world_params* p) {
    if (!p) return;
    std::memset(p, 0, sizeof(*p));
    p->struct_size = sizeof(hh_world_params);
    p->dt = 1.0 / 30.0;
    p->gravity[2] = -9.81;
    p->contact_thickness = 1e-3;
    p->contact_patch = 4e-3;
    p->max_iterations = 300;
    p->tolerance = 1e-5;
    p->stall_factor = 4;
    p->threads = 2;
}

void hh_default_material(hh_material* m) {
    if (!m) return;
    std::memset(m, 0, sizeof(*m));
    m->struct_size = sizeof(hh_material);
    m->young_modulus = 5e4;
    m->poisson_ratio = 0.3;
    m->density = 1000;
    m->rayleigh_beta = 0.01;
}

int hh_world_create(const hh_world_params* p, hh_world** out) {
    return guard([&] {
        require(p && out, "hh_world_create: null pointer");
        *out = nullptr;
        require(p->struct_size == static_cast<int>(sizeof(hh_world_params)),
                "hh_world_params has the wrong size: rebuild the native library (make native)");
        require_finite_positive(p->dt, "dt", "a positive time step in seconds");
        require(p->dt <= 0.1, "dt = " + std::to_string(p->dt) + " is invalid: it must be at most 0.1 s");
        for (double g : p->gravity) require(std::isfinite(g), "gravity must be finite");
        require_finite_positive(p->contact_thickness, "contact_thickness", "a positive distance in metres (e.g. 1e-3)");
        require_finite_positive(p->contact_patch, "contact_patch", "a positive distance in metres (e.g. 4e-3)");
        require(p->max_iterations > 0, "max_iterations must be positive");
        require_finite_positive(p->tolerance, "tolerance", "a positive speed in m/s (e.g. 1e-5)");
        require(std::isfinite(p->stall_factor) && (p->stall_factor == 0 || p->stall_factor >= 1),
                "stall_factor = " + std::to_string(p->stall_factor) +
                    " is invalid: use 0 (sweep to the tolerance or max_iterations) or a factor of at least 1 (e.g. 4)");
        require(p->threads == 1 || p->threads == 2,
                "threads = " + std::to_string(p->threads) + " is invalid: use 1 (all on the caller's thread) or 2");
        hh::WorldSettings s;
        s.dt = p->dt;
        s.gravity = vec3(p->gravity);
        s.contact_thickness = p->contact_thickness;
        s.contact_patch = p->contact_patch;
        s.max_iterations = p->max_iterations;
        s.tolerance = p->tolerance;
        s.stall_factor = p->stall_factor;
        s.threads = p->threads;
        *out = new hh_world(s);
        return HH_OK;
    });
}

void hh_world_free(hh_world* world) { delete world; }

int hh_world_add_hand(hh_world* world, const hh_model* model, const int* surface_nodes, const double* surface_weights,
                      int n_surface_vertices, const int* faces, int n_faces, double friction, int self_collision,
                      int* out_body) {
    return guard([&] {
        require(world && model && out_body, "hh_world_add_hand: null pointer");
        require_friction(friction);
        auto b = std::make_unique<hh::Body>();
        b->kind = hh::BodyKind::Hand;
        b->friction = friction;
        b->kinetic_friction = friction;
        b->self_collision = self_collision != 0;
        b->hand_model = std::make_unique<hh::Model>(model->m);
        b->hand_model->params.dt = world->w.settings.dt;
        for (int i = 0; i < 3; ++i) b->hand_model->params.gravity[i] = world->w.settings.gravity[i];
        b->hand = std::make_unique<hh::Data>(*b->hand_model);
        set_surface(b->surface, surface_nodes, surface_weights, n_surface_vertices, faces, n_faces);
        b->has_surface = true;
        require_idle(world);
        *out_body = world->w.add(std::move(b));
        return HH_OK;
    });
}

int hh_world_add_soft_body(hh_world* world, const double* nodes, int n_nodes, const int* tets, int n_tets,
                           const hh_material* material, const int* fixed_nodes, int n_fixed, const int* surface_nodes,
                           const double* surface_weights, int n_surface_vertices, const int* faces, int n_faces,
                           double friction, int* out_body) {
    return guard([&] {
        require(world && material && out_body, "hh_world_add_soft_body: null pointer");
        require(material->struct_size == static_cast<int>(sizeof(hh_material)),
                "hh_material has the wrong size: rebuild the native library (make native)");
        require_finite_positive(material->young_modulus, "young_modulus", "a positive stiffness in Pa");
        require(std::isfinite(material->poisson_ratio) && material->poisson_ratio > 0 && material->poisson_ratio < 0.5,
                "poisson_ratio must be in (0, 0.5)");
        require_finite_positive(material->density, "density", "a positive density in kg/m^3");
        require(std::isfinite(material->rayleigh_alpha) && material->rayleigh_alpha >= 0 &&
                    std::isfinite(material->rayleigh_beta) && material->rayleigh_beta >= 0,
                "rayleigh_alpha and rayleigh_beta must be zero or positive");
        require_friction(friction);
        auto b = std::make_unique<hh::Body>();
        b->kind = hh::BodyKind::Soft;
        b->friction = friction;
        b->kinetic_friction = friction;
        b->flesh = std::make_unique<hh::Flesh>(hh::build_flesh(
            nodes, n_nodes, tets, n_tets,
            hh::Material{material->young_modulus, material->poisson_ratio, material->density}));
        b->alpha = material->rayleigh_alpha;
        b->beta = material->rayleigh_beta;
        hh::reset_flesh(*b->flesh, b->state);
        b->tool = std::make_unique<hh::DeformableSystem>();
        b->tool->configure(hh::DeformableSolver::Cholesky, 1e-8, 5000);
        b->tool->A = b->flesh->pattern.matrix;
        b->fixed.assign(n_nodes, 0);
        require(n_fixed == 0 || fixed_nodes, "fixed nodes: null array");
        for (int k = 0; k < n_fixed; ++k) {
            require(fixed_nodes[k] >= 0 && fixed_nodes[k] < n_nodes,
                    "fixed node " + std::to_string(fixed_nodes[k]) + " is not a node of the body");
            b->fixed[fixed_nodes[k]] = 1;
        }
        // entries of At in the rows or columns of fixed nodes, zeroed every step
        const hh::SpMat& pat = b->flesh->pattern.matrix;
        for (int col = 0; col < pat.outerSize(); ++col)
            for (int p = pat.outerIndexPtr()[col]; p < pat.outerIndexPtr()[col + 1]; ++p)
                if (b->fixed[col / 3] || b->fixed[pat.innerIndexPtr()[p] / 3]) b->fixed_entries.push_back(p);
        set_surface(b->surface, surface_nodes, surface_weights, n_surface_vertices, faces, n_faces);
        b->has_surface = true;
        require_idle(world);
        *out_body = world->w.add(std::move(b));
        return HH_OK;
    });
}

int hh_world_add_mesh_body(hh_world* world, int kind, const double* vertices, int n_vertices, const int* faces,
                           int n_faces, double density, double friction, int* out_body) {
    return guard([&] {
        require(world && vertices && faces && out_body, "hh_world_add_mesh_body: null pointer");
        require(kind == HH_BODY_RIGID || kind == HH_BODY_KINEMATIC || kind == HH_BODY_STATIC,
                "mesh body kind must be HH_BODY_RIGID, HH_BODY_KINEMATIC or HH_BODY_STATIC");
        require(n_vertices >= 3 && n_faces >= 1, "a mesh body needs at least one triangle");
        require_friction(friction);
        auto b = std::make_unique<hh::Body>();
        b->kind = kind == HH_BODY_RIGID ? hh::BodyKind::Rigid
                                        : (kind == HH_BODY_KINEMATIC ? hh::BodyKind::Kinematic : hh::BodyKind::Static);
        b->friction = friction;
        b->kinetic_friction = friction;
        std::vector<hh::Vec3> x(n_vertices);
        for (int v = 0; v < n_vertices; ++v) {
            x[v] = vec3(vertices + 3 * v);
            require(x[v].allFinite(), "mesh body vertex " + std::to_string(v) + " is not finite");
        }
        std::vector<Eigen::Vector3i> tris(n_faces);
        for (int t = 0; t < n_faces; ++t) {
            tris[t] = Eigen::Vector3i(faces[3 * t], faces[3 * t + 1], faces[3 * t + 2]);
            for (int k = 0; k < 3; ++k)
                require(tris[t][k] >= 0 && tris[t][k] < n_vertices,
                        "mesh body triangle " + std::to_string(t) + " refers to a vertex out of range");
        }
        hh::Vec3 com = hh::Vec3::Zero();
        if (kind == HH_BODY_RIGID) {
            require_finite_positive(density, "density", "a positive density in kg/m^3");
            hh::mesh_mass_properties(x, tris, density, b->mass, com, b->inertia_body);
            b->rigid_system = std::make_unique<hh::RigidSystem>();
        } else {
            for (const auto& p : x) com += p;
            com /= n_vertices;
        }
        b->rigid.x_com = com;
        b->target = b->rigid;
        b->local.resize(n_vertices);
        for (int v = 0; v < n_vertices; ++v) b->local[v] = x[v] - com;
        b->surface.triangles = tris;
        b->surface.nodes.resize(n_vertices);
        b->surface.weights.resize(n_vertices);
        for (int v = 0; v < n_vertices; ++v) {
            b->surface.nodes[v] = Eigen::Vector4i(v, 0, 0, 0);
            b->surface.weights[v] = hh::Vec4(1, 0, 0, 0);
        }
        b->has_surface = true;
        require_idle(world);
        *out_body = world->w.add(std::move(b));
        return HH_OK;
    });
}

int hh_world_add_plane(hh_world* world, const double point[3], const double normal[3], double friction, int* out_body) {
    return guard([&] {
        require(world && point && normal && out_body, "hh_world_add_plane: null pointer");
        require_friction(friction);
        const hh::Vec3 n = vec3(normal);
        require(n.allFinite() && n.norm() > 1e-12 && vec3(point).allFinite(), "plane point and normal must be finite, normal non-zero");
        auto b = std::make_unique<hh::Body>();
        b->kind = hh::BodyKind::Plane;
        b->friction = friction;
        b->kinetic_friction = friction;
        b->plane_point = vec3(point);
        b->plane_normal = n.normalized();
        require_idle(world);
        *out_body = world->w.add(std::move(b));
        return HH_OK;
    });
}

int hh_world_set_friction(hh_world* world, int body, double static_friction, double kinetic_friction) {
    return guard([&] {
        hh::Body& b = body_at(world, body);
        require_friction(static_friction);
        require_friction(kinetic_friction);
        require(kinetic_friction <= static_friction,
                "kinetic friction " + std::to_string(kinetic_friction) + " exceeds static friction " +
                    std::to_string(static_friction) + ": a sliding contact cannot hold more than a sticking one");
        b.friction = static_friction;
        b.kinetic_friction = kinetic_friction;
        return HH_OK;
    });
}

int hh_world_set_body_solver(hh_world* world, int body, int solver, double cg_tolerance, int cg_max_iterations) {
    return guard([&] {
        hh::Body& b = body_at(world, body);
        require(b.kind == hh::BodyKind::Soft,
                "only soft bodies take a solver here (the hand's is in its model parameters)");
        require(solver == HH_SOLVER_CHOLESKY || solver == HH_SOLVER_REUSED_CHOLESKY,
                "a soft body's solver is HH_SOLVER_CHOLESKY or HH_SOLVER_REUSED_CHOLESKY (got " + std::to_string(solver) +
                    "): conjugate gradient would solve every contact response on its own");
        require(std::isfinite(cg_tolerance) && cg_tolerance > 0 && cg_tolerance < 1,
                "cg_tolerance must be in (0, 1): the relative residual the reused factor's CG stops at, e.g. 1e-6");
        require(cg_max_iterations > 0, "cg_max_iterations must be positive");
        require_idle(world);
        b.tool->configure(solver == HH_SOLVER_REUSED_CHOLESKY ? hh::DeformableSolver::ReusedCholesky
                                                              : hh::DeformableSolver::Cholesky,
                          cg_tolerance, cg_max_iterations);
        b.carried_impulse.resize(0);
        return HH_OK;
    });
}

int hh_world_set_pose(hh_world* world, int body, const double position[3], const double quaternion[4],
                      const double velocity[3], const double angular_velocity[3]) {
    return guard([&] {
        hh::Body& b = body_at(world, body);
        require(b.kind == hh::BodyKind::Kinematic || b.kind == hh::BodyKind::Rigid || b.kind == hh::BodyKind::Hand,
                "only kinematic and free rigid bodies and the hand's handle have a pose to set");
        hh::RigidState& s = b.kind == hh::BodyKind::Kinematic ? b.target : b.kind == hh::BodyKind::Hand ? b.hand->h : b.rigid;
        hh::RigidState n = s;
        if (position) n.x_com = vec3(position);
        if (quaternion) n.q = hh::Vec4(quaternion[0], quaternion[1], quaternion[2], quaternion[3]);
        if (velocity) n.v_com = vec3(velocity);
        if (angular_velocity) n.omega = vec3(angular_velocity);
        require(n.x_com.allFinite() && n.q.allFinite() && n.q.norm() > 1e-12 && n.v_com.allFinite() && n.omega.allFinite(),
                "pose and velocity must be finite, the quaternion non-zero");
        n.q.normalize();
        s = n;
        return HH_OK;
    });
}

int hh_world_get_pose(const hh_world* world, int body, double position[3], double quaternion[4], double velocity[3],
                      double angular_velocity[3]) {
    return guard([&] {
        const hh::Body& b = body_at(world, body);
        require(b.kind == hh::BodyKind::Kinematic || b.kind == hh::BodyKind::Rigid || b.kind == hh::BodyKind::Static ||
                    b.kind == hh::BodyKind::Hand,
                "only mesh bodies and the hand's handle have a pose");
        const hh::RigidState& s = b.kind == hh::BodyKind::Hand ? b.hand->h : b.rigid;
        put3(s.x_com, position);
        if (quaternion) std::memcpy(quaternion, s.q.data(), 4 * sizeof(double));
        put3(s.v_com, velocity);
        put3(s.omega, angular_velocity);
        return HH_OK;
    });
}

int hh_world_set_device(hh_world* world, int hand_body, int enabled, const double position[3], const double quaternion[4],
                        const double velocity[3], const double angular_velocity[3]) {
    return guard([&] {
        hh::Body& b = body_at(world, hand_body);
        require(b.kind == hh::BodyKind::Hand, "the device drives the hand: give the hand's body index");
        b.hand->device = hh::capi::updated_device(b.hand->device, enabled, position, quaternion, velocity,
                                                  angular_velocity);
        return HH_OK;
    });
}

int hh_world_step(hh_world* world, hh_world_stats* out) {
    return guard([&] {
        require(world, "hh_world_step: null world");
        require_idle(world);
        world->w.step();
        return hh_world_last_stats(world, out);
    });
}

int hh_world_last_stats(const hh_world* world, hh_world_stats* out) {
    return guard([&] {
        require_idle(world);
        const hh::WorldStats& s = world->w.stats;
        if (out) {
            out->contacts = s.contacts;
            out->self_contacts = s.self_contacts;
            out->max_penetration = s.max_penetration;
            out->min_distance = s.min_distance;
            out->residual = s.residual;
            out->iterations = s.iterations;
            out->t_detection = s.t_detection;
            out->t_dynamics = s.t_dynamics;
            out->t_contact = s.t_contact;
            out->t_total = s.t_total;
        }
        return HH_OK;
    });
}

int hh_world_body_kind(const hh_world* world, int body, int* out_kind, int* out_n_nodes, int* out_n_surface_vertices) {
    return guard([&] {
        const hh::Body& b = body_at(world, body);
        if (out_kind) *out_kind = static_cast<int>(b.kind);
        if (out_n_nodes) *out_n_nodes = b.kind == hh::BodyKind::Hand ? b.hand_model->mesh.n_nodes
                                        : b.kind == hh::BodyKind::Soft ? b.flesh->mesh.n_nodes : 0;
        if (out_n_surface_vertices) *out_n_surface_vertices = b.has_surface ? b.surface.n_vertices() : 0;
        return HH_OK;
    });
}

int hh_world_body_nodes(const hh_world* world, int body, double* x, double* v, int n_nodes) {
    return guard([&] {
        const hh::Body& b = body_at(world, body);
        require(b.kind == hh::BodyKind::Hand || b.kind == hh::BodyKind::Soft, "only hand and soft bodies have nodes");
        const hh::FleshState& s = b.kind == hh::BodyKind::Hand ? static_cast<const hh::FleshState&>(*b.hand) : b.state;
        require_size(n_nodes, static_cast<int>(s.x.size() / 3), "body nodes");
        if (x) std::copy(s.x.data(), s.x.data() + s.x.size(), x);
        if (v) std::copy(s.v.data(), s.v.data() + s.v.size(), v);
        return HH_OK;
    });
}

int hh_world_set_body_nodes(hh_world* world, int body, const double* x, const double* v, int n_nodes) {
    return guard([&] {
        hh::Body& b = body_at(world, body);
        require(b.kind == hh::BodyKind::Hand || b.kind == hh::BodyKind::Soft, "only hand and soft bodies have nodes");
        hh::FleshState& s = b.kind == hh::BodyKind::Hand ? static_cast<hh::FleshState&>(*b.hand) : b.state;
        require_size(n_nodes, static_cast<int>(s.x.size() / 3), "body nodes");
        const Eigen::Map<const hh::VecX> nx(x ? x : s.x.data(), s.x.size()), nv(v ? v : s.v.data(), s.v.size());
        require(nx.allFinite() && nv.allFinite(), "node positions and velocities must be finite");
        s.x = nx;
        s.v = nv;
        b.carried_impulse.resize(0);  // (the last step's impulses were on another state)
        return HH_OK;
    });
}

int hh_world_surface_positions(const hh_world* world, int body, double* x, int n_vertices) {
    return guard([&] {
        const hh::Body& b = body_at(world, body);
        require(b.has_surface && x, "this body has no collision surface");
        require_size(n_vertices, b.surface.n_vertices(), "surface vertices");
        for (int v = 0; v < n_vertices; ++v) put3(b.surface.x[v], x + 3 * v);
        return HH_OK;
    });
}

int hh_world_contact_force(const hh_world* world, int body, double force[3]) {
    return guard([&] {
        put3(body_at(world, body).contact_force, force);
        return HH_OK;
    });
}

int hh_world_hand_state(const hh_world* world, int hand_body, double handle_position[3], double handle_quaternion[4],
                        double force[3], double torque[3]) {
    return guard([&] {
        const hh::Body& b = body_at(world, hand_body);
        require(b.kind == hh::BodyKind::Hand, "not the hand's body index");
        const hh::Model& m = *b.hand_model;
        const hh::Data& d = *b.hand;
        put3(d.h.x_com, handle_position);
        if (handle_quaternion) std::memcpy(handle_quaternion, d.h.q.data(), 4 * sizeof(double));
        hh::Vec3 f, t;
        hh::coupling_wrench(m, d, f, t);
        put3(f, force);
        put3(t, torque);
        return HH_OK;
    });
}

int hh_world_hand_step_stats(const hh_world* world, int hand_body, hh_step_stats* out) {
    return guard([&] {
        const hh::Body& b = body_at(world, hand_body);
        require(b.kind == hh::BodyKind::Hand && out, "not the hand's body index, or a null output");
        *out = b.hand->stats;
        return HH_OK;
    });
}

int hh_world_linear_momentum(const hh_world* world, double out[3]) {
    return guard([&] {
        require(world && out, "hh_world_linear_momentum: null pointer");
        hh::Vec3 p = hh::Vec3::Zero();
        for (const auto& bp : world->w.bodies) {
            const hh::Body& b = *bp;
            if (b.kind == hh::BodyKind::Hand) {
                p += b.hand_model->handle.mass * b.hand->h.v_com;
                for (int i = 0; i < b.hand_model->mesh.n_nodes; ++i) p += b.hand_model->masses[i] * b.hand->v.segment<3>(3 * i);
            } else if (b.kind == hh::BodyKind::Soft) {
                for (int i = 0; i < b.flesh->mesh.n_nodes; ++i) p += b.flesh->masses[i] * b.state.v.segment<3>(3 * i);
            } else if (b.kind == hh::BodyKind::Rigid) {
                p += b.mass * b.rigid.v_com;
            }
        }
        put3(p, out);
        return HH_OK;
    });
}

}  // extern "C"
