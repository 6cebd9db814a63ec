// A body's collision surface: triangles over surface vertices, each vertex a fixed linear
// combination of up to four body points (the tet nodes that embed it, or itself for a rigid
// mesh). Positions, normals and the BVH are updated every step from the body's state.
#pragma once
#include <vector>

#include "contact/bvh.h"

namespace hh {

struct CollisionSurface {
    // surface vertex v = sum_k weights[v][k] * point(nodes[v][k]); unused slots have weight 0
    std::vector<Eigen::Vector4i> nodes;
    std::vector<Vec4> weights;
    std::vector<Eigen::Vector3i> triangles;
    std::vector<Eigen::Vector2i> edges;              // each edge once
    std::vector<Eigen::Vector2i> edge_triangles;     // the (one or two) triangles of each edge
    std::vector<Eigen::Vector3i> triangle_edges;     // the three edges of each triangle
    std::vector<std::vector<int>> vertex_triangles;  // triangles around each vertex

    // per step
    std::vector<Vec3> x;               // vertex positions
    std::vector<Vec3> vertex_normal;   // area-weighted, outward
    std::vector<Vec3> triangle_normal; // unit, outward
    Bvh bvh;                           // over the triangles, boxes inflated by the detection distance

    // Fixed once the BVH is built (first update): the triangles by rank (Bvh), and which leaf
    // carries each vertex and each edge in a traversal of the tree against another one. A
    // vertex or an edge belongs to the leaf of one of its triangles, so the leaf's (tight)
    // box contains it; node i's own vertices are leaf_vertex[leaf_vertex_begin[i] ..
    // leaf_vertex_begin[i + 1]) (none for inner nodes), likewise edges.
    std::vector<Eigen::Vector3i> rank_triangles;
    std::vector<int> leaf_vertex_begin, leaf_vertex, leaf_edge_begin, leaf_edge;
    std::vector<int> loose_vertices;  // on no triangle: queried one by one
    // the ranks of the triangles having each edge, ascending: edge_ranks[edge_rank_begin[e] ..
    // edge_rank_begin[e + 1])
    std::vector<int> edge_rank_begin, edge_ranks;

    int n_vertices() const { return static_cast<int>(nodes.size()); }
};

// Checks indices and builds edges and adjacency; throws InvalidArgument naming the problem.
void init_surface(CollisionSurface& s, int n_points);

// Recomputes x from the body's points, normals, boxes (inflated by margin) and the BVH.
void update_surface(CollisionSurface& s, const std::vector<Vec3>& points, double margin);

}  // namespace hh
