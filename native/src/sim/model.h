// The static part of a simulation (MuJoCo's mjModel in spirit): rest mesh, material,
// element data, lumped masses, handle and springs, parameters. Built once, validated.
#pragma once
#include "fem/element_order.h"
#include "coupling/springs.h"
#include "fem/corotational.h"
#include "haptic_hand.h"
#include "rigid/handle.h"

namespace hh {

// Static data of any co-rotational FEM body: the hand's flesh or another soft body.
struct Flesh {
    TetMesh mesh;
    CorotationalElements elements;
    VecX masses;  // lumped, per node
    StiffnessPattern pattern;
    ElementPassParts passes;  // the element pass in parts two threads can share (fem/element_order.h)
};

// Validates the mesh (indices, finite coordinates, every node in a tet, orientation) and
// precomputes elements, masses and the sparse pattern.
Flesh build_flesh(const double* rest_positions, int n_nodes, const int* tets, int n_tets, const Material& material);

struct Model : Flesh {
    hh_params params;
    HandleModel handle;
};

// Throws InvalidArgument naming the first bad parameter and the fix.
void validate_params(const hh_params& p);

Model build_model(const double* rest_positions, int n_nodes, const int* tets, int n_tets,
                  const hh_params& params);

}  // namespace hh
