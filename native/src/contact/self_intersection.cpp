#include "contact/self_intersection.h"

#include <algorithm>
#include <cmath>

#include "contact/bvh.h"

namespace hh {

namespace {

constexpr double kEps = 1.1102230246251565e-16;  // 2^-53, the unit roundoff of double
// Shewchuk's static error bounds ("Adaptive precision floating-point arithmetic", 1997): a
// determinant computed in double whose magnitude exceeds bound * permanent has the right sign.
constexpr double kOrient3dBound = (7.0 + 56.0 * kEps) * kEps;
constexpr double kOrient2dBound = (3.0 + 16.0 * kEps) * kEps;

// Sign of det[a - d, b - d, c - d]: +1, -1, or 0 where rounding could flip it.
int orient3d(const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& d) {
    const Vec3 u = a - d, v = b - d, w = c - d;
    const double m1 = v.y() * w.z(), m2 = v.z() * w.y();
    const double m3 = w.y() * u.z(), m4 = w.z() * u.y();
    const double m5 = u.y() * v.z(), m6 = u.z() * v.y();
    const double det = u.x() * (m1 - m2) + v.x() * (m3 - m4) + w.x() * (m5 - m6);
    const double permanent = (std::abs(m1) + std::abs(m2)) * std::abs(u.x()) +
                             (std::abs(m3) + std::abs(m4)) * std::abs(v.x()) +
                             (std::abs(m5) + std::abs(m6)) * std::abs(w.x());
    if (det > kOrient3dBound * permanent) return 1;
    if (-det > kOrient3dBound * permanent) return -1;
    return 0;
}

using Vec2 = Eigen::Vector2d;

int orient2d(const Vec2& a, const Vec2& b, const Vec2& c) {
    const double l = (a.x() - c.x()) * (b.y() - c.y()), r = (a.y() - c.y()) * (b.x() - c.x());
    const double det = l - r;
    const double bound = kOrient2dBound * (std::abs(l) + std::abs(r));
    if (det > bound) return 1;
    if (-det > bound) return -1;
    return 0;
}

// Segments (p, q) and (a, b) in the plane cross at a point inside both.
bool segments_cross(const Vec2& p, const Vec2& q, const Vec2& a, const Vec2& b) {
    return orient2d(p, q, a) * orient2d(p, q, b) < 0 && orient2d(a, b, p) * orient2d(a, b, q) < 0;
}

// p strictly inside triangle (a, b, c) in the plane.
bool strictly_inside(const Vec2& a, const Vec2& b, const Vec2& c, const Vec2& p) {
    const int s1 = orient2d(a, b, p), s2 = orient2d(b, c, p), s3 = orient2d(c, a, p);
    return s1 != 0 && s1 == s2 && s2 == s3;
}

// Coplanar triangles whose interiors overlap: drop the normal's largest axis, then an edge of
// one crosses an edge of the other, or a vertex of one lies inside the other.
bool coplanar_overlap(const Vec3* t, const Vec3* u) {
    int axis;
    ((t[1] - t[0]).cross(t[2] - t[0])).cwiseAbs().maxCoeff(&axis);
    const int i = (axis + 1) % 3, j = (axis + 2) % 3;
    Vec2 a[3], b[3];
    for (int k = 0; k < 3; ++k) {
        a[k] = Vec2(t[k][i], t[k][j]);
        b[k] = Vec2(u[k][i], u[k][j]);
    }
    if (orient2d(a[0], a[1], a[2]) == 0 || orient2d(b[0], b[1], b[2]) == 0) return false;  // degenerate
    for (int k = 0; k < 3; ++k) {
        for (int m = 0; m < 3; ++m)
            if (segments_cross(a[k], a[(k + 1) % 3], b[m], b[(m + 1) % 3])) return true;
        if (strictly_inside(a[0], a[1], a[2], b[k]) || strictly_inside(b[0], b[1], b[2], a[k])) return true;
    }
    return false;
}

// Segment (p, q) passes through the interior of triangle (a, b, c): its ends strictly on either
// side of the plane, the line strictly on the same side of all three edges. Touching (an end on
// the plane, the line through an edge or a vertex) does not count: a rounding error could make
// it up, and a real crossing of two surfaces crosses some triangle properly.
bool segment_crosses_triangle(const Vec3& p, const Vec3& q, const Vec3& a, const Vec3& b, const Vec3& c) {
    if (orient3d(a, b, c, p) * orient3d(a, b, c, q) >= 0) return false;
    const int s1 = orient3d(p, q, a, b), s2 = orient3d(p, q, b, c), s3 = orient3d(p, q, c, a);
    return s1 != 0 && s1 == s2 && s2 == s3;
}

bool coplanar(const Vec3* t, const Vec3* u) {
    return orient3d(t[0], t[1], t[2], u[0]) == 0 && orient3d(t[0], t[1], t[2], u[1]) == 0 &&
           orient3d(t[0], t[1], t[2], u[2]) == 0;
}

// Two triangles with no common vertex cross when an edge of one crosses the other (where their
// planes meet, the ends of the common segment lie on their edges), or overlap when coplanar.
bool triangles_meet(const Vec3* t, const Vec3* u) {
    if (coplanar(t, u)) return coplanar_overlap(t, u);
    for (int k = 0; k < 3; ++k) {
        if (segment_crosses_triangle(t[k], t[(k + 1) % 3], u[0], u[1], u[2])) return true;
        if (segment_crosses_triangle(u[k], u[(k + 1) % 3], t[0], t[1], t[2])) return true;
    }
    return false;
}

struct Shared {
    int count = 0;
    int in_t[3], in_u[3];  // local indices of the shared vertices
};

Shared shared_vertices(const Eigen::Vector3i& t, const Eigen::Vector3i& u) {
    Shared s;
    for (int a = 0; a < 3; ++a)
        for (int b = 0; b < 3; ++b)
            if (t[a] == u[b]) {
                s.in_t[s.count] = a;
                s.in_u[s.count] = b;
                ++s.count;
            }
    return s;
}

bool pair_intersects(const std::vector<Vec3>& V, const Eigen::Vector3i& ft, const Eigen::Vector3i& fu) {
    const Vec3 t[3] = {V[ft[0]], V[ft[1]], V[ft[2]]};
    const Vec3 u[3] = {V[fu[0]], V[fu[1]], V[fu[2]]};
    const Shared s = shared_vertices(ft, fu);
    if (s.count == 0) return triangles_meet(t, u);
    if (s.count == 1) {
        // they meet at the shared vertex; beyond it when coplanar and overlapping, or when the
        // edge opposite it in one crosses the other
        const int a = s.in_t[0], b = s.in_u[0];
        if (coplanar(t, u)) return coplanar_overlap(t, u);
        return segment_crosses_triangle(t[(a + 1) % 3], t[(a + 2) % 3], u[0], u[1], u[2]) ||
               segment_crosses_triangle(u[(b + 1) % 3], u[(b + 2) % 3], t[0], t[1], t[2]);
    }
    if (s.count == 2) {
        // neighbours across an edge: a fold when coplanar with both on the same side of it
        const Vec3& p = t[s.in_t[0]];
        const Vec3& q = t[s.in_t[1]];
        const Vec3& a = t[3 - s.in_t[0] - s.in_t[1]];
        const Vec3& b = u[3 - s.in_u[0] - s.in_u[1]];
        if (orient3d(p, q, a, b) != 0) return false;
        const Vec3 e = q - p;
        return e.cross(a - p).dot(e.cross(b - p)) > 0;
    }
    return false;  // the same three vertices: a duplicate face, which the edge checks report
}

}  // namespace

std::vector<std::pair<int, int>> surface_self_intersections(const std::vector<Vec3>& vertices,
                                                            const std::vector<Eigen::Vector3i>& faces) {
    std::vector<Aabb> boxes(faces.size());
    for (size_t f = 0; f < faces.size(); ++f)
        for (int k = 0; k < 3; ++k) boxes[f].grow(vertices[faces[f][k]]);
    Bvh bvh;
    bvh.build(boxes);
    std::vector<std::pair<int, int>> pairs;
    for (int i = 0; i < static_cast<int>(faces.size()); ++i)
        bvh.query(boxes[i], [&](int j) {
            if (j > i && pair_intersects(vertices, faces[i], faces[j])) pairs.emplace_back(i, j);
        });
    std::sort(pairs.begin(), pairs.end());
    return pairs;
}

}  // namespace hh
