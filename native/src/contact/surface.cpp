#include "contact/surface.h"

#include <map>
#include <string>

namespace hh {

void init_surface(CollisionSurface& s, int n_points) {
    const int nv = s.n_vertices();
    for (int v = 0; v < nv; ++v)
        for (int k = 0; k < 4; ++k)
            if (s.weights[v][k] != 0 && (s.nodes[v][k] < 0 || s.nodes[v][k] >= n_points))
                throw InvalidArgument("collision surface vertex " + std::to_string(v) + " refers to point " +
                                      std::to_string(s.nodes[v][k]) + ", outside the body's " +
                                      std::to_string(n_points) + " points");
    s.vertex_triangles.assign(nv, {});
    std::map<std::pair<int, int>, int> edge_index;
    s.edges.clear();
    s.edge_triangles.clear();
    s.triangle_edges.assign(s.triangles.size(), Eigen::Vector3i(-1, -1, -1));
    for (size_t t = 0; t < s.triangles.size(); ++t) {
        const auto& tri = s.triangles[t];
        for (int k = 0; k < 3; ++k) {
            if (tri[k] < 0 || tri[k] >= nv)
                throw InvalidArgument("collision triangle " + std::to_string(t) + " refers to vertex " +
                                      std::to_string(tri[k]) + ", outside 0.." + std::to_string(nv - 1));
            s.vertex_triangles[tri[k]].push_back(static_cast<int>(t));
            const int a = tri[k], b = tri[(k + 1) % 3];
            const auto key = std::make_pair(std::min(a, b), std::max(a, b));
            auto it = edge_index.find(key);
            if (it == edge_index.end()) {
                s.triangle_edges[t][k] = static_cast<int>(s.edges.size());
                edge_index[key] = static_cast<int>(s.edges.size());
                s.edges.emplace_back(key.first, key.second);
                s.edge_triangles.emplace_back(static_cast<int>(t), -1);
            } else {
                s.triangle_edges[t][k] = it->second;
                s.edge_triangles[it->second][1] = static_cast<int>(t);
            }
        }
    }
    s.x.assign(nv, Vec3::Zero());
    s.vertex_normal.assign(nv, Vec3::Zero());
    s.triangle_normal.assign(s.triangles.size(), Vec3::Zero());
    s.bvh = Bvh{};  // built at the first update
}

namespace {

// Which leaf carries each vertex and each edge (see CollisionSurface), once the tree is built.
void assign_to_leaves(CollisionSurface& s) {
    const auto& nodes = s.bvh.nodes();
    const int n_nodes = static_cast<int>(nodes.size());
    std::vector<int> leaf_of_rank(s.triangles.size(), -1);
    for (int i = 0; i < n_nodes; ++i)
        if (nodes[i].leaf())
            for (int r = nodes[i].begin; r < nodes[i].end; ++r) leaf_of_rank[r] = i;
    auto bucket = [&](int n_items, auto triangle_of, std::vector<int>& begin, std::vector<int>& items) {
        std::vector<int> owner(n_items, -1);
        begin.assign(n_nodes + 1, 0);
        for (int k = 0; k < n_items; ++k) {
            const int t = triangle_of(k);
            if (t < 0) continue;
            owner[k] = leaf_of_rank[s.bvh.rank_of(t)];
            ++begin[owner[k] + 1];
        }
        for (int i = 0; i < n_nodes; ++i) begin[i + 1] += begin[i];
        items.assign(begin[n_nodes], -1);
        std::vector<int> fill(begin.begin(), begin.end() - 1);
        for (int k = 0; k < n_items; ++k)
            if (owner[k] >= 0) items[fill[owner[k]]++] = k;
    };
    bucket(s.n_vertices(), [&](int v) { return s.vertex_triangles[v].empty() ? -1 : s.vertex_triangles[v][0]; },
           s.leaf_vertex_begin, s.leaf_vertex);
    bucket(static_cast<int>(s.edges.size()), [&](int e) { return s.edge_triangles[e][0]; }, s.leaf_edge_begin,
           s.leaf_edge);
    s.loose_vertices.clear();
    for (int v = 0; v < s.n_vertices(); ++v)
        if (s.vertex_triangles[v].empty()) s.loose_vertices.push_back(v);
    s.rank_triangles.resize(s.triangles.size());
    for (int r = 0; r < s.bvh.n_items(); ++r) s.rank_triangles[r] = s.triangles[s.bvh.order()[r]];
    const int n_edges = static_cast<int>(s.edges.size());
    s.edge_rank_begin.assign(n_edges + 1, 0);
    for (int r = 0; r < s.bvh.n_items(); ++r)
        for (int k = 0; k < 3; ++k) ++s.edge_rank_begin[s.triangle_edges[s.bvh.order()[r]][k] + 1];
    for (int e = 0; e < n_edges; ++e) s.edge_rank_begin[e + 1] += s.edge_rank_begin[e];
    s.edge_ranks.assign(s.edge_rank_begin[n_edges], 0);
    std::vector<int> fill(s.edge_rank_begin.begin(), s.edge_rank_begin.end() - 1);
    for (int r = 0; r < s.bvh.n_items(); ++r)  // ranks ascending, so each list is sorted
        for (int k = 0; k < 3; ++k) s.edge_ranks[fill[s.triangle_edges[s.bvh.order()[r]][k]]++] = r;
}

}  // namespace

void update_surface(CollisionSurface& s, const std::vector<Vec3>& points, double margin) {
    const int nv = s.n_vertices();
    for (int v = 0; v < nv; ++v) {
        Vec3 p = Vec3::Zero();
        for (int k = 0; k < 4; ++k)
            if (s.weights[v][k] != 0) p += s.weights[v][k] * points[s.nodes[v][k]];
        s.x[v] = p;
        s.vertex_normal[v].setZero();
    }
    // in triangle order: the vertex normals are sums over their triangles in this order
    for (size_t t = 0; t < s.triangles.size(); ++t) {
        const auto& tri = s.triangles[t];
        const Vec3 area2 = (s.x[tri[1]] - s.x[tri[0]]).cross(s.x[tri[2]] - s.x[tri[0]]);
        const double len = area2.norm();
        s.triangle_normal[t] = len > 0 ? Vec3(area2 / len) : Vec3::Zero();
        for (int k = 0; k < 3; ++k) s.vertex_normal[tri[k]] += area2;
    }
    for (auto& n : s.vertex_normal) {
        const double len = n.norm();
        if (len > 0) n /= len;
    }
    auto triangle_box = [&](const Eigen::Vector3i& tri) {
        Aabb box;
        for (int k = 0; k < 3; ++k) box.grow(s.x[tri[k]]);
        return box;
    };
    if (!s.bvh.empty()) {
        s.bvh.refit_ranks(margin, [&](int r) { return triangle_box(s.rank_triangles[r]); });
    } else if (!s.triangles.empty()) {
        std::vector<Aabb> boxes(s.triangles.size());
        for (size_t t = 0; t < s.triangles.size(); ++t) boxes[t] = triangle_box(s.triangles[t]);
        s.bvh.build(boxes, margin);
        assign_to_leaves(s);
    }
}

}  // namespace hh
