#include "fem/element_order.h"

#include <algorithm>
#include <cstdint>
#include <numeric>

namespace hh {

namespace {
// 10 bits per axis interleaved: 2^30 cells, far finer than any tet mesh here
uint32_t morton(const Vec3& unit) {
    uint32_t key = 0;
    unsigned q[3];
    for (int c = 0; c < 3; ++c) q[c] = static_cast<unsigned>(std::clamp(unit[c], 0.0, 1.0) * 1023.0);
    for (int b = 9; b >= 0; --b)
        for (int c = 0; c < 3; ++c) key = (key << 1) | ((q[c] >> b) & 1u);
    return key;
}

template <typename T>
void permute(std::vector<T>& v, const std::vector<size_t>& order) {
    if (v.size() != order.size()) return;
    std::vector<T> out;
    out.reserve(v.size());
    for (size_t i : order) out.push_back(v[i]);
    v.swap(out);
}
}  // namespace

void order_elements_spatially(TetMesh& mesh, CorotationalElements& elements) {
    const size_t m = mesh.tets.size();
    if (m < 2) return;
    std::vector<Vec3> centroid(m);
    Vec3 lo = Vec3::Constant(1e300), hi = Vec3::Constant(-1e300);
    for (size_t e = 0; e < m; ++e) {
        Vec3 c = Vec3::Zero();
        for (int a = 0; a < 4; ++a) c += mesh.rest.segment<3>(3 * mesh.tets[e][a]);
        centroid[e] = 0.25 * c;
        lo = lo.cwiseMin(centroid[e]);
        hi = hi.cwiseMax(centroid[e]);
    }
    const Vec3 extent = (hi - lo).cwiseMax(Vec3::Constant(1e-300));
    std::vector<uint32_t> key(m);
    for (size_t e = 0; e < m; ++e) key[e] = morton((centroid[e] - lo).cwiseQuotient(extent));
    std::vector<size_t> order(m);
    std::iota(order.begin(), order.end(), 0);
    // ties (elements in one cell) keep the user's order: a deterministic order on any platform
    std::sort(order.begin(), order.end(), [&](size_t a, size_t b) { return key[a] < key[b] || (key[a] == key[b] && a < b); });
    permute(mesh.tets, order);
    permute(elements.rest_inverse, order);
    permute(elements.volume, order);
    permute(elements.stiffness, order);
    permute(elements.gradients, order);
}

}  // namespace hh
