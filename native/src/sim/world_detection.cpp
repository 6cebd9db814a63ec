// Collision detection of a world step (World, sim/world.h), in parts the step runs as tasks
// (sim/world_schedule.cpp): each body's reach, then its surface, then each pair (or self, or
// plane) on its own, then the pairs' contacts gathered in a fixed order and reduced to one per
// patch cell (docs/contact.md, Detection).
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <unordered_map>

#include "sim/world.h"
#include "sim/world_contact.h"

namespace hh {

namespace {
// Fraction of the contact thickness by which last step's representative of a patch cell may be
// shallower than the deepest contact there and still be kept (reduce_contacts)
constexpr double kKeepRepresentative = 0.01;
}  // namespace

// (As tasks on two threads side by side, detection does not hold back every contact response
// while the other thread is already in the bodies' free solves, as one task would.)
void World::begin_detection() {
    // Resting contacts settle at exactly the thickness: look half a thickness further so they
    // are found every step instead of flickering in and out at the edge of the reach.
    const double base = 1.5 * settings.contact_thickness;
    // Fast surfaces may close more than that within a step: each body is looked at further by
    // how far its farthest-moving point can travel in the step (Body::step_travel: from its
    // velocities and, for what is driven, its end-of-step target), so a falling or thrown body meets what
    // it will hit as an open contact whose gap the solve closes exactly within the step
    // (speculative contact) instead of tunnelling in. Per body, so that one fast body does not
    // widen every pair's search. (It was one reach for all, capped at two thicknesses: the
    // 10x letters fell 16 mm into the ground.)
    motion_.assign(bodies.size(), 0.0);
    for (size_t i = 0; i < bodies.size(); ++i) {
        const double travel = bodies[i]->step_travel(settings.dt);
        motion_[i] = std::isfinite(travel) ? travel : 0.0;
    }
    // The trees' margin: the self-collision reach (one body's parts, such as fingers, move
    // against each other far slower than the body moves); pairs with a fast body reach further
    // by inflating the query side (detect_pair).
    surface_reach_.resize(bodies.size());
    for (size_t i = 0; i < bodies.size(); ++i) surface_reach_[i] = base + std::min(motion_[i], 2 * settings.contact_thickness);
    // pairs: World::pair_closing
    drift_.resize(bodies.size());
    for (size_t i = 0; i < bodies.size(); ++i) drift_[i] = bodies[i]->drift();
    base_reach_ = base;
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
                detection_jobs_.push_back({ai, static_cast<int>(j), base + pair_closing(ai, static_cast<int>(j)), {}});
        }
    }
}

namespace {
// A pair closes by at most m_a + m_b. Searching that less s = min(m_a, m_b, thickness / 2)
// misses only pairs farther than base + m_a + m_b - s, which end the step farther than
// base - s >= the thickness: found in time next step. (It keeps slow pairs, such as the paper
// bunny's, at the reach of the faster body alone.)
double closing(double ma, double mb, double thickness) { return ma + mb - std::min({ma, mb, 0.5 * thickness}); }
}  // namespace

// The bound holds with m_a and m_b seen from any one frame moving at c: the pair's points close
// by |(x_a - c h) - (x_b - c h)|. The least of c = 0 and each body's drift keeps a pair carried
// together at the reach of their motion relative to each other: a ball lifted in the grasping
// hand at 9 cm/s was searched 6 mm around, which found ~340 contacts where ~140 hold it
// (bench/bench_grasp.py).
double World::pair_closing(int a, int b) const {
    const double t = settings.contact_thickness;
    double least = closing(motion_[a], motion_[b], t);
    for (const Vec3& c : {drift_[a], drift_[b]}) {
        const double ma = bodies[a]->step_travel(settings.dt, c), mb = bodies[b]->step_travel(settings.dt, c);
        if (std::isfinite(ma) && std::isfinite(mb)) least = std::min(least, closing(ma, mb, t));
    }
    return least;
}

// A skeleton hand's pair is searched as far as its fastest bone moves, but each contact needs
// only the reach of the bones its points move with: each node's region (its bone, or for flesh
// the bone nearest at rest, SkeletonModel::node_region), that bone's parent and children (the
// flesh between two bones moves between their motions), and the node's own velocity. A hand
// closing its fingers on a ball kept ~300 contacts a step, the palm's and the ball's within a
// fingertip's travel of each other; the contacts dropped here are beyond the reach of their own
// points' motion, so they end the step farther than the thickness (as the pair bound's).
void World::drop_beyond_own_reach(DetectionJob& job) const {
    auto skeleton_hand = [&](int i) { return bodies[i]->skeleton(); };
    if (job.a == job.b || (!skeleton_hand(job.a) && !skeleton_hand(job.b)) || job.found.empty()) return;
    const double dt = settings.dt, t = settings.contact_thickness;
    const Vec3 frames[3] = {Vec3::Zero(), drift_[job.a], drift_[job.b]};
    // per frame: each skeleton side's bone travels, else the body's whole travel
    struct Side { std::vector<double> bone[3]; double whole[3]; };
    Side side[2];
    const int body[2] = {job.a, job.b};
    for (int s = 0; s < 2; ++s) {
        const Body& b = *bodies[body[s]];
        for (int f = 0; f < 3; ++f) {
            side[s].whole[f] = b.step_travel(dt, frames[f]);
            if (!b.skeleton()) continue;
            for (int k = 0; k < b.hand_model->n_bones(); ++k) side[s].bone[f].push_back(b.bone_travel(k, dt, frames[f]));
        }
    }
    // m: how far the points of one side of a contact move, seen from frame f (either side may
    // be either body: detect_pair takes the vertices of each against the other's triangles)
    auto travel = [&](const ContactSide& cs, int f) {
        const int s = cs.body == job.a ? 0 : 1;
        const Body& b = *bodies[body[s]];
        if (!b.skeleton()) return side[s].whole[f];
        const SkeletonModel& rig = b.hand_model->skeleton;
        double m = 0;
        for (int k = 0; k < cs.count; ++k)
            for (int slot = 0; slot < 4; ++slot) {
                if (b.surface.weights[cs.vertex[k]][slot] == 0) continue;
                const int node = b.surface.nodes[cs.vertex[k]][slot], region = rig.node_region[node];
                m = std::max(m, (b.hand->v.segment<3>(3 * node) - frames[f]).norm() * dt);
                for (int bone : rig.region_bones[region]) m = std::max(m, side[s].bone[f][bone]);
            }
        return m;
    };
    std::vector<Contact> kept;
    kept.reserve(job.found.size());
    for (const Contact& c : job.found) {
        double least = std::numeric_limits<double>::infinity();
        for (int f = 0; f < 3; ++f) least = std::min(least, closing(travel(c.a, f), travel(c.b, f), t));
        if (!(c.distance >= base_reach_ + least)) kept.push_back(c);
    }
    job.found.swap(kept);
}

void World::update_body_surface(int i) {
    Body& b = *bodies[i];
    b.update_points();
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
        detect_plane(a.surface, job.a, b.plane.point, b.plane.normal, job.b, DetectionSettings{job.reach}, job.found);
    else
        detect_pair(a.surface, job.a, b.surface, job.b, DetectionSettings{job.reach}, job.found);
    drop_beyond_own_reach(job);
}

void World::finish_detection() {
    contacts.clear();  // (in the jobs' order: the same contacts in the same order on one thread as on two)
    for (const DetectionJob& job : detection_jobs_) contacts.insert(contacts.end(), job.found.begin(), job.found.end());
    reduce_contacts();
    defer_separating_contacts();
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

}  // namespace hh
