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
    m.skeleton = palm_skeleton(m.handle, n_nodes);
    return m;
}

Model build_skeleton_model(const double* rest_positions, int n_nodes, const int* tets, int n_tets,
                           const hh_params& params, const std::vector<BoneDesc>& bones) {
    require(rest_positions && tets, "rest positions and tets must not be null");
    require(n_nodes >= 5, "the hand mesh needs at least 5 nodes (a bone of 4 and some flesh); got " +
                              std::to_string(n_nodes));
    validate_params(params);
    Model m;
    static_cast<Flesh&>(m) = build_flesh(rest_positions, n_nodes, tets, n_tets,
                                         Material{params.young_modulus, params.poisson_ratio, params.density});
    m.params = params;
    m.skeleton = build_skeleton(m.mesh.rest, m.masses, bones);
    m.handle = m.skeleton.bones[0];
    return m;
}

Vec4 bone_drive(const Model& model, int bone) {
    const hh_params& p = model.params;
    const double scale = model.skeleton.drive_scale[bone];
    if (bone == 0)
        return scale * Vec4(p.coupling_stiffness, p.coupling_damping, p.coupling_angular_stiffness,
                            p.coupling_angular_damping);
    // k = m w^2, d = 2 zeta m w: every bone reaches its target in the same time whatever its mass
    const HandleModel& h = model.skeleton.bones[bone];
    const double w = 2 * M_PI * p.drive_frequency, zeta = p.drive_damping_ratio;
    const double mean_inertia = h.inertia_body.trace() / 3;
    return scale * Vec4(h.mass * w * w, 2 * zeta * h.mass * w, mean_inertia * w * w, 2 * zeta * mean_inertia * w);
}

}  // namespace hh
