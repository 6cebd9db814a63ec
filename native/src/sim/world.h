// A scene of several bodies simulated together in the visual loop: the hand (flesh + handle),
// soft FEM bodies, free rigid bodies, kinematic bodies moved along a script, static meshes and
// planes. One step: every dynamic body formulates and solves its own implicit system (the
// hand through the Schur complement), contacts are detected at the start of the step, and the
// contact impulses are solved together with the implicit step through each body's black-box
// solve (Delassus operator W = J A^-1 J^T, projected Gauss-Seidel), then all bodies advance.
#pragma once
#include <cstdint>
#include <map>
#include <memory>
#include <unordered_map>
#include <vector>

#include "contact/detection.h"
#include "contact/pgs.h"
#include "sim/data.h"
#include "sim/keyframes.h"

namespace hh {

enum class BodyKind { Hand, Soft, Rigid, Kinematic, Static, Plane };

// A rigid body's pose and velocity: the same four quantities as the hand's handle.
using RigidState = HandleState;

struct Body {
    BodyKind kind = BodyKind::Static;
    double friction = 0.5;          // static Coulomb coefficient
    double kinetic_friction = 0.5;  // kinetic coefficient, at most the static one
    bool self_collision = false;
    SelfExclusions self_exclusions;  // self-collision pairs already in contact at rest
    bool has_surface = false;
    CollisionSurface surface;
    std::vector<Vec3> points;  // the points the surface is made of, this step (world frame)

    // hand
    std::unique_ptr<Model> hand_model;
    std::unique_ptr<Data> hand;
    // soft body
    std::unique_ptr<Flesh> flesh;
    FleshState state;
    std::unique_ptr<DeformableSystem> tool;
    std::vector<char> fixed;         // per node
    std::vector<int> fixed_entries;  // offsets in At's values zeroed for fixed nodes
    double alpha = 0, beta = 0;
    VecX soft_rhs;
    // rigid, kinematic, static mesh: vertices in the body frame (origin at the centre of mass)
    std::vector<Vec3> local;
    RigidState rigid;
    RigidState target;  // kinematic: the pose and velocity at the end of the next step
    Keyframes script;   // kinematic: when set, the world moves the body along it (target = script at t + dt)
    double mass = 0;
    Mat3 inertia_body = Mat3::Zero();
    std::unique_ptr<RigidSystem> rigid_system;
    // plane
    Vec3 plane_point = Vec3::Zero(), plane_normal = Vec3::UnitZ();

    // last step
    VecX v_free, v_new;     // velocities of the body's unknowns (dofs())
    Vec3 contact_force = Vec3::Zero();  // N, total over the last step

    bool dynamic() const { return kind == BodyKind::Hand || kind == BodyKind::Soft || kind == BodyKind::Rigid; }
    int dofs() const;
};

struct WorldSettings {
    double dt = 1.0 / 30.0;
    Vec3 gravity = Vec3(0, 0, -9.81);
    double contact_thickness = 1e-3;  // m: surfaces are kept this far apart
    double contact_patch = 4e-3;      // m: one contact per cell of this size per pair of bodies
    int max_iterations = 300;         // projected Gauss-Seidel sweeps (resting contacts end far sooner)
    double tolerance = 1e-5;          // m/s: largest constraint velocity error that ends the sweeps
};

struct WorldStats {
    int contacts = 0;
    int self_contacts = 0;
    double max_penetration = 0;  // m: deepest a contact ended inside the thickness layer
    double min_distance = 0;     // m: smallest signed distance of a contact after the step
    double residual = 0;         // m/s: largest constraint violation left by the solver
    int iterations = 0;
    double t_detection = 0, t_dynamics = 0, t_contact = 0, t_total = 0;  // s
};

class World {
public:
    explicit World(const WorldSettings& settings);
    WorldSettings settings;
    std::vector<std::unique_ptr<Body>> bodies;
    std::vector<Contact> contacts;  // of the last step, one per patch
    std::vector<Contact> detected;  // every pair found within reach, before the reduction
    WorldStats stats;
    // impulses of the last step's contacts (world frame, N s), by contact identity, to warm
    // start the next step's solve: a resting contact's impulse changes little between steps
    std::unordered_map<std::uint64_t, Vec3> previous_impulse;
    // The last contact solve, kept for the handle-space linearization (haptics/coupling_model):
    // W = J A^-1 J^T before it is symmetrized for Gauss-Seidel, the impulses, the static
    // friction coefficients, and per dynamic body the columns A_b^-1 J_b^T (empty where the
    // body is not in the row).
    MatX contact_W;
    VecX contact_lambda;
    VecX contact_friction;
    std::map<int, std::vector<VecX>> contact_columns;
    double time = 0;  // s: simulated time, advanced by step()

    int add(std::unique_ptr<Body> body);
    void step();

private:
    void update_points(Body& b);
    void detect();
    void reduce_contacts();
    void solve_free();
    void solve_contacts();
    void integrate();
    double contact_distance(const Contact& c) const;
};

// Mass, centre of mass and inertia about it of a closed, outward-wound triangle mesh of
// uniform density (divergence theorem over the tetrahedra it makes with the origin).
void mesh_mass_properties(const std::vector<Vec3>& vertices, const std::vector<Eigen::Vector3i>& triangles,
                          double density, double& mass, Vec3& com, Mat3& inertia);

}  // namespace hh
