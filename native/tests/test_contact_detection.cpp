// Collision detection against a reference: the straightforward implementation it replaced
// (one BVH query per vertex and per edge, median-split tree, first-found wins ties), kept here
// verbatim in namespace ref. Detection must produce exactly the same contacts, in the same
// order: the patch reduction keeps the first of equally deep contacts and the contact solve is
// a Gauss-Seidel sweep in contact order, so any change would change the physics.
//
// Without arguments: synthetic scenes (a sphere pressed into a box-ish blob, a folded sheet
// touching itself) at several jitters. With HH_DETECTION_DUMPS=FILE[:FILE...], files written by
//   bench/bench_detection.py --cases CASE --dump FILE
// (real surfaces and points of a bench_visual scene before every frame), it also checks every
// frame and prints the time of the reference and of the new detection per frame.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <map>
#include <stdexcept>
#include <fstream>
#include <functional>
#include <random>
#include <string>

#include "check.h"
#include "contact/detection.h"
#include "contact/geometry.h"
#include "contact/surface.h"

using namespace hh;

namespace ref {

class Bvh {
public:
    void build(const std::vector<Aabb>& boxes) {
        nodes_.clear();
        if (boxes.empty()) return;
        std::vector<Vec3> centres(boxes.size());
        for (size_t i = 0; i < boxes.size(); ++i) centres[i] = 0.5 * (boxes[i].lo + boxes[i].hi);
        std::vector<int> items(boxes.size());
        for (size_t i = 0; i < items.size(); ++i) items[i] = static_cast<int>(i);
        nodes_.reserve(2 * boxes.size());
        build_range(items, 0, static_cast<int>(items.size()), centres, boxes);
    }
    void refit(const std::vector<Aabb>& boxes) {
        for (int i = static_cast<int>(nodes_.size()) - 1; i >= 0; --i) {
            Node& n = nodes_[i];
            if (n.item >= 0) {
                n.box = boxes[n.item];
            } else {
                n.box = nodes_[n.left].box;
                n.box.grow(nodes_[n.right].box);
            }
        }
    }
    template <class Visit>
    void query(const Aabb& query, Visit&& visit) const {
        if (nodes_.empty()) return;
        int stack[128];
        int top = 0;
        stack[top++] = 0;
        while (top > 0) {
            const Node& n = nodes_[stack[--top]];
            if (!n.box.overlaps(query)) continue;
            if (n.item >= 0) {
                visit(n.item);
            } else {
                stack[top++] = n.left;
                stack[top++] = n.right;
            }
        }
    }
    const Aabb& bounds() const { return nodes_.front().box; }
    bool empty() const { return nodes_.empty(); }

private:
    struct Node {
        Aabb box;
        int left = -1, right = -1, item = -1;
    };
    int build_range(std::vector<int>& items, int begin, int end, const std::vector<Vec3>& centres,
                    const std::vector<Aabb>& boxes) {
        const int index = static_cast<int>(nodes_.size());
        nodes_.emplace_back();
        if (end - begin == 1) {
            nodes_[index].item = items[begin];
            nodes_[index].box = boxes[items[begin]];
            return index;
        }
        Aabb spread;
        for (int i = begin; i < end; ++i) spread.grow(centres[items[i]]);
        int axis;
        (spread.hi - spread.lo).maxCoeff(&axis);
        const int mid = (begin + end) / 2;
        std::nth_element(items.begin() + begin, items.begin() + mid, items.begin() + end,
                         [&](int a, int b) { return centres[a][axis] < centres[b][axis]; });
        const int left = build_range(items, begin, mid, centres, boxes);
        const int right = build_range(items, mid, end, centres, boxes);
        nodes_[index].left = left;
        nodes_[index].right = right;
        nodes_[index].box = nodes_[left].box;
        nodes_[index].box.grow(nodes_[right].box);
        return index;
    }
    std::vector<Node> nodes_;
};

// The reference's own copy of a surface's per-step data.
struct Surface {
    const CollisionSurface* topo = nullptr;  // connectivity, embedding
    std::vector<Vec3> x, vertex_normal, triangle_normal;
    std::vector<Aabb> triangle_box;
    Bvh bvh;
};

void update(Surface& r, const std::vector<Vec3>& points, double margin) {
    const CollisionSurface& s = *r.topo;
    const int nv = s.n_vertices();
    r.x.resize(nv);
    r.vertex_normal.resize(nv);
    r.triangle_normal.resize(s.triangles.size());
    r.triangle_box.resize(s.triangles.size());
    for (int v = 0; v < nv; ++v) {
        Vec3 p = Vec3::Zero();
        for (int k = 0; k < 4; ++k)
            if (s.weights[v][k] != 0) p += s.weights[v][k] * points[s.nodes[v][k]];
        r.x[v] = p;
        r.vertex_normal[v].setZero();
    }
    for (size_t t = 0; t < s.triangles.size(); ++t) {
        const auto& tri = s.triangles[t];
        const Vec3 area2 = (r.x[tri[1]] - r.x[tri[0]]).cross(r.x[tri[2]] - r.x[tri[0]]);
        const double len = area2.norm();
        r.triangle_normal[t] = len > 0 ? Vec3(area2 / len) : Vec3::Zero();
        for (int k = 0; k < 3; ++k) r.vertex_normal[tri[k]] += area2;
        Aabb box;
        for (int k = 0; k < 3; ++k) box.grow(r.x[tri[k]]);
        box.inflate(margin);
        r.triangle_box[t] = box;
    }
    for (auto& n : r.vertex_normal) {
        const double len = n.norm();
        if (len > 0) n /= len;
    }
    if (r.bvh.empty())
        r.bvh.build(r.triangle_box);
    else
        r.bvh.refit(r.triangle_box);
}

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

Vec3 edge_normal_at(const Surface& s, int e) {
    Vec3 n = s.triangle_normal[s.topo->edge_triangles[e][0]];
    if (s.topo->edge_triangles[e][1] >= 0) n += s.triangle_normal[s.topo->edge_triangles[e][1]];
    return n;
}

bool shares_vertex(const Eigen::Vector3i& tri, int v) { return tri[0] == v || tri[1] == v || tri[2] == v; }

bool same_element(const CollisionSurface& s, int v, const Eigen::Vector3i& tri) {
    for (int k = 0; k < 3; ++k)
        if (s.nodes[tri[k]] == s.nodes[v]) return true;
    return false;
}

Vec3 pseudo_normal(const Surface& s, int t, const Vec3& w) {
    const double eps = 1e-9;
    const int zero = (w[0] <= eps) + (w[1] <= eps) + (w[2] <= eps);
    if (zero == 0) return s.triangle_normal[t];
    if (zero == 2) {
        int k;
        w.maxCoeff(&k);
        return s.vertex_normal[s.topo->triangles[t][k]];
    }
    int k;
    w.minCoeff(&k);
    return edge_normal_at(s, s.topo->triangle_edges[t][(k + 1) % 3]);
}

void vertices_against_triangles(const Surface& sa, int body_a, const Surface& sb, int body_b, bool self,
                                const SelfExclusions* skip, double reach, std::vector<Contact>& out) {
    for (int v = 0; v < sa.topo->n_vertices(); ++v) {
        const Vec3& p = sa.x[v];
        Aabb query;
        query.grow(p);
        double best = reach;
        int best_t = -1;
        Vec3 best_w, best_q;
        sb.bvh.query(query, [&](int t) {
            const auto& tri = sb.topo->triangles[t];
            if (self && (shares_vertex(tri, v) || sa.vertex_normal[v].dot(sb.triangle_normal[t]) > -0.5 ||
                         same_element(*sa.topo, v, tri)))
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
        Vec3 n = best > 1e-12 ? Vec3((outside ? d : Vec3(-d)) / best) : outward.normalized();
        Contact c = make_contact(body_a, body_b, n, outside ? best : -best, best_q);
        c.a.count = 1;
        c.a.vertex[0] = v;
        c.a.weight[0] = 1;
        c.b.count = 3;
        for (int k = 0; k < 3; ++k) {
            c.b.vertex[k] = sb.topo->triangles[best_t][k];
            c.b.weight[k] = best_w[k];
        }
        out.push_back(c);
    }
}

void edges_against_edges(const Surface& sa, int body_a, const Surface& sb, int body_b, double reach,
                         std::vector<Contact>& out) {
    const CollisionSurface& ta = *sa.topo;
    const CollisionSurface& tb = *sb.topo;
    std::vector<int> stamp(tb.edges.size(), -1);
    for (size_t ea = 0; ea < ta.edges.size(); ++ea) {
        const Vec3& p0 = sa.x[ta.edges[ea][0]];
        const Vec3& p1 = sa.x[ta.edges[ea][1]];
        Aabb query;
        query.grow(p0);
        query.grow(p1);
        const Vec3 na = edge_normal_at(sa, static_cast<int>(ea));
        sb.bvh.query(query, [&](int t) {
            for (int k = 0; k < 3; ++k) {
                const int eb = tb.triangle_edges[t][k];
                if (stamp[eb] == static_cast<int>(ea)) continue;
                stamp[eb] = static_cast<int>(ea);
                const Vec3& q0 = sb.x[tb.edges[eb][0]];
                const Vec3& q1 = sb.x[tb.edges[eb][1]];
                double s, u;
                closest_between_segments(p0, p1, q0, q1, s, u);
                if (s <= 1e-6 || s >= 1 - 1e-6 || u <= 1e-6 || u >= 1 - 1e-6) continue;
                const Vec3 pa = p0 + s * (p1 - p0), pb = q0 + u * (q1 - q0);
                const Vec3 d = pa - pb;
                const double dist = d.norm();
                if (dist >= reach || dist < 1e-12) continue;
                const Vec3 n = d / dist;
                if (na.dot(n) >= 0 || edge_normal_at(sb, eb).dot(n) <= 0) continue;
                Contact c = make_contact(body_a, body_b, n, dist, pb);
                c.a.count = 2;
                c.a.vertex[0] = ta.edges[ea][0];
                c.a.vertex[1] = ta.edges[ea][1];
                c.a.weight[0] = 1 - s;
                c.a.weight[1] = s;
                c.b.count = 2;
                c.b.vertex[0] = tb.edges[eb][0];
                c.b.vertex[1] = tb.edges[eb][1];
                c.b.weight[0] = 1 - u;
                c.b.weight[1] = u;
                out.push_back(c);
            }
        });
    }
}

void detect_pair(const Surface& sa, int body_a, const Surface& sb, int body_b, double reach, std::vector<Contact>& out) {
    if (!sa.bvh.empty() && !sb.bvh.empty() && !sa.bvh.bounds().overlaps(sb.bvh.bounds())) return;
    vertices_against_triangles(sa, body_a, sb, body_b, false, nullptr, reach, out);
    vertices_against_triangles(sb, body_b, sa, body_a, false, nullptr, reach, out);
    edges_against_edges(sa, body_a, sb, body_b, reach, out);
}

void detect_self(const Surface& s, int body, double reach, const SelfExclusions* skip, std::vector<Contact>& out) {
    vertices_against_triangles(s, body, s, body, true, skip, reach, out);
}

}  // namespace ref

namespace {

bool same_side(const ContactSide& a, const ContactSide& b) {
    if (a.body != b.body || a.count != b.count) return false;
    for (int k = 0; k < 3; ++k)
        if (a.vertex[k] != b.vertex[k] || std::memcmp(&a.weight[k], &b.weight[k], sizeof(double)) != 0) return false;
    return true;
}

bool same_vec(const Vec3& a, const Vec3& b) { return std::memcmp(a.data(), b.data(), 3 * sizeof(double)) == 0; }

// Bit for bit, in the same order; prints the first difference.
bool same_contacts(const std::vector<Contact>& want, const std::vector<Contact>& got, const char* what) {
    if (want.size() != got.size()) {
        std::fprintf(stderr, "%s: %zu contacts expected, %zu found\n", what, want.size(), got.size());
        return false;
    }
    for (size_t i = 0; i < want.size(); ++i) {
        const Contact &a = want[i], &b = got[i];
        if (!same_side(a.a, b.a) || !same_side(a.b, b.b) || !same_vec(a.normal, b.normal) ||
            !same_vec(a.tangent1, b.tangent1) || !same_vec(a.tangent2, b.tangent2) || !same_vec(a.point, b.point) ||
            std::memcmp(&a.distance, &b.distance, sizeof(double)) != 0) {
            std::fprintf(stderr, "%s: contact %zu differs (expected a %d:%d/%d b %d:%d,%d,%d d %.17g; found a %d:%d/%d b %d:%d,%d,%d d %.17g)\n",
                         what, i, a.a.body, a.a.vertex[0], a.a.vertex[1], a.b.body, a.b.vertex[0], a.b.vertex[1],
                         a.b.vertex[2], a.distance, b.a.body, b.a.vertex[0], b.a.vertex[1], b.b.body, b.b.vertex[0],
                         b.b.vertex[1], b.b.vertex[2], b.distance);
            return false;
        }
    }
    return true;
}

struct Body {
    CollisionSurface surface;
    ref::Surface reference;
    SelfExclusions exclusions;
    bool dynamic = true, self_collision = false;
    std::vector<Vec3> points;
};

// The World's loop over bodies (World::detect), with the reference or the new functions.
struct Scene {
    std::vector<Body> bodies;

    void init(double rest_reach) {
        for (Body& b : bodies) {
            init_surface(b.surface, static_cast<int>(b.points.size()));
            b.reference.topo = &b.surface;
            update_surface(b.surface, b.points, rest_reach);
            ref::update(b.reference, b.points, rest_reach);
            if (b.self_collision) b.exclusions = rest_exclusions(b.surface, DetectionSettings{rest_reach});
        }
    }
    void update_new(double reach) {
        for (Body& b : bodies) update_surface(b.surface, b.points, reach);
    }
    void update_ref(double reach) {
        for (Body& b : bodies) ref::update(b.reference, b.points, reach);
    }
    void detect_new(double reach, std::vector<Contact>& out) {
        out.clear();
        t_self_new = 0;
        const DetectionSettings ds{reach};
        for (size_t i = 0; i < bodies.size(); ++i) {
            Body& a = bodies[i];
            if (!a.dynamic) continue;
            const auto t0 = std::chrono::steady_clock::now();
            if (a.self_collision) detect_self(a.surface, static_cast<int>(i), ds, &a.exclusions, out);
            t_self_new += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
            for (size_t j = 0; j < bodies.size(); ++j)
                if (j != i && (j > i || !bodies[j].dynamic))
                    detect_pair(a.surface, static_cast<int>(i), bodies[j].surface, static_cast<int>(j), ds, out);
        }
    }
    double t_self_ref = 0, t_self_new = 0;  // of the last detect_ref / detect_new
    void detect_ref(double reach, std::vector<Contact>& out) {
        out.clear();
        t_self_ref = 0;
        for (size_t i = 0; i < bodies.size(); ++i) {
            Body& a = bodies[i];
            if (!a.dynamic) continue;
            const auto t0 = std::chrono::steady_clock::now();
            if (a.self_collision) ref::detect_self(a.reference, static_cast<int>(i), reach, &a.exclusions, out);
            t_self_ref += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
            for (size_t j = 0; j < bodies.size(); ++j)
                if (j != i && (j > i || !bodies[j].dynamic))
                    ref::detect_pair(a.reference, static_cast<int>(i), bodies[j].reference, static_cast<int>(j), reach, out);
        }
    }
    // Updates both and compares the per-step surface data and the contacts.
    bool check(double reach, const char* what, std::vector<Contact>& want, std::vector<Contact>& got) {
        update_new(reach);
        update_ref(reach);
        bool ok = true;
        for (const Body& b : bodies)
            for (int v = 0; v < b.surface.n_vertices(); ++v)
                if (!same_vec(b.surface.x[v], b.reference.x[v]) ||
                    !same_vec(b.surface.vertex_normal[v], b.reference.vertex_normal[v]))
                    ok = false;
        if (!ok) std::fprintf(stderr, "%s: surface positions or normals differ\n", what);
        detect_ref(reach, want);
        detect_new(reach, got);
        return ok && same_contacts(want, got, what);
    }
};

// A closed, bumpy blob: a subdivided octahedron projected onto a sphere, radius modulated.
void blob(CollisionSurface& s, std::vector<Vec3>& points, const Vec3& centre, double radius, int subdivisions,
          double bumps, std::mt19937& rng) {
    std::vector<Vec3> v = {Vec3(1, 0, 0), Vec3(-1, 0, 0), Vec3(0, 1, 0), Vec3(0, -1, 0), Vec3(0, 0, 1), Vec3(0, 0, -1)};
    std::vector<Eigen::Vector3i> f = {{0, 2, 4}, {2, 1, 4}, {1, 3, 4}, {3, 0, 4},
                                      {2, 0, 5}, {1, 2, 5}, {3, 1, 5}, {0, 3, 5}};
    for (int level = 0; level < subdivisions; ++level) {
        std::map<std::pair<int, int>, int> mid;
        auto middle = [&](int a, int b) {
            const auto key = std::make_pair(std::min(a, b), std::max(a, b));
            auto it = mid.find(key);
            if (it != mid.end()) return it->second;
            v.push_back((v[a] + v[b]).normalized());
            return mid[key] = static_cast<int>(v.size() - 1);
        };
        std::vector<Eigen::Vector3i> g;
        for (const auto& t : f) {
            const int ab = middle(t[0], t[1]), bc = middle(t[1], t[2]), ca = middle(t[2], t[0]);
            g.push_back({t[0], ab, ca});
            g.push_back({ab, t[1], bc});
            g.push_back({ca, bc, t[2]});
            g.push_back({ab, bc, ca});
        }
        f.swap(g);
    }
    std::uniform_real_distribution<double> u(-1, 1);
    const int base = static_cast<int>(points.size());
    for (const Vec3& d : v) points.push_back(centre + radius * (1 + bumps * u(rng)) * d);
    for (size_t i = 0; i < v.size(); ++i) {
        // embed each vertex in a made-up "element" of 4 points: itself and three neighbours by
        // index, so same_element has something to reject
        const int i0 = base + static_cast<int>(i);
        const int j = base + static_cast<int>((i / 4) * 4);
        s.nodes.push_back(Eigen::Vector4i(i0, j, j + 1 < base + static_cast<int>(v.size()) ? j + 1 : j, j));
        s.weights.push_back(Vec4(1, 0, 0, 0));
    }
    for (const auto& t : f) s.triangles.push_back(t);
}

// A grid of rows x cols points, point (r, c) at at(r, c), two triangles a cell, facing +z
// (or -z when facing_down) where the grid lies flat with rows along +y
void grid_sheet(CollisionSurface& s, std::vector<Vec3>& points, int rows, int cols,
                const std::function<Vec3(int, int)>& at, bool facing_down = false) {
    const int base = static_cast<int>(points.size());
    for (int r = 0; r < rows; ++r)
        for (int c = 0; c < cols; ++c) {
            points.push_back(at(r, c));
            s.nodes.push_back(Eigen::Vector4i(static_cast<int>(points.size() - 1), 0, 0, 0));
            s.weights.push_back(Vec4(1, 0, 0, 0));
        }
    for (int r = 0; r + 1 < rows; ++r)
        for (int c = 0; c + 1 < cols; ++c) {
            const int a = base + r * cols + c, b = a + 1, d = a + cols, e = d + 1;
            if (facing_down) {
                s.triangles.push_back({a, e, b});
                s.triangles.push_back({a, d, e});
            } else {
                s.triangles.push_back({a, b, e});
                s.triangles.push_back({a, e, d});
            }
        }
}

// A sheet folded over itself (a U), so its two halves face each other within reach.
void folded_sheet(CollisionSurface& s, std::vector<Vec3>& points, int n, double gap, double jitter, std::mt19937& rng) {
    std::uniform_real_distribution<double> u(-jitter, jitter);
    grid_sheet(s, points, 2 * n + 6, n, [&](int r, int c) {
        const double along = r / static_cast<double>(n);  // 0..2+
        Vec3 p;
        if (r <= n) {
            p = Vec3(c / static_cast<double>(n), along, 0);
        } else if (r < n + 6) {  // the bend: a half circle of radius gap / 2
            const double a = M_PI * (r - n) / 6.0;
            p = Vec3(c / static_cast<double>(n), 1 + 0.5 * gap * std::sin(a), 0.5 * gap * (1 - std::cos(a)));
        } else {
            p = Vec3(c / static_cast<double>(n), 1 - (r - n - 6) / static_cast<double>(n), gap);
        }
        return Vec3(p + Vec3(u(rng), u(rng), u(rng)));
    });
}

// A flat square grid of n x n quads in the plane z = height, its corner at (x0, y0).
void flat_sheet(CollisionSurface& s, std::vector<Vec3>& points, double x0, double y0, double height, int n,
                double spacing, bool facing_down) {
    grid_sheet(s, points, n + 1, n + 1, [&](int r, int c) { return Vec3(x0 + c * spacing, y0 + r * spacing, height); },
               facing_down);
}

}  // namespace

TEST(detection_matches_reference_on_blobs_and_a_folded_sheet) {
    std::mt19937 rng(7);
    std::vector<Contact> want, got;
    size_t synthetic_edges = 0;
    for (int trial = 0; trial < 12; ++trial) {
        Scene scene;
        scene.bodies.resize(4);
        // a bumpy ball pressed into a larger one (dynamic pair), a static blob under both,
        // and a folded sheet with self-collision crossing them
        blob(scene.bodies[0].surface, scene.bodies[0].points, Vec3(0, 0, 0), 0.3, 4, 0.02, rng);
        blob(scene.bodies[1].surface, scene.bodies[1].points, Vec3(0.5, 0.1, 0.05), 0.25, 3, 0.03, rng);
        blob(scene.bodies[2].surface, scene.bodies[2].points, Vec3(0.1, 0.2, -0.55), 0.3, 4, 0.0, rng);
        scene.bodies[2].dynamic = false;
        folded_sheet(scene.bodies[3].surface, scene.bodies[3].points, 24, 0.04, 0.002, rng);
        scene.bodies[3].self_collision = true;
        scene.bodies[0].self_collision = true;
        scene.init(0.02);
        // then squeeze the sheet's halves together and move the balls into each other
        for (int step = 0; step < 4; ++step) {
            for (Vec3& p : scene.bodies[3].points) p.z() *= 0.8;
            for (Vec3& p : scene.bodies[1].points) p.x() -= 0.02;
            for (Vec3& p : scene.bodies[2].points) p.z() += 0.02;
            std::uniform_real_distribution<double> u(-0.004, 0.004);
            for (Body& b : scene.bodies)
                for (Vec3& p : b.points) p += Vec3(u(rng), u(rng), u(rng));
            const double reach = 0.015 + 0.005 * step;
            CHECK(scene.check(reach, "synthetic", want, got));
            CHECK(!want.empty() || step == 0);
            for (const Contact& c : want) synthetic_edges += c.a.count == 2;
        }
        // exact ties: a vertex exactly above a shared vertex of the other surface
        scene.bodies[1].points[0] = scene.bodies[0].points[0] + Vec3(0.001, 0, 0);
        CHECK(scene.check(0.01, "ties", want, got));
    }
    CHECK(synthetic_edges > 0);  // the order of edge-edge contacts is checked too
}

// The edge pairs' culls (detection.cpp, edge_pair_culled) where they are easiest to get wrong: a
// reach several times the edges (a fast ball's speculative search), edges parallel to each
// other (two aligned grids, and grids offset by half a cell: every pair's closest points are
// ill-defined or on an edge's end), and slivers (an edge a hundred-thousandth of a
// nanometre long). The contacts must still be the reference's, bit for bit.
TEST(detection_matches_reference_at_long_reach_with_parallel_edges_and_slivers) {
    std::mt19937 rng(11);
    std::vector<Contact> want, got;
    size_t edge_contacts = 0;
    for (int trial = 0; trial < 6; ++trial) {
        Scene scene;
        scene.bodies.resize(4);
        blob(scene.bodies[0].surface, scene.bodies[0].points, Vec3(0, 0, 0), 0.05, 4, 0.02, rng);
        blob(scene.bodies[1].surface, scene.bodies[1].points, Vec3(0.085 + 0.003 * trial, 0.01, 0.005), 0.04, 3, 0.03, rng);
        const double offset = trial % 2 ? 0.0025 : 0.0;  // half a cell, or aligned
        flat_sheet(scene.bodies[2].surface, scene.bodies[2].points, -0.04, -0.04, 0.08, 16, 0.005, false);
        flat_sheet(scene.bodies[3].surface, scene.bodies[3].points, -0.04 + offset, -0.04 + offset, 0.095, 16, 0.005, true);
        // slivers: a few of the smaller blob's vertices onto a neighbour, 1e-14 m off
        std::vector<Vec3>& p = scene.bodies[1].points;
        for (int k = 0; k < 6; ++k) {
            const Eigen::Vector3i& t = scene.bodies[1].surface.triangles[(37 * k + 5 * trial) % scene.bodies[1].surface.triangles.size()];
            p[t[1]] = p[t[0]] + Vec3(1e-14, 0, 0);
        }
        scene.init(0.002);
        for (const double reach : {0.01, 0.02, 0.035}) {
            CHECK(scene.check(reach, "long reach", want, got));
            for (const Contact& c : want) edge_contacts += c.a.count == 2;
        }
    }
    CHECK(edge_contacts > 0);
}

namespace {

template <class T>
void read(std::ifstream& in, T* data, size_t n) {
    in.read(reinterpret_cast<char*>(data), static_cast<std::streamsize>(n * sizeof(T)));
    if (!in) throw std::runtime_error("truncated dump");
}

double now() { return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count(); }

int run_dump(const char* path) {
    std::ifstream in(path, std::ios::binary);
    if (!in) {
        std::fprintf(stderr, "cannot open %s\n", path);
        return 2;
    }
    int n_bodies;
    read(in, &n_bodies, 1);
    Scene scene;
    scene.bodies.resize(n_bodies);
    for (Body& b : scene.bodies) {
        int head[5];
        read(in, head, 5);
        const int nv = head[0], nt = head[1], np = head[2];
        b.dynamic = head[3] != 0;
        b.self_collision = head[4] != 0;
        b.surface.nodes.resize(nv);
        b.surface.weights.resize(nv);
        b.surface.triangles.resize(nt);
        b.points.resize(np);
        std::vector<int> ints(4 * static_cast<size_t>(nv));
        std::vector<double> reals(4 * static_cast<size_t>(nv));
        read(in, ints.data(), ints.size());
        read(in, reals.data(), reals.size());
        for (int v = 0; v < nv; ++v)
            for (int k = 0; k < 4; ++k) {
                b.surface.nodes[v][k] = ints[4 * v + k];
                b.surface.weights[v][k] = reals[4 * v + k];
            }
        ints.resize(3 * static_cast<size_t>(nt));
        read(in, ints.data(), ints.size());
        for (int t = 0; t < nt; ++t) b.surface.triangles[t] = Eigen::Vector3i(ints[3 * t], ints[3 * t + 1], ints[3 * t + 2]);
    }
    int n_frames;
    read(in, &n_frames, 1);
    std::vector<double> reaches(n_frames);
    std::vector<std::vector<std::vector<Vec3>>> frames(n_frames);
    for (int f = 0; f < n_frames; ++f) {
        read(in, &reaches[f], 1);
        frames[f].resize(n_bodies);
        for (int i = 0; i < n_bodies; ++i) {
            frames[f][i].resize(scene.bodies[i].points.size());
            read(in, frames[f][i][0].data(), 3 * frames[f][i].size());
        }
    }
    for (int i = 0; i < n_bodies; ++i) scene.bodies[i].points = frames[0][i];
    scene.init(reaches[0]);

    std::vector<Contact> want, got;
    bool ok = true;
    double t_ref = 0, t_new = 0, t_ref_update = 0, t_new_update = 0, t_ref_self = 0, t_new_self = 0;
    size_t contacts = 0, edge_contacts = 0;
    const int repeats = 3;  // per frame, the best of a few runs: the machine is shared
    for (int f = 1; f < n_frames; ++f) {
        for (int i = 0; i < n_bodies; ++i) scene.bodies[i].points = frames[f][i];
        char what[64];
        std::snprintf(what, sizeof what, "%s frame %d", path, f);
        ok = scene.check(reaches[f], what, want, got) && ok;
        contacts += want.size();
        for (const Contact& c : want) edge_contacts += c.a.count == 2;
        double best[6] = {1e9, 1e9, 1e9, 1e9, 1e9, 1e9};
        for (int r = 0; r < repeats; ++r) {
            double t0 = now();
            scene.update_ref(reaches[f]);
            double t1 = now();
            scene.detect_ref(reaches[f], want);
            double t2 = now();
            scene.update_new(reaches[f]);
            double t3 = now();
            scene.detect_new(reaches[f], got);
            double t4 = now();
            best[0] = std::min(best[0], t1 - t0);
            best[1] = std::min(best[1], t2 - t1);
            best[2] = std::min(best[2], t3 - t2);
            best[3] = std::min(best[3], t4 - t3);
            best[4] = std::min(best[4], scene.t_self_ref);
            best[5] = std::min(best[5], scene.t_self_new);
        }
        t_ref_self += best[4];
        t_new_self += best[5];
        t_ref_update += best[0];
        t_ref += best[1];
        t_new_update += best[2];
        t_new += best[3];
    }
    const int n = n_frames - 1;
    std::printf("%s: %d frames, %.1f contacts per frame before the patch reduction (%.1f edge-edge), %s\n", path, n,
                contacts / static_cast<double>(n), edge_contacts / static_cast<double>(n), ok ? "identical" : "DIFFERENT");
    std::printf("  reference: update %.3f ms + detect %.3f ms (self %.3f) = %.3f ms per frame\n",
                1e3 * t_ref_update / n, 1e3 * t_ref / n, 1e3 * t_ref_self / n, 1e3 * (t_ref_update + t_ref) / n);
    std::printf("  new:       update %.3f ms + detect %.3f ms (self %.3f) = %.3f ms per frame (%.2fx)\n",
                1e3 * t_new_update / n, 1e3 * t_new / n, 1e3 * t_new_self / n, 1e3 * (t_new_update + t_new) / n,
                (t_ref_update + t_ref) / (t_new_update + t_new));
    return ok ? 0 : 1;
}

}  // namespace

// HH_DETECTION_DUMPS=a.bin:b.bin: check (and time) every frame of those dumps too.
TEST(detection_matches_reference_on_dumped_scenes) {
    const char* list = std::getenv("HH_DETECTION_DUMPS");
    if (!list) return;
    std::string all(list);
    size_t begin = 0;
    while (begin <= all.size()) {
        const size_t end = std::min(all.find(':', begin), all.size());
        if (end > begin) CHECK(run_dump(all.substr(begin, end - begin).c_str()) == 0);
        begin = end + 1;
    }
}
