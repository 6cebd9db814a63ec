// The contact solve of a world step (World, sim/world.h), in parts the step schedules
// (World::step): prepare_contacts from the detected contacts alone; build_contact_body per
// dynamic body once its free solve is done (its responses to the contacts through its
// black-box solve); solve_contact_group per group of coupled contacts once its bodies are
// built (projected Gauss-Seidel); apply_contact_body per body once its group is solved (its
// final velocity solve); finish_contacts (impulses kept for the next step's warm start, forces, statistics).
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <functional>
#include <map>
#include <string>

#include "common/clock.h"
#include "sim/world_contact.h"
#include "rigid/quaternion.h"
#include "solver/block_ldlt.h"

namespace hh {

namespace {
// Shares of a body's contact responses (solve_contact_body): more than the two threads, so that
// the thread done with one body's still finds some of the other's to take
constexpr int kResponseShares = 4;
// Response columns (double) above which a group's are formed in shares (setup_contact_group)
constexpr size_t kSharedColumnsBytes = size_t(4) << 20;
// A row's solve costs about this many unit columns at the touched rows only (rows_cost_less)
constexpr size_t kUnitsPerRow = 3;

// Kinematic and static bodies: the velocity over the step of a world point carried by the
// body, from where the body is to its end-of-step target (World::integrate puts it there).
// Its displacement over dt, not its start-of-step velocity: a pusher that sets off fast this
// step moves now, and the gap the contact closes is the one it really crosses.
Vec3 carried_velocity(const Body& b, const Vec3& x, double dt) {
    if (b.kind != BodyKind::Kinematic) return Vec3::Zero();
    const Vec3 local = quat_to_matrix(b.mesh.state.q).transpose() * (x - b.mesh.state.x_com);
    return (b.mesh.target.x_com + quat_to_matrix(b.mesh.target.q) * local - x) / dt;
}

// A contact row's direction in the world: normal, tangent1, tangent2 (rows 3c, 3c + 1, 3c + 2)
const Vec3& contact_direction(const std::vector<Contact>& contacts, int row) {
    const Contact& c = contacts[row / 3];
    return row % 3 == 0 ? c.normal : (row % 3 == 1 ? c.tangent1 : c.tangent2);
}
}  // namespace

// One side of a contact on its body's unknowns: the terms of J's rows (sign: +1 for side a,
// -1 for side b), a rigid body's lever arm or each flesh node's share of the point
void append_side_terms(const Body& b, const ContactSide& side, double sign, std::vector<ContactTerm>& ts) {
    for (int k = 0; k < side.count; ++k) {
        const int v = side.vertex[k];
        if (b.kind == BodyKind::Rigid) {
            ts.push_back({0, sign * side.weight[k], true, b.surface.x[v] - b.mesh.state.x_com});
        } else {
            const int base = b.handle_dofs();
            for (int q = 0; q < 4; ++q) {
                const int node = b.surface.nodes[v][q];
                // a fixed node of a soft body does not move: it takes no impulse
                if (b.surface.weights[v][q] == 0 || (b.kind == BodyKind::Soft && b.soft.fixed[node])) continue;
                ts.push_back({base + 3 * node, sign * side.weight[k] * b.surface.weights[v][q], false, Vec3::Zero()});
            }
        }
    }
}

double World::contact_gap(const Contact& k) const {
    double gap = k.distance - settings.contact_thickness;
    // A hand's side ends its step beyond x + dt v by its step frame's turn (sim/step_frame.h)
    for (int s = 0; s < 2; ++s) {
        const ContactSide& side = s == 0 ? k.a : k.b;
        const Body& b = *bodies[side.body];
        if (b.kind == BodyKind::Hand && side.count > 0)
            gap += (s == 0 ? 1.0 : -1.0) * k.normal.dot(turn_remainder(b.hand->frame, side.point(b.surface)));
    }
    return gap;
}

Vec3 World::kinematic_velocity(const Contact& k) const {
    Vec3 vel = Vec3::Zero();
    for (int s = 0; s < 2; ++s) {
        const ContactSide& side = s == 0 ? k.a : k.b;
        const Body& b = *bodies[side.body];
        if (b.kind != BodyKind::Kinematic) continue;
        const Vec3 p = side.count > 0 ? side.point(b.surface) : k.point;
        vel += (s == 0 ? 1.0 : -1.0) * carried_velocity(b, p, settings.dt);
    }
    return vel;
}

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

World::~World() = default;

const std::vector<int>& World::contact_involved() const { return setup_->involved; }
const std::vector<int>& World::contact_group_bodies(int group) const { return setup_->group_bodies[group]; }

void World::prepare_contacts() {
    setup_ = std::make_unique<ContactSetup>();
    ContactSetup& cs = *setup_;
    cs.start = std::chrono::steady_clock::now();
    const int nc = cs.nc = static_cast<int>(contacts.size());
    contact_groups.clear();
    contact_group_of.assign(nc, -1);
    contact_slot.assign(nc, -1);
    contact_bodies.clear();
    contact_lambda.resize(0);
    contact_friction.resize(0);
    contact_velocity.resize(0);
    if (nc == 0) return;
    const int rows = cs.rows = 3 * nc;
    auto direction = [&](int row) -> const Vec3& { return contact_direction(contacts, row); };

    auto& sides = cs.sides;
    sides.assign(nc, {});
    std::vector<int>& involved = cs.involved;
    for (int c = 0; c < nc; ++c)
        for (int s = 0; s < 2; ++s) {
            const ContactSide& side = s == 0 ? contacts[c].a : contacts[c].b;
            if (side.body < 0 || !bodies[side.body]->dynamic()) continue;
            const Body& b = *bodies[side.body];
            const double sign = s == 0 ? 1.0 : -1.0;
            std::vector<ContactTerm>* ts = nullptr;
            for (auto& e : sides[c])
                if (e.first == side.body) ts = &e.second;  // self-contact: both sides on one body
            if (!ts) {
                if (sides[c].empty()) sides[c].reserve(2);  // (at most two bodies: few allocations)
                sides[c].emplace_back(side.body, std::vector<ContactTerm>());
                ts = &sides[c].back().second;
                ts->reserve(4 * side.count);
            }
            append_side_terms(b, side, sign, *ts);
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
    VecX &u_free = cs.u_free, &gap = cs.gap, &friction = cs.friction, &kinetic = cs.kinetic;
    u_free.setZero(rows);
    gap.resize(nc);
    friction.resize(nc);
    kinetic.resize(nc);
    for (int c = 0; c < nc; ++c) {
        const Contact& k = contacts[c];
        gap[c] = contact_gap(k);
        friction[c] = std::sqrt(bodies[k.a.body]->friction * bodies[k.b.body]->friction);
        kinetic[c] = std::sqrt(bodies[k.a.body]->kinetic_friction * bodies[k.b.body]->kinetic_friction);
        // kinematic bodies' motion enters as a known relative velocity
        const Vec3 vel = kinematic_velocity(k);
        for (int d = 0; d < 3; ++d) u_free[3 * c + d] += direction(3 * c + d).dot(vel);
    }

    cs.group_solve.resize(contact_groups.size());
    cs.group_bodies.resize(contact_groups.size());
    for (size_t g = 0; g < contact_groups.size(); ++g) {
        std::vector<int>& gb = cs.group_bodies[g];
        for (int c : contact_groups[g].contacts)
            for (const auto& e : sides[c])
                if (std::find(gb.begin(), gb.end(), e.first) == gb.end()) gb.push_back(e.first);
        std::sort(gb.begin(), gb.end());
    }
    for (int bi : involved) {  // (made here: the bodies are then built side by side)
        contact_bodies[bi];
        cs.build[bi];
        cs.response[bi];
        cs.u_body[bi];
    }

    // Warm start from the previous step's impulses of the same contacts
    VecX& lambda = cs.lambda;
    lambda.setZero(rows);
    for (int c = 0; c < nc; ++c) {
        auto it = previous_impulse.find(contact_key(contacts[c]));
        if (it == previous_impulse.end()) {
            // another vertex is the deepest of the same patch now: start from that patch's impulse
            it = previous_patch_impulse.find(contact_patch_keys[c]);
            if (it == previous_patch_impulse.end()) continue;
            ++cs.patch_hits;
        } else {
            ++cs.warm_hits;
        }
        lambda[3 * c] = it->second.dot(contacts[c].normal);
        lambda[3 * c + 1] = it->second.dot(contacts[c].tangent1);
        lambda[3 * c + 2] = it->second.dot(contacts[c].tangent2);
    }
}

// Per dynamic body: J_b on the unknowns it touches (G), their responses K from batched
// black-box solves (up to kWidestSolve right-hand sides per pass), its block G K G^T (or G K)
// of W, and its share of u_free. Writes only the body's own entries.
//
// A body on the per-step Cholesky factor (a soft body, or the hand through its tool under the
// Schur complement) splits its solves in kResponseShares shares that run side by side: the
// factor is only read by them (DeformableSystem::prepare_concurrent_solves). In the 10x bunny
// scene the bunny's ~500 solves were ~10 ms on one thread while the other, done with the
// hand's, waited. Bodies on the iterative or the reused solver take one share (their calls
// write warm starts and kept columns).
int World::contact_body_parts(int bi) const {
    const DeformableSystem* system = bodies[bi]->response_system();
    return system && system->solver() == DeformableSolver::Cholesky ? kResponseShares : 1;
}

void World::begin_contact_body(int bi) {
    ContactSetup& cs = *setup_;
    const int nc = cs.nc, rows = cs.rows;
    const auto& sides = cs.sides;
    auto direction = [&](int row) -> const Vec3& { return contact_direction(contacts, row); };
    Body& b = *bodies[bi];
    ContactBody& cb = contact_bodies.at(bi);
    const int dofs = b.dofs();
    std::vector<int> touched_mark(dofs, 0);
    for (int c = 0; c < nc; ++c)
        for (const auto& e : sides[c]) {
            if (e.first != bi) continue;
            for (int d = 0; d < 3; ++d) cb.rows.push_back(3 * c + d);
            for (const ContactTerm& t : e.second) {
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
    // G straight in compressed row form, each row's terms on one unknown summed in the order
    // they come (as setFromTriplets would; it and the transpose the solves no longer need cost
    // ~0.5 ms of the 10x bunny's build, before its solves could start)
    std::vector<int> outer(nr + 1, 0), inner;
    std::vector<double> values;
    std::vector<std::pair<int, double>> terms;
    for (int l = 0; l < nr; ++l) {
        const int row = cb.rows[l];
        const Vec3& u = direction(row);
        terms.clear();
        for (const auto& e : sides[row / 3]) {
            if (e.first != bi) continue;
            for (const ContactTerm& t : e.second) {
                if (t.rigid) {
                    const Vec3 ru = t.r.cross(u);
                    for (int d = 0; d < 3; ++d) {
                        terms.emplace_back(index_of[d], t.weight * u[d]);
                        terms.emplace_back(index_of[3 + d], t.weight * ru[d]);
                    }
                } else {
                    for (int d = 0; d < 3; ++d) terms.emplace_back(index_of[t.offset + d], t.weight * u[d]);
                }
            }
        }
        std::stable_sort(terms.begin(), terms.end(), [](const auto& x, const auto& y) { return x.first < y.first; });
        for (size_t k = 0; k < terms.size(); ++k) {
            if (k > 0 && terms[k].first == terms[k - 1].first) {
                values.back() += terms[k].second;
                continue;
            }
            inner.push_back(terms[k].first);
            values.push_back(terms[k].second);
        }
        outer[l + 1] = static_cast<int>(inner.size());
    }
    cb.G = Eigen::Map<const Eigen::SparseMatrix<double, Eigen::RowMajor>>(nr, nt, static_cast<Eigen::Index>(inner.size()),
                                                                         outer.data(), inner.data(), values.data());
    // the nodes of the touched unknowns: the solves need only their rows (BlockLDLT::solve)
    std::vector<int> touched_nodes;
    if (b.kind == BodyKind::Soft)
        for (int k : cb.touched)
            if (touched_nodes.empty() || touched_nodes.back() != k / 3) touched_nodes.push_back(k / 3);
    cs.build.at(bi).touched_nodes = std::move(touched_nodes);
}

// Whether the body's contact responses are its flesh system's inverse alone, at its touched
// unknowns less its handle's: a soft body's, or a skeleton hand's whose bones all follow their
// targets and whose contacts touch only its flesh (S = I and v_h = 0 in
// SkeletonSystem::apply_inverse_many: A_t^-1 itself, on the reused factor its lagged operator
// P^-1). After the body's free solve: a skeleton hand's bones_prescribed is the step's.
bool World::flesh_alone(int bi) const {
    const Body& b = *bodies[bi];
    const ContactBody& cb = contact_bodies.at(bi);
    return !cb.touched.empty() && loads_flesh_alone(b, cb.touched.front() < b.handle_dofs());
}

// Whether a load on the body moves its flesh alone: a soft body's, or a skeleton hand's whose
// bones all follow their targets when the load is on flesh only (on_bones false)
bool World::loads_flesh_alone(const Body& b, bool on_bones) {
    return b.kind == BodyKind::Soft || (b.skeleton() && b.hand->bones_prescribed && !on_bones);
}

// The jobs the body's flesh solves may run as (its system's two threads)
const Beside& World::flesh_beside(const Body& b) { return b.kind == BodyKind::Soft ? b.soft.beside : b.hand->hand.beside; }

// Whether the body's unit columns are solved on the step's Cholesky factor at the touched rows
// only (solve_upper_units): flesh alone, on the per-step factor (see ready_contact_body)
bool World::units_at_touched_rows(int bi) const {
    const DeformableSystem* system = static_cast<const Body&>(*bodies[bi]).response_system();
    return system && system->solver() == DeformableSolver::Cholesky && flesh_alone(bi);
}

// The unit columns of a body whose flesh responds alone (flesh_alone) from the blocks its
// reused factor keeps at the touched nodes (DeformableSystem::response_units): the same
// operator as the impulses' pass, without a pass through the factor for the nodes touched since
// it was renewed. False on the other solvers, or when the factor keeps none (not yet made).
bool World::kept_units(int bi) {
    Body& b = *bodies[bi];
    return b.response_system()->response_units(touched_flesh(bi), contact_bodies.at(bi).K, flesh_beside(b));
}

// The body's touched unknowns counted in its flesh system (past the handle's unknowns)
std::vector<int> World::touched_flesh(int bi) const {
    const std::vector<int>& touched = contact_bodies.at(bi).touched;
    std::vector<int> flesh(touched.size());
    for (size_t k = 0; k < touched.size(); ++k) flesh[k] = touched[k] - bodies[bi]->handle_dofs();
    return flesh;
}

// Whether the body's responses cost less on its contact rows than on its touched unknowns. A
// unit column at the touched rows only costs about a third of a row's full solve: in the grasp
// scene's opening, 31 contacts on the hand, 93 row solves took 5.8 ms where its 213 unit
// columns take 3.9 ms. Any other unit column costs about a row's. On a reused factor that keeps
// the flesh's blocks (kept_units) only the columns not kept yet cost a solve, at the kept rows:
// counting every touched unknown there had the grasp's opening take its 90 rows through the
// factor, 10.5 ms, where its few fresh columns cost well under a millisecond.
bool World::rows_cost_less(int bi) const {
    const ContactBody& cb = contact_bodies.at(bi);
    if (flesh_alone(bi)) {
        const int fresh = static_cast<const Body&>(*bodies[bi]).response_system()->fresh_response_unknowns(touched_flesh(bi));
        if (fresh >= 0) return kUnitsPerRow * cb.rows.size() < static_cast<size_t>(fresh);
    }
    return (units_at_touched_rows(bi) ? kUnitsPerRow : 1) * cb.rows.size() < cb.touched.size();
}

// Once the body's free solve is done too (its system, factor and Schur complement are the step's)
void World::ready_contact_body(int bi) {
    Body& b = *bodies[bi];
    ContactBody& cb = contact_bodies.at(bi);
    cb.row_basis = rows_cost_less(bi);
    read_carried(bi);
    cb.K.resize(cb.touched.size(), cb.row_basis ? cb.rows.size() : cb.touched.size());
    if (cb.row_basis) setup_->build.at(bi).gt = cb.G.transpose();  // (unit columns need none)
    // the unit columns from the kept response columns, when the body's solver keeps them: the
    // palm hand's with Eq. 12 on top; a soft body's or a prescribed skeleton hand's flesh alone
    // (any other skeleton hand's columns go through SkeletonSystem::apply_inverse_many)
    bool units = false;
    const bool palm = b.kind == BodyKind::Hand && !b.skeleton();
    if (!cb.row_basis && palm) units = b.hand->hand.apply_inverse_units(cb.touched, cb.touched, cb.K);
    if (!cb.row_basis && flesh_alone(bi)) units = kept_units(bi);
    if (palm) {
        if (!cb.row_basis && !units) b.hand->hand.prepare_unit_columns(cb.touched);
        if (!handle_terms_apart(bi)) form_handle_terms(bi);
    }
    ContactSetup::Build& build = setup_->build.at(bi);
    build.first = units ? static_cast<int>(cb.K.cols()) : 0;
    // On the step's Cholesky factor (readied here, so that the shares only read it): the unit
    // columns in the factor's elimination order, each batch's units in one part of the tree
    // (on the 10x bunny the build went from ~11 to ~10.2 ms on one thread)
    build.unit_order.clear();
    // A skeleton hand whose bones all follow their targets (Ah = I and A_ht = 0 in each bone's
    // rows, sim/skeleton_step.cpp): impulses on the flesh leave the bones' velocities as they are
    // (S = I, v_h = 0 in SkeletonSystem::apply_inverse_many), and the flesh's response is A_t^-1
    // itself. Its unit columns then need the factor only at the touched nodes, not at every
    // bone's nodes too (A_ht's rows read those): the grasping hand's ~200 columns cost ~0.6 of
    // that pass (bench/bench_grasp.py). The same values, bit for bit, at the touched rows.
    const bool flesh_alone = b.skeleton() && !cb.row_basis && units_at_touched_rows(bi);
    DeformableSystem* system = b.response_system();
    if (system && system->prepare_concurrent_solves() && !cb.row_basis && build.first == 0) {
        const int base = b.handle_dofs();
        std::vector<std::pair<int, int>> keyed;  // (elimination position of the node, column)
        keyed.reserve(cb.touched.size());
        for (size_t j = 0; j < cb.touched.size(); ++j) {
            const int u = cb.touched[j] - base;
            keyed.emplace_back(u < 0 ? -1 : system->elimination_position(u / 3), static_cast<int>(j));
        }
        std::stable_sort(keyed.begin(), keyed.end(), [](const auto& x, const auto& y) { return x.first < y.first; });
        for (const auto& e : keyed) build.unit_order.push_back(e.second);
    }
    build.upper = !build.unit_order.empty() && (b.kind == BodyKind::Soft || flesh_alone);
}

// The handle-space linearization's terms (haptics/coupling_model.cpp) of a hand with a
// prescribed handle: six solves (twelve on the reused factor) instead of every contact response
// at the handle nodes. Only the coupling model reads them, after the step.
void World::form_handle_terms(int bi) {
    Body& b = *bodies[bi];
    if (b.kind != BodyKind::Hand || b.skeleton() || !b.hand->device.prescribed) return;
    ContactBody& cb = contact_bodies.at(bi);
    MatX at_touched;
    // (Aht at the handle's end-of-step pose, where the model differentiates the springs' wrench)
    b.hand->hand.handle_columns(cb.touched, b.hand->end_aht, at_touched);
    cb.handle_terms = cb.G * at_touched;
}

// Whether the step runs form_handle_terms as a task of its own, which may run beside the
// sweeps and the final solves (on the 10x bunny with the ~17000-tet hand the other thread idles
// through the sweeps, ~7 ms): on the reused factor, whose response solves only read it (a
// pass through the factor, DeformableSystem::solve_response; the other solvers' solve_many
// writes the solve's bookkeeping).
bool World::handle_terms_apart(int bi) const {
    const Body& b = *bodies[bi];
    return b.kind == BodyKind::Hand && !b.skeleton() && b.hand->device.prescribed &&
           b.hand->tool.solver() == DeformableSolver::ReusedCholesky;
}

// Share `part` of `parts` of the body's solves: every parts-th batch of kWidestSolve columns
// (K's columns are written by one share each).
void World::solve_contact_body(int bi, int part, int parts) {
    const ContactSetup& cs = *setup_;
    const ContactSetup::Build& build = cs.build.at(bi);
    Body& b = *bodies[bi];
    ContactBody& cb = contact_bodies.at(bi);
    const int dofs = b.dofs();
    const int m = static_cast<int>(cb.K.cols());
    const Eigen::SparseMatrix<double>& gt = build.gt;
    MatX rhs, x;
    for (int first = build.first + part * kWidestSolve; first < m; first += parts * kWidestSolve) {
        const int w = std::min(kWidestSolve, m - first);
        // unit columns on the step's Cholesky factor: solved straight at the touched rows (the
        // full-length right-hand sides and solutions, built, copied and permuted per column, were
        // ~a third of these solves' time in the 10x bunny scene)
        if (build.upper) {
            solve_upper_units(bi, first, w);
            continue;
        }
        if (!cb.row_basis && !build.unit_order.empty() && b.kind == BodyKind::Hand && !b.skeleton()) {
            int units[kWidestSolve];
            for (int j = 0; j < w; ++j) units[j] = cb.touched[build.unit_order[first + j]];
            x.resize(cb.K.rows(), w);
            if (b.hand->hand.apply_inverse_unit_columns(units, w, cb.touched, x)) {
                for (int j = 0; j < w; ++j) cb.K.col(build.unit_order[first + j]) = x.col(j);
                continue;
            }
        }
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
            case BodyKind::Hand:  // only the touched rows, straight into K
                if (b.skeleton()) b.hand->skeleton.apply_inverse_many(rhs, x, &cb.touched);
                else b.hand->hand.apply_inverse_many(rhs, x, &cb.touched);
                cb.K.middleCols(first, w) = x;
                continue;
            case BodyKind::Soft: b.soft.tool->solve_response(rhs, x, &build.touched_nodes); break;
            default: x = Eigen::FullPivLU<Mat6>(b.mesh.system->A).solve(rhs);
        }
        for (size_t k = 0; k < cb.touched.size(); ++k) cb.K.block(k, first, 1, w) = x.block(cb.touched[k], 0, 1, w);
    }
}

// The unit columns first .. first + w (in elimination order) of A^-1 (ContactSetup::Build::upper)
// at the rows of the units from first on: their nodes and ancestors only, where all the rows'
// would reach the ancestors of every touched node (on the grasping hand's 216 columns, 3.8 ms
// against 4.3: the top of the elimination tree, which every column's path crosses, stays).
void World::solve_upper_units(int bi, int first, int w) {
    const ContactSetup::Build& build = setup_->build.at(bi);
    Body& b = *bodies[bi];
    ContactBody& cb = contact_bodies.at(bi);
    const int m = static_cast<int>(cb.K.cols()), base = b.kind == BodyKind::Soft ? 0 : b.handle_dofs();
    std::vector<int> rows(m - first);
    for (int r = first; r < m; ++r) rows[r - first] = cb.touched[build.unit_order[r]] - base;
    MatX x(rows.size(), w);
    DeformableSystem& system = b.kind == BodyKind::Soft ? *b.soft.tool : b.hand->tool;
    if (!system.solve_units(rows.data(), w, rows, x.data(), x.rows()))
        throw std::logic_error("World::solve_upper_units: the factor is not ready");
    for (int j = 0; j < w; ++j)
        for (size_t r = 0; r < rows.size(); ++r) cb.K(build.unit_order[first + r], build.unit_order[first + j]) = x(r, j);
}

// The entries solve_upper_units left: row a, column c with a's unit before c's batch, by symmetry
void World::mirror_upper(int bi) {
    const ContactSetup::Build& build = setup_->build.at(bi);
    ContactBody& cb = contact_bodies.at(bi);
    const int m = static_cast<int>(cb.K.cols());
    for (int c = 0; c < m; ++c) {
        const int batch_start = c - c % kWidestSolve;
        for (int a = 0; a < batch_start; ++a) cb.K(build.unit_order[a], build.unit_order[c]) = cb.K(build.unit_order[c], build.unit_order[a]);
    }
}

void World::finish_contact_body(int bi) {
    ContactSetup& cs = *setup_;
    const Body& b = *bodies[bi];
    ContactBody& cb = contact_bodies.at(bi);
    const int nt = static_cast<int>(cb.touched.size());
    if (cs.build.at(bi).upper) mirror_upper(bi);
    if (!cb.K.allFinite())  // (the solves above check only the rows they were asked for)
        throw NumericalError("the contact response of body " + std::to_string(bi) +
                             " is not finite: reduce the time step or check its material");
    // u_free, and the body's symmetric response on its basis for the sweeps
    VecX v_touched(nt);
    for (int k = 0; k < nt; ++k) v_touched[k] = b.v_free[cb.touched[k]];
    if (cb.carried_at_touched.size()) v_touched -= cb.carried_at_touched;  // (P f still in v_free)
    cs.u_body.at(bi) = cb.G * v_touched;
    MatX& response = cs.response.at(bi);
    if (cb.row_basis) {
        const MatX c_b = cb.G * cb.K;
        response = 0.5 * (c_b + c_b.transpose());
    } else {
        response = 0.5 * (cb.K + cb.K.transpose());
    }
    if (contact_trace) std::fprintf(contact_trace, "[body %d built at %.2f ms] ", bi, 1e3 * seconds_since(cs.start));
}

// One group of coupled contacts (it shares no body with the other groups): its problem on its
// bodies' responses (setup), the sweeps' response columns in kColumnShares shares that may run
// side by side (in the 10x bunny scene ~5 ms of one thread while the other waited), and the
// sweeps.
// Each group is its own contact problem. The hand's system is not symmetric (spring
// torques), so neither is W; Gauss-Seidel is only sure to converge on a symmetric one. Its
// symmetric part differs by terms of the order of the springs' damping times the handle's
// spin; the velocities below use the true operator.
void World::setup_contact_group(int group) {
    ContactSetup& cs = *setup_;
    for (int bi : cs.group_bodies[group]) {  // the group's part of u_free: its bodies' shares
        const ContactBody& cb = contact_bodies.at(bi);
        for (size_t l = 0; l < cb.rows.size(); ++l) cs.u_free[cb.rows[l]] += cs.u_body.at(bi)[l];
    }
    ContactGroup& g = contact_groups[group];
    const int gc = static_cast<int>(g.contacts.size());
    ContactSetup::GroupSolve& gs = cs.group_solve[group];
    ReducedContactProblem& prob = gs.problem;
    prob.dt = settings.dt;
    prob.u_free.resize(3 * gc);
    prob.gap.resize(gc);
    prob.friction.resize(gc);
    prob.kinetic.resize(gc);
    prob.begin.assign(1, 0);
    prob.begin.reserve(gc + 1);
    prob.entries.reserve(static_cast<size_t>(24) * gc);  // (a vertex and a triangle's nodes: up to 16 x 3 unknowns)
    std::map<int, int> slot;  // body -> index in prob.bodies
    VecX& lg = gs.lambda;
    lg.resize(3 * gc);
    for (int i = 0; i < gc; ++i) {
        const int c = g.contacts[i];
        prob.u_free.segment<3>(3 * i) = cs.u_free.segment<3>(3 * c);
        prob.gap[i] = cs.gap[c];
        prob.friction[i] = cs.friction[c];
        prob.kinetic[i] = cs.kinetic[c];
        lg.segment<3>(3 * i) = cs.lambda.segment<3>(3 * c);
        for (const auto& e : cs.sides[c]) {
            const int bi = e.first;
            auto sl = slot.find(bi);
            if (sl == slot.end()) {
                sl = slot.emplace(bi, static_cast<int>(prob.bodies.size())).first;
                prob.bodies.push_back({std::move(cs.response.at(bi))});
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
    gs.columns = std::make_unique<ReducedColumns>(prob, &lg);  // (the warm start picks the columns formed up front)
    gs.form_seconds.assign(kColumnShares, 0.0);
    // small groups' columns at once, here: handing a share to the other thread costs more
    // than it saves (paper bunny, ~1 MB of columns: contact 4.2 -> 4.5 ms a frame)
    gs.shared = gs.columns->bytes > kSharedColumnsBytes;
    if (!gs.shared) {
        const auto t0 = std::chrono::steady_clock::now();
        gs.columns->form(0, 1);
        gs.form_seconds[0] = seconds_since(t0);
    }
}

void World::form_contact_columns(int group, int part) {
    ContactSetup::GroupSolve& gs = setup_->group_solve[group];
    if (!gs.shared) return;
    const auto t0 = std::chrono::steady_clock::now();
    gs.columns->form(part, kColumnShares);
    gs.form_seconds[part] = seconds_since(t0);
}

void World::solve_contact_group(int group) {
    ContactSetup& cs = *setup_;
    ContactSetup::GroupSolve& gs = cs.group_solve[group];
    ContactGroup& g = contact_groups[group];
    const PgsResult res = solve_pgs(gs.problem, *gs.columns, gs.lambda, settings.max_iterations, settings.tolerance,
                                    settings.stall_factor);
    g.iterations = res.iterations;
    g.residual = res.residual;
    for (size_t i = 0; i < g.contacts.size(); ++i) cs.lambda.segment<3>(3 * g.contacts[i]) = gs.lambda.segment<3>(3 * i);
    gs.formed = gs.columns->formed_count();
    gs.columns.reset();  // (tens of MB in the 10x scenes)
}

// v = v* + A^-1 J^T lambda: one more solve per body, once its group is solved
void World::apply_contact_body(int bi) {
    const ContactSetup& cs = *setup_;
    Body& b = *bodies[bi];
    const ContactBody& cb = contact_bodies.at(bi);
    VecX lb(cb.rows.size());
    for (size_t l = 0; l < cb.rows.size(); ++l) lb[l] = cs.lambda[cb.rows[l]];
    const VecX f = cb.G.transpose() * lb;
    VecX rhs = VecX::Zero(b.dofs());
    for (size_t k = 0; k < cb.touched.size(); ++k) rhs[cb.touched[k]] = f[k];
    switch (b.kind) {
        case BodyKind::Hand:
            b.v_new += b.skeleton() ? b.hand->skeleton.apply_inverse(impulse_pass_load(b, rhs)) : b.hand->hand.apply_inverse(rhs);
            // (carried into the next free solve, World::solve_free)
            if (b.hand->tool.solver() == DeformableSolver::ReusedCholesky) b.carried_impulse = rhs;
            break;
        case BodyKind::Soft: {
            // the operator the sweeps saw, so the constraints hold (on the per-step factor the
            // exact solve; on the reused one its lagged operator, and the impulses carried into
            // the next free solve, World::solve_free)
            MatX x;
            b.soft.tool->solve_response(impulse_pass_load(b, rhs), x);
            b.v_new += x.col(0);
            if (b.soft.tool->solver() == DeformableSolver::ReusedCholesky) b.carried_impulse = rhs;
            break;
        }
        default: b.v_new += Eigen::FullPivLU<Mat6>(b.mesh.system->A).solve(rhs);
    }
}

void World::finish_contacts() {
    ContactSetup& cs = *setup_;
    const int nc = cs.nc;
    if (nc == 0) {
        previous_impulse.clear();
        previous_patch_impulse.clear();
        return;
    }
    const VecX& lambda = cs.lambda;
    stats.contact_groups = static_cast<int>(contact_groups.size());
    stats.iterations = 0;
    stats.residual = 0;
    for (const ContactGroup& g : contact_groups) {
        stats.iterations = std::max(stats.iterations, g.iterations);
        stats.residual = std::max(stats.residual, g.residual);
    }
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
    contact_friction = cs.friction;
    // the relative velocities the step leaves at its contacts: the free ones (every group's
    // u_free) changed by each body's response to the impulses (the coupling model's sliding ones)
    contact_velocity = cs.u_free;
    for (const auto& e : contact_bodies) {
        const ContactBody& cb = e.second;
        const Body& b = *bodies[e.first];
        VecX v_touched(cb.touched.size());
        for (size_t k = 0; k < cb.touched.size(); ++k) v_touched[k] = b.v_new[cb.touched[k]];
        const VecX change = cb.G * v_touched - cs.u_body.at(e.first);
        for (size_t l = 0; l < cb.rows.size(); ++l) contact_velocity[cb.rows[l]] += change[l];
    }
}

// The step's contact solve, to contact_trace: called once the step has summed its parts' times
void World::trace_contacts() const {
    if (!contact_trace || !setup_) return;
    const ContactSetup& cs = *setup_;
    std::fprintf(contact_trace, "warm %d patch %d deferred %zu ", cs.warm_hits, cs.patch_hits, deferred.size());
    double columns = 0;  // (of the sweeps' time)
    int formed = 0;
    for (const auto& gs : cs.group_solve) {
        for (double t : gs.form_seconds) columns += t;
        formed += gs.formed;
    }
    std::fprintf(contact_trace, "contacts %zu groups %zu build %.2f sweeps %.2f (columns %.2f, formed %d) apply %.2f ms it %d |",
                 contacts.size(), contact_groups.size(), 1e3 * stats.t_contact_build, 1e3 * stats.t_contact_sweeps, 1e3 * columns,
                 formed, 1e3 * stats.t_contact_apply, stats.iterations);
    for (const auto& e : contact_bodies)
        std::fprintf(contact_trace, " body %d rows %zu touched %zu %s", e.first, e.second.rows.size(), e.second.touched.size(), e.second.row_basis ? "R" : "D");
    std::fprintf(contact_trace, "\n");
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
                h.col(j) = cb.K.col(local[j]);
            } else {
                h.col(j).setZero();
                for (Eigen::SparseMatrix<double, Eigen::RowMajor>::InnerIterator it(cb.G, local[j]); it; ++it)
                    h.col(j) += cb.K.col(it.col()) * it.value();
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

bool World::contact_handle_terms(int body, int row, Vec6& through_ath, Vec6& through_aht) const {
    auto it = contact_bodies.find(body);
    if (it == contact_bodies.end() || row < 0 || row >= static_cast<int>(it->second.local_row.size())) return false;
    const ContactBody& cb = it->second;
    const int l = cb.local_row[row];
    if (l < 0) return false;
    if (cb.handle_terms.rows() != static_cast<Eigen::Index>(cb.rows.size()))
        throw InvalidArgument("World::contact_handle_terms: the body is not a hand with a prescribed handle");
    through_ath = cb.handle_terms.row(l).head<6>().transpose();
    through_aht = cb.handle_terms.row(l).tail<6>().transpose();
    return true;
}

}  // namespace hh
