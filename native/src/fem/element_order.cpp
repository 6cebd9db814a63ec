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

namespace {
constexpr size_t kLanes = 8;  // AVX-512 lanes; a multiple of AVX2's 4
}  // namespace

ElementPassParts split_element_pass(TetMesh& mesh, CorotationalElements& elements, int n_nodes) {
    const size_t m = mesh.tets.size();
    ElementPassParts parts;
    std::vector<char> in_a(n_nodes, 0);
    // A's end: where A and B come out about equal (B loses the seam, so A is a bit under half)
    auto b_size = [&](size_t end_a) {
        std::fill(in_a.begin(), in_a.end(), 0);
        for (size_t e = 0; e < end_a; ++e)
            for (int a = 0; a < 4; ++a) in_a[mesh.tets[e][a]] = 1;
        size_t count = 0;
        for (size_t e = end_a; e < m; ++e) {
            bool touches_a = false;
            for (int a = 0; a < 4; ++a) touches_a = touches_a || in_a[mesh.tets[e][a]];
            count += !touches_a;
        }
        return count;
    };
    size_t lo = 0, hi = m / 2;  // b_size(lo) >= lo; find the largest such end_a
    while (hi - lo > 1) {
        const size_t mid = (lo + hi) / 2;
        (b_size(mid) >= mid ? lo : hi) = mid;
    }
    // whole SIMD batches (kLanes, the widest): the parts then run the same batches as one
    // pass over the whole order would, and give the same sums bit for bit
    const size_t half = (b_size(hi) >= hi ? hi : lo) / kLanes * kLanes;
    b_size(half);  // (leaves in_a for A = [0, half))
    std::vector<size_t> order, seam;
    order.reserve(m);
    for (size_t e = 0; e < half; ++e) order.push_back(e);
    for (size_t e = half; e < m; ++e) {
        bool touches_a = false;
        for (int a = 0; a < 4; ++a) touches_a = touches_a || in_a[mesh.tets[e][a]];
        (touches_a ? seam : order).push_back(e);
    }
    parts.end[0] = half;
    while ((order.size() - half) % kLanes) {  // B's last elements to the seam (S may touch any node)
        seam.insert(seam.begin(), order.back());
        order.pop_back();
    }
    std::sort(seam.begin(), seam.end());  // (the seam in the spatial order too)
    parts.end[1] = order.size();
    order.insert(order.end(), seam.begin(), seam.end());
    parts.end[2] = m;
    permute(mesh.tets, order);
    permute(elements.rest_inverse, order);
    permute(elements.volume, order);
    permute(elements.stiffness, order);
    permute(elements.gradients, order);
    for (int i = 0; i < n_nodes; ++i) parts.owned_nodes[in_a[i] ? 0 : 1].push_back(i);
    return parts;
}

}  // namespace hh
