// The C ABI of worlds (scenes with contact). Same rules as capi.cpp: guard() around every body.
#include <cmath>
#include <memory>

#include "capi/guard.h"
#include "params/table.h"
#include "rigid/quaternion.h"

using hh::capi::guard;
using hh::capi::put3;
using hh::capi::require;
using hh::capi::require_size;
using hh::capi::vec3;

namespace {

void require_idle(const hh_world* world) {
    require(world != nullptr, "null world");
    require(!world->in_live_session(),
            "a live haptic session is stepping this world: read it through the session, or stop the session first");
}

hh::Body& body_at(hh_world* world, int body) {
    require_idle(world);
    require(body >= 0 && body < static_cast<int>(world->w.bodies.size()),
            "body index " + std::to_string(body) + " does not exist in this world");
    return *world->w.bodies[body];
}
const hh::Body& body_at(const hh_world* world, int body) { return body_at(const_cast<hh_world*>(world), body); }

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

// A body's Coulomb coefficient, checked against the table's row of the body (or the hand).
void require_friction(double friction, bool hand = false) {
    hh::params::check(hand ? "hand.friction" : "bodies[].friction", friction);
}

// HH_SOLVER_AUTO's rule: the per-step factor (exact to round-off) for a soft body of fewer tets
// than this, the reused factor from here on. On a soft block resting on the ground
// (bench/bench_soft_solver.py) both cost under ~1 ms a frame at 384 tets and the reused factor
// took 0.21x the per-step factor's time at 2058 tets and 0.07x at 20250.
constexpr int kReusedFactorFromTets = 1000;

// The soft-body solver a C code names (auto: by the body's tet count).
hh::DeformableSolver soft_solver(int solver, int n_tets) {
    if (solver == HH_SOLVER_AUTO) solver = n_tets >= kReusedFactorFromTets ? HH_SOLVER_REUSED_CHOLESKY : HH_SOLVER_CHOLESKY;
    return solver == HH_SOLVER_REUSED_CHOLESKY ? hh::DeformableSolver::ReusedCholesky : hh::DeformableSolver::Cholesky;
}

}  // namespace

extern "C" {

int hh_world_create(const hh_world_params* p, hh_world** out) {
    return guard([&] {
        require(p && out, "hh_world_create: null pointer");
        *out = nullptr;
        hh::params::validate(HH_STRUCT_WORLD_PARAMS, p);
        const hh::WorldSettings s(*p);
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
        require_friction(friction, true);
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
        require(n_nodes >= 4 && n_tets >= 1 && n_fixed >= 0 && n_surface_vertices >= 0 && n_faces >= 0,
                "hh_world_add_soft_body: a soft body needs at least 4 nodes and 1 tet, and no count may be negative");
        hh::params::validate(HH_STRUCT_MATERIAL, material);
        require_friction(friction);
        auto b = std::make_unique<hh::Body>();
        b->kind = hh::BodyKind::Soft;
        b->friction = friction;
        b->kinetic_friction = friction;
        b->soft.flesh = std::make_unique<hh::Flesh>(hh::build_flesh(
            nodes, n_nodes, tets, n_tets,
            hh::Material{material->young_modulus, material->poisson_ratio, material->density}));
        b->soft.alpha = material->rayleigh_alpha;
        b->soft.beta = material->rayleigh_beta;
        hh::reset_flesh(*b->soft.flesh, b->soft.state);
        b->soft.tool = std::make_unique<hh::DeformableSystem>();
        b->soft.tool->configure(soft_solver(static_cast<int>(hh::params::row("bodies[].solver.name").default_value[0]),
                                            n_tets),
                                hh::params::row("bodies[].solver.cg_tolerance").default_value[0],
                                static_cast<int>(hh::params::row("bodies[].solver.cg_max_iterations").default_value[0]));
        b->soft.tool->A = b->soft.flesh->pattern.matrix;
        b->soft.fixed.assign(n_nodes, 0);
        require(n_fixed == 0 || fixed_nodes, "fixed nodes: null array");
        for (int k = 0; k < n_fixed; ++k) {
            require(fixed_nodes[k] >= 0 && fixed_nodes[k] < n_nodes,
                    "fixed node " + std::to_string(fixed_nodes[k]) + " is not a node of the body");
            b->soft.fixed[fixed_nodes[k]] = 1;
        }
        // entries of At in the rows or columns of fixed nodes, zeroed every step
        const hh::SpMat& pat = b->soft.flesh->pattern.matrix;
        for (int col = 0; col < pat.outerSize(); ++col)
            for (int p = pat.outerIndexPtr()[col]; p < pat.outerIndexPtr()[col + 1]; ++p)
                if (b->soft.fixed[col / 3] || b->soft.fixed[pat.innerIndexPtr()[p] / 3]) b->soft.fixed_entries.push_back(p);
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
            hh::params::check("bodies[].density", density);
            hh::mesh_mass_properties(x, tris, density, b->mesh.mass, com, b->mesh.inertia_body);
            b->mesh.system = std::make_unique<hh::RigidSystem>();
        } else {
            for (const auto& p : x) com += p;
            com /= n_vertices;
        }
        b->mesh.state.x_com = com;
        b->mesh.target = b->mesh.state;
        b->mesh.local.resize(n_vertices);
        for (int v = 0; v < n_vertices; ++v) b->mesh.local[v] = x[v] - com;
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
        b->plane.point = vec3(point);
        b->plane.normal = n.normalized();
        require_idle(world);
        *out_body = world->w.add(std::move(b));
        return HH_OK;
    });
}

int hh_world_set_friction(hh_world* world, int body, double static_friction, double kinetic_friction) {
    return guard([&] {
        hh::Body& b = body_at(world, body);
        require_friction(static_friction, b.kind == hh::BodyKind::Hand);
        hh::params::check(b.kind == hh::BodyKind::Hand ? "hand.kinetic_friction" : "bodies[].kinetic_friction",
                          kinetic_friction);
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
        hh::params::check("bodies[].solver.name", solver);
        require(solver != HH_SOLVER_CG, "bodies[].solver.name = cg is invalid for a soft body: use cholesky or "
                                        "reused_cholesky (conjugate gradient would solve every contact response "
                                        "on its own)");
        hh::params::check("bodies[].solver.cg_tolerance", cg_tolerance);
        hh::params::check("bodies[].solver.cg_max_iterations", cg_max_iterations);
        require_idle(world);
        b.soft.tool->configure(soft_solver(solver, static_cast<int>(b.soft.flesh->mesh.tets.size())), cg_tolerance,
                               cg_max_iterations);
        b.soft.tool->analyse_ahead();
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
        hh::RigidState& s = b.kind == hh::BodyKind::Kinematic ? b.mesh.target : b.kind == hh::BodyKind::Hand ? b.hand->h : b.mesh.state;
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
        const hh::RigidState& s = b.kind == hh::BodyKind::Hand ? b.hand->h : b.mesh.state;
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
                                        : b.kind == hh::BodyKind::Soft ? b.soft.flesh->mesh.n_nodes : 0;
        if (out_n_surface_vertices) *out_n_surface_vertices = b.has_surface ? b.surface.n_vertices() : 0;
        return HH_OK;
    });
}

int hh_world_body_nodes(const hh_world* world, int body, double* x, double* v, int n_nodes) {
    return guard([&] {
        const hh::Body& b = body_at(world, body);
        require(b.kind == hh::BodyKind::Hand || b.kind == hh::BodyKind::Soft, "only hand and soft bodies have nodes");
        const hh::FleshState& s = b.kind == hh::BodyKind::Hand ? static_cast<const hh::FleshState&>(*b.hand) : b.soft.state;
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
        hh::FleshState& s = b.kind == hh::BodyKind::Hand ? static_cast<hh::FleshState&>(*b.hand) : b.soft.state;
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
                for (int i = 0; i < b.soft.flesh->mesh.n_nodes; ++i) p += b.soft.flesh->masses[i] * b.soft.state.v.segment<3>(3 * i);
            } else if (b.kind == hh::BodyKind::Rigid) {
                p += b.mesh.mass * b.mesh.state.v_com;
            }
        }
        put3(p, out);
        return HH_OK;
    });
}

}  // extern "C"
