// A skeleton of B rigid bones, each a handle of Section 4 (docs/skeleton.md, Section 1): the
// capture of tet nodes by bone (explicit node sets first, then the nearest bone segment among
// the capsules holding the node), its checks, and Eq. 3 per bone. One bone with head = tail =
// the palm seed and radius = the handle radius captures exactly today's palm handle
// (rigid/handle.cpp), node for node and in the same ascending order.
#pragma once
#include <limits>
#include <string>
#include <vector>

#include "rigid/handle.h"

namespace hh {

struct BoneDesc {
    std::string name;
    int parent = -1;  // index of the parent bone, -1 for a root
    Vec3 head = Vec3::Zero(), tail = Vec3::Zero();
    double radius = 0;          // capsule radius (m); unused with an explicit set
    bool explicit_set = false;  // the bone holds exactly `nodes` (a Blender vertex group)
    std::vector<int> nodes;
    double drive_scale = 1;  // multiplies its virtual coupling's gains (0: free)
    // Angular limits (docs/skeleton.md, Section 5; coupling/joint_limits.h): its rotation
    // relative to its parent, as a rotation vector in its rest axes (columns x, y, z, world
    // frame), within [limit_min, limit_max] per axis (rad; -inf / +inf: free, the default)
    Mat3 axes = Mat3::Identity();
    Vec3 limit_min = Vec3::Constant(-std::numeric_limits<double>::infinity());
    Vec3 limit_max = Vec3::Constant(std::numeric_limits<double>::infinity());
};

// The static skeleton of a model: one handle model per bone (Eq. 3), bone 0 the root.
struct SkeletonModel {
    std::vector<HandleModel> bones;
    std::vector<int> parents;
    std::vector<std::string> names;
    std::vector<double> drive_scale;
    std::vector<int> node_bone;  // per tet node: its bone, -1 for flesh only
    // per tet node: its bone, or for flesh the bone whose segment is nearest at rest (the flesh
    // it moves with: speculative contact's reach per bone, World::drop_beyond_own_reach)
    std::vector<int> node_region;
    // per bone: itself, its parent and its children, the bones whose motion its region's
    // nodes follow (World::drop_beyond_own_reach reads it for every touched node, every step)
    std::vector<std::vector<int>> region_bones;
    // Per bone with a parent, its ball joint (docs/skeleton.md, Section 5): the bone's rest head
    // as a point of its parent (head - parent's rest centre of mass) and of itself (head - its
    // own); zero for a root. Body frames are the world frame at rest, as the springs' r_B.
    std::vector<Vec3> joint_on_parent, joint_on_child;
    // Per bone its angular limits (BoneDesc) and whether any axis is limited (never a root's)
    std::vector<Mat3> limit_axes;
    std::vector<Vec3> limit_min, limit_max;
    std::vector<unsigned char> limited;
};

// Distance of p to the segment [head, tail]; |p - head| exactly when head == tail (so a
// zero-length bone is the palm handle's sphere, bit for bit).
double segment_distance(const Vec3& p, const Vec3& head, const Vec3& tail);

// Throws InvalidArgument naming the bone and the fix: empty skeleton, repeated names, parents
// out of range or not a tree, non-finite segments, a capsule bone without a positive radius.
void check_skeleton(const std::vector<BoneDesc>& bones);

// Each node's bone (-1: flesh only) by the capture rule, after every check of the capture (at
// least 4 nodes per bone, a node in at most one explicit set, explicit nodes in range, not
// every node held). Bones are checked first (check_skeleton).
std::vector<int> capture_skeleton(const VecX& rest, const std::vector<BoneDesc>& bones);

// Eq. 3 per bone from the lumped masses, nodes ascending; throws when a bone's nodes are
// collinear (its inertia's smallest eigenvalue at most 1e-12 of its largest, as build_handle).
SkeletonModel build_skeleton(const VecX& rest, const VecX& node_masses, const std::vector<BoneDesc>& bones);

// The one-bone skeleton of a model built around the palm handle (its handle, called "palm").
SkeletonModel palm_skeleton(const HandleModel& handle, int n_nodes);

}  // namespace hh
