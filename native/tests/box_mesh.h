// A deterministic test mesh: a box of nx*ny*nz cubes, each split into 6 positively oriented
// tetrahedra around its main diagonal (a conforming Kuhn subdivision).
#pragma once
#include <vector>

#include "common/types.h"
#include "haptic_hand.h"

struct BoxMesh {
    std::vector<double> nodes;  // 3 per node
    std::vector<int> tets;      // 4 per tet
    int n_nodes() const { return static_cast<int>(nodes.size() / 3); }
    int n_tets() const { return static_cast<int>(tets.size() / 4); }
};

inline BoxMesh make_box(int nx, int ny, int nz, double h) {
    BoxMesh m;
    auto id = [&](int i, int j, int k) { return (k * (ny + 1) + j) * (nx + 1) + i; };
    for (int k = 0; k <= nz; ++k)
        for (int j = 0; j <= ny; ++j)
            for (int i = 0; i <= nx; ++i) {
                m.nodes.push_back(i * h);
                m.nodes.push_back(j * h);
                m.nodes.push_back(k * h);
            }
    // the six paths from corner 0 to corner 7 of the unit cube, one tet each
    const int paths[6][2] = {{1, 3}, {1, 5}, {2, 3}, {2, 6}, {4, 5}, {4, 6}};
    for (int k = 0; k < nz; ++k)
        for (int j = 0; j < ny; ++j)
            for (int i = 0; i < nx; ++i) {
                int c[8];
                for (int b = 0; b < 8; ++b) c[b] = id(i + (b & 1), j + ((b >> 1) & 1), k + ((b >> 2) & 1));
                for (const auto& p : paths) {
                    int t[4] = {c[0], c[p[0]], c[p[1]], c[7]};
                    const auto x = [&](int n) { return hh::Vec3(m.nodes[3 * n], m.nodes[3 * n + 1], m.nodes[3 * n + 2]); };
                    hh::Mat3 d;
                    d << x(t[1]) - x(t[0]), x(t[2]) - x(t[0]), x(t[3]) - x(t[0]);
                    if (d.determinant() < 0) std::swap(t[1], t[2]);
                    m.tets.insert(m.tets.end(), t, t + 4);
                }
            }
    return m;
}

// Parameters of a hand rig on make_box(4, 3, 2, 0.01): a handle around the box's middle.
inline hh_params box_hand_params() {
    hh_params p;
    hh_default_params(&p);
    p.palm_seed[0] = 0.02;
    p.palm_seed[1] = 0.015;
    p.palm_seed[2] = 0.01;
    p.handle_radius = 0.0125;
    return p;
}
