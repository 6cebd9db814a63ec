#include "sim/world.h"

#include <chrono>
#include <cmath>
#include <limits>
#include <map>

#include "rigid/quaternion.h"

namespace hh {

namespace {
// Identity of a contact across steps: its sides' bodies and first vertices (a vertex against
// a body keeps its identity when the closest triangle changes).
std::uint64_t contact_key(const Contact& c) {
    std::uint64_t h = 1469598103934665603ull;
    auto mix = [&](std::uint64_t v) { h = (h ^ v) * 1099511628211ull; };
    mix(static_cast<std::uint64_t>(c.a.body));
    mix(static_cast<std::uint64_t>(c.a.count));
    for (int k = 0; k < c.a.count; ++k) mix(static_cast<std::uint64_t>(c.a.vertex[k]));
    mix(static_cast<std::uint64_t>(c.b.body) + 7919);
    if (c.b.count == 2)
        for (int k = 0; k < 2; ++k) mix(static_cast<std::uint64_t>(c.b.vertex[k]));
    return h;
}

double seconds_since(std::chrono::steady_clock::time_point t0) {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

// Velocity unknowns of a body where a point of the surface (source point `node`) takes part:
// flesh nodes map to 3 unknowns; a rigid body's point maps to (v, omega) through r x u.
struct PointJacobian {
    int offset;   // first unknown of the node (flesh) or 0 (rigid)
    bool rigid;
    Vec3 r;       // rigid: the point relative to the centre of mass
};

// Kinematic and static bodies: the velocity of a world point carried by the body.
Vec3 carried_velocity(const Body& b, const Vec3& x) {
    if (b.kind != BodyKind::Kinematic) return Vec3::Zero();
    return b.rigid.v_com + b.rigid.omega.cross(x - b.rigid.x_com);
}
}  // namespace

int Body::dofs() const {
    switch (kind) {
        case BodyKind::Hand: return 6 + 3 * hand_model->mesh.n_nodes;
        case BodyKind::Soft: return 3 * flesh->mesh.n_nodes;
        case BodyKind::Rigid: return 6;
        default: return 0;
    }
}

World::World(const WorldSettings& s) : settings(s) {}

int World::add(std::unique_ptr<Body> body) {
    bodies.push_back(std::move(body));
    Body& b = *bodies.back();
    update_points(b);
    if (b.has_surface) {
        init_surface(b.surface, static_cast<int>(b.points.size()));
        const double rest_reach = 2 * settings.contact_thickness;
        update_surface(b.surface, b.points, rest_reach);
        if (b.self_collision) b.self_exclusions = rest_exclusions(b.surface, DetectionSettings{rest_reach});
    }
    return static_cast<int>(bodies.size() - 1);
}

void World::update_points(Body& b) {
    switch (b.kind) {
        case BodyKind::Hand:
        case BodyKind::Soft: {
            const VecX& x = b.kind == BodyKind::Hand ? b.hand->x : b.state.x;
            b.points.resize(x.size() / 3);
            for (size_t i = 0; i < b.points.size(); ++i) b.points[i] = x.segment<3>(3 * i);
            break;
        }
        case BodyKind::Rigid:
        case BodyKind::Kinematic:
        case BodyKind::Static: {
            const Mat3 r = quat_to_matrix(b.rigid.q);
            b.points.resize(b.local.size());
            for (size_t i = 0; i < b.local.size(); ++i) b.points[i] = b.rigid.x_com + r * b.local[i];
            break;
        }
        case BodyKind::Plane: break;
    }
}

void World::detect() {
    // fast surfaces may close more than the thickness within a step: look that much further
    double speed = 0;
    for (const auto& bp : bodies) {
        const Body& b = *bp;
        if (b.kind == BodyKind::Hand) speed = std::max(speed, b.hand->v.cwiseAbs().maxCoeff());
        if (b.kind == BodyKind::Soft) speed = std::max(speed, b.state.v.cwiseAbs().maxCoeff());
        if (b.kind == BodyKind::Rigid || b.kind == BodyKind::Kinematic)
            speed = std::max(speed, b.rigid.v_com.norm() + b.rigid.omega.norm() * 0.5);
    }
    // Resting contacts settle at exactly the thickness: look half a thickness further so they
    // are found every step instead of flickering in and out at the edge of the reach.
    const double reach = 1.5 * settings.contact_thickness + std::min(speed * settings.dt, 2 * settings.contact_thickness);
    for (auto& bp : bodies) {
        update_points(*bp);
        if (bp->has_surface) update_surface(bp->surface, bp->points, reach);
    }
    contacts.clear();
    const DetectionSettings ds{reach};
    for (size_t i = 0; i < bodies.size(); ++i) {
        Body& a = *bodies[i];
        if (a.dynamic() && a.has_surface && a.self_collision)
            detect_self(a.surface, static_cast<int>(i), ds, &a.self_exclusions, contacts);
        for (size_t j = 0; j < bodies.size(); ++j) {
            if (j == i) continue;
            Body& b = *bodies[j];
            if (!a.dynamic() || !a.has_surface) continue;
            if (b.kind == BodyKind::Plane) {
                detect_plane(a.surface, static_cast<int>(i), b.plane_point, b.plane_normal, static_cast<int>(j), ds, contacts);
            } else if (b.has_surface && (j > i || !b.dynamic())) {
                detect_pair(a.surface, static_cast<int>(i), b.surface, static_cast<int>(j), ds, contacts);
            }
        }
    }
}

void World::reduce_contacts() {
    // Keep, per pair of bodies and per patch cell, the deepest contact whose normal points the
    // same way (octant of the normal), so two sides of a thin part stay apart. A large contact
    // area then costs a bounded number of constraints; the dropped pairs are within a patch of
    // a kept one and are still measured in the statistics.
    detected.swap(contacts);
    contacts.clear();
    std::unordered_map<std::uint64_t, int> best;
    const double h = settings.contact_patch;
    for (const Contact& c : detected) {
        std::uint64_t key = 1469598103934665603ull;
        auto mix = [&](std::int64_t v) { key = (key ^ static_cast<std::uint64_t>(v)) * 1099511628211ull; };
        mix(c.a.body);
        mix(c.b.body);
        mix((c.normal.x() > 0) | ((c.normal.y() > 0) << 1) | ((c.normal.z() > 0) << 2));
        // one contact per patch cell and element of the side-a body that carries the contact
        // point: a fine embedded surface moves only as its elements do
        const Body& a = *bodies[c.a.body];
        if (a.kind == BodyKind::Hand || a.kind == BodyKind::Soft) {
            const Eigen::Vector4i& element = a.surface.nodes[c.a.vertex[0]];
            for (int k = 0; k < 4; ++k) mix(element[k]);
        }
        for (int d = 0; d < 3; ++d) mix(static_cast<std::int64_t>(std::floor(c.point[d] / h)));
        auto it = best.find(key);
        if (it == best.end()) {
            best[key] = static_cast<int>(contacts.size());
            contacts.push_back(c);
        } else if (c.distance < contacts[it->second].distance) {
            contacts[it->second] = c;
        }
    }
}

void World::solve_free() {
    const double dt = settings.dt;
    for (auto& bp : bodies) {
        Body& b = *bp;
        switch (b.kind) {
            case BodyKind::Hand: {
                const auto t0 = std::chrono::steady_clock::now();
                formulate(*b.hand_model, *b.hand);
                hh_step_stats& st = b.hand->stats;
                st = hh_step_stats{};
                st.t_assembly = seconds_since(t0);
                b.hand->tool.reset_counters();
                b.hand->hand.solve();
                st.t_deformable = b.hand->hand.t_deformable;
                st.t_schur = b.hand->hand.t_schur;
                st.cg_iterations = b.hand->tool.iterations;
                st.max_residual = b.hand->tool.max_residual;
                st.t_total = seconds_since(t0);
                b.v_free = b.hand->hand.s;
                break;
            }
            case BodyKind::Soft: {
                const int n3 = 3 * b.flesh->mesh.n_nodes;
                b.soft_rhs.resize(n3);
                formulate_flesh(*b.flesh, b.state, dt, settings.gravity, b.alpha, b.beta, *b.tool, b.soft_rhs);
                // fixed nodes: identity rows and columns, zero right-hand side (velocity 0)
                double* values = b.tool->A.valuePtr();
                for (int off : b.fixed_entries) values[off] = 0;
                for (int i = 0; i < b.flesh->mesh.n_nodes; ++i)
                    if (b.fixed[i]) {
                        add_node_block(*b.flesh, i, Mat3::Identity(), values);
                        b.soft_rhs.segment<3>(3 * i).setZero();
                    }
                b.tool->r = b.soft_rhs;
                b.tool->select_slot(0);
                b.tool->solve();
                b.v_free = b.tool->s;
                break;
            }
            case BodyKind::Rigid: {
                const Mat3 r = quat_to_matrix(b.rigid.q);
                const Mat3 inertia = r * b.inertia_body * r.transpose();
                RigidSystem& rs = *b.rigid_system;
                rs.A.setZero();
                rs.A.topLeftCorner<3, 3>() = b.mass * Mat3::Identity();
                rs.A.bottomRightCorner<3, 3>() = inertia;
                rs.r.head<3>() = b.mass * (b.rigid.v_com + dt * settings.gravity);
                rs.r.tail<3>() = inertia * b.rigid.omega - dt * b.rigid.omega.cross(inertia * b.rigid.omega);
                rs.solve();
                b.v_free = rs.s;
                break;
            }
            default: b.v_free.resize(0);
        }
        b.v_new = b.v_free;
        b.contact_force.setZero();
    }
}

void World::solve_contacts() {
    const int nc = static_cast<int>(contacts.size());
    contact_W.resize(0, 0);
    contact_lambda.resize(0);
    contact_friction.resize(0);
    contact_columns.clear();
    if (nc == 0) {
        previous_impulse.clear();
        return;
    }
    const int rows = 3 * nc;
    // every (body, row) pair: the sparse Jacobian row as (unknown offset, coefficient) terms
    struct Term {
        int offset;
        double weight;
        bool rigid;
        Vec3 r;
    };
    std::map<int, std::vector<std::vector<Term>>> terms;  // body -> contact -> side terms
    auto side_terms = [&](const ContactSide& side, double sign) {
        std::vector<Term> out;
        const Body& b = *bodies[side.body];
        for (int k = 0; k < side.count; ++k) {
            const int v = side.vertex[k];
            if (b.kind == BodyKind::Rigid) {
                out.push_back({0, sign * side.weight[k], true, b.surface.x[v] - b.rigid.x_com});
            } else {
                const int base = b.kind == BodyKind::Hand ? 6 : 0;
                for (int s = 0; s < 4; ++s)
                    if (b.surface.weights[v][s] != 0)
                        out.push_back({base + 3 * b.surface.nodes[v][s], sign * side.weight[k] * b.surface.weights[v][s], false, Vec3::Zero()});
            }
        }
        return out;
    };
    std::vector<int> involved;
    for (int c = 0; c < nc; ++c)
        for (int s = 0; s < 2; ++s) {
            const ContactSide& side = s == 0 ? contacts[c].a : contacts[c].b;
            if (side.body < 0 || !bodies[side.body]->dynamic()) continue;
            auto& per_body = terms[side.body];
            if (per_body.empty()) {
                per_body.resize(nc);
                involved.push_back(side.body);
            }
            auto t = side_terms(side, s == 0 ? 1.0 : -1.0);
            per_body[c].insert(per_body[c].end(), t.begin(), t.end());
        }
    auto direction = [&](int row) -> const Vec3& {
        const Contact& c = contacts[row / 3];
        return row % 3 == 0 ? c.normal : (row % 3 == 1 ? c.tangent1 : c.tangent2);
    };
    auto scatter = [&](const std::vector<Term>& ts, const Vec3& u, VecX& out) {
        for (const Term& t : ts) {
            if (t.rigid) {
                out.head<3>() += t.weight * u;
                out.tail<3>() += t.weight * t.r.cross(u);
            } else {
                out.segment<3>(t.offset) += t.weight * u;
            }
        }
    };
    auto gather = [&](const std::vector<Term>& ts, const Vec3& u, const VecX& y) {
        double sum = 0;
        for (const Term& t : ts)
            sum += t.rigid ? t.weight * (u.dot(y.head<3>()) + t.r.cross(u).dot(y.tail<3>()))
                           : t.weight * u.dot(y.segment<3>(t.offset));
        return sum;
    };

    ContactProblem prob;
    prob.dt = settings.dt;
    prob.W = MatX::Zero(rows, rows);
    prob.u_free = VecX::Zero(rows);
    prob.gap.resize(nc);
    prob.friction.resize(nc);
    prob.kinetic.resize(nc);
    for (int c = 0; c < nc; ++c) {
        const Contact& k = contacts[c];
        prob.gap[c] = k.distance - settings.contact_thickness;
        const double mu_a = bodies[k.a.body]->friction, mu_b = bodies[k.b.body]->friction;
        prob.friction[c] = std::sqrt(mu_a * mu_b);
        prob.kinetic[c] = std::sqrt(bodies[k.a.body]->kinetic_friction * bodies[k.b.body]->kinetic_friction);
        // kinematic bodies' motion enters as a known relative velocity
        for (int s = 0; s < 2; ++s) {
            const ContactSide& side = s == 0 ? k.a : k.b;
            const Body& b = *bodies[side.body];
            if (b.kind != BodyKind::Kinematic) continue;
            const Vec3 p = side.count > 0 ? side.point(b.surface) : k.point;
            const Vec3 vel = carried_velocity(b, p);
            for (int d = 0; d < 3; ++d) prob.u_free[3 * c + d] += (s == 0 ? 1.0 : -1.0) * direction(3 * c + d).dot(vel);
        }
    }
    // columns A_b^-1 J_b^T, one black-box solve per row a body takes part in
    std::map<int, std::vector<VecX>> columns;
    for (int bi : involved) {
        Body& b = *bodies[bi];
        auto& cols = columns[bi];
        cols.assign(rows, VecX());
        const auto& bt = terms[bi];
        for (int row = 0; row < rows; ++row) {
            const auto& ts = bt[row / 3];
            if (ts.empty()) continue;
            VecX rhs = VecX::Zero(b.dofs());
            scatter(ts, direction(row), rhs);
            switch (b.kind) {
                case BodyKind::Hand: cols[row] = b.hand->hand.apply_inverse(rhs); break;
                case BodyKind::Soft:
                    for (int i = 0; i < b.flesh->mesh.n_nodes; ++i)
                        if (b.fixed[i]) rhs.segment<3>(3 * i).setZero();
                    b.tool->r = rhs;
                    b.tool->select_slot(1 + row % 3);
                    b.tool->solve();
                    cols[row] = b.tool->s;
                    break;
                default:
                    b.rigid_system->r = rhs;
                    b.rigid_system->solve();
                    cols[row] = b.rigid_system->s;
            }
        }
        for (int row = 0; row < rows; ++row) {
            const auto& ts = bt[row / 3];
            if (ts.empty()) continue;
            prob.u_free[row] += gather(ts, direction(row), b.v_free);
            for (int col = 0; col < rows; ++col)
                if (cols[col].size() > 0) prob.W(row, col) += gather(ts, direction(row), cols[col]);
        }
    }
    VecX lambda = VecX::Zero(rows);
    for (int c = 0; c < nc; ++c) {
        auto it = previous_impulse.find(contact_key(contacts[c]));
        if (it == previous_impulse.end()) continue;
        lambda[3 * c] = it->second.dot(contacts[c].normal);
        lambda[3 * c + 1] = it->second.dot(contacts[c].tangent1);
        lambda[3 * c + 2] = it->second.dot(contacts[c].tangent2);
    }
    // The hand's system is not symmetric (spring torques), so neither is W; Gauss-Seidel is
    // only sure to converge on a symmetric one. Its symmetric part differs by terms of the
    // order of the springs' damping times the handle's spin; the velocities below use the
    // true columns.
    contact_W = prob.W;
    prob.W = 0.5 * (prob.W + prob.W.transpose()).eval();
    const PgsResult res = solve_pgs(prob, lambda, settings.max_iterations, settings.tolerance);
    previous_impulse.clear();
    stats.iterations = res.iterations;
    stats.residual = res.residual;
    for (int bi : involved) {
        Body& b = *bodies[bi];
        for (int row = 0; row < rows; ++row)
            if (columns[bi][row].size() > 0) b.v_new += columns[bi][row] * lambda[row];
    }
    for (int c = 0; c < nc; ++c) {
        const Contact& k = contacts[c];
        const Vec3 impulse = lambda[3 * c] * k.normal + lambda[3 * c + 1] * k.tangent1 + lambda[3 * c + 2] * k.tangent2;
        previous_impulse[contact_key(k)] = impulse;
        bodies[k.a.body]->contact_force += impulse / settings.dt;
        bodies[k.b.body]->contact_force -= impulse / settings.dt;
    }
    contact_lambda = lambda;
    contact_friction = prob.friction;
    contact_columns = std::move(columns);
}

void World::integrate() {
    const double dt = settings.dt;
    for (auto& bp : bodies) {
        Body& b = *bp;
        switch (b.kind) {
            case BodyKind::Hand: hh::integrate(*b.hand_model, *b.hand, b.v_new); break;
            case BodyKind::Soft:
                b.state.v = b.v_new;
                for (int i = 0; i < b.flesh->mesh.n_nodes; ++i)
                    if (b.fixed[i]) b.state.v.segment<3>(3 * i).setZero();
                b.state.x += dt * b.state.v;
                break;
            case BodyKind::Rigid:
                b.rigid.v_com = b.v_new.head<3>();
                b.rigid.omega = b.v_new.tail<3>();
                b.rigid.x_com += dt * b.rigid.v_com;
                b.rigid.q = quat_multiply(quat_from_rotation_vector(dt * b.rigid.omega), b.rigid.q).normalized();
                break;
            case BodyKind::Kinematic: b.rigid = b.target; break;
            default: break;
        }
        update_points(b);
        if (b.has_surface) {
            // positions only (normals and boxes are refreshed by the next detection)
            for (int v = 0; v < b.surface.n_vertices(); ++v) {
                Vec3 p = Vec3::Zero();
                for (int k = 0; k < 4; ++k)
                    if (b.surface.weights[v][k] != 0) p += b.surface.weights[v][k] * b.points[b.surface.nodes[v][k]];
                b.surface.x[v] = p;
            }
        }
    }
}

double World::contact_distance(const Contact& c) const {
    const Body& a = *bodies[c.a.body];
    const Body& b = *bodies[c.b.body];
    const Vec3 pa = c.a.point(a.surface);
    if (b.kind == BodyKind::Plane) return (pa - b.plane_point).dot(b.plane_normal);
    return c.normal.dot(pa - c.b.point(b.surface));
}

void World::step() {
    using clock = std::chrono::steady_clock;
    const auto t0 = clock::now();
    stats = WorldStats{};
    for (auto& bp : bodies)
        if (bp->kind == BodyKind::Kinematic && !bp->script.empty()) {
            // the velocity that carries the body exactly from the script's pose at t to t + dt
            const Pose p0 = bp->script.at(time), p1 = bp->script.at(time + settings.dt);
            bp->target.x_com = p1.position;
            bp->target.q = p1.quaternion;
            bp->target.v_com = (p1.position - p0.position) / settings.dt;
            bp->target.omega = quat_to_rotation_vector(quat_multiply(p1.quaternion, quat_conjugate(p0.quaternion))) / settings.dt;
        }
    detect();
    reduce_contacts();
    const auto t1 = clock::now();
    stats.t_detection = seconds_since(t0);
    solve_free();
    const auto t2 = clock::now();
    stats.t_dynamics = seconds_since(t1);
    solve_contacts();
    stats.t_contact = seconds_since(t2);
    integrate();
    stats.contacts = static_cast<int>(contacts.size());
    stats.min_distance = std::numeric_limits<double>::infinity();  // no pair within reach
    for (const Contact& c : detected) {
        const double d = contact_distance(c);
        stats.min_distance = std::min(stats.min_distance, d);
        stats.max_penetration = std::max(stats.max_penetration, settings.contact_thickness - d);
    }
    for (const Contact& c : contacts) stats.self_contacts += c.a.body == c.b.body;
    time += settings.dt;
    stats.t_total = seconds_since(t0);
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
