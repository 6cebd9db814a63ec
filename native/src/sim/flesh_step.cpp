#include "sim/flesh_step.h"

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

void formulate_flesh(const Flesh& flesh, FleshState& state, double dt, const Vec3& gravity, double alpha,
                     double beta, DeformableSystem& tool, Eigen::Ref<VecX> bt) {
    const int n = flesh.mesh.n_nodes;
    if (tool.A.rows() != 3 * n) tool.A = flesh.pattern.matrix;
    state.f_elastic.setZero(3 * n);
    double* values = tool.A.valuePtr();
    std::fill(values, values + tool.A.nonZeros(), 0.0);
    // rotations, elastic forces and dt (beta + dt) R K R^T in one pass over the elements
    state.elastic_energy = assemble_corotational(flesh.mesh, flesh.elements, state.x, state.f_elastic, state.rotations,
                                                 flesh.pattern, dt * beta + dt * dt, values);
    for (int i = 0; i < n; ++i) {
        for (int c = 0; c < 3; ++c) values[flesh.pattern.node_block_offsets[9 * i + 4 * c]] += flesh.masses[i] * (1 + dt * alpha);
        bt.segment<3>(3 * i) = flesh.masses[i] * state.v.segment<3>(3 * i) +
                               dt * (state.f_elastic.segment<3>(3 * i) + flesh.masses[i] * gravity);
    }
    tool.matrix_changed();
    tool.set_element_rotations(flesh.mesh.tets, state.rotations.r);  // for a reused factor's warp
}

}  // namespace hh
