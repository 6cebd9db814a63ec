#include "sim/model.h"

#include "fem/element_order.h"

#include <cmath>
#include <sstream>

namespace hh {

namespace {
void require(bool ok, const std::string& message) {
    if (!ok) throw InvalidArgument(message);
}

std::string describe(const char* name, double value, const char* rule) {
    std::ostringstream msg;
    msg << name << " = " << value << " is invalid: it must be " << rule;
    return msg.str();
}

void require_positive(const char* name, double value, const char* fix) {
    require(std::isfinite(value) && value > 0, describe(name, value, fix));
}
void require_non_negative(const char* name, double value, const char* fix) {
    require(std::isfinite(value) && value >= 0, describe(name, value, fix));
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

void validate_params(const hh_params& p) {
    require(p.struct_size == static_cast<int>(sizeof(hh_params)),
            "hh_params has the wrong size: the Python bindings and the native library are from "
            "different versions; rebuild the native library (make native)");
    require_positive("young_modulus", p.young_modulus, "a positive stiffness in Pa (soft tissue: 1e4 to 1e6)");
    require(std::isfinite(p.poisson_ratio) && p.poisson_ratio > 0 && p.poisson_ratio < 0.5,
            describe("poisson_ratio", p.poisson_ratio, "in (0, 0.5); nearly incompressible flesh is about 0.45"));
    require_positive("density", p.density, "a positive density in kg/m^3 (flesh: about 1000-1100)");
    require_non_negative("rayleigh_alpha", p.rayleigh_alpha, "zero or positive (1/s)");
    require_non_negative("rayleigh_beta", p.rayleigh_beta, "zero or positive (s)");
    for (int i = 0; i < 3; ++i)
        require(std::isfinite(p.palm_seed[i]), describe("palm_seed", p.palm_seed[i], "a finite point in metres"));
    require_positive("handle_radius", p.handle_radius, "a positive radius in metres");
    require_positive("spring_stiffness", p.spring_stiffness, "a positive stiffness in N/m");
    require_non_negative("spring_damping", p.spring_damping, "zero or positive (N s/m)");
    require_non_negative("coupling_stiffness", p.coupling_stiffness, "zero or positive (N/m)");
    require_non_negative("coupling_damping", p.coupling_damping, "zero or positive (N s/m)");
    require_non_negative("coupling_angular_stiffness", p.coupling_angular_stiffness, "zero or positive (N m/rad)");
    require_non_negative("coupling_angular_damping", p.coupling_angular_damping, "zero or positive (N m s/rad)");
    for (int i = 0; i < 3; ++i)
        require(std::isfinite(p.gravity[i]), describe("gravity", p.gravity[i], "finite (m/s^2)"));
    require(std::isfinite(p.dt) && p.dt > 0, describe("dt", p.dt, "a positive time step in seconds"));
    require(p.dt <= 0.1, describe("dt", p.dt,
                                  "at most 0.1 s: the linearized implicit step loses accuracy beyond "
                                  "that; the visual loop needs 1/30 s or less"));
    require(p.solver == HH_SOLVER_CHOLESKY || p.solver == HH_SOLVER_CG || p.solver == HH_SOLVER_REUSED_CHOLESKY,
            describe("solver", p.solver, "HH_SOLVER_CHOLESKY (0), HH_SOLVER_CG (1) or HH_SOLVER_REUSED_CHOLESKY (2)"));
    require(std::isfinite(p.cg_tolerance) && p.cg_tolerance > 0 && p.cg_tolerance < 1,
            describe("cg_tolerance", p.cg_tolerance, "in (0, 1), e.g. 1e-8"));
    require(p.cg_max_iterations > 0, describe("cg_max_iterations", p.cg_max_iterations, "positive"));
}

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
