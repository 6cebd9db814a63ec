// Closest-point queries of the narrow phase (after Ericson, Real-Time Collision Detection, 5.1).
#pragma once
#include "common/types.h"

namespace hh {

struct Aabb {
    Vec3 lo = Vec3::Constant(1e300);
    Vec3 hi = Vec3::Constant(-1e300);
    void grow(const Vec3& p) {
        lo = lo.cwiseMin(p);
        hi = hi.cwiseMax(p);
    }
    void grow(const Aabb& b) {
        lo = lo.cwiseMin(b.lo);
        hi = hi.cwiseMax(b.hi);
    }
    void inflate(double r) {
        lo.array() -= r;
        hi.array() += r;
    }
    bool overlaps(const Aabb& b) const {
        return (lo.array() <= b.hi.array()).all() && (b.lo.array() <= hi.array()).all();
    }
};

// Closest point to p on triangle (a, b, c) as barycentric weights (wa, wb, wc).
Vec3 closest_on_triangle(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c);

// Closest points p0 + s (p1 - p0) and q0 + t (q1 - q0) of two segments; s, t in [0, 1].
void closest_between_segments(const Vec3& p0, const Vec3& p1, const Vec3& q0, const Vec3& q1, double& s, double& t);

}  // namespace hh
