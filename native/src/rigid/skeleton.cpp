#include "rigid/skeleton.h"

#include <cmath>
#include <limits>
#include <sstream>

namespace hh {

namespace {
void require(bool ok, const std::string& message) {
    if (!ok) throw InvalidArgument(message);
}

std::string quoted(const BoneDesc& bone) { return "bone '" + bone.name + "'"; }

constexpr double kFree = std::numeric_limits<double>::infinity();  // an axis without a limit

bool has_limits(const BoneDesc& bone) {
    return (bone.limit_min.array() > -kFree).any() || (bone.limit_max.array() < kFree).any();
}

// Its angular limits: right-handed orthonormal rest axes, ranges that hold its rest pose (a
// range beside the rest pose would push the bone out of it from the first step) within a half
// turn (a rotation vector's length is at most pi: a range past it could never be left, and
// near it the vector flips), none on a root.
void check_limits(const BoneDesc& bone) {
    require(!bone.limit_min.hasNaN() && !bone.limit_max.hasNaN(),
            quoted(bone) + " has a NaN angular limit: give radians, or -inf / +inf for a free axis");
    require(!has_limits(bone) || bone.parent >= 0,
            quoted(bone) + " is a root with angular limits: a root turns with its target, not against a parent; "
                           "remove its limits");
    for (int i = 0; i < 3; ++i) {
        const double lo = bone.limit_min[i], hi = bone.limit_max[i];
        const std::string axis = quoted(bone) + ": its angular limit on its " + std::string(1, "xyz"[i]) + " axis, [" +
                                 std::to_string(lo) + ", " + std::to_string(hi) + "] rad,";
        require(lo <= 0 && hi >= 0, axis + " does not hold its rest pose (0): give a minimum <= 0 <= maximum");
        require((lo == -kFree || lo > -M_PI) && (hi == kFree || hi < M_PI),
                axis + " reaches a half turn: give limits within (-pi, pi) rad, or -inf / +inf for a free axis");
    }
    require(bone.axes.allFinite() && (bone.axes.transpose() * bone.axes - Mat3::Identity()).cwiseAbs().maxCoeff() < 1e-6 &&
                bone.axes.determinant() > 0,
            quoted(bone) + ": its rest axes are not a rotation (orthonormal, right-handed columns x, y, z): give its "
                           "rest matrix's axes");
}

// The explicit sets' owners (docs/skeleton.md: a node in two sets is an error).
std::vector<int> explicit_owners(int n, const std::vector<BoneDesc>& bones) {
    std::vector<int> owner(n, -1);
    for (size_t b = 0; b < bones.size(); ++b) {
        if (!bones[b].explicit_set) continue;
        for (int i : bones[b].nodes) {
            // (messages built only on failure: this runs per node)
            if (i < 0 || i >= n)
                throw InvalidArgument(quoted(bones[b]) + ": node " + std::to_string(i) +
                                      " of its vertex group is not a tet node (0.." + std::to_string(n - 1) +
                                      "): map the vertex group to the tet nodes again");
            if (owner[i] == static_cast<int>(b)) continue;  // listed twice in its own set
            if (owner[i] >= 0)
                throw InvalidArgument("node " + std::to_string(i) + " is in the vertex groups of both '" +
                                      bones[owner[i]].name + "' and '" + bones[b].name +
                                      "'; a node belongs to at most one bone: remove it from one group");
            owner[i] = static_cast<int>(b);
        }
    }
    return owner;
}

void check_counts(const std::vector<int>& owner, const std::vector<BoneDesc>& bones) {
    std::vector<int> count(bones.size(), 0);
    int held = 0;
    for (int b : owner)
        if (b >= 0) ++count[b], ++held;
    for (size_t b = 0; b < bones.size(); ++b) {
        if (count[b] >= 4) continue;
        std::ostringstream msg;
        msg << quoted(bones[b]) << ": ";
        if (bones[b].explicit_set)
            msg << "its vertex group holds " << count[b] << " node(s) of its own; a rigid bone needs at least 4: "
                << "add vertices to its vertex group";
        else
            msg << "its capsule of radius " << bones[b].radius << " m captures " << count[b]
                << " node(s) of its own; a rigid bone needs at least 4: increase its radius or move its segment "
                   "into the flesh";
        throw InvalidArgument(msg.str());
    }
    require(held < static_cast<int>(owner.size()),
            "the bones capture all " + std::to_string(owner.size()) +
                " nodes, so nothing of the hand is soft: decrease the capsule radii");
}
}  // namespace

double segment_distance(const Vec3& p, const Vec3& head, const Vec3& tail) {
    const Vec3 ab = tail - head;
    const double length2 = ab.squaredNorm();
    if (length2 == 0.0) return (p - head).norm();
    const double t = std::min(1.0, std::max(0.0, (p - head).dot(ab) / length2));
    return (p - (head + t * ab)).norm();
}

void check_skeleton(const std::vector<BoneDesc>& bones) {
    const int nb = static_cast<int>(bones.size());
    require(nb >= 1, "a skeleton needs at least one bone");
    for (int b = 0; b < nb; ++b) {
        const BoneDesc& bone = bones[b];
        for (int c = 0; c < b; ++c)
            require(bones[c].name != bone.name, "two bones are named '" + bone.name + "': bone names must be unique");
        require(bone.parent >= -1 && bone.parent < nb,
                quoted(bone) + " has parent " + std::to_string(bone.parent) +
                    ", which is not a bone of the skeleton: name an existing bone or none (-1, a root)");
        require(bone.head.allFinite() && bone.tail.allFinite(),
                quoted(bone) + " has a non-finite head or tail: give three finite coordinates in metres");
        require(bone.explicit_set || (std::isfinite(bone.radius) && bone.radius > 0),
                quoted(bone) + " has capsule radius " + std::to_string(bone.radius) +
                    " m and no vertex group: give it a positive radius (a few millimetres for a phalanx) or a "
                    "vertex group");
        require(std::isfinite(bone.drive_scale) && bone.drive_scale >= 0,
                quoted(bone) + " has a negative or non-finite drive scale: give 0 (free) or a positive factor");
        check_limits(bone);
    }
    for (int b = 0; b < nb; ++b) {  // every chain of parents ends at a root
        int j = bones[b].parent;
        for (int steps = 0; j >= 0; ++steps, j = bones[j].parent)
            require(steps < nb, quoted(bones[b]) + " is its own ancestor: the parents must form a tree");
    }
}

std::vector<int> capture_skeleton(const VecX& rest, const std::vector<BoneDesc>& bones) {
    check_skeleton(bones);
    const int n = static_cast<int>(rest.size() / 3);
    std::vector<int> owner = explicit_owners(n, bones);
    for (int i = 0; i < n; ++i) {
        if (owner[i] >= 0) continue;
        double best = 0;
        for (size_t b = 0; b < bones.size(); ++b) {
            if (bones[b].explicit_set) continue;
            const double d = segment_distance(rest.segment<3>(3 * i), bones[b].head, bones[b].tail);
            // the nearest segment wins (a thin finger bone takes the knuckle from the fat palm
            // capsule around it); strictly nearer, so an exact tie stays with the bone listed first
            if (d <= bones[b].radius && (owner[i] < 0 || d < best)) {
                owner[i] = static_cast<int>(b);
                best = d;
            }
        }
    }
    check_counts(owner, bones);
    return owner;
}

SkeletonModel build_skeleton(const VecX& rest, const VecX& node_masses, const std::vector<BoneDesc>& bones) {
    SkeletonModel s;
    s.node_bone = capture_skeleton(rest, bones);
    s.bones.resize(bones.size());
    for (size_t i = 0; i < s.node_bone.size(); ++i)
        if (s.node_bone[i] >= 0) s.bones[s.node_bone[i]].nodes.push_back(static_cast<int>(i));
    for (size_t b = 0; b < bones.size(); ++b) {
        HandleModel& h = s.bones[b];
        require(fill_mass_and_inertia(h, rest, node_masses),  // (Eq. 3 as the palm handle's)
                quoted(bones[b]) + ": its " + std::to_string(h.nodes.size()) +
                    " nodes lie on a line, so its inertia is singular: increase its radius so it holds nodes off "
                    "its axis");
        s.parents.push_back(bones[b].parent);
        s.names.push_back(bones[b].name);
        s.drive_scale.push_back(bones[b].drive_scale);
    }
    s.node_region = s.node_bone;
    for (size_t i = 0; i < s.node_region.size(); ++i) {
        if (s.node_region[i] >= 0) continue;
        double nearest = std::numeric_limits<double>::infinity();
        for (size_t b = 0; b < bones.size(); ++b) {
            const double d = segment_distance(rest.segment<3>(3 * i), bones[b].head, bones[b].tail);
            if (d < nearest) nearest = d, s.node_region[i] = static_cast<int>(b);
        }
    }
    s.region_bones.assign(bones.size(), {});
    for (size_t b = 0; b < bones.size(); ++b) {
        s.region_bones[b].push_back(static_cast<int>(b));
        if (bones[b].parent >= 0) {
            s.region_bones[b].push_back(bones[b].parent);
            s.region_bones[bones[b].parent].push_back(static_cast<int>(b));
        }
    }
    // after every bone's centre of mass: a parent may be listed after its child
    s.joint_on_parent.assign(bones.size(), Vec3::Zero());
    s.joint_on_child.assign(bones.size(), Vec3::Zero());
    for (size_t b = 0; b < bones.size(); ++b) {
        if (bones[b].parent < 0) continue;
        s.joint_on_parent[b] = bones[b].head - s.bones[bones[b].parent].rest_com;
        s.joint_on_child[b] = bones[b].head - s.bones[b].rest_com;
    }
    for (const BoneDesc& bone : bones) {
        s.limit_axes.push_back(bone.axes);
        s.limit_min.push_back(bone.limit_min);
        s.limit_max.push_back(bone.limit_max);
        s.limited.push_back(bone.parent >= 0 && has_limits(bone));
    }
    return s;
}

SkeletonModel palm_skeleton(const HandleModel& handle, int n_nodes) {
    SkeletonModel s;
    s.bones = {handle};
    s.parents = {-1};
    s.names = {"palm"};
    s.drive_scale = {1.0};
    s.joint_on_parent = s.joint_on_child = {Vec3::Zero()};
    s.limit_axes = {Mat3::Identity()};
    s.limit_min = {Vec3::Constant(-kFree)};
    s.limit_max = {Vec3::Constant(kFree)};
    s.limited = {0};
    s.node_bone.assign(n_nodes, -1);
    for (int i : handle.nodes) s.node_bone[i] = 0;
    s.node_region.assign(n_nodes, 0);
    s.region_bones = {{0}};
    return s;
}

}  // namespace hh
