// Speculative contacts a step leaves out of its contact solve while their points separate
// (docs/contact.md, Reach).
//
// A contact farther than the base reach (1.5 thicknesses) is found only because its bodies move:
// the search reaches as far as they may travel in the step, in any direction. When the contact's
// points separate at the start of the step (their relative velocity along its normal, from the
// bodies' velocities and the kinematic bodies' targets, is not closing), it waits outside the
// solve. After the solve each waiting contact's constraint is checked in the solve's own terms,
// u_n + gap / dt >= 0 with u_n from the solved velocities; if one fails, the step solves its
// contacts again with all of them (World::step). When none fails, the result is the one with
// them: a constraint that holds with zero impulse leaves the complementarity problem's solution
// as it is. A ball dropped from the grasping hand moves ~27 mm a step past its fingers: up to
// ~600 such contacts, each with its own unit columns on the factor.
#include <algorithm>

#include "sim/world.h"
#include "sim/world_contact.h"

namespace hh {

void World::defer_separating_contacts() {
    deferred.clear();
    deferred_patch_keys_.clear();
    if (!settings.defer_separating) return;
    size_t kept = 0;
    for (size_t c = 0; c < contacts.size(); ++c) {
        const Contact& k = contacts[c];
        const Vec3 relative = start_velocity(k.a) - start_velocity(k.b) + kinematic_velocity(k);
        if (k.distance >= base_reach_ && k.normal.dot(relative) >= 0) {
            deferred.push_back(k);
            deferred_patch_keys_.push_back(contact_patch_keys[c]);
        } else {
            contacts[kept] = k;
            contact_patch_keys[kept] = contact_patch_keys[c];
            ++kept;
        }
    }
    contacts.resize(kept);
    contact_patch_keys.resize(kept);
}

// A dynamic side's point velocity at the start of the step (kinematic sides: kinematic_velocity;
// a plane's side, which has no vertices: zero)
Vec3 World::start_velocity(const ContactSide& side) const {
    const Body& b = *bodies[side.body];
    switch (b.kind) {
        case BodyKind::Hand:
        case BodyKind::Soft: {
            const VecX& v = b.kind == BodyKind::Hand ? b.hand->v : b.soft.state.v;
            Vec3 u = Vec3::Zero();
            for (int k = 0; k < side.count; ++k)
                for (int q = 0; q < 4; ++q)
                    u += side.weight[k] * b.surface.weights[side.vertex[k]][q] * v.segment<3>(3 * b.surface.nodes[side.vertex[k]][q]);
            return u;
        }
        case BodyKind::Rigid:
            return b.mesh.state.v_com + b.mesh.state.omega.cross(side.point(b.surface) - b.mesh.state.x_com);
        default: return Vec3::Zero();
    }
}

// u_n of a contact from the bodies' velocities after the solve (J v_new, as the solve's rows);
// terms: scratch for J's terms, one for all the contacts checked
double World::solved_normal_velocity(const Contact& k, std::vector<ContactTerm>& terms) const {
    double u = k.normal.dot(kinematic_velocity(k));
    for (int s = 0; s < 2; ++s) {
        const ContactSide& side = s == 0 ? k.a : k.b;
        const Body& b = *bodies[side.body];
        if (!b.dynamic()) continue;
        terms.clear();
        append_side_terms(b, side, s == 0 ? 1.0 : -1.0, terms);
        for (const ContactTerm& t : terms) {
            const Vec3 v = t.rigid ? Vec3(b.v_new.head<3>() + b.v_new.segment<3>(3).cross(t.r)) : Vec3(b.v_new.segment<3>(t.offset));
            u += t.weight * k.normal.dot(v);
        }
    }
    return u;
}

bool World::a_deferred_contact_closes() const {
    std::vector<ContactTerm> terms;
    return std::any_of(deferred.begin(), deferred.end(),
                       [&](const Contact& k) { return contact_gap(k) + settings.dt * solved_normal_velocity(k, terms) < 0; });
}

// Before the second solve: the contacts with the deferred ones, every body back at its free
// velocities (the first solve's impulses are added to them in apply_contact_body)
void World::take_back_deferred_contacts() {
    for (const auto& bp : bodies) bp->v_new = bp->v_free;
    contacts.insert(contacts.end(), deferred.begin(), deferred.end());
    contact_patch_keys.insert(contact_patch_keys.end(), deferred_patch_keys_.begin(), deferred_patch_keys_.end());
    deferred.clear();
    deferred_patch_keys_.clear();
}

}  // namespace hh
