#include "contact/detection.h"

#include <algorithm>
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

// Per vertex of one surface, the closest triangle of the other within reach so far: the
// smallest distance, ties going to the lowest rank (the triangle the first, one-query-per-
// vertex detection met first). Only vertices that got a candidate are touched (stamps), so a
// step costs nothing for the many vertices far from everything.
struct ClosestTriangles {
    std::vector<double> dist;
    std::vector<int> rank;
    std::vector<Vec3> w, q;
    std::vector<unsigned> stamp;
    std::vector<int> touched;
    unsigned epoch = 0;

    void start(int n_vertices) {
        if (static_cast<int>(stamp.size()) < n_vertices) {
            dist.resize(n_vertices);
            rank.resize(n_vertices);
            w.resize(n_vertices);
            q.resize(n_vertices);
            stamp.resize(n_vertices, 0);
        }
        if (++epoch == 0) {  // wrapped: forget every stamp
            std::fill(stamp.begin(), stamp.end(), 0u);
            epoch = 1;
        }
        touched.clear();
    }
    // d is below the reach
    void offer(int v, int r, double d, const Vec3& wv, const Vec3& qv) {
        if (stamp[v] != epoch) {
            stamp[v] = epoch;
            touched.push_back(v);
        } else if (!(d < dist[v] || (d == dist[v] && r < rank[v]))) {
            return;
        }
        dist[v] = d;
        rank[v] = r;
        w[v] = wv;
        q[v] = qv;
    }
};

// Per node of a self-colliding surface, boxes around the normals of its triangles and of the
// vertices it carries: a pair of nodes none of whose vertex-triangle pairs face each other
// (normals within 120 degrees, the self-collision filter) is skipped whole, so the smooth
// neighbourhood of every vertex costs a few box tests instead of a query down to its leaves.
struct NormalBounds {
    std::vector<Vec3> vertex_lo, vertex_hi, triangle_lo, triangle_hi;

    void compute(const CollisionSurface& s) {
        const auto& nodes = s.bvh.nodes();
        const size_t n = nodes.size();
        vertex_lo.resize(n);
        vertex_hi.resize(n);
        triangle_lo.resize(n);
        triangle_hi.resize(n);
        const Vec3 big = Vec3::Constant(1e300);
        for (int i = static_cast<int>(n) - 1; i >= 0; --i) {
            const Bvh::Node& node = nodes[i];
            Vec3 vlo = big, vhi = -big, tlo = big, thi = -big;
            if (node.leaf()) {
                for (int r = node.begin; r < node.end; ++r) {
                    const Vec3& nt = s.triangle_normal[s.bvh.order()[r]];
                    tlo = tlo.cwiseMin(nt);
                    thi = thi.cwiseMax(nt);
                }
                for (int k = s.leaf_vertex_begin[i]; k < s.leaf_vertex_begin[i + 1]; ++k) {
                    const Vec3& nv = s.vertex_normal[s.leaf_vertex[k]];
                    vlo = vlo.cwiseMin(nv);
                    vhi = vhi.cwiseMax(nv);
                }
            } else {
                vlo = vertex_lo[node.left].cwiseMin(vertex_lo[node.right]);
                vhi = vertex_hi[node.left].cwiseMax(vertex_hi[node.right]);
                tlo = triangle_lo[node.left].cwiseMin(triangle_lo[node.right]);
                thi = triangle_hi[node.left].cwiseMax(triangle_hi[node.right]);
            }
            vertex_lo[i] = vlo;
            vertex_hi[i] = vhi;
            triangle_lo[i] = tlo;
            triangle_hi[i] = thi;
        }
    }
    // True when no vertex of node a faces a triangle of node b: the smallest dot product of
    // two normals in the boxes (at their corners, axis by axis) is above -0.5. The margin
    // covers the rounding of the per-pair dot product, so no pair the filter keeps is lost.
    bool none_facing(int a, int b) const {
        const Vec3 &alo = vertex_lo[a], &ahi = vertex_hi[a], &blo = triangle_lo[b], &bhi = triangle_hi[b];
        if (alo.x() > ahi.x()) return true;  // carries no vertex
        double lowest = 0;
        for (int k = 0; k < 3; ++k)
            lowest += std::min(std::min(alo[k] * blo[k], alo[k] * bhi[k]), std::min(ahi[k] * blo[k], ahi[k] * bhi[k]));
        return lowest > -0.5 + 1e-6;
    }
    // The same for one vertex normal against node b's triangles.
    bool none_facing(const Vec3& n, int b) const {
        const Vec3 &blo = triangle_lo[b], &bhi = triangle_hi[b];
        double lowest = 0;
        for (int k = 0; k < 3; ++k) lowest += std::min(n[k] * blo[k], n[k] * bhi[k]);
        return lowest > -0.5 + 1e-6;
    }
};

// Where the one-query-per-edge detection met an edge-edge contact: edge ea of a, then the
// rank of the first triangle of b (in rank order) overlapping ea's box that has edge eb,
// then eb's place in that triangle. Contacts are sorted by it.
struct EdgeKey {
    int ea, rank, k;
    bool operator<(const EdgeKey& o) const {
        return ea != o.ea ? ea < o.ea : rank != o.rank ? rank < o.rank : k < o.k;
    }
};

// A pair of nodes to visit, and which directions are still open (descend_self).
struct Visit {
    int a, b, dirs;
};

// Reused from step to step: detection allocates only while the surfaces grow.
struct Scratch {
    ClosestTriangles closest[2];
    NormalBounds normals;
    std::vector<Visit> stack;
    std::vector<std::pair<EdgeKey, Contact>> edge_found;
};
thread_local Scratch scratch;

// Vertex v of sa against the triangle of rank r of sb, as the one-query-per-vertex detection
// did: the triangle's inflated box must contain the vertex; for self-collision (same surface)
// the vertex must not belong to the triangle or share its element, the surfaces must face
// each other and the pair must not be excluded, so neighbouring points of one smooth surface
// never count as a contact.
// Whether the box (lo, hi) overlaps b's box inflated by b's margin plus `grow`: a reach beyond
// b's margin (a pair with a fast body, see World::detect) adds the rest; grow <= 0 is the
// plain test (bit for bit what it was).
inline bool overlaps_within(const Bvh& b, const Vec3& lo, const Vec3& hi, const Vec3& blo, const Vec3& bhi, double grow) {
    if (grow > 0) return b.overlaps_inflated(lo, hi, blo, bhi, grow);
    return b.overlaps_inflated(lo, hi, blo, bhi);
}

template <bool Self>
inline void vertex_against_triangle(const CollisionSurface& sa, int v, const CollisionSurface& sb, int r,
                                    const SelfExclusions* skip, double reach, ClosestTriangles& closest) {
    const Vec3& p = sa.x[v];
    const Aabb& box = sb.bvh.rank_boxes()[r];
    if (!overlaps_within(sb.bvh, p, p, box.lo, box.hi, reach - sb.bvh.margin())) return;
    const Eigen::Vector3i& tri = sb.rank_triangles[r];
    if (Self) {
        if (shares_vertex(tri, v)) return;
        const int t = sb.bvh.order()[r];
        if (sa.vertex_normal[v].dot(sb.triangle_normal[t]) > -0.5 || same_element(sa, v, tri)) return;
        if (skip && skip->excludes(v, t)) return;
    }
    const Vec3 w = closest_on_triangle(p, sb.x[tri[0]], sb.x[tri[1]], sb.x[tri[2]]);
    const Vec3 q = w[0] * sb.x[tri[0]] + w[1] * sb.x[tri[1]] + w[2] * sb.x[tri[2]];
    const double dist = (p - q).norm();
    if (dist >= reach) return;
    closest.offer(v, r, dist, w, q);
}

// Edge pairs that cannot be a contact, for reasons cheaper to see than the closest points:
// - their boxes are apart by more than the reach on some axis (most of the edges of a
//   triangle near ea are);
// - a's edge does not reach into b's slab (the points projecting inside b's edge): the
//   closest point on b would be an end of b, a vertex contact. At a long reach (a fast ball
//   falling past a hand) nearly every pair within reach is of this kind, and it is decided
//   from the two projections alone. The closest points' parameter on b is that projection of
//   the point on a, so the test agrees with edge_against_edge's (whose ends are 1e-6 of the
//   edge in) with a wide margin; an edge b too short to project on reliably is left to it.
bool edge_pair_culled(const Vec3& p0, const Vec3& p1, const Vec3& q0, const Vec3& q1, double reach) {
    const double gap = reach + 1e-9;  // 1e-9 m, far above rounding
    for (int k = 0; k < 3; ++k)
        if (std::min(p0[k], p1[k]) - std::max(q0[k], q1[k]) > gap || std::min(q0[k], q1[k]) - std::max(p0[k], p1[k]) > gap)
            return true;
    const Vec3 d = q1 - q0;
    const double e = d.squaredNorm(), f = d.dot(p0 - q0), g = d.dot(p1 - q0);
    if (std::abs(f) + std::abs(g) > 1e6 * e) return false;
    return std::max(f, g) < 0.5e-6 * e || std::min(f, g) > (1 - 0.5e-6) * e;
}

// Edge ea of sa against edge eb of sb, a pair edge_pair_culled kept: a contact when the closest
// points are inside both edges (the other configurations are vertex-triangle contacts), within
// reach, and the edges face each other.
bool edge_against_edge(const CollisionSurface& sa, int body_a, int ea, const Vec3& na, const CollisionSurface& sb,
                       int body_b, int eb, double reach, Contact& c) {
    const Vec3& p0 = sa.x[sa.edges[ea][0]];
    const Vec3& p1 = sa.x[sa.edges[ea][1]];
    const Vec3& q0 = sb.x[sb.edges[eb][0]];
    const Vec3& q1 = sb.x[sb.edges[eb][1]];
    double s, u;
    closest_between_segments(p0, p1, q0, q1, s, u);
    if (s <= 1e-6 || s >= 1 - 1e-6 || u <= 1e-6 || u >= 1 - 1e-6) return false;
    const Vec3 pa = p0 + s * (p1 - p0), pb = q0 + u * (q1 - q0);
    const Vec3 d = pa - pb;
    const double dist = d.norm();
    if (dist >= reach || dist < 1e-12) return false;
    const Vec3 n = d / dist;
    // separated edges face each other: a's surface looks along -n, b's along +n
    if (na.dot(n) >= 0 || edge_normal_at(sb, eb).dot(n) <= 0) return false;
    c = make_contact(body_a, body_b, n, dist, pb);
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
    return true;
}

// A's vertices in leaf ia against b's triangles in leaf ib.
template <bool Self>
inline void leaf_vertices(const CollisionSurface& sa, int ia, const CollisionSurface& sb, int ib,
                          const SelfExclusions* skip, double reach, ClosestTriangles& closest) {
    const Bvh::Node& b = sb.bvh.nodes()[ib];
    const double grow = reach - sb.bvh.margin();
    for (int k = sa.leaf_vertex_begin[ia]; k < sa.leaf_vertex_begin[ia + 1]; ++k) {
        const int v = sa.leaf_vertex[k];
        if (!overlaps_within(sb.bvh, sa.x[v], sa.x[v], b.lo, b.hi, grow)) continue;
        if (Self && scratch.normals.none_facing(sa.vertex_normal[v], ib)) continue;
        for (int r = b.begin; r < b.end; ++r) vertex_against_triangle<Self>(sa, v, sb, r, skip, reach, closest);
    }
}

// a's edges in leaf ia against the edges of b's triangles in leaf ib. The one-query-per-edge
// detection tested each edge eb of b once per edge ea of a, when it met the first triangle
// (by rank) having eb whose box overlaps ea's: here too, through that triangle only, so a
// contact comes out once and with the key that puts it where it was.
void leaf_edges(const CollisionSurface& sa, int body_a, int ia, const CollisionSurface& sb, int body_b, int ib,
                double reach) {
    const Bvh::Node& b = sb.bvh.nodes()[ib];
    const auto& boxes = sb.bvh.rank_boxes();
    const double grow = reach - sb.bvh.margin();
    Contact c;
    for (int k = sa.leaf_edge_begin[ia]; k < sa.leaf_edge_begin[ia + 1]; ++k) {
        const int ea = sa.leaf_edge[k];
        const Vec3& p0 = sa.x[sa.edges[ea][0]];
        const Vec3& p1 = sa.x[sa.edges[ea][1]];
        const Vec3 lo = p0.cwiseMin(p1), hi = p0.cwiseMax(p1);
        if (!overlaps_within(sb.bvh, lo, hi, b.lo, b.hi, grow)) continue;
        const Vec3 na = edge_normal_at(sa, ea);
        for (int r = b.begin; r < b.end; ++r) {
            if (!overlaps_within(sb.bvh, lo, hi, boxes[r].lo, boxes[r].hi, grow)) continue;
            const int t = sb.bvh.order()[r];
            for (int j = 0; j < 3; ++j) {
                const int eb = sb.triangle_edges[t][j];
                if (edge_pair_culled(p0, p1, sb.x[sb.edges[eb][0]], sb.x[sb.edges[eb][1]], reach)) continue;
                bool first = true;  // no lower-ranked triangle of eb overlaps ea's box
                for (int m = sb.edge_rank_begin[eb]; m < sb.edge_rank_begin[eb + 1] && sb.edge_ranks[m] < r; ++m)
                    if (overlaps_within(sb.bvh, lo, hi, boxes[sb.edge_ranks[m]].lo, boxes[sb.edge_ranks[m]].hi, grow)) {
                        first = false;
                        break;
                    }
                if (!first) continue;
                if (edge_against_edge(sa, body_a, ea, na, sb, body_b, eb, reach, c))
                    scratch.edge_found.emplace_back(EdgeKey{ea, r, j}, c);
            }
        }
    }
}

// Both trees descended together from their roots: a pair of nodes is opened only if the box
// of a's node (tight: the vertices and edges it carries are inside) overlaps b's inflated
// box; at a pair of leaves a's vertices and edges meet b's triangles.
void descend(const CollisionSurface& sa, int body_a, const CollisionSurface& sb, int body_b, double reach,
             ClosestTriangles& closest, bool edges) {
    const auto& na = sa.bvh.nodes();
    const auto& nb = sb.bvh.nodes();
    const double grow = reach - sb.bvh.margin();  // (see overlaps_within)
    auto& stack = scratch.stack;
    stack.clear();
    stack.push_back({0, 0, 0});
    while (!stack.empty()) {
        const Visit top = stack.back();
        stack.pop_back();
        const Bvh::Node& a = na[top.a];
        const Bvh::Node& b = nb[top.b];
        if (!overlaps_within(sb.bvh, a.lo, a.hi, b.lo, b.hi, grow)) continue;
        if (!a.leaf() || !b.leaf()) {
            // open the larger node (or the one that is not a leaf)
            if (b.leaf() || (!a.leaf() && (a.hi - a.lo).sum() > (b.hi - b.lo).sum())) {
                stack.push_back({a.left, top.b, 0});
                stack.push_back({a.right, top.b, 0});
            } else {
                stack.push_back({top.a, b.left, 0});
                stack.push_back({top.a, b.right, 0});
            }
            continue;
        }
        leaf_vertices<false>(sa, top.a, sb, top.b, nullptr, reach, closest);
        if (edges) leaf_edges(sa, body_a, top.a, sb, body_b, top.b, reach);
    }
}

// Self-collision: the tree against itself, each unordered pair of nodes once with the two
// directions (a's vertices against b's triangles, b's against a's) tracked apart, and each
// node against itself. A direction is dropped as soon as the boxes are apart or no vertex
// faces a triangle (normal bounds); its descendants inherit that.
void descend_self(const CollisionSurface& s, const SelfExclusions* skip, double reach, ClosestTriangles& closest) {
    enum { kAB = 1, kBA = 2, kSelf = 4 };
    const auto& nodes = s.bvh.nodes();
    const NormalBounds& normals = scratch.normals;
    auto& stack = scratch.stack;
    stack.clear();
    stack.push_back({0, 0, kSelf});
    while (!stack.empty()) {
        const Visit top = stack.back();
        stack.pop_back();
        const Bvh::Node& a = nodes[top.a];
        if (top.dirs == kSelf) {
            if (normals.none_facing(top.a, top.a)) continue;
            if (a.leaf()) {
                leaf_vertices<true>(s, top.a, s, top.a, skip, reach, closest);
            } else {
                stack.push_back({a.left, a.right, kAB | kBA});
                stack.push_back({a.left, a.left, kSelf});
                stack.push_back({a.right, a.right, kSelf});
            }
            continue;
        }
        const Bvh::Node& b = nodes[top.b];
        int dirs = 0;
        if ((top.dirs & kAB) && s.bvh.overlaps_inflated(a.lo, a.hi, b.lo, b.hi) && !normals.none_facing(top.a, top.b))
            dirs |= kAB;
        if ((top.dirs & kBA) && s.bvh.overlaps_inflated(b.lo, b.hi, a.lo, a.hi) && !normals.none_facing(top.b, top.a))
            dirs |= kBA;
        if (!dirs) continue;
        if (a.leaf() && b.leaf()) {
            if (dirs & kAB) leaf_vertices<true>(s, top.a, s, top.b, skip, reach, closest);
            if (dirs & kBA) leaf_vertices<true>(s, top.b, s, top.a, skip, reach, closest);
        } else if (b.leaf() || (!a.leaf() && (a.hi - a.lo).sum() > (b.hi - b.lo).sum())) {
            stack.push_back({a.left, top.b, dirs});
            stack.push_back({a.right, top.b, dirs});
        } else {
            stack.push_back({top.a, b.left, dirs});
            stack.push_back({top.a, b.right, dirs});
        }
    }
}

// Each vertex of sa against its closest triangle of sb within reach (found by descend), in
// vertex order. For self-collision only a vertex outside the surface it faces is a contact.
template <bool Self>
void closest_triangles(const CollisionSurface& sa, int body_a, const CollisionSurface& sb, int body_b,
                       const SelfExclusions* skip, double reach, ClosestTriangles& closest, bool edges) {
    closest.start(sa.n_vertices());
    if (!sa.bvh.empty() && !sb.bvh.empty()) {
        if (Self)
            descend_self(sa, skip, reach, closest);
        else
            descend(sa, body_a, sb, body_b, reach, closest, edges);
    }
    for (int v : sa.loose_vertices)  // on no triangle, so in no leaf: one query each
        if (!sb.bvh.empty()) {
            Aabb query;
            query.grow(sa.x[v]);
            if (reach > sb.bvh.margin()) query.inflate(reach - sb.bvh.margin());  // (see descend)
            sb.bvh.query_ranks(query, [&](int r) { vertex_against_triangle<Self>(sa, v, sb, r, skip, reach, closest); });
        }
}

void vertex_contacts(const CollisionSurface& sa, int body_a, const CollisionSurface& sb, int body_b, bool self,
                     ClosestTriangles& closest, std::vector<Contact>& out) {
    std::sort(closest.touched.begin(), closest.touched.end());
    for (int v : closest.touched) {
        const Vec3& p = sa.x[v];
        const double best = closest.dist[v];
        const int best_t = sb.bvh.order()[closest.rank[v]];
        const Vec3& best_w = closest.w[v];
        const Vec3& best_q = closest.q[v];
        const Vec3 d = p - best_q;
        const Vec3 outward = pseudo_normal(sb, best_t, best_w);
        const bool outside = d.dot(outward) >= 0;
        if (self && !outside) continue;
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

// Edges against edges within one surface, one query per edge, recording the pairs found:
// only for the exclusions at rest (once per body), so kept simple.
void rest_edge_pairs(const CollisionSurface& s, double reach, SelfExclusions& record) {
    std::vector<int> stamp(s.edges.size(), -1);
    Contact found;
    for (size_t ea = 0; ea < s.edges.size(); ++ea) {
        const Vec3& p0 = s.x[s.edges[ea][0]];
        const Vec3& p1 = s.x[s.edges[ea][1]];
        Aabb query;
        query.grow(p0);
        query.grow(p1);
        const Vec3 na = edge_normal_at(s, static_cast<int>(ea));
        s.bvh.query(query, [&](int t) {
            // the edge's own neighbourhood, and surfaces not facing each other, are no contact
            if (shares_vertex(s.triangles[t], s.edges[ea][0]) || shares_vertex(s.triangles[t], s.edges[ea][1]) ||
                na.dot(s.triangle_normal[t]) > -0.5 * na.norm())
                return;
            for (int k = 0; k < 3; ++k) {
                const int eb = s.triangle_edges[t][k];
                if (stamp[eb] == static_cast<int>(ea)) continue;
                stamp[eb] = static_cast<int>(ea);
                if (static_cast<int>(ea) >= eb || s.edges[ea][0] == s.edges[eb][0] || s.edges[ea][0] == s.edges[eb][1] ||
                    s.edges[ea][1] == s.edges[eb][0] || s.edges[ea][1] == s.edges[eb][1])
                    continue;
                if (!edge_pair_culled(p0, p1, s.x[s.edges[eb][0]], s.x[s.edges[eb][1]], reach) &&
                    edge_against_edge(s, -1, static_cast<int>(ea), na, s, -1, eb, reach, found))
                    record.edge_edge.insert(SelfExclusions::key(static_cast<int>(ea), eb));
            }
        });
    }
}

}  // namespace

void SelfExclusions::compile(int n_vertices) {
    begin.assign(n_vertices + 1, 0);
    for (std::uint64_t k : vertex_triangle) {
        const int v = static_cast<int>(k >> 32);
        if (v >= 0 && v < n_vertices) ++begin[v + 1];
    }
    for (int v = 0; v < n_vertices; ++v) begin[v + 1] += begin[v];
    triangles.assign(begin[n_vertices], 0);
    std::vector<int> fill(begin.begin(), begin.end() - 1);
    for (std::uint64_t k : vertex_triangle) {
        const int v = static_cast<int>(k >> 32);
        if (v >= 0 && v < n_vertices) triangles[fill[v]++] = static_cast<int>(k & 0xffffffffu);
    }
    for (int v = 0; v < n_vertices; ++v) std::sort(triangles.begin() + begin[v], triangles.begin() + begin[v + 1]);
}

bool SelfExclusions::excludes(int v, int t) const {
    if (v < 0 || v + 1 >= static_cast<int>(begin.size())) return vertex_triangle.count(key(v, t)) > 0;
    return std::binary_search(triangles.begin() + begin[v], triangles.begin() + begin[v + 1], t);
}

void detect_pair(const CollisionSurface& sa, int body_a, const CollisionSurface& sb, int body_b,
                 const DetectionSettings& settings, std::vector<Contact>& out) {
    const double reach = settings.distance;
    if (!sa.bvh.empty() && !sb.bvh.empty()) {
        Aabb bounds = sa.bvh.bounds();  // inflated by a's margin, b's by its own: the rest of the reach
        bounds.inflate(std::max(0.0, reach - sa.bvh.margin() - sb.bvh.margin()));
        if (!bounds.overlaps(sb.bvh.bounds())) return;
    }
    // a's vertices and edges against b's triangles in one descent, then b's vertices against a's
    auto& edges = scratch.edge_found;
    edges.clear();
    closest_triangles<false>(sa, body_a, sb, body_b, nullptr, reach, scratch.closest[0], true);
    closest_triangles<false>(sb, body_b, sa, body_a, nullptr, reach, scratch.closest[1], false);
    vertex_contacts(sa, body_a, sb, body_b, false, scratch.closest[0], out);
    vertex_contacts(sb, body_b, sa, body_a, false, scratch.closest[1], out);
    std::sort(edges.begin(), edges.end(), [](const auto& x, const auto& y) { return x.first < y.first; });
    for (const auto& e : edges) out.push_back(e.second);
}

void detect_self(const CollisionSurface& s, int body, const DetectionSettings& settings, const SelfExclusions* skip,
                 std::vector<Contact>& out) {
    // Vertex-triangle only: edge-edge pairs within one body also pair edges across the folds
    // between fingers and palm, whose relative motion is that of a few shared elements, and
    // made the contact problem ill-conditioned (measured: squeezed fingers blew up). Between a
    // vertex and a facing triangle, both directions are found, which covers finger contact.
    if (!s.bvh.empty()) scratch.normals.compute(s);
    closest_triangles<true>(s, body, s, body, skip, settings.distance, scratch.closest[0], false);
    vertex_contacts(s, body, s, body, true, scratch.closest[0], out);
}

SelfExclusions rest_exclusions(const CollisionSurface& s, const DetectionSettings& settings) {
    SelfExclusions found;
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
    rest_edge_pairs(s, settings.distance, found);
    found.compile(s.n_vertices());
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
