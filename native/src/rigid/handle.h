// The rigid handle of Section 4: the hand nodes inside a sphere around the palm seed, with
// mass and inertia from their lumped masses (Eq. 3). Its body frame is the world frame at
// rest, centred at the captured nodes' centre of mass, so each spring's r_B is X_i - x_com.
#pragma once
#include <vector>

#include "common/types.h"

namespace hh {

struct HandleModel {
    std::vector<int> nodes;        // captured hand nodes
    std::vector<Vec3> r_body;      // r_B of each node's spring, body frame
    double mass = 0;               // m_h of Eq. 3
    Vec3 rest_com = Vec3::Zero();  // x_com at rest
    Mat3 inertia_body = Mat3::Zero();  // M_q of Eq. 3, about the centre of mass
};

std::vector<int> capture_nodes(const VecX& rest, const Vec3& seed, double radius);

// Throws InvalidArgument when a sphere of this radius captures fewer than 4 of the n nodes
// (`captured` of them) or all of them: the one rule of a usable handle.
void check_capture(int captured, int n, double radius);

// Eq. 3 for the handle's nodes (h.nodes): its mass, rest centre of mass, springs' r_B and
// inertia, in one order for the palm handle and every bone (so one bone is the palm handle bit
// for bit). Returns false when the nodes are collinear (the inertia's smallest eigenvalue at
// most 1e-12 of its largest): the caller names the fix.
bool fill_mass_and_inertia(HandleModel& h, const VecX& rest, const VecX& node_masses);

// Throws InvalidArgument when the sphere captures fewer than 4 nodes or every node, or
// when the captured nodes are collinear (singular inertia).
HandleModel build_handle(const VecX& rest, const VecX& node_masses, const Vec3& seed, double radius);

}  // namespace hh
