#include "sim/model.h"

#include "fem/element_order.h"
#include "params/table.h"

#include <cmath>
#include <sstream>

namespace hh {

namespace {
void require(bool ok, const std::string& message) {
    if (!ok) throw InvalidArgument(message);
}

bool point_in_tet(const TetMesh& mesh, const Eigen::Vector4i& t, const Vec3& p) {
    Mat3 d;
    const Vec3 x0 = mesh.rest.segment<3>(3 * t[0]);
    d << mesh.rest.segment<3>(3 * t[1]) - x0, mesh.rest.segment<3>(3 * t[2]) - x0,
        mesh.rest.segment<3>(3 * t[3]) - x0;
    const Vec3 b = d.fullPivLu().solve(p - x0);
    const double eps = 1e-9;
    return b.minCoeff() >= -eps && b.sum() <= 1 + eps;
}
}  // namespace

void validate_params(const hh_params& p) { params::validate(HH_STRUCT_PARAMS, &p); }

Flesh build_flesh(const double* rest_positions, int n_nodes, const int* tets, int n_tets, const Material& material) {
    require(rest_positions && tets, "rest positions and tets must not be null");
    require(n_tets >= 1, "the mesh has no tetrahedra: tetrahedralize the surface first");
    Flesh f;
    f.mesh.n_nodes = n_nodes;
    f.mesh.rest = Eigen::Map<const VecX>(rest_positions, 3 * n_nodes);
    for (int i = 0; i < 3 * n_nodes; ++i)
        require(std::isfinite(f.mesh.rest[i]),
                "node " + std::to_string(i / 3) + " has a non-finite coordinate: fix the mesh");
    std::vector<int> use(n_nodes, 0);
    f.mesh.tets.resize(n_tets);
    for (int e = 0; e < n_tets; ++e) {
        for (int a = 0; a < 4; ++a) {
            const int i = tets[4 * e + a];
            require(i >= 0 && i < n_nodes, "tetrahedron " + std::to_string(e) + " refers to node " +
                                               std::to_string(i) + ", outside 0.." +
                                               std::to_string(n_nodes - 1));
            f.mesh.tets[e][a] = i;
            ++use[i];
        }
    }
    for (int i = 0; i < n_nodes; ++i)
        require(use[i] > 0, "node " + std::to_string(i) +
                                " belongs to no tetrahedron, so it has no mass: remove unreferenced nodes");
    f.elements = precompute_elements(f.mesh, material);  // validates, naming tets in the user's order
    f.masses = lumped_masses(f.mesh, f.elements, material.density);
    order_elements_spatially(f.mesh, f.elements);
    f.passes = split_element_pass(f.mesh, f.elements, n_nodes);
    f.pattern = build_stiffness_pattern(f.mesh);
    return f;
}

Model build_model(const double* rest_positions, int n_nodes, const int* tets, int n_tets,
                  const hh_params& params) {
    require(rest_positions && tets, "rest positions and tets must not be null");
    require(n_nodes >= 5, "the hand mesh needs at least 5 nodes (a handle of 4 and some flesh); got " +
                              std::to_string(n_nodes));
    validate_params(params);
    Model m;
    static_cast<Flesh&>(m) = build_flesh(rest_positions, n_nodes, tets, n_tets,
                                         Material{params.young_modulus, params.poisson_ratio, params.density});
    m.params = params;
    const Vec3 seed(params.palm_seed[0], params.palm_seed[1], params.palm_seed[2]);
    bool inside = false;
    for (const auto& t : m.mesh.tets)
        if (point_in_tet(m.mesh, t, seed)) {
            inside = true;
            break;
        }
    if (!inside) {
        std::ostringstream msg;
        msg << "palm seed (" << seed.x() << ", " << seed.y() << ", " << seed.z()
            << ") m lies outside the hand's tetrahedral mesh: place it inside the palm";
        throw InvalidArgument(msg.str());
    }
    m.handle = build_handle(m.mesh.rest, m.masses, seed, params.handle_radius);
    return m;
}

}  // namespace hh
