#include "contact/detection.h"

#include <cmath>

#include "contact/geometry.h"

namespace hh {

void tangent_frame(const Vec3& n, Vec3& t1, Vec3& t2) {
    const Vec3 helper = std::abs(n.x()) < 0.57 ? Vec3(1, 0, 0) : Vec3(0, 1, 0);
    t1 = n.cross(helper).normalized();
    t2 = n.cross(t1);
}

namespace {

Contact make_contact(int body_a, int body_b, const Vec3& normal, double distance, const Vec3& point) {
    Contact c;
    c.a.body = body_a;
    c.b.body = body_b;
    c.normal = normal;
    tangent_frame(normal, c.tangent1, c.tangent2);
    c.distance = distance;
    c.point = point;
    return c;
}

Vec3 edge_normal_at(const CollisionSurface& s, int e) {
    Vec3 n = s.triangle_normal[s.edge_triangles[e][0]];
    if (s.edge_triangles[e][1] >= 0) n += s.triangle_normal[s.edge_triangles[e][1]];
    return n;
}

bool shares_vertex(const Eigen::Vector3i& tri, int v) { return tri[0] == v || tri[1] == v || tri[2] == v; }

// Surface points embedded in the same element cannot move apart except by deforming it: no
// contact between them.
bool same_element(const CollisionSurface& s, int v, const Eigen::Vector3i& tri) {
    for (int k = 0; k < 3; ++k)
        if (s.nodes[tri[k]] == s.nodes[v]) return true;
    return false;
}

// Vertices of sa against triangles of sb. For self-collision (same surface) the vertex must
// not belong to the triangle and the two surfaces must face each other, so neighbouring
// points of one smooth surface never count as a contact.
// Outward pseudo-normal of surface b at the closest point with barycentric weights w on
// triangle t: the face normal inside the face, the mean of the two faces' normals on an edge,
// the vertex normal at a corner. Its sign tells inside from outside even near edges, where
// one face's plane would misclassify a point beside the body as behind it.
Vec3 pseudo_normal(const CollisionSurface& s, int t, const Vec3& w) {
    const double eps = 1e-9;
    const int zero = (w[0] <= eps) + (w[1] <= eps) + (w[2] <= eps);
    if (zero == 0) return s.triangle_normal[t];
    if (zero == 2) {
        int k;
        w.maxCoeff(&k);
        return s.vertex_normal[s.triangles[t][k]];
    }
    int k;  // the edge opposite the zero weight: triangle_edges[t][j] joins corners j and j+1
    w.minCoeff(&k);
    return edge_normal_at(s, s.triangle_edges[t][(k + 1) % 3]);
}

// Vertices of sa against triangles of sb: each vertex's closest triangle within reach. For
// self-collision (same surface) the vertex must not belong to the triangle or share its
// element, the surfaces must face each other, and the vertex must be outside, so neighbouring
// points of one smooth surface never count as a contact.
void vertices_against_triangles(const CollisionSurface& sa, int body_a, const CollisionSurface& sb, int body_b,
                                bool self, const SelfExclusions* skip, double reach, std::vector<Contact>& out,
                                SelfExclusions* record = nullptr) {
    for (int v = 0; v < sa.n_vertices(); ++v) {
        const Vec3& p = sa.x[v];
        Aabb query;
        query.grow(p);
        double best = reach;
        int best_t = -1;
        Vec3 best_w, best_q;
        sb.bvh.query(query, [&](int t) {
            const auto& tri = sb.triangles[t];
            if (self && (shares_vertex(tri, v) || sa.vertex_normal[v].dot(sb.triangle_normal[t]) > -0.5 ||
                         same_element(sa, v, tri)))
                return;
            if (skip && skip->vertex_triangle.count(SelfExclusions::key(v, t))) return;
            const Vec3 w = closest_on_triangle(p, sb.x[tri[0]], sb.x[tri[1]], sb.x[tri[2]]);
            const Vec3 q = w[0] * sb.x[tri[0]] + w[1] * sb.x[tri[1]] + w[2] * sb.x[tri[2]];
            const double dist = (p - q).norm();
            if (dist >= best) return;
            best = dist;
            best_t = t;
            best_w = w;
            best_q = q;
        });
        if (best_t < 0) continue;
        const Vec3 d = p - best_q;
        const Vec3 outward = pseudo_normal(sb, best_t, best_w);
        const bool outside = d.dot(outward) >= 0;
        if (self && !outside) continue;
        if (record) record->vertex_triangle.insert(SelfExclusions::key(v, best_t));
        // outside: separate along p - q; inside: move p back out through q
        Vec3 n = best > 1e-12 ? Vec3((outside ? d : Vec3(-d)) / best) : outward.normalized();
        Contact c = make_contact(body_a, body_b, n, outside ? best : -best, best_q);
        c.a.count = 1;
        c.a.vertex[0] = v;
        c.a.weight[0] = 1;
        c.b.count = 3;
        for (int k = 0; k < 3; ++k) {
            c.b.vertex[k] = sb.triangles[best_t][k];
            c.b.weight[k] = best_w[k];
        }
        out.push_back(c);
    }
}


// Edges of sa against edges of sb whose closest points are inside both edges (the other
// configurations are vertex-triangle contacts).
void edges_against_edges(const CollisionSurface& sa, int body_a, const CollisionSurface& sb, int body_b, bool self,
                         const SelfExclusions* skip, double reach, std::vector<Contact>& out,
                         SelfExclusions* record = nullptr) {
    std::vector<int> stamp(sb.edges.size(), -1);
    for (size_t ea = 0; ea < sa.edges.size(); ++ea) {
        const Vec3& p0 = sa.x[sa.edges[ea][0]];
        const Vec3& p1 = sa.x[sa.edges[ea][1]];
        Aabb query;
        query.grow(p0);
        query.grow(p1);
        const Vec3 na = edge_normal_at(sa, static_cast<int>(ea));
        sb.bvh.query(query, [&](int t) {
            // self: the edge's own neighbourhood, and surfaces not facing each other, are no contact
            if (self && (shares_vertex(sb.triangles[t], sa.edges[ea][0]) || shares_vertex(sb.triangles[t], sa.edges[ea][1]) ||
                         na.dot(sb.triangle_normal[t]) > -0.5 * na.norm()))
                return;
            for (int k = 0; k < 3; ++k) {
                const int eb = sb.triangle_edges[t][k];
                if (stamp[eb] == static_cast<int>(ea)) continue;
                stamp[eb] = static_cast<int>(ea);
                if (self && (static_cast<int>(ea) >= eb || sa.edges[ea][0] == sb.edges[eb][0] ||
                             sa.edges[ea][0] == sb.edges[eb][1] || sa.edges[ea][1] == sb.edges[eb][0] ||
                             sa.edges[ea][1] == sb.edges[eb][1]))
                    continue;
                if (skip && skip->edge_edge.count(SelfExclusions::key(static_cast<int>(ea), eb))) continue;
                const Vec3& q0 = sb.x[sb.edges[eb][0]];
                const Vec3& q1 = sb.x[sb.edges[eb][1]];
                double s, u;
                closest_between_segments(p0, p1, q0, q1, s, u);
                if (s <= 1e-6 || s >= 1 - 1e-6 || u <= 1e-6 || u >= 1 - 1e-6) continue;
                const Vec3 pa = p0 + s * (p1 - p0), pb = q0 + u * (q1 - q0);
                const Vec3 d = pa - pb;
                const double dist = d.norm();
                if (dist >= reach || dist < 1e-12) continue;
                const Vec3 n = d / dist;
                // separated edges face each other: a's surface looks along -n, b's along +n
                if (na.dot(n) >= 0 || edge_normal_at(sb, eb).dot(n) <= 0) continue;
                if (record) record->edge_edge.insert(SelfExclusions::key(static_cast<int>(ea), eb));
                Contact c = make_contact(body_a, body_b, n, dist, pb);
                c.a.count = 2;
                c.a.vertex[0] = sa.edges[ea][0];
                c.a.vertex[1] = sa.edges[ea][1];
                c.a.weight[0] = 1 - s;
                c.a.weight[1] = s;
                c.b.count = 2;
                c.b.vertex[0] = sb.edges[eb][0];
                c.b.vertex[1] = sb.edges[eb][1];
                c.b.weight[0] = 1 - u;
                c.b.weight[1] = u;
                out.push_back(c);
            }
        });
    }
}

}  // namespace

void detect_pair(const CollisionSurface& sa, int body_a, const CollisionSurface& sb, int body_b,
                 const DetectionSettings& settings, std::vector<Contact>& out) {
    if (!sa.bvh.empty() && !sb.bvh.empty() && !sa.bvh.bounds().overlaps(sb.bvh.bounds())) return;
    vertices_against_triangles(sa, body_a, sb, body_b, false, nullptr, settings.distance, out);
    vertices_against_triangles(sb, body_b, sa, body_a, false, nullptr, settings.distance, out);
    edges_against_edges(sa, body_a, sb, body_b, false, nullptr, settings.distance, out);
}

void detect_self(const CollisionSurface& s, int body, const DetectionSettings& settings, const SelfExclusions* skip,
                 std::vector<Contact>& out) {
    // Vertex-triangle only: edge-edge pairs within one body also pair edges across the folds
    // between fingers and palm, whose relative motion is that of a few shared elements, and
    // made the contact problem ill-conditioned (measured: squeezed fingers blew up). Between a
    // vertex and a facing triangle, both directions are found, which covers finger contact.
    vertices_against_triangles(s, body, s, body, true, skip, settings.distance, out);
}

SelfExclusions rest_exclusions(const CollisionSurface& s, const DetectionSettings& settings) {
    SelfExclusions found;
    std::vector<Contact> ignored;
    // every pair within reach, not only each vertex's closest triangle
    for (int v = 0; v < s.n_vertices(); ++v) {
        Aabb query;
        query.grow(s.x[v]);
        s.bvh.query(query, [&](int t) {
            const auto& tri = s.triangles[t];
            if (shares_vertex(tri, v)) return;
            const Vec3 w = closest_on_triangle(s.x[v], s.x[tri[0]], s.x[tri[1]], s.x[tri[2]]);
            const Vec3 q = w[0] * s.x[tri[0]] + w[1] * s.x[tri[1]] + w[2] * s.x[tri[2]];
            if ((s.x[v] - q).norm() < settings.distance) found.vertex_triangle.insert(SelfExclusions::key(v, t));
        });
    }
    edges_against_edges(s, -1, s, -1, true, nullptr, settings.distance, ignored, &found);
    return found;
}

void detect_plane(const CollisionSurface& s, int body, const Vec3& plane_point, const Vec3& plane_normal,
                  int plane_body, const DetectionSettings& settings, std::vector<Contact>& out) {
    for (int v = 0; v < s.n_vertices(); ++v) {
        const double dist = (s.x[v] - plane_point).dot(plane_normal);
        if (dist >= settings.distance) continue;
        Contact c = make_contact(body, plane_body, plane_normal, dist, s.x[v] - dist * plane_normal);
        c.a.count = 1;
        c.a.vertex[0] = v;
        c.a.weight[0] = 1;
        out.push_back(c);
    }
}

}  // namespace hh
