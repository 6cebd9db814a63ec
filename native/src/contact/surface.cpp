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
    s.triangle_box.assign(s.triangles.size(), Aabb{});
}

void update_surface(CollisionSurface& s, const std::vector<Vec3>& points, double margin) {
    const int nv = s.n_vertices();
    for (int v = 0; v < nv; ++v) {
        Vec3 p = Vec3::Zero();
        for (int k = 0; k < 4; ++k)
            if (s.weights[v][k] != 0) p += s.weights[v][k] * points[s.nodes[v][k]];
        s.x[v] = p;
        s.vertex_normal[v].setZero();
    }
    for (size_t t = 0; t < s.triangles.size(); ++t) {
        const auto& tri = s.triangles[t];
        const Vec3 area2 = (s.x[tri[1]] - s.x[tri[0]]).cross(s.x[tri[2]] - s.x[tri[0]]);
        const double len = area2.norm();
        s.triangle_normal[t] = len > 0 ? Vec3(area2 / len) : Vec3::Zero();
        for (int k = 0; k < 3; ++k) s.vertex_normal[tri[k]] += area2;
        Aabb box;
        for (int k = 0; k < 3; ++k) box.grow(s.x[tri[k]]);
        box.inflate(margin);
        s.triangle_box[t] = box;
    }
    for (auto& n : s.vertex_normal) {
        const double len = n.norm();
        if (len > 0) n /= len;
    }
    if (s.bvh.empty())
        s.bvh.build(s.triangle_box);
    else
        s.bvh.refit(s.triangle_box);
}

}  // namespace hh
