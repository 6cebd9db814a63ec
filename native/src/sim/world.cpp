#include "sim/world.h"
#include "solver/block_ldlt.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <functional>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <map>
#include <string>

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

World::World(const WorldSettings& s) : settings(s) {
    if (settings.threads > 1) worker_ = std::make_unique<Worker>();
}

void World::share(const std::vector<int>& order, const std::function<void(int)>& body, const std::function<void()>& first) {
    std::atomic<size_t> next{0};
    auto take = [&] {
        for (size_t k; (k = next.fetch_add(1)) < order.size();) body(order[k]);
    };
    if (!worker_) {
        first();
        take();
        return;
    }
    worker_->start([&] {
        first();
        take();
    });
    try {
        take();
    } catch (...) {
        worker_->join_quietly();  // it still uses this frame's variables
        throw;
    }
    worker_->join();
}

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
    // Resting contacts settle at exactly the thickness: look half a thickness further so they
    // are found every step instead of flickering in and out at the edge of the reach.
    const double base = 1.5 * settings.contact_thickness;
    // Fast surfaces may close more than that within a step: each body is looked at further by
    // how far its fastest point can travel in the step, so a falling or thrown body meets what
    // it will hit as an open contact whose gap the solve closes exactly within the step
    // (speculative contact) instead of tunnelling in. Per body, so that one fast body does not
    // widen every pair's search. (It was one reach for all, capped at two thicknesses: the
    // 10x letters fell 16 mm into the ground.)
    motion_.assign(bodies.size(), 0.0);
    for (size_t i = 0; i < bodies.size(); ++i) {
        const Body& b = *bodies[i];
        double speed = 0;
        if (b.kind == BodyKind::Hand || b.kind == BodyKind::Soft) {
            const VecX& v = b.kind == BodyKind::Hand ? b.hand->v : b.state.v;
            for (Eigen::Index k = 0; k + 2 < v.size(); k += 3) speed = std::max(speed, v.segment<3>(k).squaredNorm());
            speed = std::sqrt(speed);
        } else if (b.kind == BodyKind::Rigid || b.kind == BodyKind::Kinematic) {
            double arm = 0;  // farthest surface point from the centre of mass
            for (const Vec3& p : b.local) arm = std::max(arm, p.norm());
            speed = b.rigid.v_com.norm() + b.rigid.omega.norm() * arm;
        }
        motion_[i] = std::isfinite(speed) ? speed * settings.dt : 0.0;
    }
    // The trees' margin: the self-collision reach (one body's parts, such as fingers, move
    // against each other far slower than the body moves); pairs with a fast body reach further
    // by inflating the query side (detect_pair).
    auto self_reach = [&](size_t i) { return base + std::min(motion_[i], 2 * settings.contact_thickness); };
    // A pair closes by at most m_a + m_b. Searching that less s = min(m_a, m_b, thickness / 2)
    // misses only pairs farther than base + m_a + m_b - s, which end the step farther than
    // base - s >= the thickness: found in time next step. (It keeps slow pairs, such as the
    // paper bunny's, at the reach of the faster body alone, as before.)
    auto pair_motion = [&](double ma, double mb) {
        return ma + mb - std::min({ma, mb, 0.5 * settings.contact_thickness});
    };
    for (size_t i = 0; i < bodies.size(); ++i) {
        Body& b = *bodies[i];
        update_points(b);
        if (b.has_surface) update_surface(b.surface, b.points, self_reach(i));
    }
    contacts.clear();
    for (size_t i = 0; i < bodies.size(); ++i) {
        Body& a = *bodies[i];
        if (a.dynamic() && a.has_surface && a.self_collision)
            detect_self(a.surface, static_cast<int>(i), DetectionSettings{self_reach(i)}, &a.self_exclusions, contacts);
        for (size_t j = 0; j < bodies.size(); ++j) {
            if (j == i) continue;
            Body& b = *bodies[j];
            if (!a.dynamic() || !a.has_surface) continue;
            if (b.kind == BodyKind::Plane) {
                detect_plane(a.surface, static_cast<int>(i), b.plane_point, b.plane_normal, static_cast<int>(j),
                             DetectionSettings{base + motion_[i]}, contacts);
            } else if (b.has_surface && (j > i || !b.dynamic())) {
                detect_pair(a.surface, static_cast<int>(i), b.surface, static_cast<int>(j),
                            DetectionSettings{base + pair_motion(motion_[i], motion_[j])}, contacts);
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
    contact_patch_keys.clear();
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
            contact_patch_keys.push_back(key);
        } else if (c.distance < contacts[it->second].distance) {
            contacts[it->second] = c;
        }
    }
}

void World::solve_free(Body& b) {
    const double dt = settings.dt;
    {
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
    using clock = std::chrono::steady_clock;
    const auto t_start = clock::now();
    const int nc = static_cast<int>(contacts.size());
    contact_groups.clear();
    contact_group_of.assign(nc, -1);
    contact_slot.assign(nc, -1);
    contact_bodies.clear();
    contact_lambda.resize(0);
    contact_friction.resize(0);
    if (nc == 0) {
        previous_impulse.clear();
        previous_patch_impulse.clear();
        return;
    }
    const int rows = 3 * nc;
    const bool use_patch_warm = !std::getenv("HH_NO_PATCH_WARM");
    auto direction = [&](int row) -> const Vec3& {
        const Contact& c = contacts[row / 3];
        return row % 3 == 0 ? c.normal : (row % 3 == 1 ? c.tangent1 : c.tangent2);
    };

    // Per contact and dynamic side: the body's unknowns it moves, as (first unknown, weight)
    // terms for flesh nodes (3 unknowns each) or the rigid body's (v, omega) lever arm.
    struct Term {
        int offset;
        double weight;
        bool rigid;
        Vec3 r;
    };
    std::vector<std::vector<std::pair<int, std::vector<Term>>>> sides(nc);  // contact -> (body, terms)
    std::vector<int> involved;
    for (int c = 0; c < nc; ++c)
        for (int s = 0; s < 2; ++s) {
            const ContactSide& side = s == 0 ? contacts[c].a : contacts[c].b;
            if (side.body < 0 || !bodies[side.body]->dynamic()) continue;
            const Body& b = *bodies[side.body];
            const double sign = s == 0 ? 1.0 : -1.0;
            std::vector<Term>* ts = nullptr;
            for (auto& e : sides[c])
                if (e.first == side.body) ts = &e.second;  // self-contact: both sides on one body
            if (!ts) {
                sides[c].emplace_back(side.body, std::vector<Term>());
                ts = &sides[c].back().second;
            }
            for (int k = 0; k < side.count; ++k) {
                const int v = side.vertex[k];
                if (b.kind == BodyKind::Rigid) {
                    ts->push_back({0, sign * side.weight[k], true, b.surface.x[v] - b.rigid.x_com});
                } else {
                    const int base = b.kind == BodyKind::Hand ? 6 : 0;
                    for (int q = 0; q < 4; ++q) {
                        const int node = b.surface.nodes[v][q];
                        // a fixed node of a soft body does not move: it takes no impulse
                        if (b.surface.weights[v][q] == 0 || (b.kind == BodyKind::Soft && b.fixed[node])) continue;
                        ts->push_back({base + 3 * node, sign * side.weight[k] * b.surface.weights[v][q], false, Vec3::Zero()});
                    }
                }
            }
            if (std::find(involved.begin(), involved.end(), side.body) == involved.end()) involved.push_back(side.body);
        }
    std::sort(involved.begin(), involved.end());

    // Groups: contacts joined by the dynamic bodies they share (union-find over bodies).
    std::vector<int> parent(bodies.size());
    for (size_t i = 0; i < parent.size(); ++i) parent[i] = static_cast<int>(i);
    std::function<int(int)> root = [&](int i) { return parent[i] == i ? i : (parent[i] = root(parent[i])); };
    for (int c = 0; c < nc; ++c)
        for (size_t e = 1; e < sides[c].size(); ++e) parent[root(sides[c][e].first)] = root(sides[c][0].first);
    std::map<int, int> group_of_root;
    for (int c = 0; c < nc; ++c) {
        const int r = sides[c].empty() ? -1 - c : root(sides[c][0].first);
        auto it = group_of_root.find(r);
        if (it == group_of_root.end()) {
            it = group_of_root.emplace(r, static_cast<int>(contact_groups.size())).first;
            contact_groups.emplace_back();
        }
        ContactGroup& g = contact_groups[it->second];
        contact_group_of[c] = it->second;
        contact_slot[c] = static_cast<int>(g.contacts.size());
        g.contacts.push_back(c);
    }

    // The problem's data per contact (global rows)
    VecX u_free = VecX::Zero(rows), gap(nc), friction(nc), kinetic(nc);
    for (int c = 0; c < nc; ++c) {
        const Contact& k = contacts[c];
        gap[c] = k.distance - settings.contact_thickness;
        friction[c] = std::sqrt(bodies[k.a.body]->friction * bodies[k.b.body]->friction);
        kinetic[c] = std::sqrt(bodies[k.a.body]->kinetic_friction * bodies[k.b.body]->kinetic_friction);
        // kinematic bodies' motion enters as a known relative velocity
        for (int s = 0; s < 2; ++s) {
            const ContactSide& side = s == 0 ? k.a : k.b;
            const Body& b = *bodies[side.body];
            if (b.kind != BodyKind::Kinematic) continue;
            const Vec3 p = side.count > 0 ? side.point(b.surface) : k.point;
            const Vec3 vel = carried_velocity(b, p);
            for (int d = 0; d < 3; ++d) u_free[3 * c + d] += (s == 0 ? 1.0 : -1.0) * direction(3 * c + d).dot(vel);
        }
    }

    std::map<int, MatX> response;  // per body: its symmetrized C_b (see ReducedContactProblem)
    std::map<int, VecX> u_body;    // per body: its share of u_free on its rows
    for (int bi : involved) {      // (made here: the bodies below are built side by side)
        contact_bodies[bi];
        response[bi];
        u_body[bi];
    }
    // Per dynamic body: J_b on the unknowns it touches (G), their responses K from batched
    // black-box solves (8 right-hand sides per pass), and its block G K G^T (or G K) of W.
    // Each body's solves are its own: with a worker, two bodies are built at once (the largest
    // first), each writing only its own entries.
    auto build = [&](int bi) {
        Body& b = *bodies[bi];
        ContactBody& cb = contact_bodies.at(bi);
        const int dofs = b.dofs();
        std::vector<int> touched_mark(dofs, 0);
        for (int c = 0; c < nc; ++c)
            for (const auto& e : sides[c]) {
                if (e.first != bi) continue;
                for (int d = 0; d < 3; ++d) cb.rows.push_back(3 * c + d);
                for (const Term& t : e.second) {
                    if (t.rigid) std::fill(touched_mark.begin(), touched_mark.begin() + 6, 1);
                    else for (int d = 0; d < 3; ++d) touched_mark[t.offset + d] = 1;
                }
            }
        std::vector<int> index_of(dofs, -1);
        for (int k = 0; k < dofs; ++k)
            if (touched_mark[k]) {
                index_of[k] = static_cast<int>(cb.touched.size());
                cb.touched.push_back(k);
            }
        const int nr = static_cast<int>(cb.rows.size()), nt = static_cast<int>(cb.touched.size());
        cb.local_row.assign(rows, -1);
        for (int l = 0; l < nr; ++l) cb.local_row[cb.rows[l]] = l;
        std::vector<Eigen::Triplet<double>> trip;
        for (int l = 0; l < nr; ++l) {
            const int row = cb.rows[l];
            const Vec3& u = direction(row);
            for (const auto& e : sides[row / 3]) {
                if (e.first != bi) continue;
                for (const Term& t : e.second) {
                    if (t.rigid) {
                        const Vec3 ru = t.r.cross(u);
                        for (int d = 0; d < 3; ++d) {
                            trip.emplace_back(l, index_of[d], t.weight * u[d]);
                            trip.emplace_back(l, index_of[3 + d], t.weight * ru[d]);
                        }
                    } else {
                        for (int d = 0; d < 3; ++d) trip.emplace_back(l, index_of[t.offset + d], t.weight * u[d]);
                    }
                }
            }
        }
        cb.G.resize(nr, nt);
        cb.G.setFromTriplets(trip.begin(), trip.end());
        // watched unknowns: the touched ones, then (hand) the handle nodes' for the coupling model
        cb.watched = cb.touched;
        if (b.kind == BodyKind::Hand)
            for (int node : b.hand_model->handle.nodes)
                for (int d = 0; d < 3; ++d)
                    if (!touched_mark[6 + 3 * node + d]) cb.watched.push_back(6 + 3 * node + d);
        for (size_t w = 0; w < cb.watched.size(); ++w) cb.watched_index[cb.watched[w]] = static_cast<int>(w);
        // basis: whichever needs fewer solves
        cb.row_basis = nr < nt;
        const int m = cb.row_basis ? nr : nt;
        cb.K.resize(cb.watched.size(), m);
        const Eigen::SparseMatrix<double> gt = cb.G.transpose();  // touched x rows, column-major
        // the nodes of the watched unknowns: the solves need only their rows (BlockLDLT::solve)
        std::vector<int> watched_nodes;
        if (b.kind == BodyKind::Soft)
            for (int k : cb.watched)
                if (watched_nodes.empty() || watched_nodes.back() != k / 3) watched_nodes.push_back(k / 3);
        MatX rhs, x;
        // the hand's unit columns from its kept response columns, when its solver keeps them
        const bool units = b.kind == BodyKind::Hand && !cb.row_basis &&
                           b.hand->hand.apply_inverse_units(cb.touched, cb.watched, cb.K);
        for (int first = units ? m : 0; first < m; first += kWidestSolve) {  // (as many as a solve pass takes)
            const int w = std::min(kWidestSolve, m - first);
            rhs.setZero(dofs, w);
            for (int j = 0; j < w; ++j) {
                if (cb.row_basis) {
                    for (Eigen::SparseMatrix<double>::InnerIterator it(gt, first + j); it; ++it)
                        rhs(cb.touched[it.row()], j) = it.value();
                } else {
                    rhs(cb.touched[first + j], j) = 1;
                }
            }
            switch (b.kind) {
                case BodyKind::Hand:  // only the watched rows, straight into K
                    b.hand->hand.apply_inverse_many(rhs, x, &cb.watched);
                    cb.K.middleCols(first, w) = x;
                    continue;
                case BodyKind::Soft: b.tool->solve_many(rhs, x, 1, &watched_nodes); break;
                default: x = Eigen::FullPivLU<Mat6>(b.rigid_system->A).solve(rhs);
            }
            for (size_t k = 0; k < cb.watched.size(); ++k) cb.K.block(k, first, 1, w) = x.block(cb.watched[k], 0, 1, w);
        }
        if (!cb.K.allFinite())  // (the solves above check only the rows they were asked for)
            throw NumericalError("the contact response of body " + std::to_string(bi) +
                                 " is not finite: reduce the time step or check its material");
        // u_free, and the body's symmetric response on its basis for the sweeps
        VecX v_touched(nt);
        for (int k = 0; k < nt; ++k) v_touched[k] = b.v_free[cb.touched[k]];
        u_body.at(bi) = cb.G * v_touched;
        MatX c_b = cb.row_basis ? MatX(cb.G * cb.K.topRows(nt)) : MatX(cb.K.topRows(nt));
        response.at(bi) = 0.5 * (c_b + c_b.transpose());
        if (std::getenv("HH_CONTACT_TRACE")) std::fprintf(stderr, "[body %d built at %.2f ms] ", bi, 1e3 * seconds_since(t_start));
    };
    std::vector<int> order = involved;
    std::stable_sort(order.begin(), order.end(), [&](int a, int b) { return bodies[a]->dofs() > bodies[b]->dofs(); });
    share(order, build, [] {});
    for (int bi : involved) {
        const ContactBody& cb = contact_bodies.at(bi);
        for (size_t l = 0; l < cb.rows.size(); ++l) u_free[cb.rows[l]] += u_body.at(bi)[l];
    }
    const auto t_built = clock::now();
    stats.t_contact_build = std::chrono::duration<double>(t_built - t_start).count();
    stats.contact_groups = static_cast<int>(contact_groups.size());

    // Warm start from the previous step's impulses of the same contacts
    VecX lambda = VecX::Zero(rows);
    int warm_hits = 0, patch_hits = 0;
    for (int c = 0; c < nc; ++c) {
        auto it = previous_impulse.find(contact_key(contacts[c]));
        if (it == previous_impulse.end() && use_patch_warm) {
            // another vertex is the deepest of the same patch now: start from that patch's impulse
            it = previous_patch_impulse.find(contact_patch_keys[c]);
            if (it == previous_patch_impulse.end()) continue;
            ++patch_hits;
        } else if (it == previous_impulse.end()) {
            continue;
        } else {
            ++warm_hits;
        }
        lambda[3 * c] = it->second.dot(contacts[c].normal);
        lambda[3 * c + 1] = it->second.dot(contacts[c].tangent1);
        lambda[3 * c + 2] = it->second.dot(contacts[c].tangent2);
    }
    // Each group is its own contact problem. The hand's system is not symmetric (spring
    // torques), so neither is W; Gauss-Seidel is only sure to converge on a symmetric one. Its
    // symmetric part differs by terms of the order of the springs' damping times the handle's
    // spin; the velocities below use the true operator.
    // Groups share no body, so with a worker two are solved at once (the most contacts first),
    // each writing its own impulses.
    auto solve_group = [&](int group) {
        ContactGroup& g = contact_groups[group];
        const int gc = static_cast<int>(g.contacts.size());
        ReducedContactProblem prob;
        prob.dt = settings.dt;
        prob.u_free.resize(3 * gc);
        prob.gap.resize(gc);
        prob.friction.resize(gc);
        prob.kinetic.resize(gc);
        prob.begin.assign(1, 0);
        std::map<int, int> slot;  // body -> index in prob.bodies
        VecX lg(3 * gc);
        for (int i = 0; i < gc; ++i) {
            const int c = g.contacts[i];
            prob.u_free.segment<3>(3 * i) = u_free.segment<3>(3 * c);
            prob.gap[i] = gap[c];
            prob.friction[i] = friction[c];
            prob.kinetic[i] = kinetic[c];
            lg.segment<3>(3 * i) = lambda.segment<3>(3 * c);
            for (const auto& e : sides[c]) {
                const int bi = e.first;
                auto sl = slot.find(bi);
                if (sl == slot.end()) {
                    sl = slot.emplace(bi, static_cast<int>(prob.bodies.size())).first;
                    prob.bodies.push_back({std::move(response.at(bi))});
                }
                const ContactBody& cb = contact_bodies.at(bi);
                const int l0 = cb.local_row[3 * c];
                if (cb.row_basis) {
                    for (int d = 0; d < 3; ++d) prob.entries.push_back({sl->second, l0 + d, Vec3::Unit(d)});
                } else {
                    const size_t first = prob.entries.size();
                    for (int d = 0; d < 3; ++d)
                        for (Eigen::SparseMatrix<double, Eigen::RowMajor>::InnerIterator it(cb.G, l0 + d); it; ++it) {
                            size_t k = first;
                            while (k < prob.entries.size() && prob.entries[k].index != it.col()) ++k;
                            if (k == prob.entries.size()) prob.entries.push_back({sl->second, static_cast<int>(it.col()), Vec3::Zero()});
                            prob.entries[k].coefficient[d] += it.value();
                        }
                }
            }
            prob.begin.push_back(static_cast<int>(prob.entries.size()));
        }
        const PgsResult res = solve_pgs(prob, lg, settings.max_iterations, settings.tolerance);
        g.iterations = res.iterations;
        g.residual = res.residual;
        for (int i = 0; i < gc; ++i) lambda.segment<3>(3 * g.contacts[i]) = lg.segment<3>(3 * i);
    };
    std::vector<int> group_order(contact_groups.size());
    for (size_t k = 0; k < group_order.size(); ++k) group_order[k] = static_cast<int>(k);
    std::stable_sort(group_order.begin(), group_order.end(), [&](int a, int b) {
        return contact_groups[a].contacts.size() > contact_groups[b].contacts.size();
    });
    share(group_order, solve_group, [] {});
    stats.iterations = 0;
    stats.residual = 0;
    for (const ContactGroup& g : contact_groups) {
        stats.iterations = std::max(stats.iterations, g.iterations);
        stats.residual = std::max(stats.residual, g.residual);
    }
    const auto t_swept = clock::now();
    stats.t_contact_sweeps = std::chrono::duration<double>(t_swept - t_built).count();

    // v = v* + A^-1 J^T lambda: one more solve per body (two bodies at once with a worker)
    share(order, [&](int bi) {
        Body& b = *bodies[bi];
        const ContactBody& cb = contact_bodies.at(bi);
        VecX lb(cb.rows.size());
        for (size_t l = 0; l < cb.rows.size(); ++l) lb[l] = lambda[cb.rows[l]];
        const VecX f = cb.G.transpose() * lb;
        VecX rhs = VecX::Zero(b.dofs());
        for (size_t k = 0; k < cb.touched.size(); ++k) rhs[cb.touched[k]] = f[k];
        switch (b.kind) {
            case BodyKind::Hand: b.v_new += b.hand->hand.apply_inverse(rhs); break;
            case BodyKind::Soft:
                b.tool->r = rhs;
                b.tool->select_slot(1);
                b.tool->solve();
                b.v_new += b.tool->s;
                break;
            default: b.v_new += Eigen::FullPivLU<Mat6>(b.rigid_system->A).solve(rhs);
        }
    }, [] {});
    previous_impulse.clear();
    previous_patch_impulse.clear();
    for (int c = 0; c < nc; ++c) {
        const Contact& k = contacts[c];
        const Vec3 impulse = lambda[3 * c] * k.normal + lambda[3 * c + 1] * k.tangent1 + lambda[3 * c + 2] * k.tangent2;
        previous_impulse[contact_key(k)] = impulse;
        previous_patch_impulse[contact_patch_keys[c]] = impulse;
        bodies[k.a.body]->contact_force += impulse / settings.dt;
        bodies[k.b.body]->contact_force -= impulse / settings.dt;
    }
    contact_lambda = lambda;
    contact_friction = friction;
    stats.t_contact_apply = seconds_since(t_swept);
    if (std::getenv("HH_CONTACT_TRACE")) {
        std::fprintf(stderr, "warm %d patch %d ", warm_hits, patch_hits);
        std::fprintf(stderr, "contacts %d groups %zu build %.2f sweeps %.2f apply %.2f ms it %d |", nc, contact_groups.size(),
                     1e3 * stats.t_contact_build, 1e3 * stats.t_contact_sweeps, 1e3 * stats.t_contact_apply, stats.iterations);
        for (const auto& e : contact_bodies)
            std::fprintf(stderr, " body %d rows %zu touched %zu %s", e.first, e.second.rows.size(), e.second.touched.size(), e.second.row_basis ? "R" : "D");
        std::fprintf(stderr, "\n");
    }
}

MatX World::contact_delassus(const std::vector<int>& rows) const {
    const int n = static_cast<int>(rows.size());
    MatX out = MatX::Zero(n, n);
    for (const auto& e : contact_bodies) {
        const ContactBody& cb = e.second;
        std::vector<int> at, local;  // the asked rows this body takes part in
        for (int a = 0; a < n; ++a)
            if (rows[a] >= 0 && rows[a] < static_cast<int>(cb.local_row.size()) && cb.local_row[rows[a]] >= 0) {
                at.push_back(a);
                local.push_back(cb.local_row[rows[a]]);
            }
        if (at.empty()) continue;
        const int nt = static_cast<int>(cb.touched.size());
        const int k = static_cast<int>(at.size());
        // H = A_b^-1 J_b^T of those rows at the touched unknowns (touched x k)
        MatX h(nt, k);
        for (int j = 0; j < k; ++j) {
            if (cb.row_basis) {
                h.col(j) = cb.K.col(local[j]).head(nt);
            } else {
                h.col(j).setZero();
                for (Eigen::SparseMatrix<double, Eigen::RowMajor>::InnerIterator it(cb.G, local[j]); it; ++it)
                    h.col(j) += cb.K.col(it.col()).head(nt) * it.value();
            }
        }
        for (int i = 0; i < k; ++i)
            for (int j = 0; j < k; ++j) {
                double sum = 0;
                for (Eigen::SparseMatrix<double, Eigen::RowMajor>::InnerIterator it(cb.G, local[i]); it; ++it) sum += it.value() * h(it.col(), j);
                out(at[i], at[j]) += sum;
            }
    }
    return out;
}

VecX World::contact_column(int body, int row, const std::vector<int>& unknowns) const {
    auto it = contact_bodies.find(body);
    if (it == contact_bodies.end() || row < 0 || row >= static_cast<int>(it->second.local_row.size())) return VecX();
    const ContactBody& cb = it->second;
    const int l = cb.local_row[row];
    if (l < 0) return VecX();
    VecX out(unknowns.size());
    for (size_t k = 0; k < unknowns.size(); ++k) {
        auto w = cb.watched_index.find(unknowns[k]);
        if (w == cb.watched_index.end())
            throw InvalidArgument("World::contact_column: that unknown's response was not kept");
        if (cb.row_basis) out[k] = cb.K(w->second, l);
        else {
            double sum = 0;  // G's sparse row l against row w of K
            for (Eigen::SparseMatrix<double, Eigen::RowMajor>::InnerIterator g(cb.G, l); g; ++g) sum += g.value() * cb.K(w->second, g.col());
            out[k] = sum;
        }
    }
    return out;
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
    // Detection reads the bodies' positions and velocities at the start of the step; the free
    // solves read them too and write only their own systems and v_free: independent, so with a
    // worker they run side by side (the worker detects, then joins in on the solves, the
    // largest body first).
    std::vector<int> order(bodies.size());
    for (size_t i = 0; i < order.size(); ++i) order[i] = static_cast<int>(i);
    std::stable_sort(order.begin(), order.end(), [&](int a, int b) { return bodies[a]->dofs() > bodies[b]->dofs(); });
    std::vector<double> free_seconds(bodies.size(), 0.0);
    share(
        order,
        [&](int i) {
            const auto t = clock::now();
            solve_free(*bodies[i]);
            free_seconds[i] = seconds_since(t);
        },
        [&] {
            const auto t = clock::now();
            detect();
            reduce_contacts();
            stats.t_detection = seconds_since(t);
        });
    for (double s : free_seconds) stats.t_dynamics += s;
    const auto t2 = clock::now();
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
