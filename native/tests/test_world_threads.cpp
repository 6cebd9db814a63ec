// The world step on two threads (WorldSettings::threads, common/worker.h): the worker runs
// collision detection and a share of the bodies' free solves and contact responses. Only
// independent parts run side by side, each writing its own results, so a scene must step
// exactly as on one thread, bit for bit. Run under ThreadSanitizer too (make test-tsan).
#include <algorithm>
#include <atomic>
#include <chrono>
#include <thread>
#include <mutex>
#include <cmath>
#include <cstring>
#include <stdexcept>
#include <vector>

#include "box_mesh.h"
#include "capi/guard.h"
#include "check.h"
#include "common/task_graph.h"
#include "common/worker.h"
#include "haptic_hand.h"
#include "sim/data.h"
#include "sim/model.h"

namespace {

// the hand's box starts 0.4 mm above the upper soft box's top (2.32 + 2 cm), within reach
constexpr double kHandLift = 0.0436;

// The box hand pressed by its device onto a stack of two soft boxes on the ground: hand-box,
// box-box and box-ground contacts, three dynamic bodies whose solves and responses can share
// the two threads.
struct Stack {
    int hx, hy;  // the hand box's cells along x and y
    BoxMesh hand_box;
    BoxMesh soft = make_box(3, 3, 2, 0.01);
    hh_model* model = nullptr;
    hh_world* world = nullptr;
    int hand = -1, lower = -1, upper = -1;
    double com[3] = {0, 0, 0};

    // hx x hy x hz: the hand box's cells (a larger one gets a factor split in parts)
    // solver: the hand's (default: box_hand_params')
    explicit Stack(int threads, int hx_ = 4, int hy_ = 3, int hz = 2, int solver = -1)
        : hx(hx_), hy(hy_), hand_box(make_box(hx_, hy_, hz, 0.01)) {
        hh_params p = box_hand_params();
        if (solver >= 0) p.solver = solver;
        p.palm_seed[2] += kHandLift;
        hh_world_params wp;
        hh_default_world_params(&wp);
        wp.threads = threads;
        CHECK(hh_world_create(&wp, &world) == HH_OK);
        const double ground[3] = {0, 0, 0}, up[3] = {0, 0, 1};
        int plane = -1;
        CHECK(hh_world_add_plane(world, ground, up, 0.6, &plane) == HH_OK);
        lower = add_soft(0.0011);
        upper = add_soft(0.0232);
        // the hand above the stack: its bottom face (z = 0 of its box) as collision surface
        std::vector<double> x = hand_box.nodes;
        for (size_t i = 0; i < x.size(); i += 3) x[i + 2] += kHandLift;
        CHECK(hh_model_create(x.data(), hand_box.n_nodes(), hand_box.tets.data(), hand_box.n_tets(), &p, &model) ==
              HH_OK);
        std::vector<int> nodes;
        std::vector<double> weights;
        std::vector<int> faces;
        bottom_surface(hand_box, hx, hy, nodes, weights, faces);
        CHECK(hh_world_add_hand(world, model, nodes.data(), weights.data(), static_cast<int>(nodes.size() / 4),
                                faces.data(), static_cast<int>(faces.size() / 3), 0.5, 0, &hand) == HH_OK);
        hh_model_info info;
        CHECK(hh_model_info_get(model, &info) == HH_OK);
        for (int i = 0; i < 3; ++i) com[i] = info.handle_com[i];
    }
    ~Stack() {
        hh_world_free(world);
        hh_model_free(model);
    }

    // The bottom face (k = 0) of a box mesh, as a vertex surface on its nodes (two triangles per
    // cell); top = true for the top face, wound outwards.
    static void bottom_surface(const BoxMesh& m, int nx, int ny, std::vector<int>& nodes, std::vector<double>& weights,
                               std::vector<int>& faces, bool top = false, int nz = 0) {
        const int k = top ? nz : 0;
        auto id = [&](int i, int j) { return (k * (ny + 1) + j) * (nx + 1) + i; };
        for (int j = 0; j <= ny; ++j)
            for (int i = 0; i <= nx; ++i) {
                const int n[4] = {id(i, j), 0, 0, 0};
                const double w[4] = {1, 0, 0, 0};
                nodes.insert(nodes.end(), n, n + 4);
                weights.insert(weights.end(), w, w + 4);
            }
        (void)m;
        auto v = [&](int i, int j) { return j * (nx + 1) + i; };
        for (int j = 0; j < ny; ++j)
            for (int i = 0; i < nx; ++i) {
                int a = v(i, j), b = v(i + 1, j), c = v(i + 1, j + 1), d = v(i, j + 1);
                if (top) {
                    faces.insert(faces.end(), {a, b, c, a, c, d});
                } else {
                    faces.insert(faces.end(), {a, c, b, a, d, c});
                }
            }
    }

    // A soft box (3 x 3 x 2 cells of 1 cm) with its bottom at height z; its collision surface
    // is its bottom and top faces.
    int add_soft(double z) {
        std::vector<double> x = soft.nodes;
        for (size_t i = 0; i < x.size(); i += 3) {
            x[i] += 0.005;
            x[i + 2] += z;
        }
        std::vector<int> nodes, faces;
        std::vector<double> weights;
        bottom_surface(soft, 3, 3, nodes, weights, faces);
        const int offset = static_cast<int>(nodes.size() / 4);
        std::vector<int> top_nodes, top_faces;
        std::vector<double> top_weights;
        bottom_surface(soft, 3, 3, top_nodes, top_weights, top_faces, true, 2);
        nodes.insert(nodes.end(), top_nodes.begin(), top_nodes.end());
        weights.insert(weights.end(), top_weights.begin(), top_weights.end());
        for (int f : top_faces) faces.push_back(f + offset);
        hh_material mat;
        hh_default_material(&mat);
        int body = -1;
        CHECK(hh_world_add_soft_body(world, x.data(), soft.n_nodes(), soft.tets.data(), soft.n_tets(), &mat, nullptr, 0,
                                     nodes.data(), weights.data(), static_cast<int>(nodes.size() / 4), faces.data(),
                                     static_cast<int>(faces.size() / 3), 0.6, &body) == HH_OK);
        return body;
    }

    // The device 1 cm below the handle's rest position: the hand presses down on the stack.
    // mode 2: the handle prescribed there instead (moving down at 1 cm/s), as in a session's
    // visual loop (hh_world_set_device).
    void press(int mode = 1) {
        const double q[4] = {0, 0, 0, 1}, zero[3] = {0, 0, 0}, down[3] = {0, 0, -0.01};
        const double target[3] = {com[0], com[1], com[2] - 0.01};
        CHECK(hh_world_set_device(world, hand, mode, target, q, mode == 2 ? down : zero, zero) == HH_OK);
    }

    std::vector<double> nodes_of(int body, int n) const {
        std::vector<double> x(3 * static_cast<size_t>(n)), v(3 * static_cast<size_t>(n));
        CHECK(hh_world_body_nodes(world, body, x.data(), v.data(), n) == HH_OK);
        x.insert(x.end(), v.begin(), v.end());
        return x;
    }
    std::vector<double> state() const {
        std::vector<double> out = nodes_of(hand, hand_box.n_nodes());
        for (int b : {lower, upper}) {
            const std::vector<double> s = nodes_of(b, soft.n_nodes());
            out.insert(out.end(), s.begin(), s.end());
        }
        return out;
    }
};

// Both stacks pressed and stepped `steps` times side by side: the same contacts, sweeps and
// states bit for bit after every step. Returns the most contacts of a step.
int pressed_side_by_side(Stack& one, Stack& two, int steps) {
    one.press();
    two.press();
    int most_contacts = 0;
    for (int step = 0; step < steps; ++step) {
        hh_world_stats s1, s2;
        CHECK(hh_world_step(one.world, &s1) == HH_OK);
        CHECK(hh_world_step(two.world, &s2) == HH_OK);
        CHECK(s1.contacts == s2.contacts && s1.iterations == s2.iterations);
        most_contacts = std::max(most_contacts, s1.contacts);
        const std::vector<double> a = one.state(), b = two.state();
        CHECK(a.size() == b.size());
        CHECK(std::memcmp(a.data(), b.data(), a.size() * sizeof(double)) == 0);
    }
    return most_contacts;
}

}  // namespace

TEST(two_threads_step_a_scene_exactly_as_one) {
    Stack one(1), two(2);
    one.press();
    two.press();
    int most_contacts = 0;
    double most_upward = 0;  // N: largest upward contact force on the hand
    for (int step = 0; step < 12; ++step) {
        hh_world_stats s1, s2;
        CHECK(hh_world_step(one.world, &s1) == HH_OK);
        CHECK(hh_world_step(two.world, &s2) == HH_OK);
        CHECK(s1.contacts == s2.contacts);
        CHECK(s1.iterations == s2.iterations);
        CHECK(s1.residual == s2.residual);
        most_contacts = std::max(most_contacts, s1.contacts);
        double f[3];
        CHECK(hh_world_contact_force(two.world, two.hand, f) == HH_OK);
        most_upward = std::max(most_upward, f[2]);
        const std::vector<double> a = one.state(), b = two.state();
        CHECK(a.size() == b.size());
        CHECK(std::memcmp(a.data(), b.data(), a.size() * sizeof(double)) == 0);
    }
    // the scene did what it is for: the boxes met each other and the ground (more contacts
    // than one 4 x 4-vertex face), and the upper box pushed the hand up at least once
    CHECK(most_contacts > 32);
    CHECK(most_upward > 0);
}

TEST(a_large_hand_factored_in_parts_on_two_threads_steps_exactly_as_on_one) {
    // a hand large enough for its per-step factor to be split in two parts (BlockLDLT::
    // factor_parts), which the step runs on the two threads between its assembly and its solve
    Stack one(1, 12, 8, 6), two(2, 12, 8, 6);
    {
        const hh_params p = box_hand_params();
        const hh::Model m = hh::build_model(two.hand_box.nodes.data(), two.hand_box.n_nodes(), two.hand_box.tets.data(),
                                    two.hand_box.n_tets(), p);
        hh::Data d(m);
        hh::formulate(m, d);
        CHECK(d.tool.factor_parts() == 2);
    }
    CHECK(pressed_side_by_side(one, two, 4) > 0);
}

TEST(a_large_hand_on_the_reused_factor_renews_it_in_parts_and_steps_exactly_as_on_one_thread) {
    // with the reused factor, a step that renews it (the first one here) runs the factorization's
    // two parts side by side too, and the rest in the hand's solve; the other steps split the
    // hand's CG lanes in two groups (TaskGraph::run_beside): the same steps on one thread
    {
        const BoxMesh box = make_box(12, 8, 6, 0.01);
        hh_params p = box_hand_params();
        p.solver = HH_SOLVER_REUSED_CHOLESKY;
        const hh::Model m = hh::build_model(box.nodes.data(), box.n_nodes(), box.tets.data(), box.n_tets(), p);
        hh::Data d(m);
        CHECK(d.tool.factor_parts() == 2);  // (no factor yet: the first step makes one)
        hh::formulate(m, d);
        d.hand.solve();
        hh::integrate(m, d, d.hand.s);
        hh::formulate(m, d);
        CHECK(d.tool.factor_parts() == 0);  // (the next step reuses it)
    }
    // (the first step renews in parts; the next ones solve b_t and the Schur columns side by
    // side on the reused factor, HandSystem::beside)
    Stack one(1, 12, 8, 6, HH_SOLVER_REUSED_CHOLESKY), two(2, 12, 8, 6, HH_SOLVER_REUSED_CHOLESKY);
    CHECK(pressed_side_by_side(one, two, 3) > 0);
}

TEST(soft_bodies_on_the_reused_factor_step_exactly_as_on_one_thread) {
    // both soft boxes on the reused factor (hh_world_set_body_solver): their fresh response
    // columns in two shares beside each other (DeformableSystem::response_units, more than one
    // batch of units: two faces of 16 nodes each), their impulses carried into the next free
    // solve; the same steps on one thread as on two, and the wrong solver kinds refused
    Stack one(1), two(2);
    for (Stack* s : {&one, &two})
        for (int body : {s->lower, s->upper})
            CHECK(hh_world_set_body_solver(s->world, body, HH_SOLVER_REUSED_CHOLESKY, 1e-8, 5000) == HH_OK);
    CHECK(hh_world_set_body_solver(one.world, one.lower, HH_SOLVER_CG, 1e-8, 5000) == HH_ERR_INVALID_ARGUMENT);
    CHECK(hh_world_set_body_solver(one.world, one.hand, HH_SOLVER_REUSED_CHOLESKY, 1e-8, 5000) == HH_ERR_INVALID_ARGUMENT);
    CHECK(pressed_side_by_side(one, two, 8) > 32);
}

TEST(a_prescribed_handle_on_the_reused_factor_gives_the_same_coupling_model_on_two_threads) {
    // with the handle prescribed (a session's visual loop) the handle-space linearization's
    // solves (World::form_handle_terms) are a task of their own, which the thread the sweeps
    // leave idle takes: the same steps and the same coupling model, bit for bit, as on one thread
    Stack one(1, 12, 8, 6, HH_SOLVER_REUSED_CHOLESKY), two(2, 12, 8, 6, HH_SOLVER_REUSED_CHOLESKY);
    one.press(2);
    two.press(2);
    int held_most = 0;
    for (int step = 0; step < 3; ++step) {
        hh_world_stats s1, s2;
        CHECK(hh_world_step(one.world, &s1) == HH_OK);
        CHECK(hh_world_step(two.world, &s2) == HH_OK);
        CHECK(s1.contacts == s2.contacts && s1.iterations == s2.iterations);
        const std::vector<double> a = one.state(), b = two.state();
        CHECK(std::memcmp(a.data(), b.data(), a.size() * sizeof(double)) == 0);
        double w1[6], w2[6], k1[36], k2[36];
        int h1 = -1, h2 = -1;
        CHECK(hh_world_coupling_model(one.world, one.hand, w1, k1, &h1) == HH_OK);
        CHECK(hh_world_coupling_model(two.world, two.hand, w2, k2, &h2) == HH_OK);
        CHECK(h1 == h2);
        CHECK(std::memcmp(w1, w2, sizeof w1) == 0 && std::memcmp(k1, k2, sizeof k1) == 0);
        held_most = std::max(held_most, h1);
    }
    CHECK(held_most > 0);  // (the contacts' terms were in the model)
}

// A body whose state went bad (NaN: here written past the C API's checks) makes its solve fail
// on whichever thread runs it; the step returns that as a status with a message instead of
// crashing or hanging, on one thread as on two, and the world can be freed afterwards.
TEST(a_failing_body_solve_comes_back_as_a_status_on_either_thread) {
    for (int threads : {1, 2}) {
        Stack stack(threads);
        hh_world_stats st;
        CHECK(hh_world_step(stack.world, &st) == HH_OK);
        for (int body : {stack.lower, stack.upper}) {
            Stack again(threads);
            again.world->w.bodies[body]->soft.state.v[0] = std::nan("");
            const int status = hh_world_step(again.world, &st);
            CHECK(status == HH_ERR_NUMERICAL);
            CHECK(std::strstr(hh_last_error(), "non-finite") != nullptr);
        }
    }
}

TEST(bad_thread_counts_are_refused_with_a_message) {
    hh_world_params wp;
    hh_default_world_params(&wp);
    CHECK(wp.threads == 2);
    hh_world* world = nullptr;
    for (int bad : {0, 3, -1}) {
        wp.threads = bad;
        CHECK(hh_world_create(&wp, &world) == HH_ERR_INVALID_ARGUMENT);
        CHECK(world == nullptr);
        CHECK(std::strstr(hh_last_error(), "threads") != nullptr);
    }
}

TEST(a_worker_job_that_throws_reaches_join_and_the_worker_runs_on) {
    hh::Worker worker;
    int ran = 0;
    worker.start([&] { throw std::runtime_error("job failed"); });
    bool caught = false;
    try {
        worker.join();
    } catch (const std::runtime_error& e) {
        caught = std::strcmp(e.what(), "job failed") == 0;
    }
    CHECK(caught);
    worker.start([&] { ran = 1; });
    worker.join();
    CHECK(ran == 1);
    // join_quietly drops the error (the caller is already unwinding from its own)
    worker.start([&] { throw std::runtime_error("dropped"); });
    worker.join_quietly();
    worker.start([&] { ran = 2; });
    worker.join();
    CHECK(ran == 2);
}

// The step's scheduler (common/task_graph.h): a task never starts before those it comes after
// have ended, on one thread or two; tasks added by a running task run too; one thread takes
// the ready tasks by priority; an error stops the graph and comes back from run; a task cannot
// come after one that does not exist yet.
TEST(task_graph_keeps_order_runs_added_tasks_and_returns_errors) {
    for (bool two : {false, true}) {
        hh::Worker worker;
        hh::TaskGraph graph;
        std::mutex m;
        std::vector<int> log;  // task ids in the order they ended
        std::atomic<int> running{0}, most{0};  // tasks running at once, and the most seen
        auto task = [&](int id) {
            return [&, id] {
                const int now = ++running;
                int seen = most.load();
                while (now > seen && !most.compare_exchange_weak(seen, now)) {
                }
                volatile double x = 0;  // some work, so the two threads overlap
                for (int k = 0; k < 200000; ++k) x = x + k;
                --running;
                std::lock_guard<std::mutex> lock(m);
                log.push_back(id);
            };
        };
        const int a = graph.add(task(0), {}, 1);
        const int b = graph.add(task(1), {}, 2);
        graph.add(
            [&, a, b] {
                task(2)();
                // added while running: 3 after a and b, 4 after 3
                const int c = graph.add(task(3), {a, b}, 1);
                graph.add(task(4), {c}, 5);
            },
            {a}, 0);
        graph.add(task(5), {}, 0.5);
        graph.run(two ? &worker : nullptr);
        CHECK(log.size() == 6);
        auto pos = [&](int id) { return std::find(log.begin(), log.end(), id) - log.begin(); };
        CHECK(pos(2) > pos(0));
        CHECK(pos(3) > pos(0) && pos(3) > pos(1) && pos(3) > pos(2));
        CHECK(pos(4) > pos(3));
        if (!two) {
            CHECK(most.load() == 1);
            CHECK(log[0] == 1 && log[1] == 0);  // by priority among the ready ones
        }
    }
    {  // two ready tasks run at once on two threads: each waits (up to 20 s) to see the other start
        hh::Worker worker;
        hh::TaskGraph graph;
        std::atomic<int> started{0};
        std::atomic<int> met{0};
        auto meet = [&] {
            ++started;
            const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(20);
            while (started.load() < 2 && std::chrono::steady_clock::now() < until) std::this_thread::yield();
            if (started.load() == 2) ++met;
        };
        graph.add(meet, {}, 1);
        graph.add(meet, {}, 1);
        graph.run(&worker);
        CHECK(met.load() == 2);
    }
    for (bool two : {false, true}) {
        hh::Worker worker;
        hh::TaskGraph graph;
        std::atomic<int> after_error{0};
        const int bad = graph.add([] { throw std::runtime_error("task failed"); }, {}, 10);
        graph.add([&] { ++after_error; }, {bad}, 0);
        bool caught = false;
        try {
            graph.run(two ? &worker : nullptr);
        } catch (const std::runtime_error& e) {
            caught = std::strcmp(e.what(), "task failed") == 0;
        }
        CHECK(caught);
        CHECK(after_error.load() == 0);
    }
    hh::TaskGraph graph;  // a task after one not added yet is refused (no cycles, no hang)
    bool refused = false;
    try {
        graph.add([] {}, {0}, 0);
    } catch (const std::invalid_argument&) {
        refused = true;
    }
    CHECK(refused);
}


TEST(task_graph_runs_a_job_beside_another_and_returns_its_errors) {
    // run_beside from inside a task: with the worker free, the other job runs on it while this
    // thread runs its own (each waits up to 20 s to see the other start); with no worker, this
    // thread runs both; what the other job throws comes back from run_beside
    {
        hh::Worker worker;
        hh::TaskGraph graph;
        std::atomic<int> started{0}, met{0};
        auto meet = [&] {
            ++started;
            const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(20);
            while (started.load() < 2 && std::chrono::steady_clock::now() < until) std::this_thread::yield();
            if (started.load() == 2) ++met;
        };
        graph.add([&] { graph.run_beside(meet, meet, 1); }, {}, 1);
        graph.run(&worker);
        CHECK(met.load() == 2);
    }
    for (bool two : {false, true}) {
        hh::Worker worker;
        hh::TaskGraph graph;
        int mine = 0, other = 0;
        bool caught = false;
        graph.add(
            [&] {
                graph.run_beside([&] { ++mine; }, [&] { ++other; }, 1);
                try {
                    graph.run_beside([&] { ++mine; }, [] { throw std::runtime_error("beside failed"); }, 1);
                } catch (const std::runtime_error& e) {
                    caught = std::strcmp(e.what(), "beside failed") == 0;
                }
            },
            {}, 1);
        graph.run(two ? &worker : nullptr);
        CHECK(mine == 2 && other == 1);
        CHECK(caught);
    }
}
