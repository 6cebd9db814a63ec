// The last step's contact impulses f carried into a reused factor's free solve
// (World::solve_free): the free solve takes them as a known load, and their lagged response
// P f comes out again, so that only the change of the impulses sees the factor's lag.
//
// For a body whose contact responses come from the blocks its factor keeps (a soft body, or a
// skeleton hand whose bones all follow their targets and whose contacts touch only flesh:
// World::flesh_alone) taking P f out waits. The contact build reads P f at the touched
// unknowns from those blocks (the few columns of f's nodes not kept yet are solved), and the
// step's impulse pass applies P (J^T lambda - f) in one pass through the factor, where a pass
// for P f and one for P J^T lambda were made: ~0.8 ms a step on the grasping hand. The same
// operator, so the same velocities to round-off. A body whose build takes its responses per
// row, or that has no contact this step, takes P f out whole.
#include "sim/world.h"

namespace hh {

bool World::defers_carried(const Body& b, const VecX& carried) const {
    if (!carried.size()) return false;
    const DeformableSystem* system = b.response_system();
    if (!system || system->solver() != DeformableSolver::ReusedCholesky) return false;
    return loads_flesh_alone(b, !carried.head(b.handle_dofs()).isZero(0));
}

// The body's lagged response to a load on its unknowns (the operator of its impulse pass)
VecX World::lagged_response(Body& b, const VecX& load) {
    if (b.kind == BodyKind::Hand) return b.hand->skeleton.apply_inverse(load);
    MatX x;
    b.soft.tool->solve_response(load, x);
    return x.col(0);
}

// P f out of the free velocities now, whole
void World::take_out_carried(int bi) {
    Body& b = *bodies[bi];
    if (!b.carried_pending.size()) return;
    b.v_free -= lagged_response(b, b.carried_pending);
    b.v_new = b.v_free;
    b.carried_pending.resize(0);
}

// In the contact build (ready_contact_body, the basis chosen): P f at the touched unknowns from
// the kept blocks, or P f out whole
void World::read_carried(int bi) {
    Body& b = *bodies[bi];
    ContactBody& cb = contact_bodies.at(bi);
    cb.carried_at_touched.resize(0);
    if (!b.carried_pending.size()) return;
    const Eigen::Index flesh = b.dofs() - b.handle_dofs();
    if (!cb.row_basis && flesh_alone(bi) &&
        b.response_system()->response_at(touched_flesh(bi), b.carried_pending.tail(flesh), cb.carried_at_touched,
                                         flesh_beside(b)))
        return;
    take_out_carried(bi);
}

// The step's impulse pass's load: J^T lambda, less f while P f is still in the free velocities
VecX World::impulse_pass_load(const Body& b, const VecX& impulses) const {
    return b.carried_pending.size() ? VecX(impulses - b.carried_pending) : impulses;
}

}  // namespace hh
