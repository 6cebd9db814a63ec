// The static part of a simulation (MuJoCo's mjModel in spirit): rest mesh, material,
// element data, lumped masses, handle and springs, parameters. Built once, validated.
#pragma once
#include "fem/element_order.h"
#include "coupling/springs.h"
#include "fem/corotational.h"
#include "haptic_hand.h"
#include "rigid/handle.h"
#include "rigid/skeleton.h"

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
    HandleModel handle;  // the root bone's (bone 0), the palm handle of Section 4
    // Every bone, bone 0 the root (a copy of handle); a palm-handle model has one bone.
    SkeletonModel skeleton;
    int n_bones() const { return static_cast<int>(skeleton.bones.size()); }
};

// Throws InvalidArgument naming the first bad parameter and the fix.
void validate_params(const hh_params& p);

Model build_model(const double* rest_positions, int n_nodes, const int* tets, int n_tets,
                  const hh_params& params);
// The same with the bones of a skeleton as handles instead of the palm handle (params.palm_seed
// and handle_radius are not read; docs/skeleton.md). One bone with head = tail = seed and
// radius = handle_radius is build_model's model.
Model build_skeleton_model(const double* rest_positions, int n_nodes, const int* tets, int n_tets,
                           const hh_params& params, const std::vector<BoneDesc>& bones);

// Bone b's virtual coupling gains (k, d, k_r, d_r), docs/skeleton.md Section 4: the root keeps
// the scene's coupling.* gains (the palm-only device path); the others scale with the bone's
// mass and mean inertia at skeleton.drive.frequency and damping_ratio; both times its drive scale.
Vec4 bone_drive(const Model& model, int bone);

}  // namespace hh
