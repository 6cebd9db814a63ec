// The C ABI of the surface checks made before a mesh is tetrahedralized or simulated. Same rules
// as capi.cpp: guard() around every body.
#include <algorithm>
#include <cmath>
#include <string>

#include "capi/guard.h"
#include "contact/self_intersection.h"

using hh::capi::guard;
using hh::capi::require;

extern "C" {

int hh_surface_self_intersections(const double* vertices, int n_vertices, const int* faces, int n_faces,
                                  int* out_pairs, int capacity, int* out_count) {
    return guard([&] {
        require(out_count != nullptr, "hh_surface_self_intersections: null out_count");
        *out_count = 0;
        require(n_vertices >= 0 && n_faces >= 0 && capacity >= 0,
                "hh_surface_self_intersections: negative vertex, face or pair count");
        require((vertices || n_vertices == 0) && (faces || n_faces == 0) && (out_pairs || capacity == 0),
                "hh_surface_self_intersections: null array with a non-zero count");
        std::vector<hh::Vec3> v(n_vertices);
        for (int i = 0; i < n_vertices; ++i) {
            const double* p = vertices + 3 * static_cast<size_t>(i);
            v[i] = hh::Vec3(p[0], p[1], p[2]);
            require(v[i].allFinite(), "surface vertex " + std::to_string(i) +
                                          " has a NaN or infinite coordinate: delete or re-place it");
        }
        std::vector<Eigen::Vector3i> f(n_faces);
        for (int i = 0; i < n_faces; ++i) {
            const int* t = faces + 3 * static_cast<size_t>(i);
            f[i] = Eigen::Vector3i(t[0], t[1], t[2]);
            require(f[i].minCoeff() >= 0 && f[i].maxCoeff() < n_vertices,
                    "surface triangle " + std::to_string(i) + " refers to a vertex outside 0.." +
                        std::to_string(n_vertices - 1) + ": fix the face indices");
        }
        const auto pairs = hh::surface_self_intersections(v, f);
        const size_t kept = std::min(pairs.size(), static_cast<size_t>(capacity));
        for (size_t k = 0; k < kept; ++k) {
            out_pairs[2 * k] = pairs[k].first;
            out_pairs[2 * k + 1] = pairs[k].second;
        }
        *out_count = static_cast<int>(std::min(pairs.size(), static_cast<size_t>(2147483647)));
        return HH_OK;
    });
}

}  // extern "C"
