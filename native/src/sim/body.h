// One body of a World (sim/world.h): what every kind has (kind, friction, collision surface,
// the step's velocities and contact force) and each kind's own component: the hand's model and
// state (sim/data.h) with its step's bookkeeping, a soft body's nodes and FEM system
// (SoftParts), a mesh body's pose and rigid parts (MeshParts), a plane's point and normal
// (PlaneParts).
#pragma once
#include <memory>
#include <vector>

#include "common/beside.h"
#include "contact/detection.h"
#include "sim/data.h"
#include "sim/keyframes.h"

namespace hh {

enum class BodyKind { Hand, Soft, Rigid, Kinematic, Static, Plane };

// A rigid body's pose and velocity: the same four quantities as the hand's handle.
using RigidState = HandleState;

// The hand's step as World::step's tasks run it: the element pass's parts (formulate_begin,
// parts 0 and 1) and, for a large hand, its assembly and the factor's two parts side by side
// before its free solve (World::solve_free reads their times).
struct HandStep {
    double pass_seconds[3] = {0, 0, 0};  // s, this step: formulate_begin, element pass parts 0 and 1
    bool assemble_apart = false;         // assembled by its own task, with the factor's parts between
    double assembly_seconds = 0, factor_part_seconds[2] = {0, 0};
};

// A soft FEM body (BodyKind::Soft): its mesh and material, its implicit system At (Eq. 7
// without the handle), the nodes held still, and its free solve (sim/body.cpp).
struct SoftParts {
    FleshState state;  // its nodes' positions and velocities
    std::unique_ptr<Flesh> flesh;
    std::unique_ptr<DeformableSystem> tool;
    std::vector<char> fixed;         // per node
    std::vector<int> fixed_entries;  // offsets in At's values zeroed for fixed nodes
    double alpha = 0, beta = 0;      // Rayleigh damping
    VecX rhs;                        // the step's right-hand side
    // on the reused factor, during World::step: its fresh response columns in two shares that
    // may run side by side (DeformableSystem::response_units); empty otherwise
    Beside beside;

    // v_free = At^-1 (b + carried) - P^-1 carried for the step from state (P: the reused
    // factor's response operator; carried: the last step's contact impulses, empty without)
    // take_out_carried false: P f is left in v_free (World::defers_carried)
    void solve_free(double dt, const Vec3& gravity, const VecX& carried, VecX& v_free, bool take_out_carried = true);
    // state advanced by the velocities v (the fixed nodes' held at zero)
    void integrate(const VecX& v, double dt);
};

// A mesh body (Rigid, Kinematic, Static): its vertices in the body frame (origin at the centre
// of mass) and, for a free rigid body, its mass properties and 6x6 system.
struct MeshParts {
    RigidState state;
    RigidState target;  // kinematic: the pose and velocity at the end of the next step
    Keyframes script;   // kinematic: when set, the world moves the body along it (target = script at t + dt)
    std::vector<Vec3> local;
    double mass = 0;
    Mat3 inertia_body = Mat3::Zero();
    std::unique_ptr<RigidSystem> system;

    // the free rigid body's velocities (v, omega) after one implicit step of dt from `state`
    void solve_free(double dt, const Vec3& gravity, VecX& v_free) const;
    // the free rigid body's state advanced by the velocities v = (v, omega)
    void integrate(const VecX& v, double dt);
};

// An infinite plane (BodyKind::Plane): a point on it and its unit normal.
struct PlaneParts {
    Vec3 point = Vec3::Zero(), normal = Vec3::UnitZ();
};

struct Body {
    BodyKind kind = BodyKind::Static;
    double friction = 0.5;          // static Coulomb coefficient
    double kinetic_friction = 0.5;  // kinetic coefficient, at most the static one
    bool self_collision = false;
    SelfExclusions self_exclusions;  // self-collision pairs already in contact at rest
    bool has_surface = false;
    CollisionSurface surface;
    std::vector<Vec3> points;  // the points the surface is made of, this step (world frame)

    // each kind's own component: the hand's, a soft body's, a mesh body's (rigid, kinematic,
    // static), a plane's
    std::unique_ptr<Model> hand_model;
    std::unique_ptr<Data> hand;
    HandStep hand_step;
    SoftParts soft;
    MeshParts mesh;
    PlaneParts plane;

    // last step
    VecX v_free, v_new;     // velocities of the body's unknowns (dofs())
    Vec3 contact_force = Vec3::Zero();  // N, total over the last step
    // A hand or soft body whose contact responses come from a lagged operator (ReusedCholesky):
    // the last step's contact impulses on its unknowns (J^T lambda, N s), which its next free
    // solve takes as a known load (World::solve_free); empty when it had no contact.
    VecX carried_impulse;
    // This step's carried impulses f whose response P f is still in v_free (and v_new): the
    // contact build reads it at the touched unknowns and the impulse pass takes it out
    // (sim/world_carried.cpp); empty otherwise.
    VecX carried_pending;

    bool dynamic() const { return kind == BodyKind::Hand || kind == BodyKind::Soft || kind == BodyKind::Rigid; }
    // a hand driven by a skeleton of more than one bone (docs/skeleton.md): its step is
    // step_skeleton's (sim/skeleton_step.h) and its unknowns (v_1, omega_1, ..., v_B, omega_B, v_t)
    bool skeleton() const { return kind == BodyKind::Hand && hand_model->n_bones() > 1; }
    int dofs() const;
    // how many of its unknowns come before the flesh's: 6 per bone of a hand, else 0
    int handle_dofs() const { return kind == BodyKind::Hand ? 6 * hand_model->n_bones() : 0; }
    // The flesh system its contact responses are solved through (hand, soft body), or null
    DeformableSystem* response_system();
    const DeformableSystem* response_system() const;
    // points from the body's state (the surface's points: flesh nodes or mesh vertices)
    void update_points();
    // the surface's vertex positions from the points (normals and boxes: the next detection)
    void update_surface_positions();
    // m: how far its farthest-moving surface point can travel in the next step of dt, seen from
    // a frame moving at `frame` (m/s): speculative contact's reach (World::begin_detection)
    double step_travel(double dt, const Vec3& frame = Vec3::Zero()) const;
    double bone_travel(int bone, double dt, const Vec3& frame) const;  // (a hand's part of it, per bone)
    // m/s: a velocity its points share, the frame from which a pair's relative motion is seen
    // (the mean of its nodes' velocities; a rigid body's centre's)
    Vec3 drift() const;
};

// Mass, centre of mass and inertia about it of a closed, outward-wound triangle mesh of
// uniform density (divergence theorem over the tetrahedra it makes with the origin).
void mesh_mass_properties(const std::vector<Vec3>& vertices, const std::vector<Eigen::Vector3i>& triangles,
                          double density, double& mass, Vec3& com, Mat3& inertia);

}  // namespace hh
