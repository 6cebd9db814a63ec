#include "sim/body.h"

#include <algorithm>
#include <cmath>

#include "rigid/quaternion.h"

namespace hh {

int Body::dofs() const {
    switch (kind) {
        case BodyKind::Hand: return handle_dofs() + 3 * hand_model->mesh.n_nodes;
        case BodyKind::Soft: return 3 * soft.flesh->mesh.n_nodes;
        case BodyKind::Rigid: return 6;
        default: return 0;
    }
}

DeformableSystem* Body::response_system() {
    return const_cast<DeformableSystem*>(static_cast<const Body&>(*this).response_system());
}

const DeformableSystem* Body::response_system() const {
    if (kind == BodyKind::Soft) return soft.tool.get();
    if (kind == BodyKind::Hand) return &hand->hand.tool;
    return nullptr;
}

void Body::update_points() {
    switch (kind) {
        case BodyKind::Hand:
        case BodyKind::Soft: {
            const VecX& x = kind == BodyKind::Hand ? hand->x : soft.state.x;
            points.resize(x.size() / 3);
            for (size_t i = 0; i < points.size(); ++i) points[i] = x.segment<3>(3 * i);
            break;
        }
        case BodyKind::Rigid:
        case BodyKind::Kinematic:
        case BodyKind::Static: {
            const Mat3 r = quat_to_matrix(mesh.state.q);
            points.resize(mesh.local.size());
            for (size_t i = 0; i < mesh.local.size(); ++i) points[i] = mesh.state.x_com + r * mesh.local[i];
            break;
        }
        case BodyKind::Plane: break;
    }
}

void Body::update_surface_positions() {
    if (!has_surface) return;
    for (int v = 0; v < surface.n_vertices(); ++v) {
        Vec3 p = Vec3::Zero();
        for (int k = 0; k < 4; ++k)
            if (surface.weights[v][k] != 0) p += surface.weights[v][k] * points[surface.nodes[v][k]];
        surface.x[v] = p;
    }
}

namespace {
// m: the farthest of `points` from `centre`
double farthest(const std::vector<Vec3>& points, const Vec3& centre) {
    double arm = 0;
    for (const Vec3& p : points) arm = std::max(arm, (p - centre).norm());
    return arm;
}

// m: how far a point at most `arm` from the centre moves when the pose goes from (x0, q0) to
// (x1, q1), seen from a frame that moves by `shift` meanwhile: the centre's displacement less
// the shift, plus the arc of the rotation between them
double pose_travel(const Vec3& x0, const Vec4& q0, const Vec3& x1, const Vec4& q1, double arm, const Vec3& shift) {
    const double angle = quat_to_rotation_vector(quat_multiply(q1, quat_conjugate(q0))).norm();
    return (x1 - x0 - shift).norm() + angle * arm;
}

// m/s: the fastest node's speed relative to `frame`
double fastest_node(const VecX& v, const Vec3& frame) {
    double speed = 0;
    for (Eigen::Index k = 0; k + 2 < v.size(); k += 3) speed = std::max(speed, (v.segment<3>(k) - frame).squaredNorm());
    return std::sqrt(speed);
}

Vec3 mean_node(const VecX& v) {
    Vec3 sum = Vec3::Zero();
    for (Eigen::Index k = 0; k + 2 < v.size(); k += 3) sum += v.segment<3>(k);
    return v.size() >= 3 ? Vec3(sum / static_cast<double>(v.size() / 3)) : Vec3(Vec3::Zero());
}
}  // namespace

// m: how far the points bone b carries move in the step of dt (relative to `frame`, m/s): the
// palm handle carries the whole hand (its arm reaches every point); a bone of a skeleton its own
// nodes, each of which is carried further by its parent's motion only through that parent's own
// target
double Body::bone_travel(int b, double dt, const Vec3& frame) const {
    const HandleState& h = bone_state(*hand, b);
    const DeviceFrame& d = bone_target(*hand, b);
    double arm = 0;
    if (!skeleton()) arm = farthest(points, h.x_com);
    else for (int i : hand_model->skeleton.bones[b].nodes) arm = std::max(arm, (points[i] - h.x_com).norm());
    double travel = ((h.v_com - frame).norm() + h.omega.norm() * arm) * dt;
    if (d.enabled) {  // the bone goes to its target's pose (prescribed) or is pulled toward it
        travel = std::max(travel, pose_travel(h.x_com, h.q, d.position, d.quaternion, arm, frame * dt));
        travel = std::max(travel, ((d.velocity - frame).norm() + d.angular_velocity.norm() * arm) * dt);
    }
    return travel;
}

// Bounds from what the step knows before it starts. Start-of-step velocities alone miss what
// is driven: a scripted pusher or a prescribed handle that is still at the start of a fast
// move, or a hand whose device has jumped away; their end-of-step targets are known already.
double Body::step_travel(double dt, const Vec3& frame) const {
    switch (kind) {
        case BodyKind::Soft: return fastest_node(soft.state.v, frame) * dt;
        case BodyKind::Hand: {
            double travel = fastest_node(hand->v, frame) * dt;
            for (int b = 0; b < hand_model->n_bones(); ++b) travel = std::max(travel, bone_travel(b, dt, frame));
            return travel;
        }
        case BodyKind::Rigid: {
            const double arm = farthest(mesh.local, Vec3::Zero());
            return ((mesh.state.v_com - frame).norm() + mesh.state.omega.norm() * arm) * dt;
        }
        case BodyKind::Kinematic: {
            const double arm = farthest(mesh.local, Vec3::Zero());
            const double moving = ((mesh.state.v_com - frame).norm() + mesh.state.omega.norm() * arm) * dt;
            return std::max(moving, pose_travel(mesh.state.x_com, mesh.state.q, mesh.target.x_com, mesh.target.q, arm, frame * dt));
        }
        default: return frame.norm() * dt;  // (planes and static meshes stand still)
    }
}

Vec3 Body::drift() const {
    switch (kind) {
        case BodyKind::Soft: return mean_node(soft.state.v);
        case BodyKind::Hand: return mean_node(hand->v);
        case BodyKind::Rigid:
        case BodyKind::Kinematic: return mesh.state.v_com;
        default: return Vec3::Zero();
    }
}

void SoftParts::solve_free(double dt, const Vec3& gravity, const VecX& carried, VecX& v_free, bool take_out_carried) {
    const int n3 = 3 * flesh->mesh.n_nodes;
    rhs.resize(n3);
    formulate_flesh(*flesh, state, dt, gravity, alpha, beta, *tool, rhs);
    // fixed nodes: identity rows and columns, zero right-hand side (velocity 0)
    double* values = tool->A.valuePtr();
    for (int off : fixed_entries) values[off] = 0;
    for (int i = 0; i < flesh->mesh.n_nodes; ++i)
        if (fixed[i]) {
            add_node_block(*flesh, i, Mat3::Identity(), values);
            rhs.segment<3>(3 * i).setZero();
        }
    // On the reused factor, as the hand's (World::solve_free): the last step's contact impulses
    // f in the free solve, and P f taken out again, so that only their change sees the lag
    tool->r = rhs;
    if (carried.size()) {
        tool->set_reference_norm(0, rhs.norm());
        tool->r += carried;
    }
    tool->select_slot(0);
    tool->solve();
    v_free = tool->s;
    if (carried.size() && take_out_carried) {
        VecX response;
        tool->solve_response_single(carried, response);
        v_free -= response;
    }
}

void SoftParts::integrate(const VecX& v, double dt) {
    state.v = v;
    for (int i = 0; i < flesh->mesh.n_nodes; ++i)
        if (fixed[i]) state.v.segment<3>(3 * i).setZero();
    state.x += dt * state.v;
}

void MeshParts::solve_free(double dt, const Vec3& gravity, VecX& v_free) const {
    const Mat3 r = quat_to_matrix(state.q);
    const Mat3 inertia = r * inertia_body * r.transpose();
    RigidSystem& rs = *system;
    rs.A.setZero();
    rs.A.topLeftCorner<3, 3>() = mass * Mat3::Identity();
    rs.A.bottomRightCorner<3, 3>() = inertia;
    rs.r.head<3>() = mass * (state.v_com + dt * gravity);
    rs.r.tail<3>() = inertia * state.omega - dt * state.omega.cross(inertia * state.omega);
    rs.solve();
    v_free = rs.s;
}

void MeshParts::integrate(const VecX& v, double dt) {
    state.v_com = v.head<3>();
    state.omega = v.tail<3>();
    state.x_com += dt * state.v_com;
    state.q = quat_multiply(quat_from_rotation_vector(dt * state.omega), state.q).normalized();
}

void mesh_mass_properties(const std::vector<Vec3>& x, const std::vector<Eigen::Vector3i>& triangles, double density,
                          double& mass, Vec3& com, Mat3& inertia) {
    double volume = 0;
    Vec3 first = Vec3::Zero();
    Mat3 second = Mat3::Zero();  // integral of x x^T over the solid
    for (const auto& t : triangles) {
        const Vec3 &a = x[t[0]], &b = x[t[1]], &c = x[t[2]];
        const double v = a.dot(b.cross(c)) / 6.0;  // tet (0, a, b, c)
        const Vec3 s = a + b + c;
        volume += v;
        first += v * s / 4.0;
        second += v / 20.0 * (a * a.transpose() + b * b.transpose() + c * c.transpose() + s * s.transpose());
    }
    if (!(volume > 0))
        throw InvalidArgument("the rigid body's mesh encloses no positive volume: it must be closed and wound outward");
    mass = density * volume;
    com = first / volume;
    const Mat3 central = density * (second - volume * com * com.transpose());
    inertia = central.trace() * Mat3::Identity() - central;
}

}  // namespace hh
