// The world step's schedule (World::step, sim/world.h): its parts as tasks of a graph
// (common/task_graph.h), each run by whichever thread is free, the caller's or the world's
// worker (contact.threads = 2), and the step's statistics from the times they wrote.
// - detection reads the bodies' positions and velocities at the start of the step;
// - each body's free solve reads them too, and writes only its own system and v_free;
// - the contact solve's preparation needs the contacts; a body's responses need its free
//   solve (its factor is the step's); a group's sweeps need its bodies' responses; a body's
//   final velocity solve needs its group's impulses.
// So on two threads the worker detects while the caller solves the largest body (the hand),
// then takes the other bodies, their responses and the groups that do not involve the hand
// (letters resting on the ground) while the hand's solve goes on. Every task writes only its
// own results, so the step is the same on one thread as on two, bit for bit.
#include <chrono>
#include <functional>
#include <limits>
#include <vector>

#include "common/clock.h"
#include "common/task_graph.h"
#include "rigid/quaternion.h"
#include "sim/skeleton_step.h"
#include "sim/world.h"
#include "sim/world_contact.h"

namespace hh {

namespace {
// Priorities among ready tasks: the hand's element pass first (its two parts are what lets
// both threads start at once), then detection and the preparation that unlock the contact
// work, then the free solves, the responses and the sweeps, largest first within each kind;
// the handle's terms below the sweeps (the thread they leave idle takes them).
constexpr double kElementPass = 5e9, kDetection = 4e9, kPrepare = 3e9, kFreeSolve = 2e9, kResponses = 1e9,
                 kSweeps = 5e8, kHandleTerms = 1e8;

// runs f and writes its wall time to `seconds` (each task its own slot: no two write one)
template <class F>
void timed(double& seconds, const F& f) {
    const auto t = std::chrono::steady_clock::now();
    f();
    seconds = seconds_since(t);
}
}  // namespace

// One step's graph and the times its tasks write, one slot each (summed by sum_step_times)
struct World::StepTasks {
    TaskGraph graph;
    std::vector<double> free_seconds, apply_seconds;   // per body
    std::vector<int> free_task;                        // per body: its free solve's task
    int detection_task = -1;                           // the contacts gathered
    double begin_detection_seconds = 0;
    std::vector<double> detection_seconds;             // per body surface, per detection job, the gathering
    double prepare_seconds = 0;
    std::vector<std::vector<double>> build_part_seconds;  // per body: its responses' parts
    std::vector<std::vector<double>> group_seconds;       // per group: setup, column shares, sweeps
    explicit StepTasks(size_t n) : free_seconds(n, 0.0), apply_seconds(n, 0.0), free_task(n), build_part_seconds(n) {}
};

namespace {
// The hand's free solve on the reused factor runs its b_t and its six Schur columns as two
// jobs, the columns a task the other thread takes once free (TaskGraph::run_beside); a soft
// body on the reused factor its fresh response columns in two shares. Set on one thread as on
// two, so the steps are the same; cleared however the step ends (the graph is the step's).
struct BesideScope {
    std::vector<std::unique_ptr<Body>>& bodies;
    BesideScope(std::vector<std::unique_ptr<Body>>& bodies, TaskGraph& graph) : bodies(bodies) {
        for (auto& bp : bodies) {
            const double priority = kFreeSolve + bp->dofs();
            Beside beside = [&graph, priority](const std::function<void()>& mine, const std::function<void()>& other) {
                graph.run_beside(mine, other, priority);
            };
            if (bp->kind == BodyKind::Hand) bp->hand->hand.beside = beside;
            if (bp->kind == BodyKind::Soft && bp->soft.tool->solver() == DeformableSolver::ReusedCholesky)
                bp->soft.beside = beside;
        }
    }
    ~BesideScope() {
        for (auto& b : bodies) {
            if (b->kind == BodyKind::Hand) b->hand->hand.beside = nullptr;
            b->soft.beside = nullptr;
        }
    }
};
}  // namespace

void World::step() {
    const auto t0 = std::chrono::steady_clock::now();
    stats = WorldStats{};
    move_kinematic_targets();
    StepTasks tasks(bodies.size());
    const BesideScope beside(bodies, tasks.graph);
    add_free_solves(tasks);
    add_detection(tasks);
    add_contact_solve(tasks);
    tasks.graph.run(worker_.get());
    std::unique_ptr<StepTasks> again;
    if (!deferred.empty() && a_deferred_contact_closes()) again = solve_contacts_again();
    const auto t_finish = std::chrono::steady_clock::now();
    finish_contacts();
    sum_step_times(tasks, seconds_since(t_finish));
    if (again) add_contact_times(*again);
    trace_contacts();
    integrate();
    measure_contacts();
    time += settings.dt;
    stats.t_total = seconds_since(t0);
}

// A deferred contact would close (sim/world_speculative.cpp): the contact solve again, with
// every contact, from the bodies' free velocities (its tasks alone: detection and the free
// solves are done)
std::unique_ptr<World::StepTasks> World::solve_contacts_again() {
    take_back_deferred_contacts();
    auto again = std::make_unique<StepTasks>(bodies.size());
    const BesideScope beside(bodies, again->graph);
    again->detection_task = again->graph.add([] {}, {}, kPrepare);
    for (size_t i = 0; i < bodies.size(); ++i) again->free_task[i] = again->graph.add([] {}, {}, kPrepare);
    add_contact_solve(*again);
    again->graph.run(worker_.get());
    return again;
}

// A scripted kinematic body's target: the velocity that carries it exactly from the script's
// pose at t to t + dt
void World::move_kinematic_targets() {
    for (auto& bp : bodies)
        if (bp->kind == BodyKind::Kinematic && !bp->mesh.script.empty()) {
            const Pose p0 = bp->mesh.script.at(time), p1 = bp->mesh.script.at(time + settings.dt);
            bp->mesh.target.x_com = p1.position;
            bp->mesh.target.q = p1.quaternion;
            bp->mesh.target.v_com = (p1.position - p0.position) / settings.dt;
            bp->mesh.target.omega = quat_to_rotation_vector(quat_multiply(p1.quaternion, quat_conjugate(p0.quaternion))) / settings.dt;
        }
}

// Per body its free solve; the hand's element pass (a sixth of its step for the 17000-tet hand)
// in two parts on disjoint nodes before it, one per thread (fem/element_order.h), and a large
// hand's factorization in two parts side by side between its assembly and its solve
// (BlockLDLT::factor_parts)
void World::add_free_solves(StepTasks& tasks) {
    TaskGraph& graph = tasks.graph;
    for (size_t i = 0; i < bodies.size(); ++i) {
        Body& b = *bodies[i];
        std::vector<int> after;
        if (b.skeleton()) {  // (its frame before the contact setup reads it; the rest in its free solve)
            HandStep& hs = b.hand_step;
            hs = HandStep{};
            timed(hs.pass_seconds[0], [&b] { formulate_skeleton_begin(*b.hand_model, *b.hand); });
        } else if (b.kind == BodyKind::Hand) {
            HandStep& hs = b.hand_step;
            timed(hs.pass_seconds[0], [&b] { formulate_begin(*b.hand_model, *b.hand); });
            for (int part = 0; part < 2; ++part)
                after.push_back(graph.add(
                    [&b, &hs, part] { timed(hs.pass_seconds[1 + part], [&b, part] { formulate_pass(*b.hand_model, *b.hand, part); }); },
                    {}, kElementPass));
            hs.assemble_apart = b.hand->tool.factor_parts() == 2;
            if (hs.assemble_apart) {
                b.hand->tool.reset_counters();
                const int assembled = graph.add([&b, this] { assemble_hand(b); }, after, kFreeSolve + b.dofs());
                after.clear();
                for (int part = 0; part < 2; ++part)
                    after.push_back(graph.add(
                        [&b, &hs, part] { timed(hs.factor_part_seconds[part], [&b, part] { b.hand->tool.factorize_part(part); }); },
                        {assembled}, kFreeSolve + b.dofs()));
            }
        }
        tasks.free_task[i] = graph.add([this, &tasks, i] { timed(tasks.free_seconds[i], [&] { solve_free(*bodies[i]); }); },
                                       after, kFreeSolve + b.dofs());
    }
}

// Detection: each body's surface, then each pair once its bodies' surfaces are up to date
// (larger first), then the pairs' contacts gathered
void World::add_detection(StepTasks& tasks) {
    TaskGraph& graph = tasks.graph;
    const size_t n = bodies.size();
    timed(tasks.begin_detection_seconds, [&] { begin_detection(); });
    tasks.detection_seconds.assign(n + detection_jobs_.size() + 1, 0.0);
    std::vector<int> surface_task(n);
    for (size_t i = 0; i < n; ++i)
        surface_task[i] = graph.add(
            [this, &tasks, i] { timed(tasks.detection_seconds[i], [&] { update_body_surface(static_cast<int>(i)); }); }, {},
            kDetection + 2 * static_cast<double>(bodies[i]->surface.triangles.size()));
    std::vector<int> job_tasks;
    for (size_t k = 0; k < detection_jobs_.size(); ++k) {
        const DetectionJob& job = detection_jobs_[k];
        job_tasks.push_back(graph.add(
            [this, &tasks, n, k] { timed(tasks.detection_seconds[n + k], [&] { detect_job(static_cast<int>(k)); }); },
            {surface_task[job.a], surface_task[job.b]},
            kDetection + static_cast<double>(bodies[job.a]->surface.triangles.size() + bodies[job.b]->surface.triangles.size())));
    }
    tasks.detection_task = graph.add(
        [this, &tasks] { timed(tasks.detection_seconds.back(), [&] { finish_detection(); }); }, job_tasks, kDetection);
}

// The contact solve: once detection is done, its preparation, which adds the bodies' responses
// and the groups' sweeps (their number is known only then)
void World::add_contact_solve(StepTasks& tasks) {
    tasks.graph.add(
        [this, &tasks] {
            timed(tasks.prepare_seconds, [&] { prepare_contacts(); });
            std::vector<int> built;
            add_contact_bodies(tasks, built);
            add_contact_groups(tasks, built);
        },
        {tasks.detection_task}, kPrepare);
}

// Per body in contact: begin (bookkeeping on the contacts alone, which may run beside the
// body's free solve), ready (after both), its solves in shares (side by side on two threads),
// finish; each part's time in its own slot (summed into t_contact_build). built: per body, the
// task that finishes its responses
void World::add_contact_bodies(StepTasks& tasks, std::vector<int>& built) {
    TaskGraph& graph = tasks.graph;
    built.assign(bodies.size(), -1);
    for (int bi : contact_involved()) {
        const int parts = contact_body_parts(bi);
        std::vector<double>& seconds = tasks.build_part_seconds[bi];
        seconds.assign(parts + 4, 0.0);
        const double priority = kResponses + bodies[bi]->dofs();
        const int begin = graph.add([this, &seconds, bi] { timed(seconds[0], [&] { begin_contact_body(bi); }); }, {}, priority);
        const int ready = graph.add([this, &seconds, bi, parts] { timed(seconds[2 + parts], [&] { ready_contact_body(bi); }); },
                                    {begin, tasks.free_task[bi]}, priority);
        std::vector<int> shares;
        for (int part = 0; part < parts; ++part)
            shares.push_back(graph.add(
                [this, &seconds, bi, part, parts] { timed(seconds[1 + part], [&] { solve_contact_body(bi, part, parts); }); },
                {ready}, priority));
        built[bi] = graph.add([this, &seconds, bi, parts] { timed(seconds[1 + parts], [&] { finish_contact_body(bi); }); },
                              shares, priority);
        // (below the sweeps: the thread they leave idle takes it)
        if (handle_terms_apart(bi))
            graph.add([this, &seconds, bi, parts] { timed(seconds[3 + parts], [&] { form_handle_terms(bi); }); }, {ready},
                      kHandleTerms);
    }
    // a body out of contact this step whose carried impulses' response waits (sim/world_carried.cpp;
    // known only once its free solve is done, which may still run: a task after it either way)
    for (size_t bi = 0; bi < bodies.size(); ++bi)
        if (built[bi] < 0 && bodies[bi]->dynamic())
            graph.add([this, &tasks, bi] { timed(tasks.apply_seconds[bi], [&] { take_out_carried(static_cast<int>(bi)); }); },
                      {tasks.free_task[bi]}, kResponses + bodies[bi]->dofs());
}

// Per group, once its bodies' responses are built: setup, its columns in shares (side by
// side), the sweeps; then each of its bodies' final velocity solve. Each part's time in its own
// slot (the sweeps' time is the three kinds together)
void World::add_contact_groups(StepTasks& tasks, const std::vector<int>& built) {
    TaskGraph& graph = tasks.graph;
    tasks.group_seconds.assign(contact_groups.size(), std::vector<double>(2 + kColumnShares, 0.0));
    for (size_t g = 0; g < contact_groups.size(); ++g) {
        const std::vector<int>& members = contact_group_bodies(static_cast<int>(g));
        std::vector<int> after;
        for (int bi : members) after.push_back(built[bi]);
        const double priority = kSweeps + static_cast<double>(contact_groups[g].contacts.size());
        const int gi = static_cast<int>(g);
        std::vector<double>& seconds = tasks.group_seconds[g];
        const int setup = graph.add([this, &seconds, gi] { timed(seconds[0], [&] { setup_contact_group(gi); }); }, after, priority);
        std::vector<int> shares;
        for (int part = 0; part < kColumnShares; ++part)
            shares.push_back(graph.add(
                [this, &seconds, gi, part] { timed(seconds[1 + part], [&] { form_contact_columns(gi, part); }); }, {setup},
                priority));
        const int group_task = graph.add(
            [this, &seconds, gi] { timed(seconds[1 + kColumnShares], [&] { solve_contact_group(gi); }); }, shares, priority);
        for (int bi : members)
            graph.add([this, &tasks, bi] { timed(tasks.apply_seconds[bi], [&] { apply_contact_body(bi); }); }, {group_task},
                      static_cast<double>(bodies[bi]->dofs()));
    }
}

// The parts' own costs (on two threads they overlap: their sum exceeds t_total)
void World::sum_step_times(const StepTasks& tasks, double finish_seconds) {
    stats.t_detection = tasks.begin_detection_seconds;
    for (double s : tasks.detection_seconds) stats.t_detection += s;
    for (double s : tasks.free_seconds) stats.t_dynamics += s;
    for (const auto& b : bodies)
        if (b->kind == BodyKind::Hand) {
            const HandStep& hs = b->hand_step;
            stats.t_dynamics += hs.pass_seconds[0] + hs.pass_seconds[1] + hs.pass_seconds[2];
            if (hs.assemble_apart) stats.t_dynamics += hs.assembly_seconds + hs.factor_part_seconds[0] + hs.factor_part_seconds[1];
        }
    stats.t_contact_apply = finish_seconds;
    add_contact_times(tasks);
}

// A contact solve's parts, added to the step's (twice when it solved again)
void World::add_contact_times(const StepTasks& tasks) {
    stats.t_contact_build += tasks.prepare_seconds;
    for (const auto& parts : tasks.build_part_seconds)
        for (double s : parts) stats.t_contact_build += s;
    for (const auto& parts : tasks.group_seconds)
        for (double s : parts) stats.t_contact_sweeps += s;
    for (double s : tasks.apply_seconds) stats.t_contact_apply += s;
    stats.t_contact = stats.t_contact_build + stats.t_contact_sweeps + stats.t_contact_apply;
}

// The contacts' statistics after the bodies moved: every detected pair's distance now
void World::measure_contacts() {
    stats.contacts = static_cast<int>(contacts.size());
    stats.min_distance = std::numeric_limits<double>::infinity();  // no pair within reach
    for (const Contact& c : detected) {
        const double d = contact_distance(c);
        stats.min_distance = std::min(stats.min_distance, d);
        stats.max_penetration = std::max(stats.max_penetration, settings.contact_thickness - d);
    }
    for (const Contact& c : contacts) stats.self_contacts += c.a.body == c.b.body;
}

}  // namespace hh
