#include "sim/flesh_step.h"

#include <algorithm>

namespace hh {

void reset_flesh(const Flesh& flesh, FleshState& state) {
    state.x = flesh.mesh.rest;
    state.v = VecX::Zero(flesh.mesh.rest.size());
    state.rotations = ElementRotations{};
    state.f_elastic = VecX::Zero(flesh.mesh.rest.size());
    state.elastic_energy = 0;
}

void add_node_block(const Flesh& flesh, int node, const Mat3& block, double* values) {
    const int* off = &flesh.pattern.node_block_offsets[9 * node];
    for (int a = 0; a < 3; ++a)
        for (int b = 0; b < 3; ++b) values[off[3 * a + b]] += block(a, b);
}

void begin_flesh(const Flesh& flesh, FleshState& state, DeformableSystem& tool) {
    const int n = flesh.mesh.n_nodes;
    if (tool.A.rows() != 3 * n) tool.A = flesh.pattern.matrix;
    state.f_elastic.resize(3 * n);
    size_rotations(state.rotations, flesh.mesh.tets.size());
}

void flesh_pass(const Flesh& flesh, FleshState& state, double dt, double beta, DeformableSystem& tool, int part,
                const VecX* positions) {
    const ElementPassParts& parts = flesh.passes;
    double* values = tool.A.valuePtr();
    if (part < 2) {  // this part's nodes start from zero: their three columns and forces
        const auto* outer = tool.A.outerIndexPtr();
        for (int i : parts.owned_nodes[part]) {
            std::fill(values + outer[3 * i], values + outer[3 * i + 3], 0.0);
            state.f_elastic.segment<3>(3 * i).setZero();
        }
    }
    // rotations, elastic forces and dt (beta + dt) R K R^T in one pass over the part's elements
    const VecX& x = positions ? *positions : state.x;
    state.part_energy[part] =
        assemble_corotational(flesh.mesh, flesh.elements, x, state.f_elastic, state.rotations, flesh.pattern,
                              dt * beta + dt * dt, values, part == 0 ? 0 : parts.end[part - 1], parts.end[part]);
}

void end_flesh(const Flesh& flesh, FleshState& state, double dt, const Vec3& gravity, double alpha, DeformableSystem& tool,
               Eigen::Ref<VecX> bt) {
    const int n = flesh.mesh.n_nodes;
    double* values = tool.A.valuePtr();
    state.elastic_energy = state.part_energy[0] + state.part_energy[1] + state.part_energy[2];
    for (int i = 0; i < n; ++i) {
        for (int c = 0; c < 3; ++c) values[flesh.pattern.node_block_offsets[9 * i + 4 * c]] += flesh.masses[i] * (1 + dt * alpha);
        bt.segment<3>(3 * i) = flesh.masses[i] * state.v.segment<3>(3 * i) +
                               dt * (state.f_elastic.segment<3>(3 * i) + flesh.masses[i] * gravity);
    }
    tool.matrix_changed();
    tool.set_element_rotations(flesh.mesh.tets, state.rotations.r);  // for a reused factor's warp
}

void formulate_flesh(const Flesh& flesh, FleshState& state, double dt, const Vec3& gravity, double alpha,
                     double beta, DeformableSystem& tool, Eigen::Ref<VecX> bt) {
    begin_flesh(flesh, state, tool);
    for (int part = 0; part < 3; ++part) flesh_pass(flesh, state, dt, beta, tool, part);
    end_flesh(flesh, state, dt, gravity, alpha, tool, bt);
}

}  // namespace hh
