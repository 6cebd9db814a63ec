// The deformable block of Eq. 7 for any co-rotational body (the hand's flesh, a soft
// object): A_t = M (1 + dt alpha) + (dt beta + dt^2) R K R^T, and
// b_t = M v + dt (f_elastic + m g), with Rayleigh damping D = alpha M + beta K.
#pragma once
#include "sim/model.h"
#include "solver/deformable_system.h"

namespace hh {

struct FleshState {
    VecX x, v;
    ElementRotations rotations;
    VecX f_elastic;
    double elastic_energy = 0;
    double part_energy[3] = {0, 0, 0};  // of the element pass's parts (flesh_pass)
};

void reset_flesh(const Flesh& flesh, FleshState& state);

// Fills tool.A (pattern from flesh.pattern) and bt; marks the matrix changed. In stages:
// begin_flesh, then flesh_pass for parts 0 and 1 (A and B of flesh.passes: disjoint nodes, so
// two threads may run them at the same time), then part 2 (the seam), then end_flesh.
// flesh_pass evaluates the elements at `positions` when given (the hand: the state its step
// linearizes about, sim/step_frame.h), else at state.x.
void formulate_flesh(const Flesh& flesh, FleshState& state, double dt, const Vec3& gravity, double alpha,
                     double beta, DeformableSystem& tool, Eigen::Ref<VecX> bt);
void begin_flesh(const Flesh& flesh, FleshState& state, DeformableSystem& tool);
void flesh_pass(const Flesh& flesh, FleshState& state, double dt, double beta, DeformableSystem& tool, int part,
                const VecX* positions = nullptr);
void end_flesh(const Flesh& flesh, FleshState& state, double dt, const Vec3& gravity, double alpha, DeformableSystem& tool,
               Eigen::Ref<VecX> bt);

// Adds a 3x3 block to node i's diagonal block of A (pattern offsets from flesh).
void add_node_block(const Flesh& flesh, int node, const Mat3& block, double* values);

}  // namespace hh
