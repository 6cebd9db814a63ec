#include "sim/world.h"
#include "sim/world_contact.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <string>

#include "common/clock.h"
#include "common/task_graph.h"
#include "rigid/quaternion.h"

namespace hh {

namespace {
// Fraction of the contact thickness by which last step's representative of a patch cell may be
// shallower than the deepest contact there and still be kept (reduce_contacts)
constexpr double kKeepRepresentative = 0.01;
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

// Detection in parts that step() runs as tasks (on two threads side by side): the bodies'
// surfaces, then each pair (or self, or plane) on its own, then the pairs' contacts in a fixed
// order and reduced. In the 10x bunny scene the surfaces took ~1.7 ms, the hand's self pairs
// ~1.4, the hand against the bunny ~3.0: one task of ~6.5 ms that held back every contact
// response while the other thread was already in the bodies' free solves.
void World::begin_detection() {
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
    surface_reach_.resize(bodies.size());
    for (size_t i = 0; i < bodies.size(); ++i) surface_reach_[i] = base + std::min(motion_[i], 2 * settings.contact_thickness);
    // A pair closes by at most m_a + m_b. Searching that less s = min(m_a, m_b, thickness / 2)
    // misses only pairs farther than base + m_a + m_b - s, which end the step farther than
    // base - s >= the thickness: found in time next step. (It keeps slow pairs, such as the
    // paper bunny's, at the reach of the faster body alone, as before.)
    auto pair_motion = [&](double ma, double mb) {
        return ma + mb - std::min({ma, mb, 0.5 * settings.contact_thickness});
    };
    detection_jobs_.clear();
    for (size_t i = 0; i < bodies.size(); ++i) {
        const Body& a = *bodies[i];
        if (!a.dynamic() || !a.has_surface) continue;
        const int ai = static_cast<int>(i);
        if (a.self_collision) detection_jobs_.push_back({ai, ai, surface_reach_[i], {}});
        for (size_t j = 0; j < bodies.size(); ++j) {
            const Body& b = *bodies[j];
            if (j == i) continue;
            if (b.kind == BodyKind::Plane)
                detection_jobs_.push_back({ai, static_cast<int>(j), base + motion_[i], {}});
            else if (b.has_surface && (j > i || !b.dynamic()))
                detection_jobs_.push_back({ai, static_cast<int>(j), base + pair_motion(motion_[i], motion_[j]), {}});
        }
    }
}

void World::update_body_surface(int i) {
    Body& b = *bodies[i];
    update_points(b);
    if (b.has_surface) update_surface(b.surface, b.points, surface_reach_[i]);
}

void World::detect_job(int k) {
    DetectionJob& job = detection_jobs_[k];
    job.found.clear();
    Body& a = *bodies[job.a];
    const Body& b = *bodies[job.b];
    if (job.a == job.b)
        detect_self(a.surface, job.a, DetectionSettings{job.reach}, &a.self_exclusions, job.found);
    else if (b.kind == BodyKind::Plane)
        detect_plane(a.surface, job.a, b.plane_point, b.plane_normal, job.b, DetectionSettings{job.reach}, job.found);
    else
        detect_pair(a.surface, job.a, b.surface, job.b, DetectionSettings{job.reach}, job.found);
}

void World::finish_detection() {
    contacts.clear();  // (in the jobs' order: the same contacts in the same order on one thread as on two)
    for (const DetectionJob& job : detection_jobs_) contacts.insert(contacts.end(), job.found.begin(), job.found.end());
    reduce_contacts();
}

void World::reduce_contacts() {
    // Keep, per pair of bodies and per patch cell, the deepest contact whose normal points the
    // same way (octant of the normal), so two sides of a thin part stay apart. A large contact
    // area then costs a bounded number of constraints; the dropped pairs are within a patch of
    // a kept one and are still measured in the statistics.
    // Last step's contact of a cell stays its representative while within kKeepRepresentative
    // of the contact thickness of the deepest: on a body resting on the ground the vertices of
    // a flat patch lie within microns of each other, and the deepest one changed from step to
    // step, so a third of the warm starts came from another point of the patch (whose impulse
    // turns the element differently). Measured on the 10x bunny at rest: 80-300 sweeps a step
    // to the tolerance, from a warm-start residual of 3-15 mm/s; keeping the representative, 1.
    detected.swap(contacts);
    contacts.clear();
    contact_patch_keys.clear();
    std::unordered_map<std::uint64_t, int> best;
    std::vector<double> best_depth;  // per kept contact: its distance, less `keep` if kept last step
    const double h = settings.contact_patch;
    const double keep = kKeepRepresentative * settings.contact_thickness;
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
        const double depth = c.distance - (previous_impulse.count(contact_key(c)) ? keep : 0.0);
        auto it = best.find(key);
        if (it == best.end()) {
            best[key] = static_cast<int>(contacts.size());
            contacts.push_back(c);
            contact_patch_keys.push_back(key);
            best_depth.push_back(depth);
        } else if (depth < best_depth[it->second]) {
            contacts[it->second] = c;
            best_depth[it->second] = depth;
        }
    }
}

// The hand's element pass's last part and its assembly (formulate_end): At then holds the
// step's values, and its factorization's parts may start.
void World::assemble_hand(Body& b) {
    const auto t0 = std::chrono::steady_clock::now();
    formulate_pass(*b.hand_model, *b.hand, 2);
    formulate_end(*b.hand_model, *b.hand);
    b.assembly_seconds = seconds_since(t0);
}

namespace {
// The last step's contact impulses a body carries into its free solve (World::solve_free), taken
// from it: empty unless its deformable system is on the reused factor (whose lagged responses
// they correct) and it touched something.
VecX take_carried_impulse(Body& b, const DeformableSystem& tool) {
    VecX carried;
    carried.swap(b.carried_impulse);
    if (tool.solver() != DeformableSolver::ReusedCholesky) carried.resize(0);
    return carried;
}
}  // namespace

void World::solve_free(Body& b) {
    const double dt = settings.dt;
    switch (b.kind) {
        case BodyKind::Hand: {
            // (formulate_begin and the element pass's parts 0 and 1 ran already, as tasks of
            // World::step that two threads can share; b.pass_seconds holds their cost)
            if (!b.assemble_apart) {  // (else done by tasks of World::step, and the factor's parts with it)
                assemble_hand(b);
                b.factor_part_seconds[0] = b.factor_part_seconds[1] = 0;
                b.hand->tool.reset_counters();
            }
            hh_step_stats& st = b.hand->stats;
            st = hh_step_stats{};
            const double parts = b.factor_part_seconds[0] + b.factor_part_seconds[1];
            st.t_assembly = b.pass_seconds[0] + b.pass_seconds[1] + b.pass_seconds[2] + b.assembly_seconds;
            const auto t1 = std::chrono::steady_clock::now();
            // With the reused factor the contact responses are its lagged operator P, not
            // A_t^-1 (DeformableSystem::solve_response). The last step's contact impulses f
            // then go into the free solve, solved with A_t itself, and the contact solve adds
            // P (J^T lambda - f): only the change of the impulses since the last step sees the
            // lag. Before, sustained contact put (P - A_t^-1) J^T lambda into every step's
            // velocities (P is 10-20% off A_t on a settled hand's impulses), and on one of
            // pytetwild's hand meshes in ten the pressed hand oscillated with period 2.
            const VecX carried = take_carried_impulse(b, b.hand->tool);
            if (carried.size()) {
                // measured against b_t alone, the free solve is as accurate as without the
                // carried impulses (DeformableSystem::set_reference_norm)
                const Eigen::Index n3 = b.hand->hand.r.size() - 6;
                b.hand->tool.set_reference_norm(0, b.hand->hand.r.tail(n3).norm());
                b.hand->hand.r += carried;
                // P^-1 f, through the factor's single-precision copy (half the traffic of the
                // pass; the step at rest is then Eq. 7's to within float round-off of P^-1 f), by
                // the solve, beside b_t (HandSystem::carried)
                b.hand->hand.carried = carried;
            }
            b.hand->hand.solve();
            b.v_free = step_velocities(*b.hand_model, *b.hand, b.hand->hand.s);  // (it solves relative to the step's frame)
            if (carried.size()) b.v_free -= b.hand->hand.carried_response;
            st.t_deformable = b.hand->hand.t_deformable + parts;  // (the carried impulses' pass too)
            st.t_schur = b.hand->hand.t_schur;
            st.cg_iterations = b.hand->tool.iterations;
            st.max_residual = b.hand->tool.max_residual;
            st.t_total = st.t_assembly + parts + seconds_since(t1);
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
            // On the reused factor, as the hand's (above): the last step's contact impulses f in
            // the free solve, and P f taken out again, so that only their change sees the lag
            const VecX carried = take_carried_impulse(b, *b.tool);
            b.tool->r = b.soft_rhs;
            if (carried.size()) {
                b.tool->set_reference_norm(0, b.soft_rhs.norm());
                b.tool->r += carried;
            }
            b.tool->select_slot(0);
            b.tool->solve();
            b.v_free = b.tool->s;
            if (carried.size()) {
                VecX response;
                b.tool->solve_response_single(carried, response);
                b.v_free -= response;
            }
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
    // The step's parts as tasks (common/task_graph.h), each run by whichever thread is free:
    // - detection reads the bodies' positions and velocities at the start of the step;
    // - each body's free solve reads them too, and writes only its own system and v_free;
    // - the contact solve's preparation needs the contacts; a body's responses need its free
    //   solve (its factor is the step's); a group's sweeps need its bodies' responses.
    // So on two threads the worker detects while the caller solves the largest body (the
    // hand), then takes the other bodies, their responses and the groups that do not involve
    // the hand (letters resting on the ground) while the hand's solve goes on. Every task
    // writes only its own results, so the step is the same on one thread as on two.
    // Priorities among ready tasks: the hand's element pass first (its two parts are what lets
    // both threads start at once), then detection and the preparation that unlock the contact
    // work, then the free solves, the responses and the sweeps, largest first within each kind.
    constexpr double kElementPass = 5e9, kDetection = 4e9, kPrepare = 3e9, kFreeSolve = 2e9, kResponses = 1e9,
                     kSweeps = 5e8, kHandleTerms = 1e8;
    // runs f and writes its wall time to `seconds` (each task its own slot: no two write one)
    auto timed = [](double& seconds, const auto& f) {
        const auto t = std::chrono::steady_clock::now();
        f();
        seconds = seconds_since(t);
    };
    const size_t n = bodies.size();
    std::vector<double> free_seconds(n, 0.0), apply_seconds(n, 0.0);
    TaskGraph graph;
    // The hand's free solve on the reused factor: its b_t (5-12 CG iterations a step on the
    // ~17000-tet hand) and its six Schur columns (1-3 from their warm starts) as two jobs, the
    // columns a task that the other thread takes once free (TaskGraph::run_beside). Set on one
    // thread as on two, so the steps are the same; cleared however the step ends (the graph
    // is this call's).
    struct ClearBeside {
        std::vector<std::unique_ptr<Body>>& bodies;
        ~ClearBeside() {
            for (auto& b : bodies) {
                if (b->kind == BodyKind::Hand) b->hand->hand.beside = nullptr;
                b->beside = nullptr;
            }
        }
    } clear_beside{bodies};
    for (auto& bp : bodies) {
        const double priority = kFreeSolve + bp->dofs();
        Beside beside = [&graph, priority](const std::function<void()>& mine, const std::function<void()>& other) {
            graph.run_beside(mine, other, priority);
        };
        if (bp->kind == BodyKind::Hand) bp->hand->hand.beside = beside;
        if (bp->kind == BodyKind::Soft && bp->tool->solver() == DeformableSolver::ReusedCholesky) bp->beside = beside;
    }
    std::vector<std::vector<double>> build_part_seconds(n);
    std::vector<std::vector<double>> group_seconds;
    double prepare_seconds = 0;
    std::vector<int> free_task(n);
    for (size_t i = 0; i < n; ++i) {
        std::vector<int> after;
        if (bodies[i]->kind == BodyKind::Hand) {
            // the hand's element pass (a sixth of its step for the 17000-tet hand) in two parts
            // on disjoint nodes, one per thread (fem/element_order.h)
            Body& b = *bodies[i];
            timed(b.pass_seconds[0], [&b] { formulate_begin(*b.hand_model, *b.hand); });
            for (int part = 0; part < 2; ++part)
                after.push_back(graph.add(
                    [&b, part, &timed] { timed(b.pass_seconds[1 + part], [&b, part] { formulate_pass(*b.hand_model, *b.hand, part); }); },
                    {}, kElementPass));
        }
        if (bodies[i]->kind == BodyKind::Hand) bodies[i]->assemble_apart = bodies[i]->hand->tool.factor_parts() == 2;
        if (bodies[i]->kind == BodyKind::Hand && bodies[i]->assemble_apart) {
            // a large hand's factorization in two parts side by side (BlockLDLT::factor_parts),
            // between its assembly and its solve: on the ~17000-tet hand ~25 -> ~18 ms
            Body& b = *bodies[i];
            b.hand->tool.reset_counters();
            const int assembled = graph.add([&b, this] { assemble_hand(b); }, after, kFreeSolve + b.dofs());
            after.clear();
            for (int part = 0; part < 2; ++part)
                after.push_back(graph.add(
                    [&b, part, &timed] { timed(b.factor_part_seconds[part], [&b, part] { b.hand->tool.factorize_part(part); }); },
                    {assembled}, kFreeSolve + b.dofs()));
        }
        free_task[i] = graph.add([&, i] { timed(free_seconds[i], [&] { solve_free(*bodies[i]); }); }, after,
                                 kFreeSolve + bodies[i]->dofs());
    }
    // detection: each body's surface, then each pair once its bodies' surfaces are up to date
    // (larger first), then the pairs' contacts gathered
    double begin_detection_seconds = 0;
    timed(begin_detection_seconds, [&] { begin_detection(); });
    std::vector<double> detection_seconds(n + detection_jobs_.size() + 1, 0.0);
    std::vector<int> surface_task(n);
    for (size_t i = 0; i < n; ++i)
        surface_task[i] = graph.add(
            [&, i] { timed(detection_seconds[i], [&] { update_body_surface(static_cast<int>(i)); }); }, {},
            kDetection + 2 * static_cast<double>(bodies[i]->surface.triangles.size()));
    std::vector<int> job_tasks;
    for (size_t k = 0; k < detection_jobs_.size(); ++k) {
        const DetectionJob& job = detection_jobs_[k];
        job_tasks.push_back(graph.add(
            [&, k] { timed(detection_seconds[n + k], [&] { detect_job(static_cast<int>(k)); }); },
            {surface_task[job.a], surface_task[job.b]},
            kDetection + static_cast<double>(bodies[job.a]->surface.triangles.size() + bodies[job.b]->surface.triangles.size())));
    }
    const int detection = graph.add([&] { timed(detection_seconds.back(), [&] { finish_detection(); }); }, job_tasks,
                                    kDetection);
    graph.add(
        [&] {
            timed(prepare_seconds, [&] { prepare_contacts(); });
            // per body: begin (beside its free solve), ready, its solves in shares (side by side
            // on two threads), finish; each part's time in its own slot (summed into
            // t_contact_build after the run)
            std::vector<int> build_task(n, -1);
            for (int bi : contact_involved()) {
                const int parts = contact_body_parts(bi);
                build_part_seconds[bi].assign(parts + 4, 0.0);
                const double priority = kResponses + bodies[bi]->dofs();
                // (the begin, bookkeeping on the contacts alone, may run beside the body's free
                // solve; its solves then wait for both)
                const int begin = graph.add(
                    [&, bi] { timed(build_part_seconds[bi][0], [&] { begin_contact_body(bi); }); }, {}, priority);
                const int ready = graph.add(
                    [&, bi, parts] { timed(build_part_seconds[bi][2 + parts], [&] { ready_contact_body(bi); }); },
                    {begin, free_task[bi]}, priority);
                std::vector<int> shares;
                for (int part = 0; part < parts; ++part)
                    shares.push_back(graph.add(
                        [&, bi, part, parts] {
                            timed(build_part_seconds[bi][1 + part], [&] { solve_contact_body(bi, part, parts); });
                        },
                        {ready}, priority));
                build_task[bi] = graph.add(
                    [&, bi, parts] { timed(build_part_seconds[bi][1 + parts], [&] { finish_contact_body(bi); }); }, shares,
                    priority);
                // (below the sweeps: the thread they leave idle takes it)
                if (handle_terms_apart(bi))
                    graph.add([&, bi, parts] { timed(build_part_seconds[bi][3 + parts], [&] { form_handle_terms(bi); }); },
                              {ready}, kHandleTerms);
            }
            // per group: setup, its columns in shares (side by side), the sweeps; each part's
            // time in its own slot (the sweeps' time is the three kinds together)
            group_seconds.assign(contact_groups.size(), std::vector<double>(2 + kColumnShares, 0.0));
            for (size_t g = 0; g < contact_groups.size(); ++g) {
                const std::vector<int>& members = contact_group_bodies(static_cast<int>(g));
                std::vector<int> after;
                for (int bi : members) after.push_back(build_task[bi]);
                const double priority = kSweeps + static_cast<double>(contact_groups[g].contacts.size());
                const int gi = static_cast<int>(g);
                const int setup = graph.add([&, gi] { timed(group_seconds[gi][0], [&] { setup_contact_group(gi); }); },
                                            after, priority);
                std::vector<int> shares;
                for (int part = 0; part < kColumnShares; ++part)
                    shares.push_back(graph.add(
                        [&, gi, part] { timed(group_seconds[gi][1 + part], [&] { form_contact_columns(gi, part); }); },
                        {setup}, priority));
                const int group_task = graph.add(
                    [&, gi] { timed(group_seconds[gi][1 + kColumnShares], [&] { solve_contact_group(gi); }); }, shares,
                    priority);
                for (int bi : members)
                    graph.add([&, bi] { timed(apply_seconds[bi], [&] { apply_contact_body(bi); }); }, {group_task},
                              static_cast<double>(bodies[bi]->dofs()));
            }
        },
        {detection}, kPrepare);
    graph.run(worker_.get());
    const auto t_finish = clock::now();
    finish_contacts();
    // the parts' own costs (on two threads they overlap: their sum exceeds t_total)
    stats.t_detection = begin_detection_seconds;
    for (double s : detection_seconds) stats.t_detection += s;
    for (double s : free_seconds) stats.t_dynamics += s;
    for (const auto& b : bodies)
        if (b->kind == BodyKind::Hand) {
            stats.t_dynamics += b->pass_seconds[0] + b->pass_seconds[1] + b->pass_seconds[2];
            if (b->assemble_apart) stats.t_dynamics += b->assembly_seconds + b->factor_part_seconds[0] + b->factor_part_seconds[1];
        }
    stats.t_contact_build = prepare_seconds;
    for (const auto& parts : build_part_seconds)
        for (double s : parts) stats.t_contact_build += s;
    for (const auto& parts : group_seconds)
        for (double s : parts) stats.t_contact_sweeps += s;
    stats.t_contact_apply = seconds_since(t_finish);
    for (double s : apply_seconds) stats.t_contact_apply += s;
    stats.t_contact = stats.t_contact_build + stats.t_contact_sweeps + stats.t_contact_apply;
    trace_contacts();
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
