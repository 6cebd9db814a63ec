// Self-intersections of a triangle surface: the pairs of triangles that cross or touch where a
// closed 2-manifold surface would keep them apart. A surface that passes bounds a volume that
// tetrahedralization and the inside tests can trust (overlapping shells, a finger pushed
// through the palm, a fold along an edge all fail).
#pragma once
#include <utility>
#include <vector>

#include "common/types.h"

namespace hh {

// Pairs (i, j), i < j, ascending: triangles that share no vertex and cross (an edge of one
// through the interior of the other) or, coplanar, overlap; triangles that share one vertex and
// cross or overlap away from it; triangles that share an edge and fold onto each other
// (coplanar, on the same side of it). Orientation signs are trusted only beyond Shewchuk's
// floating-point error bound; within it a sign counts as zero, and touching is not crossing
// (coincident vertices, the usual way surfaces touch, are the Python checks' concern).
std::vector<std::pair<int, int>> surface_self_intersections(const std::vector<Vec3>& vertices,
                                                            const std::vector<Eigen::Vector3i>& faces);

}  // namespace hh
