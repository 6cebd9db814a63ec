// Narrow phase: vertex-triangle and edge-edge proximity within the detection distance, for
// a pair of bodies or within one body (self-collision, skipping primitives that share a
// vertex and surfaces that do not face each other), and vertices against planes.
#pragma once
#include <cstdint>
#include <unordered_set>
#include <vector>

#include "contact/surface.h"

namespace hh {

// One side of a contact: a point of a body's surface as a combination of 0 to 3 of its
// surface vertices (a vertex, a point on an edge, a point on a triangle; 0 for a plane).
struct ContactSide {
    int body = -1;
    int count = 0;
    int vertex[3] = {-1, -1, -1};
    double weight[3] = {0, 0, 0};
    Vec3 point(const CollisionSurface& s) const {
        Vec3 p = Vec3::Zero();
        for (int k = 0; k < count; ++k) p += weight[k] * s.x[vertex[k]];
        return p;
    }
};

struct Contact {
    ContactSide a, b;  // the normal points from b to a: a is pushed along +normal
    Vec3 normal, tangent1, tangent2;
    double distance = 0;  // signed, negative when a is behind b's surface
    Vec3 point;           // on b's surface, for reporting
};

struct DetectionSettings {
    double distance;  // report pairs closer than this (contact thickness plus a speculative margin)
};

// Self-collision pairs to ignore: those already closer than the thickness at rest (folds of
// the same flesh, such as the crease at the root of the thumb), found once by rest_exclusions.
struct SelfExclusions {
    std::unordered_set<std::uint64_t> vertex_triangle, edge_edge;
    static std::uint64_t key(int a, int b) { return (static_cast<std::uint64_t>(a) << 32) | static_cast<std::uint32_t>(b); }
    // vertex_triangle as a sorted list of triangles per vertex (triangles[begin[v] ..
    // begin[v + 1])): a hash look-up per candidate pair cost more than the distance itself
    std::vector<int> begin, triangles;
    void compile(int n_vertices);
    bool excludes(int v, int t) const;
};

void detect_pair(const CollisionSurface& sa, int body_a, const CollisionSurface& sb, int body_b,
                 const DetectionSettings& settings, std::vector<Contact>& out);
void detect_self(const CollisionSurface& s, int body, const DetectionSettings& settings, const SelfExclusions* skip,
                 std::vector<Contact>& out);
// The pairs detect_self finds in the surface's current (rest) configuration.
SelfExclusions rest_exclusions(const CollisionSurface& s, const DetectionSettings& settings);
void detect_plane(const CollisionSurface& s, int body, const Vec3& plane_point, const Vec3& plane_normal,
                  int plane_body, const DetectionSettings& settings, std::vector<Contact>& out);

// Two unit vectors completing n to an orthonormal frame.
void tangent_frame(const Vec3& n, Vec3& t1, Vec3& t2);

}  // namespace hh
