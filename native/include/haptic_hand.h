/*
 * Haptic Hand native engine: flat C ABI.
 *
 * Shape follows MuJoCo's mjModel/mjData split: an hh_model holds what does not change
 * during a simulation (rest mesh, material, handle, springs, parameters) and an hh_data
 * holds the state (node positions and velocities, handle pose and velocity, device frame).
 *
 * Every entry point catches every exception and returns HH_OK (0) or a negative status;
 * hh_last_error() then returns a message (thread-local) that names the problem and the fix.
 * Arrays are contiguous: positions are float64 [n][3], tets int32 [m][4], quaternions are
 * (x, y, z, s) as in the paper's Appendix A. SI units throughout (m, kg, s, N).
 */
#ifndef HAPTIC_HAND_H
#define HAPTIC_HAND_H

#include "haptic_hand_params.h"

#ifdef __cplusplus
extern "C" {
#endif
/* The library is built with hidden visibility; only what this header declares is exported. */
#if defined(__GNUC__)
#pragma GCC visibility push(default)
#endif

#define HH_OK 0
#define HH_ERR_INVALID_ARGUMENT -1 /* bad input: the message names it and the fix */
#define HH_ERR_NUMERICAL -2        /* a solve failed or produced non-finite values */
#define HH_ERR_INTERNAL -3         /* a bug: please report the message */

#define HH_SOLVER_CHOLESKY 0 /* sparse Cholesky of At, factored once per step, 8 solves */
#define HH_SOLVER_CG 1       /* Jacobi-preconditioned conjugate gradient, warm started */
/* The factor of an earlier step's At, rotated by each node's rotation since, preconditions CG
 * (warm started, to the relative residual cg_tolerance); renewed when that lowers the mean cost
 * per step. For large meshes (docs/maths.md, "Schur-complement solve"). */
#define HH_SOLVER_REUSED_CHOLESKY 2
/* Soft bodies only: HH_SOLVER_CHOLESKY below 1000 tets, HH_SOLVER_REUSED_CHOLESKY from there on
 * (the rule bench/bench_soft_solver.py supports; docs/contact.md). */
#define HH_SOLVER_AUTO 3

#define HH_API_VERSION 3

typedef struct hh_model hh_model;
typedef struct hh_data hh_data;

/* The parameter structs are built field by field from the parameter table
 * (haptic_hand_params.h), which also holds every field's unit, default, range and meaning.
 * Fill one with its hh_default_* function, then change what you need; struct_size catches a
 * caller built against another version of this header. */
#define HH_FIELD_DOUBLE_1(name) double name;
#define HH_FIELD_DOUBLE_3(name) double name[3];
#define HH_FIELD_INT_1(name) int name;
#define HH_FIELD_HH_KIND_DOUBLE(name, count) HH_FIELD_DOUBLE_##count(name)
#define HH_FIELD_HH_KIND_INT(name, count) HH_FIELD_INT_##count(name)
#define HH_FIELD_HH_KIND_BOOL(name, count) HH_FIELD_INT_##count(name)
#define HH_FIELD_HH_KIND_ENUM(name, count) HH_FIELD_INT_##count(name)
#define HH_FIELD(name, kind, count, ...) HH_FIELD_##kind(name, count)

/* A hand rig: material of the flesh, the rigid handle (Section 4), its springs (Eq. 4), the
 * one-directional virtual coupling to the device (Fig. 2, top), integration and solver. */
typedef struct hh_params {
    int struct_size;
    HH_PARAMS_ROWS(HH_FIELD)
} hh_params;

typedef struct hh_model_info {
    int n_nodes;
    int n_tets;
    int n_handle_nodes;
    double total_mass;          /* kg, sum of lumped node masses */
    double handle_mass;         /* kg, Eq. 3: sum of the captured nodes' lumped masses */
    double handle_com[3];       /* m, rest centre of mass of the handle */
    double handle_inertia[9];   /* kg m^2, row-major, about handle_com, world axes at rest */
    double min_tet_volume;      /* m^3 */
    double max_tet_volume;      /* m^3 */
} hh_model_info;

/* Wall-clock cost of the last step, split as the benchmarks report it. */
typedef struct hh_step_stats {
    double t_assembly;        /* s: co-rotation, stiffness, springs, Aht/Ath */
    double t_deformable;      /* s: the 8 solves with At (factorization included) */
    double t_schur;           /* s: forming and solving the 6x6 Schur complement */
    double t_total;           /* s: the whole step */
    int cg_iterations;        /* summed over the 8 solves (0 with Cholesky) */
    double max_residual;      /* largest relative residual of the 8 At solves */
} hh_step_stats;

/* --- errors and version --- */
const char* hh_last_error(void);
int hh_api_version(void);

/* --- the parameter table (haptic_hand_params.h), for bindings and tools --- */
#define HH_STRUCT_NONE 0 /* a scene-file field with no C struct */
#define HH_STRUCT_PARAMS 1
#define HH_STRUCT_WORLD_PARAMS 2
#define HH_STRUCT_MATERIAL 3
#define HH_STRUCT_SESSION_PARAMS 4
/* Structs with no parameter rows: hh_struct_size only, for the bindings' layout checks. */
#define HH_STRUCT_SKELETON_DESC 5
#define HH_STRUCT_BONE_INFO 6
#define HH_STRUCT_MODEL_INFO 7
#define HH_STRUCT_STEP_STATS 8
#define HH_STRUCT_WORLD_STATS 9
#define HH_STRUCT_SESSION_STATUS 10
#define HH_STRUCT_SESSION_FRAME 11

/* One row of the table, as declared there (strings live in the library). A row shared by two
 * structs (dt, gravity, the coupling) comes once for each, with the same values. */
typedef struct hh_param_info {
    int struct_size;
    const char* name;
    const char* json;          /* "" for HH_INTERNAL rows */
    const char* unit;
    const char* label;
    const char* text;          /* enum choices "a|b|c", or the JSON default of a row with no number */
    const char* description;
    const char* advice;
    int kind;                  /* HH_KIND_* */
    int count;
    int flags;                 /* HH_OPEN_*, HH_NULLABLE, HH_UI_*, HH_FOR_* ... */
    int structure;             /* HH_STRUCT_* */
    int offset;                /* byte offset of the field in its struct, -1 without one */
    double default_value[3];
    double min, max, soft_min, soft_max;
} hh_param_info;

int hh_param_count(void);
int hh_param_info_get(int index, hh_param_info* out);
/* sizeof the struct HH_STRUCT_* (the bindings check their layout against it). */
int hh_struct_size(int structure, int* out_size);
/* Checks a value (count numbers; enums as their index, booleans as 0 / 1) of the row with this
 * JSON path against its range: HH_OK, or HH_ERR_INVALID_ARGUMENT with a message naming the
 * field, the valid range and a good value. The same check the structs get. */
int hh_param_check(const char* json, const double* values, int count);

/* --- checks of scene values that hold between numbers, before anything is built --- */
/* Timed poses (a device or kinematic trajectory) as the library takes them: n >= 1 poses with
 * finite values, strictly increasing times and non-zero quaternions (null: identity); else
 * HH_ERR_INVALID_ARGUMENT with a message naming the pose and the fix. */
int hh_trajectory_check(const double* times, const double* positions, const double* quaternions, int n);
/* The cells of a box body (mesh "box", 6 tets a cell; whole numbers as doubles):
 * HH_ERR_INVALID_ARGUMENT with a message naming the fix when they are out of range or make more
 * tets than a step can take. */
int hh_box_cells_check(const double cells[3]);

/* --- surface checks, before a mesh is tetrahedralized or simulated --- */
/* Pairs of triangles (faces int32 [n_faces][3]) that cross where a closed 2-manifold surface
 * keeps them apart: sharing no vertex and crossing (or overlapping, coplanar); sharing one vertex
 * and crossing away from it; sharing an edge and folded onto each other. Writes the first `capacity` pairs (i < j,
 * ascending; out_pairs may be null when capacity is 0) and how many there are to out_count. */
int hh_surface_self_intersections(const double* vertices, int n_vertices, const int* faces, int n_faces,
                                  int* out_pairs, int capacity, int* out_count);

/* --- model --- */
void hh_default_params(hh_params* params);
/* Validates everything (finite positive parameters, positively oriented tets, a handle
 * that captures at least 4 nodes and not all of them, a seed inside the mesh). */
int hh_model_create(const double* rest_positions, int n_nodes, const int* tets, int n_tets,
                    const hh_params* params, hh_model** out_model);
void hh_model_free(hh_model* model);
int hh_model_info_get(const hh_model* model, hh_model_info* out);
int hh_model_handle_nodes(const hh_model* model, int* out_nodes, int capacity);
int hh_model_lumped_masses(const hh_model* model, double* out_masses, int n_nodes);
int hh_model_params(const hh_model* model, hh_params* out);
/* Nodes a handle of this radius would capture (without building a model). */
int hh_count_captured(const double* rest_positions, int n_nodes, const double seed[3],
                      double radius, int* out_count);
/* The same count, and HH_ERR_INVALID_ARGUMENT with hh_model_create's message when the handle
 * would hold fewer than 4 nodes or all of them. */
int hh_check_handle(const double* rest_positions, int n_nodes, const double seed[3], double radius,
                    int* out_count);

/* --- data (state) --- */
int hh_data_create(const hh_model* model, hh_data** out_data);
void hh_data_free(hh_data* data);
int hh_data_reset(const hh_model* model, hh_data* data);
int hh_get_state(const hh_model* model, const hh_data* data, double* x, double* v, int n_nodes,
                 double handle_position[3], double handle_quaternion[4],
                 double handle_velocity[3], double handle_angular_velocity[3]);
int hh_set_state(const hh_model* model, hh_data* data, const double* x, const double* v, int n_nodes,
                 const double handle_position[3], const double handle_quaternion[4],
                 const double handle_velocity[3], const double handle_angular_velocity[3]);
/* The tracked device frame at the end of the next step. enabled = 0 detaches the
 * virtual coupling (free flight); 1 couples the handle to it (Fig. 2 top); 2 prescribes it:
 * the handle reaches exactly that pose at the end of the step (a haptic session drives the
 * visual loop's handle to its proxy this way). */
int hh_set_device(hh_data* data, int enabled, const double position[3], const double quaternion[4],
                  const double velocity[3], const double angular_velocity[3]);
int hh_set_solver(hh_model* model, int solver, double cg_tolerance, int cg_max_iterations);

/* --- simulation --- */
/* One implicit step of Eq. 7 through the Schur complement (Section 6 pseudocode). */
int hh_step(const hh_model* model, hh_data* data, hh_step_stats* out_stats);
/* One step through the monolithic reference solve of Eq. 7 (for tests and benchmarks). */
int hh_step_monolithic(const hh_model* model, hh_data* data, hh_step_stats* out_stats);
/* Formulates Eq. 7 at the current state, solves it both ways without changing the state,
 * and returns max|v_schur - v_mono| / max|v_mono| (0 when both are zero). */
int hh_compare_solvers(const hh_model* model, const hh_data* data, double* out_relative_difference);

/* --- handle-space linearization of the hand alone (Section 3, Garre & Otaduy 2009); with contact,
 * hh_world_coupling_model --- */
/* From the current state (not changed): the step with the handle driven at the end-of-step
 * velocity v_h = (v_com, omega) (prescribed to the pose that velocity reaches), and the springs'
 * wrench on the handle at the end of that step as a linear function of v_h about v_h = 0:
 *   W(v_h) = wrench0 + response * v_h,
 * the exact derivative of hh_coupling_response (docs/haptics.md). response is row-major 6x6;
 * wrench0 is (force, torque). */
int hh_coupling_linear_model(const hh_model* model, const hh_data* data, double wrench0[6], double response[36]);
/* The same wrench without linearizing: the full step with the handle driven at v_h, the
 * springs' wrench taken at its end. For checking the model. */
int hh_coupling_response(const hh_model* model, const hh_data* data, const double handle_velocity[6],
                         double wrench[6]);
/* After hh_step with the handle prescribed (hh_set_device enabled = 2) and before the state is
 * changed: the springs' wrench wrench0 at the handle's end-of-step pose and its stiffness (36,
 * row-major) with respect to a displacement (dx, dtheta) of the prescribed pose, the exact
 * derivative of that step (as hh_world_coupling_model, without contact). */
int hh_coupling_model(const hh_model* model, const hh_data* data, double wrench0[6], double stiffness[36]);

/* --- observables --- */
/* Total force and torque (about the handle's centre of mass) the springs apply on the handle. */
int hh_coupling_wrench(const hh_model* model, const hh_data* data, double force[3], double torque[3]);
/* Kinetic energy of flesh and handle (every bone), elastic energy of the flesh, spring energy (J):
 * the flesh springs' and a skeleton's ball joints' (docs/skeleton.md Section 5). */
int hh_energies(const hh_model* model, const hh_data* data, double* kinetic, double* elastic,
                double* spring);
/* Linear momentum of flesh plus handle (kg m/s). */
int hh_linear_momentum(const hh_model* model, const hh_data* data, double out[3]);

/* ===================== a skeleton of many handles (docs/skeleton.md) =====================
 * B rigid bones, each a handle of Section 4 with its own nodes, springs and virtual coupling to
 * its own target. Arrays are row-major and contiguous, bones in skeleton order, quaternions
 * (x, y, z, s). A one-bone model behaves exactly as today's, and the handle functions above
 * (hh_get_state's handle, hh_set_device, hh_coupling_wrench, hh_model_info_get's handle fields)
 * address bone 0, the root. With more than one bone, the palm handle's linearizations
 * (hh_coupling_linear_model, _response, _model: use hh_bone_linear_model, hh_bone_response) and
 * hh_world_coupling_model are refused (use hh_world_bone_coupling_model); a world takes the hand
 * (hh_world_add_hand) and drives its bones with hh_world_set_bone_targets, a haptic session
 * with one device frame per bone (hh_session_device_external_frames, _simulated_glove). */
#define HH_BONE_FREE 0       /* no target: carried by the flesh */
#define HH_BONE_COUPLED 1    /* follows its target through its virtual coupling */
#define HH_BONE_PRESCRIBED 2 /* reaches its target pose at the end of the step */

/* Bones: parents[B] (-1 for a root; a tree), heads[B][3], tails[B][3], radii[B] (m). Explicit
 * node sets (Blender vertex groups): bone b's nodes are set_nodes[set_offsets[b] ..
 * set_offsets[b+1]) (B + 1 non-decreasing offsets; an empty range: capture by distance); both may
 * be NULL (no explicit sets). names[B] (NULL: "bone 0", "bone 1", ...) name the bones in messages.
 * drive_scales[B] (NULL: all 1) multiply each bone's virtual coupling gains (0: free). */
typedef struct hh_skeleton_desc {
    int struct_size;
    int n_bones;
    const int* parents;
    const double* heads;
    const double* tails;
    const double* radii;
    const int* set_offsets;
    const int* set_nodes;
    const char* const* names;
    const double* drive_scales;
    /* Angular limits (docs/skeleton.md Section 5), each NULL for none: axes[B][9] each bone's rest
     * axes, row-major, its columns x, y, z (world frame; NULL: the world axes); limit_min[B][3],
     * limit_max[B][3] the range of its rotation relative to its parent, as a rotation vector in
     * those axes (rad; -inf / +inf: a free axis; min <= 0 <= max; none on a root). */
    const double* axes;
    const double* limit_min;
    const double* limit_max;
} hh_skeleton_desc;

/* The capture rule without a model: a node in an explicit set is that bone's; any other goes to
 * the nearest bone segment among the capsules holding it (ties to the bone listed first).
 * out_node_bone[n_nodes] (-1: flesh only), out_counts[B]. HH_ERR_INVALID_ARGUMENT with
 * hh_model_create_skeleton's message when a bone holds fewer than 4 nodes, a node is in two
 * explicit sets, every node is held, or the bones are not a valid tree. */
int hh_skeleton_capture(const double* rest_positions, int n_nodes, const hh_skeleton_desc* skeleton,
                        int* out_node_bone, int* out_counts);
/* hh_model_create with bones instead of the palm handle (params->palm_seed and handle_radius are
 * not read). One bone with head = tail = seed and radius = handle_radius is today's model. */
int hh_model_create_skeleton(const double* rest_positions, int n_nodes, const int* tets, int n_tets,
                             const hh_params* params, const hh_skeleton_desc* skeleton, hh_model** out_model);

typedef struct hh_bone_info {
    int struct_size;
    int parent;
    int n_nodes;         /* captured */
    double mass;         /* kg, Eq. 3 */
    double com[3];       /* m, rest centre of mass: the body frame's origin */
    double inertia[9];   /* kg m^2, row-major, about com, world axes at rest */
    double drive[4];     /* k (N/m), d (N s/m), k_r (N m/rad), d_r (N m s/rad) of its virtual coupling */
} hh_bone_info;
int hh_model_bone_count(const hh_model* model, int* out_n_bones);
/* out->struct_size must be set by the caller (sizeof(hh_bone_info)). */
int hh_model_bone_info(const hh_model* model, int bone, hh_bone_info* out);
int hh_model_bone_nodes(const hh_model* model, int bone, int* out_nodes, int capacity, int* out_count);
/* out_node_bone[n_nodes]: each node's bone, -1 for flesh only. */
int hh_model_node_bones(const hh_model* model, int* out_node_bone, int n_nodes);

/* Bone states, all B at once (any pointer may be NULL): positions[B][3] (centres of mass),
 * quaternions[B][4], velocities[B][3], angular_velocities[B][3] (world frame). */
int hh_get_bone_states(const hh_model* model, const hh_data* data, int n_bones, double* positions,
                       double* quaternions, double* velocities, double* angular_velocities);
int hh_set_bone_states(const hh_model* model, hh_data* data, int n_bones, const double* positions,
                       const double* quaternions, const double* velocities, const double* angular_velocities);
/* Targets at the end of the next step: modes[B] (HH_BONE_*), poses as above (NULL positions or
 * quaternions: kept; NULL velocities: zero). The root's target is what hh_set_device sets. */
int hh_set_bone_targets(const hh_model* model, hh_data* data, int n_bones, const int* modes, const double* positions,
                        const double* quaternions, const double* velocities, const double* angular_velocities);
/* Each bone's springs' wrench at the current state: out[B][6] = (force, torque about its centre
 * of mass), Eq. 5 summed over its nodes. */
int hh_bone_wrenches(const hh_model* model, const hh_data* data, int n_bones, double* out);
/* The 6B x 6B model of the hand alone (docs/skeleton.md, Section 6, no contacts), from the
 * current state (not changed): the step with every bone driven at the end-of-step velocity
 * v_h = (v_1, omega_1, ..., v_B, omega_B) (prescribed to the pose that velocity reaches from the
 * step's frame), and every bone's springs' wrench at the end of that step as a linear function
 * of v_h about v_h = 0: W(v_h) = wrench0 + response v_h, its exact derivative. wrench0[6B],
 * response[6B * 6B] row-major. One bone: hh_coupling_linear_model. */
int hh_bone_linear_model(const hh_model* model, const hh_data* data, int n_bones, double* wrench0, double* response);
/* The same wrenches without linearizing, for the end velocities velocities[6B]: out[6B]. */
int hh_bone_response(const hh_model* model, const hh_data* data, int n_bones, const double* velocities, double* out);


/* ===================== scenes with contact (the visual loop) =====================
 * A world holds the hand and other bodies and steps them together with contact and
 * Coulomb friction. Collision surfaces are triangles over surface vertices; vertex v is
 * sum_k weights[4v+k] * point(nodes[4v+k]) (unused slots: weight 0), where the points are
 * the tet nodes of a hand or soft body (so a fine surface rides on coarse tets) or the
 * vertices themselves for mesh bodies. Body poses are of the body's centre of mass. */
typedef struct hh_world hh_world;

#define HH_BODY_HAND 0
#define HH_BODY_SOFT 1
#define HH_BODY_RIGID 2      /* free rigid body */
#define HH_BODY_KINEMATIC 3  /* moved by hh_world_set_pose along a script */
#define HH_BODY_STATIC 4
#define HH_BODY_PLANE 5

typedef struct hh_world_params {
    int struct_size;
    HH_WORLD_PARAMS_ROWS(HH_FIELD)
} hh_world_params;

typedef struct hh_material {
    int struct_size;
    HH_MATERIAL_STRUCT_ROWS(HH_FIELD)
} hh_material;

typedef struct hh_world_stats {
    int contacts;
    int self_contacts;      /* of them, between two parts of the same body (fingers) */
    double max_penetration; /* m: deepest a contact ended inside the thickness layer */
    double min_distance;    /* m: smallest signed distance of a detected pair after the step (inf: none) */
    double residual;        /* m/s: largest constraint violation left by the contact solver */
    int iterations;         /* Gauss-Seidel sweeps */
    double t_detection, t_dynamics, t_contact, t_total; /* s: the parts' own costs (they overlap
                                                          on two threads) and the step's wall time */
} hh_world_stats;

void hh_default_world_params(hh_world_params* params);
void hh_default_material(hh_material* material);
int hh_world_create(const hh_world_params* params, hh_world** out_world);
void hh_world_free(hh_world* world);
/* The hand: a copy of the model (its dt and gravity are replaced by the world's). */
int hh_world_add_hand(hh_world* world, const hh_model* model, const int* surface_nodes,
                      const double* surface_weights, int n_surface_vertices, const int* faces,
                      int n_faces, double friction, int self_collision, int* out_body);
int hh_world_add_soft_body(hh_world* world, const double* nodes, int n_nodes, const int* tets,
                           int n_tets, const hh_material* material, const int* fixed_nodes,
                           int n_fixed, const int* surface_nodes, const double* surface_weights,
                           int n_surface_vertices, const int* faces, int n_faces, double friction,
                           int* out_body);
/* kind: HH_BODY_RIGID (needs a closed mesh and a density), HH_BODY_KINEMATIC or HH_BODY_STATIC. */
int hh_world_add_mesh_body(hh_world* world, int kind, const double* vertices, int n_vertices,
                           const int* faces, int n_faces, double density, double friction,
                           int* out_body);
int hh_world_add_plane(hh_world* world, const double point[3], const double normal[3], double friction,
                       int* out_body);
/* Coulomb friction of a body: sticking holds up to static_friction, sliding feels
 * kinetic_friction (<= static). A pair uses the geometric mean of its bodies' values. */
int hh_world_set_friction(hh_world* world, int body, double static_friction, double kinetic_friction);
/* A soft body's solver (HH_SOLVER_AUTO, the table's default, until this is called).
 * HH_SOLVER_CHOLESKY: its system factored every step, and every contact response solved on that
 * factor. HH_SOLVER_REUSED_CHOLESKY: as the hand's, an earlier step's factor warped by the nodes'
 * rotations preconditions CG to the relative residual cg_tolerance, and is the contact response
 * operator, whose columns are kept until the factor is renewed (for large soft bodies in long
 * contact, like a bunny resting on the ground). */
int hh_world_set_body_solver(hh_world* world, int body, int solver, double cg_tolerance, int cg_max_iterations);
/* Kinematic: the pose and velocity at the end of the next step. Rigid: the current state. Hand:
 * its handle's current state (with hh_world_set_body_nodes, the whole hand's state). */
int hh_world_set_pose(hh_world* world, int body, const double position[3], const double quaternion[4],
                      const double velocity[3], const double angular_velocity[3]);
int hh_world_get_pose(const hh_world* world, int body, double position[3], double quaternion[4],
                      double velocity[3], double angular_velocity[3]);
int hh_world_set_device(hh_world* world, int hand_body, int enabled, const double position[3],
                        const double quaternion[4], const double velocity[3],
                        const double angular_velocity[3]);
int hh_world_step(hh_world* world, hh_world_stats* out_stats);
/* The statistics of the world's last step (also after steps a session made). */
int hh_world_last_stats(const hh_world* world, hh_world_stats* out_stats);
int hh_world_body_kind(const hh_world* world, int body, int* out_kind, int* out_n_nodes,
                       int* out_n_surface_vertices);
/* hand and soft bodies: node positions and velocities (either pointer may be null). */
int hh_world_body_nodes(const hh_world* world, int body, double* x, double* v, int n_nodes);
int hh_world_set_body_nodes(hh_world* world, int body, const double* x, const double* v, int n_nodes);
int hh_world_surface_positions(const hh_world* world, int body, double* x, int n_vertices);
/* Total contact force on the body during the last step (N). */
int hh_world_contact_force(const hh_world* world, int body, double force[3]);
/* The hand's handle pose and the springs' force and torque on the handle. */
int hh_world_hand_state(const hh_world* world, int hand_body, double handle_position[3],
                        double handle_quaternion[4], double force[3], double torque[3]);
/* The cost split of the hand's own implicit step within the last world step. */
int hh_world_hand_step_stats(const hh_world* world, int hand_body, hh_step_stats* out);
/* Linear momentum of all dynamic bodies (kg m/s). */
int hh_world_linear_momentum(const hh_world* world, double out[3]);
/* A skeleton hand's bones in a world (any hand: a one-bone hand has n_bones 1, its root the
 * handle). Targets at the end of the next step as hh_set_bone_targets; states: each bone's
 * centre of mass positions[B][3], quaternions[B][4] and its springs' wrenches[B][6] (force,
 * torque about the centre of mass); any pointer may be NULL. */
int hh_world_set_bone_targets(hh_world* world, int hand_body, int n_bones, const int* modes,
                              const double* positions, const double* quaternions,
                              const double* velocities, const double* angular_velocities);
int hh_world_bone_states(const hh_world* world, int hand_body, int n_bones, double* positions,
                         double* quaternions, double* wrenches);
/* Each bone's velocities[B][3] (of its centre of mass) and angular_velocities[B][3] (any may be
 * NULL); and all four of a bone's state set at once (NULL: kept), as hh_set_bone_states. */
int hh_world_bone_velocities(const hh_world* world, int hand_body, int n_bones, double* velocities,
                             double* angular_velocities);
int hh_world_set_bone_states(hh_world* world, int hand_body, int n_bones, const double* positions,
                             const double* quaternions, const double* velocities, const double* angular_velocities);
/* The handle-space model of the bones with the last step's contacts held (docs/skeleton.md,
 * Section 6): after hh_world_step with every bone prescribed (HH_BONE_PRESCRIBED), every bone's
 * springs' wrench wrench0[6B] at the end of the step and its stiffness[6B][6B] (row-major) with
 * respect to displacements (dx_1, dtheta_1, ..., dx_B, dtheta_B) of the prescribed poses, the
 * exact derivative of that step; held_rows: the contact rows it holds. One bone:
 * hh_world_coupling_model's. */
int hh_world_bone_coupling_model(const hh_world* world, int hand_body, int n_bones, double* wrench0,
                                 double* stiffness, int* held_rows);
/* The force (N) the last step's contacts put on each node of the hand or a soft body,
 * out[n_nodes][3] (their sum is hh_world_contact_force's). */
int hh_world_node_contact_forces(const hh_world* world, int body, double* out, int n_nodes);

/* ===================== haptic rendering (Section 3) =====================
 * A session runs the visual loop (the world, with the hand's handle driven to the proxy and
 * the coupling force linearized in handle space after each step) and the haptic loop (the
 * proxy handle under the linearized coupling force, coupled to the device by a two-way
 * viscoelastic virtual coupling; the feedback is that coupling's reaction). Offline, both run
 * in virtual time in the caller's thread (reproducible); live, each has its own thread (or
 * the device driver's servo loop), and the world may not be touched except through the
 * session until hh_session_stop. */
typedef struct hh_session hh_session;

typedef struct hh_session_params {
    int struct_size;
    HH_SESSION_PARAMS_ROWS(HH_FIELD)
} hh_session_params;

/* One row of the haptic log, HH_LOG_COLUMNS doubles: time, period, step cost (s), device
 * position (3) and quaternion (4), proxy position (3) and quaternion (4), feedback force (3, N)
 * and torque (3, N m). */
#define HH_LOG_COLUMNS 23
int hh_log_columns(void); /* HH_LOG_COLUMNS, for bindings */

typedef struct hh_session_status {
    int running;             /* 1 while live threads run */
    int failed;              /* 1 once the session stopped on an error (message below) */
    double haptic_steps, visual_steps;
    double log_unread, log_dropped;
    int realtime;            /* 1 when the haptic thread runs with real-time priority */
    char message[512];
} hh_session_status;

/* The newest visual frame's scalars (the surfaces through hh_session_frame_surface). */
typedef struct hh_session_frame {
    double time;           /* s, the world's simulated time */
    double visual_steps;
    double handle[7], proxy[7], device[7];  /* position, quaternion (x, y, z, s) */
    double feedback[6];    /* force (N) and torque (N m) sent to the device */
    double wrench[6];      /* F_c0: the springs' wrench on the handle in the coupling model */
    int contacts;
    int held_rows;         /* contact constraint rows held in the coupling model */
} hh_session_frame;

void hh_default_session_params(hh_session_params* params);
/* The checks hh_session_create makes, without a world: every field, and the coupling's
 * stiffness within what the haptic loop is tested stable at. */
int hh_session_params_check(const hh_session_params* params);
/* The session borrows the world (it must outlive the session) and drives its hand. */
int hh_session_create(hh_world* world, int hand_body, const hh_session_params* params, hh_session** out);
void hh_session_free(hh_session* session);
/* Devices (one per session, replaced by the next call). Trajectories are timed poses, positions
 * in metres in the scene, quaternions (x, y, z, s); fail_at (s) makes the device report a
 * disconnection from that time on (for tests; pass a huge value otherwise). */
int hh_session_device_simulated(hh_session* session, const double* times, const double* positions,
                                const double* quaternions, int n, double arm_mass, double arm_stiffness,
                                double arm_damping, double fail_at);
int hh_session_device_playback(hh_session* session, const double* times, const double* positions,
                               const double* quaternions, int n, double fail_at);
/* The host pushes the pose (HID input, Blender's viewport target). Until the first pose the
 * device holds the handle's pose; none within timeout (s, haptics.external_timeout) of the
 * first haptic step fails the session with a message. */
int hh_session_device_external(hh_session* session, double timeout);
int hh_session_push_device_pose(hh_session* session, const double position[3], const double quaternion[4]);
/* OpenHaptics (Touch, Omni): library null means "libHD.so". Device millimetres map to scene
 * metres times workspace_scale about workspace_origin; max_force in N. */
int hh_session_device_openhaptics(hh_session* session, const char* library, double workspace_scale,
                                  const double workspace_origin[3], double max_force);
int hh_session_run_offline(hh_session* session, int visual_steps);
int hh_session_start(hh_session* session);
int hh_session_stop(hh_session* session);
int hh_session_get_status(hh_session* session, hh_session_status* out);
/* How the last live haptic thread ran, once hh_session_stop has returned (docs/haptics.md,
 * "Timing"): the CPU it was pinned to (-1: none), whether that CPU is isolated (isolcpus), the
 * bytes of its memory locked in RAM and those mlock refused, and the page faults (minor, major)
 * it took inside its loop. Any pointer may be null. */
int hh_session_loop_info(hh_session* session, int* cpu, int* cpu_isolated, double* locked_bytes,
                         double* unlocked_bytes, double* minor_faults, double* major_faults);
/* Takes the newest frame if there is one (out_new = 1) and copies its scalars. */
int hh_session_fetch_frame(hh_session* session, int* out_new, hh_session_frame* out);
/* The fetched frame's collision-surface vertices of a body (hand or soft body). */
int hh_session_frame_surface(hh_session* session, int body, double* out, int n_vertices);
/* The fetched frame's pose of a rigid, kinematic or static body: centre and quaternion. */
int hh_session_frame_pose(hh_session* session, int body, double pose[7]);
/* Copies up to capacity unread log rows into out (row-major, HH_LOG_COLUMNS each). */
int hh_session_read_log(hh_session* session, double* out, int capacity, int* out_rows);
/* The coupling model of the fetched frame: wrench0 (6) and stiffness (36, row-major,
 * d wrench / d (dx, dtheta)), and how many contact rows it holds. */
int hh_session_coupling_model(hh_session* session, double wrench0[6], double stiffness[36], int* held_rows);

/* --- a session on a skeleton hand of B > 1 bones (docs/skeleton.md, Section 6) ---
 * The visual loop drives every bone to its proxy (prescribed) and publishes the bones' model
 * with contacts held (hh_world_bone_coupling_model); the haptic loop steps one proxy per bone,
 * each held by its own virtual coupling (the session's gains) to its own device frame, against
 * that 6B x 6B model, and commands a wrench per bone and per group of bones. Its device has one
 * frame per bone: an external glove or the simulated glove user; or, with the fingers posed
 * (hh_session_pose_fingers), any one-frame device on the wrist (a one-frame device without posed
 * fingers is refused; and a glove on a one-handle hand's session). The log and the palm fields
 * of hh_session_frame hold the root bone's frame and proxy, and the wrench the device was
 * commanded (the root's; with posed fingers the whole hand's). Arrays are bones in skeleton order,
 * poses (position, quaternion (x, y, z, s)), wrenches (force N, torque N m). */
int hh_session_bone_count(hh_session* session, int* out);
/* A glove whose frames the host pushes (one pose per bone, hh_session_push_device_frames) and
 * whose feedback it reads (hh_session_device_feedback). Until the first push the frames hold the
 * bones' poses; none within timeout (s) of the first haptic step fails the session. */
int hh_session_device_external_frames(hh_session* session, int n_bones, double timeout);
int hh_session_push_device_frames(hh_session* session, int n_bones, const double* positions,
                                  const double* quaternions);
/* The feedback the haptic loop commanded last: bones[B][6], groups[G][6] (G as set by
 * hh_session_set_feedback_groups, 0 without), and its haptic time (any output may be NULL). */
int hh_session_device_feedback(hh_session* session, int n_bones, double* bones, int n_groups, double* groups,
                               double* time);
/* The simulated glove user: one simulated arm (as hh_session_device_simulated's, with these
 * settings) per bone, following its timed poses positions[n][B][3], quaternions[n][B][4] (NULL:
 * identity) and pushed by its bone's feedback force. */
int hh_session_device_simulated_glove(hh_session* session, int n_bones, const double* times, const double* positions,
                                      const double* quaternions, int n, double arm_mass, double arm_stiffness,
                                      double arm_damping, double fail_at);
/* The simulated glove user with an arm of its own per bone, arms[B][3] = (mass kg, stiffness N/m,
 * damping N s/m), each checked against the haptics.glove.* rows; posed[B] (NULL: none): 1 where
 * the frame follows its poses exactly and feels nothing (a finger posed by animation while a
 * palm device carries the root, docs/skeleton.md Section 8). */
int hh_session_device_simulated_glove_arms(hh_session* session, int n_bones, const double* times,
                                           const double* positions, const double* quaternions, int n,
                                           const double* arms, const int* posed, double fail_at);
/* The fingers posed on a one-frame device on the wrist (docs/skeleton.md, Section 6): bone b's pose
 * relative to the root, rel_b = T_root,anim^-1 T_b,anim, at each time (times[n] strictly
 * increasing, s; rel_positions[n][B][3] in the root's frame, m; rel_quaternions[n][B][4] unit,
 * (x, y, z, s); the root's entries, b = 0, are not read). Every one-frame device given to the
 * session after this (hh_session_device_simulated, _playback, _external, _openhaptics; one already
 * given takes the new poses) drives the root, and bone b's frame is the device's carried by rel_b;
 * the device is commanded the whole hand's wrench: every bone's force, and its torque plus the
 * force's moment about the device's frame, summed (each bone's unclamped), the sum clamped to the
 * session's and the device's limits. Quaternions within 1e-4 of unit norm are normalized. Refused
 * while feedback groups are set (they need a glove of one frame per bone). Set while stopped. */
int hh_session_pose_fingers(hh_session* session, int n_bones, const double* times, const double* rel_positions,
                            const double* rel_quaternions, int n);
/* Groups of bones whose feedback is summed (a glove's actuators: e.g. the wrist and each digit):
 * group_of_bone[B] in 0 .. n_groups-1, or -1 for none; every group holds a bone. A group's force
 * is its bones' sum, its torque their torques plus each bone's force's moment about the device
 * frame of the group's first bone. Set while stopped. */
int hh_session_set_feedback_groups(hh_session* session, int n_bones, const int* group_of_bone, int n_groups);
/* The fetched frame's bones (hh_session_fetch_frame first): handles, proxies and device frames
 * [B][7], feedback [B][6]; its groups' feedback [G][6]; and the bones' model of its visual step,
 * wrench0[6B] and stiffness[6B][6B] (row-major), held_rows. Any output may be NULL. */
int hh_session_frame_bones(hh_session* session, int n_bones, double* handles, double* proxies, double* devices,
                           double* feedback);
int hh_session_frame_groups(hh_session* session, int n_groups, double* feedback);
int hh_session_bone_coupling_model(hh_session* session, int n_bones, double* wrench0, double* stiffness,
                                   int* held_rows);

/* A kinematic body moved by the world itself along timed poses (absolute, world frame). */
int hh_world_set_script(hh_world* world, int body, const double* times, const double* positions,
                        const double* quaternions, int n);
/* The handle-space coupling model after the world's last step, whose handle must have been
 * prescribed (hh_world_set_device with enabled = 2): the springs' wrench wrench0 (6) at the
 * handle's end-of-step pose and its stiffness (36, row-major) with respect to a displacement
 * (dx, dtheta) of that pose, the step's active contacts held (held_rows of them). */
int hh_world_coupling_model(const hh_world* world, int hand_body, double wrench0[6], double stiffness[36],
                            int* held_rows);
/* The world's simulated time (s). */
int hh_world_time(const hh_world* world, double* out);

#if defined(__GNUC__)
#pragma GCC visibility pop
#endif
#ifdef __cplusplus
}
#endif
#endif
