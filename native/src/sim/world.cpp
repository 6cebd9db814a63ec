// The world's bodies (World, sim/world.h): adding them, each dynamic body's free solve of the
// step (the hand through the Schur complement, soft and rigid bodies through their parts,
// sim/body.cpp) and the integration at its end. Detection, the contact solve and the step's
// schedule have their own units (sim/world_detection.cpp, world_contact.cpp, world_schedule.cpp).
#include "sim/world.h"
#include "sim/world_contact.h"  // (World::ContactSetup, complete for the constructor)

#include <chrono>

#include "common/clock.h"
#include "params/table.h"
#include "sim/skeleton_frame.h"
#include "sim/skeleton_step.h"

namespace hh {

WorldSettings::WorldSettings() : WorldSettings(params::world_defaults()) {}

WorldSettings::WorldSettings(const hh_world_params& p)
    : dt(p.dt),
      gravity(p.gravity[0], p.gravity[1], p.gravity[2]),
      contact_thickness(p.contact_thickness),
      contact_patch(p.contact_patch),
      max_iterations(p.max_iterations),
      tolerance(p.tolerance),
      stall_factor(p.stall_factor),
      threads(p.threads),
      defer_separating(p.defer_separating != 0) {}

World::World(const WorldSettings& s) : settings(s) {
    if (settings.threads > 1) worker_ = std::make_unique<Worker>();
}

int World::add(std::unique_ptr<Body> body) {
    bodies.push_back(std::move(body));
    Body& b = *bodies.back();
    b.update_points();
    if (b.has_surface) {
        init_surface(b.surface, static_cast<int>(b.points.size()));
        const double rest_reach = 2 * settings.contact_thickness;
        update_surface(b.surface, b.points, rest_reach);
        if (b.self_collision) b.self_exclusions = rest_exclusions(b.surface, DetectionSettings{rest_reach});
    }
    // the factor's symbolic analysis now rather than in the first step (analyse_ahead)
    if (DeformableSystem* system = b.response_system()) system->analyse_ahead();
    return static_cast<int>(bodies.size() - 1);
}

// The hand's element pass's last part and its assembly (formulate_end): At then holds the
// step's values, and its factorization's parts may start.
void World::assemble_hand(Body& b) {
    const auto t0 = std::chrono::steady_clock::now();
    formulate_pass(*b.hand_model, *b.hand, 2);
    formulate_end(*b.hand_model, *b.hand);
    b.hand_step.assembly_seconds = seconds_since(t0);
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
    b.carried_pending.resize(0);
    switch (b.kind) {
        case BodyKind::Hand: {
            if (b.skeleton()) {
                solve_free_skeleton(b);
                break;
            }
            // (formulate_begin and the element pass's parts 0 and 1 ran already, as tasks of
            // World::step that two threads can share; b.hand_step.pass_seconds holds their cost)
            HandStep& hs = b.hand_step;
            if (!hs.assemble_apart) {  // (else done by tasks of World::step, and the factor's parts with it)
                assemble_hand(b);
                hs.factor_part_seconds[0] = hs.factor_part_seconds[1] = 0;
                b.hand->tool.reset_counters();
            }
            hh_step_stats& st = b.hand->stats;
            st = hh_step_stats{};
            const double parts = hs.factor_part_seconds[0] + hs.factor_part_seconds[1];
            st.t_assembly = hs.pass_seconds[0] + hs.pass_seconds[1] + hs.pass_seconds[2] + hs.assembly_seconds;
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
            const VecX carried = take_carried_impulse(b, *b.soft.tool);
            const bool defer = defers_carried(b, carried);
            b.soft.solve_free(dt, settings.gravity, carried, b.v_free, !defer);
            if (defer) b.carried_pending = carried;  // (sim/world_carried.cpp)
            break;
        }
        case BodyKind::Rigid: b.mesh.solve_free(dt, settings.gravity, b.v_free); break;
        default: b.v_free.resize(0);
    }
    b.v_new = b.v_free;
    b.contact_force.setZero();
}

// A skeleton hand's free solve: the rest of formulate_skeleton (its begin ran before the step's
// tasks, World::add_free_solves), the B-bone Schur solve, and its velocities; with the reused
// factor the last step's contact impulses carried in as for the palm-handle hand above.
void World::solve_free_skeleton(Body& b) {
    const auto t0 = std::chrono::steady_clock::now();
    Data& d = *b.hand;
    hh_step_stats& st = d.stats;
    st = hh_step_stats{};
    formulate_skeleton_end(*b.hand_model, d);
    st.t_assembly = b.hand_step.pass_seconds[0] + seconds_since(t0);
    d.tool.reset_counters();
    SkeletonSystem& sys = d.skeleton;
    const VecX carried = take_carried_impulse(b, d.tool);
    if (carried.size()) {
        const Eigen::Index n3 = sys.r.size() - b.handle_dofs();
        d.tool.set_reference_norm(0, sys.r.tail(n3).norm());
        sys.r += carried;
    }
    sys.solve();
    b.v_free = skeleton_frame_velocities(*b.hand_model, d.frame, d.carried, sys.s);
    if (defers_carried(b, carried)) b.carried_pending = carried;  // (sim/world_carried.cpp)
    else if (carried.size()) b.v_free -= sys.apply_inverse(carried);
    st.t_deformable = sys.t_deformable;
    st.t_schur = sys.t_schur;
    st.cg_iterations = d.tool.iterations;
    st.max_residual = d.tool.max_residual;
    st.t_total = b.hand_step.pass_seconds[0] + seconds_since(t0);
}

void World::integrate() {
    const double dt = settings.dt;
    for (auto& bp : bodies) {
        Body& b = *bp;
        switch (b.kind) {
            case BodyKind::Hand:
                if (b.skeleton()) integrate_skeleton(*b.hand_model, *b.hand, b.v_new);
                else hh::integrate(*b.hand_model, *b.hand, b.v_new);
                break;
            case BodyKind::Soft: b.soft.integrate(b.v_new, dt); break;
            case BodyKind::Rigid: b.mesh.integrate(b.v_new, dt); break;
            case BodyKind::Kinematic: b.mesh.state = b.mesh.target; break;
            default: break;
        }
        b.update_points();
        b.update_surface_positions();
    }
}

double World::contact_distance(const Contact& c) const {
    const Body& a = *bodies[c.a.body];
    const Body& b = *bodies[c.b.body];
    const Vec3 pa = c.a.point(a.surface);
    if (b.kind == BodyKind::Plane) return (pa - b.plane.point).dot(b.plane.normal);
    return c.normal.dot(pa - c.b.point(b.surface));
}

}  // namespace hh
