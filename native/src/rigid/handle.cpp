#include "rigid/handle.h"

#include <sstream>

namespace hh {

std::vector<int> capture_nodes(const VecX& rest, const Vec3& seed, double radius) {
    std::vector<int> nodes;
    const int n = static_cast<int>(rest.size() / 3);
    for (int i = 0; i < n; ++i)
        if ((rest.segment<3>(3 * i) - seed).norm() <= radius) nodes.push_back(i);
    return nodes;
}

void check_capture(int c, int n, double radius) {
    if (c < 4) {
        std::ostringstream msg;
        msg << "handle radius " << radius << " m around the palm seed captures " << c
            << " node(s); a rigid handle needs at least 4: increase the handle radius or move the "
               "seed deeper into the palm";
        throw InvalidArgument(msg.str());
    }
    if (c == n) {
        std::ostringstream msg;
        msg << "handle radius " << radius << " m captures all " << n
            << " nodes, so nothing of the hand is soft: decrease the handle radius";
        throw InvalidArgument(msg.str());
    }
}

bool fill_mass_and_inertia(HandleModel& h, const VecX& rest, const VecX& node_masses) {
    for (int i : h.nodes) {
        h.mass += node_masses[i];
        h.rest_com += node_masses[i] * rest.segment<3>(3 * i);
    }
    h.rest_com /= h.mass;
    for (int i : h.nodes) {
        const Vec3 r = rest.segment<3>(3 * i) - h.rest_com;
        h.r_body.push_back(r);
        h.inertia_body += node_masses[i] * (r.squaredNorm() * Mat3::Identity() - r * r.transpose());
    }
    Eigen::SelfAdjointEigenSolver<Mat3> eig(h.inertia_body);
    return eig.eigenvalues().minCoeff() > 1e-12 * eig.eigenvalues().maxCoeff();
}

HandleModel build_handle(const VecX& rest, const VecX& node_masses, const Vec3& seed, double radius) {
    HandleModel h;
    h.nodes = capture_nodes(rest, seed, radius);
    check_capture(static_cast<int>(h.nodes.size()), static_cast<int>(rest.size() / 3), radius);
    if (!fill_mass_and_inertia(h, rest, node_masses))
        throw InvalidArgument(
            "the handle's captured nodes are collinear, so its inertia is singular: increase "
            "the handle radius");
    return h;
}

}  // namespace hh
