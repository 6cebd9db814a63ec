/*
 * Haptic Hand's parameter table: every user-facing parameter, declared once.
 *
 * Each row is one parameter. haptic_hand.h builds the C structs (hh_params, hh_world_params,
 * hh_material, hh_session_params) from the struct lists below; the library fills defaults and
 * validates every value from the same rows (native/src/params); it exports the rows
 * (hh_param_count, hh_param_info_get) so the Python layer derives the ctypes structures, the
 * scene format's defaults and type checks, the Blender properties (label, tooltip, unit, limits)
 * and the docs' parameter table from them. Adding a parameter is adding a row
 * (docs/design.md, "Adding a parameter").
 *
 * A row: HH_ROW(name, kind, count, json, unit, default, min, max, flags, soft_min, soft_max,
 *               label, text, description, advice)
 *   name        the C field (struct rows) and the Blender property's name
 *   kind        HH_KIND_*; count: components (1, or 3 for vectors; 0 for rows with no number)
 *   json        the path in the scene file; "bodies[]." for a field of each body; "" for none
 *   unit        SI unit as shown to users ("" for none)
 *   default     HH_V(x) or HH_V3(x, y, z): the default of numeric rows
 *   min, max    the valid range, closed unless HH_OPEN_MIN / HH_OPEN_MAX
 *   flags       HH_OPEN_*, HH_ZERO_OR_RANGE, HH_NULLABLE, HH_REQUIRED, where Blender keeps it
 *               (HH_UI_SCENE, HH_UI_OBJECT, HH_UI_DERIVED: from the Blender scene itself),
 *               HH_UI_ADVANCED, HH_INTERNAL (not in the scene file), and for body fields the body
 *               types it applies to (HH_FOR_*)
 *   soft_min/max  the range a Blender slider offers
 *   label       the short name shown in Blender
 *   text        enum rows: the choices "a|b|c" (the JSON holds the name); rows with no number:
 *               their default as a JSON literal
 *   description one line: what it is (Blender's tooltip)
 *   advice      what a good value is, for the message that refuses a bad one
 */
#ifndef HAPTIC_HAND_PARAMS_H
#define HAPTIC_HAND_PARAMS_H

#define HH_KIND_DOUBLE 0
#define HH_KIND_INT 1
#define HH_KIND_BOOL 2   /* int 0 / 1 in C, true / false in JSON */
#define HH_KIND_ENUM 3   /* int index in C, the choice's name in JSON */
#define HH_KIND_STRING 4 /* scene-file only from here on: no C storage */
#define HH_KIND_PATH 5   /* a file path, relative to the scene file */
#define HH_KIND_JSON 6   /* a JSON value the scene loader reads (lists of poses, node lists) */

#define HH_OPEN_MIN 0x1
#define HH_OPEN_MAX 0x2
#define HH_ZERO_OR_RANGE 0x4 /* 0 is valid too */
#define HH_NULLABLE 0x8      /* JSON null is valid (its meaning is in the description) */
#define HH_REQUIRED 0x10
#define HH_UI_SCENE 0x20     /* a property of the Blender scene's settings */
#define HH_UI_OBJECT 0x40    /* a property of each object's settings */
#define HH_UI_DERIVED 0x80   /* taken from the Blender scene (meshes, timeline, empties, roles) */
#define HH_UI_ADVANCED 0x100 /* shown in the panel's Advanced section */
#define HH_INTERNAL 0x200    /* a C field that is not in the scene file */
#define HH_FOR_SOFT 0x1000   /* body fields: which body types read them */
#define HH_FOR_RIGID 0x2000
#define HH_FOR_KINEMATIC 0x4000
#define HH_FOR_STATIC 0x8000
#define HH_FOR_PLANE 0x10000
#define HH_FOR_MESHES (HH_FOR_SOFT | HH_FOR_RIGID | HH_FOR_KINEMATIC | HH_FOR_STATIC)
#define HH_FOR_ALL (HH_FOR_MESHES | HH_FOR_PLANE)

#define HH_V(x) {(x), 0, 0}
#define HH_V3(x, y, z) {(x), (y), (z)}
#define HH_INF HUGE_VAL /* <math.h>: only the library expands whole rows */

/* --- lists shared by two structs or two places in the scene (declared once) --- */

/* Linear co-rotational FEM material (Mueller & Gross 2004): the hand's flesh ("material.") and
 * each soft body ("bodies[].material."). F: where Blender keeps it. */
#define HH_MATERIAL_ROWS(X, P, F)                                                                      \
    X(young_modulus, HH_KIND_DOUBLE, 1, P "young_modulus", "Pa", HH_V(5e4), 0, HH_INF,                 \
      HH_OPEN_MIN | (F), 1e3, 1e7, "Young's modulus", "",                                              \
      "Stiffness of the material (linear co-rotational FEM)", "soft tissue is about 1e4 to 1e6 Pa")    \
    X(poisson_ratio, HH_KIND_DOUBLE, 1, P "poisson_ratio", "", HH_V(0.3), 0, 0.5,                      \
      HH_OPEN_MIN | HH_OPEN_MAX | (F), 0.0, 0.49, "Poisson ratio", "",                                 \
      "How much the material keeps its volume: near 0 it compresses freely, 0.5 is incompressible",    \
      "nearly incompressible flesh is about 0.45")                                                     \
    X(density, HH_KIND_DOUBLE, 1, P "density", "kg/m^3", HH_V(1000), 0, HH_INF, HH_OPEN_MIN | (F),     \
      10, 1e4, "Density", "", "Mass per volume; the lumped node masses come from it (Eq. 2)",          \
      "flesh is about 1000-1100 kg/m^3")                                                               \
    X(rayleigh_alpha, HH_KIND_DOUBLE, 1, P "rayleigh_alpha", "1/s", HH_V(0), 0, HH_INF,                \
      HH_UI_ADVANCED | (F), 0, 10, "Mass damping (alpha)", "",                                         \
      "Mass-proportional Rayleigh damping; it damps rigid motion too, so momentum is not conserved",   \
      "0 keeps momentum; a few 1/s damp everything")                                                   \
    X(rayleigh_beta, HH_KIND_DOUBLE, 1, P "rayleigh_beta", "s", HH_V(0.01), 0, HH_INF, (F), 0, 0.1,    \
      "Stiffness damping (beta)", "", "Stiffness-proportional Rayleigh damping: damps deformation only", \
      "about 0.01 s damps the fastest element modes at 30 Hz")

/* The stiffest device coupling the haptic loop is tested stable at (N/m): a session refuses a
 * stiffer one (hh_session_params_check), and the coupling stiffness's slider ends there. */
#define HH_HAPTIC_MAX_COUPLING_STIFFNESS 3e4
#define HH_STR_(x) #x
#define HH_STR(x) HH_STR_(x)

/* The virtual coupling between the device and the handle (Fig. 2): one-directional without the
 * haptic loop, two-way between the device and the proxy with it (hh_params, hh_session_params). */
#define HH_COUPLING_ROWS(X)                                                                            \
    X(coupling_stiffness, HH_KIND_DOUBLE, 1, "coupling.stiffness", "N/m", HH_V(2e3), 0, HH_INF,        \
      HH_UI_SCENE, 0, HH_HAPTIC_MAX_COUPLING_STIFFNESS, "Coupling stiffness", "",                      \
      "Virtual coupling between the device and the handle (the proxy, with the haptic loop on)",       \
      "a desktop haptic device renders about 1e3 to 3e3 N/m; the haptic loop is tested up to "         \
      HH_STR(HH_HAPTIC_MAX_COUPLING_STIFFNESS))                                                        \
    X(coupling_damping, HH_KIND_DOUBLE, 1, "coupling.damping", "N s/m", HH_V(20), 0, HH_INF,           \
      HH_UI_SCENE, 0, 500, "Coupling damping", "", "Damping of the virtual coupling",                  \
      "above stiffness x haptic period / 2 keeps the coupling passive (Colgate)")                      \
    X(coupling_angular_stiffness, HH_KIND_DOUBLE, 1, "coupling.angular_stiffness", "N m/rad",          \
      HH_V(20), 0, HH_INF, HH_UI_SCENE, 0, 200, "Angular stiffness", "",                               \
      "Rotational stiffness of the virtual coupling", "a few N m/rad for a hand-held device")          \
    X(coupling_angular_damping, HH_KIND_DOUBLE, 1, "coupling.angular_damping", "N m s/rad",            \
      HH_V(0.2), 0, HH_INF, HH_UI_SCENE, 0, 10, "Angular damping", "",                                 \
      "Rotational damping of the virtual coupling", "about a hundredth of the angular stiffness")

/* One implicit step (Eq. 7) and the world's gravity (hh_params, hh_world_params). */
#define HH_INTEGRATION_ROWS(X)                                                                         \
    X(dt, HH_KIND_DOUBLE, 1, "dt", "s", HH_V(1.0 / 30.0), 0, 0.1, HH_OPEN_MIN | HH_UI_DERIVED, 1e-3,   \
      0.1, "Time step", "",                                                                            \
      "One implicit step of the visual loop (Eq. 7); in Blender, one step per frame at the scene's "   \
      "frame rate",                                                                                    \
      "at most 0.1 s: the linearized implicit step loses accuracy beyond; 1/30 s is the visual rate")  \
    X(gravity, HH_KIND_DOUBLE, 3, "gravity", "m/s^2", HH_V3(0, 0, -9.81), -HH_INF, HH_INF,             \
      HH_UI_DERIVED, -20, 20, "Gravity", "", "Gravity on every body; in Blender, the scene's gravity", \
      "finite components; Earth is (0, 0, -9.81)")

/* Where a surface is tetrahedralized by pytetwild (fTetWild): the hand ("hand.tetrahedralize.")
 * and each soft body with a mesh file ("bodies[].tetrahedralize."); kept on each object. */
#define HH_TETRAHEDRALIZE_ROWS(X, P, F)                                                                \
    X(edge_length_fac, HH_KIND_DOUBLE, 1, P "edge_length_fac", "", HH_V(0.1), 0.01, 1.0, (F), 0.02,    \
      0.5, "Edge length", "",                                                                          \
      "Target tet edge length as a fraction of the bounding-box diagonal (smaller: more tets)",        \
      "0.1 gives about 1500 tets on a hand with coarsening; below 0.03 expect minutes")                \
    X(coarsen, HH_KIND_BOOL, 1, P "coarsen", "", HH_V(1), 0, 1, (F), 0, 1, "Coarsen", "",              \
      "Coarsen the tets as far as their quality allows (fewer tets, faster steps)", "true or false")   \
    X(epsilon, HH_KIND_DOUBLE, 1, P "epsilon", "", HH_V(0.002), 1e-4, 0.05, (F), 1e-4, 0.02,           \
      "Envelope", "",                                                                                  \
      "How far the tets' boundary may stray from the surface, relative to the diagonal (smaller: "     \
      "closer fit, more tets)",                                                                        \
      "about 0.002; a closer fit costs tets")

/* --- the C structs, field by field --- */

/* hh_params: a hand rig (rest mesh material, handle, springs, device coupling, integration). */
#define HH_PARAMS_ROWS(X)                                                                              \
    HH_MATERIAL_ROWS(X, "material.", HH_UI_SCENE)                                                      \
    X(palm_seed, HH_KIND_DOUBLE, 3, "hand.palm_seed", "m", HH_V3(0, 0, 0), -HH_INF, HH_INF,            \
      HH_NULLABLE | HH_UI_DERIVED, -1, 1, "Palm seed", "",                                             \
      "A point inside the palm: the handle holds the tet nodes within the handle radius of it (null: " \
      "the procedural hand's); in Blender, the seed empty",                                            \
      "a finite point inside the hand's tets, in metres")                                              \
    X(handle_radius, HH_KIND_DOUBLE, 1, "hand.handle_radius", "m", HH_V(0.03), 0, HH_INF,              \
      HH_OPEN_MIN | HH_UI_SCENE, 0.005, 0.1, "Handle radius", "",                                      \
      "Radius of the sphere around the palm seed whose tet nodes the rigid handle holds (Section 4)",  \
      "a few centimetres for a human palm: it must hold at least 4 nodes and leave flesh")             \
    X(spring_stiffness, HH_KIND_DOUBLE, 1, "springs.stiffness", "N/m", HH_V(1e4), 0, HH_INF,           \
      HH_OPEN_MIN | HH_UI_SCENE, 100, 1e6, "Spring stiffness", "",                                     \
      "k of Eq. 4: the zero-rest-length springs that tie each held node to the handle",                \
      "stiff enough that the hand does not droop: about 1e4 N/m")                                      \
    X(spring_damping, HH_KIND_DOUBLE, 1, "springs.damping", "N s/m", HH_V(10), 0, HH_INF, HH_UI_SCENE, \
      0, 1000, "Spring damping", "", "d of Eq. 4: damping of the handle's springs", "zero or positive") \
    HH_COUPLING_ROWS(X)                                                                                \
    HH_INTEGRATION_ROWS(X)                                                                             \
    X(solver, HH_KIND_ENUM, 1, "solver.name", "", HH_V(0), 0, 2, HH_UI_SCENE | HH_UI_ADVANCED, 0, 2,   \
      "Hand solver", "cholesky|cg|reused_cholesky",                                                    \
      "The hand's linear solver: a sparse Cholesky factor every step; Jacobi CG; or an earlier "       \
      "step's factor preconditioning CG (large hands)",                                                \
      "cholesky up to a few thousand tets, reused_cholesky beyond")                                    \
    X(cg_tolerance, HH_KIND_DOUBLE, 1, "solver.cg_tolerance", "", HH_V(1e-8), 0, 1,                    \
      HH_OPEN_MIN | HH_OPEN_MAX | HH_UI_SCENE | HH_UI_ADVANCED, 1e-12, 1e-3, "CG tolerance", "",       \
      "Relative residual at which the hand's CG stops", "1e-8 for cg, 1e-6 is enough on the reused factor") \
    X(cg_max_iterations, HH_KIND_INT, 1, "solver.cg_max_iterations", "", HH_V(5000), 1, 1e8,           \
      HH_UI_SCENE | HH_UI_ADVANCED, 10, 20000, "CG iterations", "",                                    \
      "Most iterations the hand's CG may take per solve", "a few thousand") \
    X(drive_frequency, HH_KIND_DOUBLE, 1, "skeleton.drive.frequency", "Hz", HH_V(20), 0, HH_INF,       \
      HH_OPEN_MIN | HH_UI_SCENE | HH_UI_ADVANCED, 1, 100, "Bone drive frequency", "",                  \
      "Natural frequency of each non-root bone's virtual coupling to its target: its gains scale "     \
      "with the bone's mass and inertia (docs/skeleton.md, Section 4)",                                \
      "a few tens of Hz: a finger follows its animation within a frame or two")                        \
    X(drive_damping_ratio, HH_KIND_DOUBLE, 1, "skeleton.drive.damping_ratio", "", HH_V(1), 0, HH_INF,  \
      HH_UI_SCENE | HH_UI_ADVANCED, 0, 4, "Bone drive damping ratio", "",                              \
      "Damping ratio of the non-root bones' virtual couplings (1: critically damped)",                 \
      "about 1; 0 leaves the fingers ringing about their targets")                                     \
    X(joint_stiffness, HH_KIND_DOUBLE, 1, "skeleton.joints.stiffness", "N/m", HH_V(0), 0, HH_INF,      \
      HH_UI_SCENE | HH_UI_ADVANCED, 0, 1e5, "Joint stiffness", "",                                     \
      "Ball joints: a zero-rest-length spring ties each bone's head to the same point of its parent "  \
      "(docs/skeleton.md, Section 5); 0 with zero joint damping: no joints",                           \
      "0 (no joints), or about the flesh springs' stiffness (1e3 to 1e4 N/m) to keep a pushed finger " \
      "on its knuckle")                                                                                \
    X(joint_damping, HH_KIND_DOUBLE, 1, "skeleton.joints.damping", "N s/m", HH_V(0), 0, HH_INF,        \
      HH_UI_SCENE | HH_UI_ADVANCED, 0, 100, "Joint damping", "",                                       \
      "Damping of the ball joints' springs (on the relative velocity of the two bones' joint points)", \
      "zero or positive; about the flesh springs' damping")                                            \
    X(joint_limit_stiffness, HH_KIND_DOUBLE, 1, "skeleton.joints.limit_stiffness", "N m/rad", HH_V(0), \
      0, HH_INF, HH_UI_SCENE | HH_UI_ADVANCED, 0, 100, "Joint limit stiffness", "",                     \
      "Angular limits: a one-sided angular spring turns a bone back into its range "                   \
      "(hand.skeleton[].limits) on each axis beyond it (docs/skeleton.md, Section 5); 0 with zero "     \
      "limit damping: no limits",                                                                      \
      "0 (no limits), or a few times the torque that bends the finger at its drive (0.1 to 10 N m/rad " \
      "for a finger)")                                                                                 \
    X(joint_limit_damping, HH_KIND_DOUBLE, 1, "skeleton.joints.limit_damping", "N m s/rad", HH_V(0),   \
      0, HH_INF, HH_UI_SCENE | HH_UI_ADVANCED, 0, 1, "Joint limit damping", "",                         \
      "Damping of the angular limits, on the axes beyond their range (relative angular velocity)",     \
      "zero or positive; about a tenth of the limit stiffness times a frame's time")

/* hh_world_params: the visual loop's world (contact and Coulomb friction). */
#define HH_WORLD_PARAMS_ROWS(X)                                                                        \
    HH_INTEGRATION_ROWS(X)                                                                             \
    X(contact_thickness, HH_KIND_DOUBLE, 1, "contact.thickness", "m", HH_V(1e-3), 0, HH_INF,           \
      HH_OPEN_MIN | HH_UI_SCENE, 1e-4, 0.01, "Contact thickness", "",                                  \
      "Gap the contact solve keeps between surfaces", "about a millimetre for a hand")                 \
    X(contact_patch, HH_KIND_DOUBLE, 1, "contact.patch", "m", HH_V(4e-3), 0, HH_INF,                   \
      HH_OPEN_MIN | HH_UI_SCENE | HH_UI_ADVANCED, 1e-3, 0.05, "Contact patch", "",                     \
      "Per pair of bodies, one contact (the deepest) per cell of this size: bounds the contact count " \
      "of large areas",                                                                                \
      "a few millimetres")                                                                             \
    X(max_iterations, HH_KIND_INT, 1, "contact.max_iterations", "", HH_V(300), 1, 1e6,                 \
      HH_UI_SCENE | HH_UI_ADVANCED, 10, 2000, "Contact sweeps", "",                                    \
      "Most projected Gauss-Seidel sweeps of the contact solve per step", "a few hundred")             \
    X(tolerance, HH_KIND_DOUBLE, 1, "contact.tolerance", "m/s", HH_V(1e-5), 0, HH_INF,                 \
      HH_OPEN_MIN | HH_UI_SCENE | HH_UI_ADVANCED, 1e-7, 1e-3, "Contact tolerance", "",                 \
      "Largest constraint velocity error that ends the contact sweeps", "about 1e-5 m/s")              \
    X(stall_factor, HH_KIND_DOUBLE, 1, "contact.stall_factor", "", HH_V(4), 1, HH_INF,                 \
      HH_ZERO_OR_RANGE | HH_UI_SCENE | HH_UI_ADVANCED, 0, 20, "Stall factor", "",                      \
      "The sweeps also end once within this factor of the tolerance and no longer on course to reach " \
      "it (0: on to the tolerance or the sweep cap)",                                                  \
      "0, or a factor of at least 1 (4 is usual)")                                                     \
    X(threads, HH_KIND_INT, 1, "contact.threads", "", HH_V(2), 1, 2, HH_UI_SCENE | HH_UI_ADVANCED, 1,  \
      2, "Simulation threads", "",                                                                     \
      "Threads of each visual-loop step: 2 runs detection and the other bodies beside the hand's "     \
      "solve (the same results as 1)",                                                                \
      "1 or 2")                                                                                        \
    X(defer_separating, HH_KIND_BOOL, 1, "contact.defer_separating", "", HH_V(1), 0, 1,                \
      HH_UI_SCENE | HH_UI_ADVANCED, 0, 1, "Defer separating contacts", "",                             \
      "Speculative contacts whose points separate at the start of the step are left out of the "      \
      "contact solve, and it solves again with them if one would close (the same contacts held)",     \
      "true or false")

/* hh_material: a soft body's material. */
#define HH_MATERIAL_STRUCT_ROWS(X) HH_MATERIAL_ROWS(X, "bodies[].material.", HH_UI_OBJECT | HH_FOR_SOFT)

/* hh_session_params: the haptic loop (Section 3). */
#define HH_SESSION_PARAMS_ROWS(X)                                                                      \
    X(haptic_rate, HH_KIND_DOUBLE, 1, "haptics.rate", "Hz", HH_V(1000), 100, 10000,                    \
      HH_UI_SCENE | HH_UI_ADVANCED, 100, 10000, "Haptic rate", "", "Rate of the haptic loop",          \
      "1000 Hz, what haptic devices expect")                                                           \
    HH_COUPLING_ROWS(X)                                                                                \
    X(max_force, HH_KIND_DOUBLE, 1, "haptics.max_force", "N", HH_V(1e9), 0, HH_INF,                    \
      HH_OPEN_MIN | HH_UI_SCENE | HH_UI_ADVANCED, 0.1, 100, "Max force", "",                           \
      "Largest force the haptic loop sends to the device", "an Omni renders 3.3 N at its peak")        \
    X(max_torque, HH_KIND_DOUBLE, 1, "haptics.max_torque", "N m", HH_V(1e9), 0, HH_INF,                \
      HH_OPEN_MIN | HH_UI_SCENE | HH_UI_ADVANCED, 0.01, 10, "Max torque", "",                          \
      "Largest torque the haptic loop sends to the device", "positive")                                \
    X(linearized, HH_KIND_BOOL, 1, "haptics.linearized", "", HH_V(1), 0, 1,                            \
      HH_UI_SCENE | HH_UI_ADVANCED, 0, 1, "Linearized", "",                                            \
      "The proxy moves under the handle-space linear model (the paper); off: feedback from the last "  \
      "visual-loop handle only",                                                                       \
      "true or false")                                                                                 \
    X(log_capacity, HH_KIND_INT, 1, "", "", HH_V(65536), 1, 67108864.0, HH_INTERNAL, 1, 1e6,         \
      "Log capacity", "", "Rows of the haptic log ring (one per haptic step)", "at least 1")           \
    X(realtime, HH_KIND_BOOL, 1, "haptics.realtime", "", HH_V(1), 0, 1, HH_UI_SCENE | HH_UI_ADVANCED,  \
      0, 1, "Real-time priority", "",                                                                  \
      "Live sessions ask for real-time priority for the haptic thread (needs an rtprio limit)",        \
      "true or false")

/* --- the scene file's other fields (no C struct: read by the scene loader, checked by the
 * library through hh_param_check where they are numbers) --- */
#define HH_SCENE_ROWS(X)                                                                               \
    X(format, HH_KIND_STRING, 0, "format", "", HH_V(0), 0, 0, HH_REQUIRED | HH_UI_DERIVED, 0, 0,       \
      "Format", "\"haptic_hand.scene/1\"", "The scene format's name and version",                      \
      "\"haptic_hand.scene/1\"")                                                                       \
    X(hand_mesh, HH_KIND_PATH, 0, "hand.mesh", "", HH_V(0), 0, 0, HH_UI_DERIVED, 0, 0, "Hand mesh",    \
      "\"procedural\"",                                                                                \
      "The hand's closed surface: an .obj path relative to the scene file, or \"procedural\"",         \
      "a closed, manifold .obj")                                                                       \
    X(hand_tets, HH_KIND_PATH, 0, "hand.tets", "", HH_V(0), 0, 0, HH_NULLABLE | HH_UI_DERIVED, 0, 0,   \
      "Hand tets", "null",                                                                             \
      "An .npz with the arrays nodes (n, 3) and tets (m, 4); null: tetrahedralize the surface",        \
      "store tets to replay a scene exactly: pytetwild is not deterministic")                          \
    HH_TETRAHEDRALIZE_ROWS(X, "hand.tetrahedralize.", HH_UI_OBJECT)                                    \
    X(friction, HH_KIND_DOUBLE, 1, "hand.friction", "", HH_V(0.5), 0, HH_INF, HH_UI_SCENE, 0, 2,       \
      "Hand friction", "", "Static Coulomb coefficient of the hand's skin", "skin is about 0.5-1")     \
    X(kinetic_friction, HH_KIND_DOUBLE, 1, "hand.kinetic_friction", "", HH_V(0.5), 0, HH_INF,          \
      HH_NULLABLE | HH_UI_SCENE | HH_UI_ADVANCED, 0, 2, "Hand kinetic friction", "",                   \
      "Sliding Coulomb coefficient of the hand's skin (null: the static one)",                         \
      "at most the static coefficient")                                                                \
    X(self_collision, HH_KIND_BOOL, 1, "hand.self_collision", "", HH_V(1), 0, 1, HH_UI_SCENE, 0, 1,    \
      "Self collision", "", "The hand's fingers collide with each other", "true or false")             \
    X(skeleton, HH_KIND_JSON, 0, "hand.skeleton", "", HH_V(0), 0, 0, HH_NULLABLE | HH_UI_DERIVED, 0, 0,\
      "Skeleton", "null",                                                                              \
      "The hand's bones, each a rigid handle (docs/skeleton.md): null: the palm handle "               \
      "(hand.palm_seed, hand.handle_radius); \"procedural\": the procedural hand's 16 bones; or a "     \
      "list of bones {name, parent, head, tail, radius, nodes, drive_scale}, the root first; in "    \
      "Blender, the deforming bones of the armature chosen in Rig > Skeleton",                        \
      "null, \"procedural\" or a list of bones")                                                      \
    X(bone_name, HH_KIND_STRING, 0, "hand.skeleton[].name", "", HH_V(0), 0, 0,                         \
      HH_REQUIRED | HH_UI_DERIVED, 0, 0, "Bone name", "null",                          \
      "A bone's unique name (targets and tracking maps name it); in Blender, the bone's name", "a unique, non-empty name")         \
    X(bone_parent, HH_KIND_STRING, 0, "hand.skeleton[].parent", "", HH_V(0), 0, 0,                     \
      HH_NULLABLE | HH_UI_DERIVED, 0, 0, "Bone parent", "null",                        \
      "The name of the bone it hangs from (null: a root; the first bone must be one); in Blender, "    \
      "its nearest deforming ancestor",                                                                \
      "the name of a bone of the list, or null")                                                       \
    X(bone_head, HH_KIND_DOUBLE, 3, "hand.skeleton[].head", "m", HH_V3(0, 0, 0), -HH_INF, HH_INF,      \
      HH_REQUIRED | HH_UI_DERIVED, -1, 1, "Bone head", "",                             \
      "The rest segment's start (the joint it turns about), world frame; in Blender, the bone's rest " \
      "head", "finite, in metres")                                                                     \
    X(bone_tail, HH_KIND_DOUBLE, 3, "hand.skeleton[].tail", "m", HH_V3(0, 0, 0), -HH_INF, HH_INF,      \
      HH_REQUIRED | HH_UI_DERIVED, -1, 1, "Bone tail", "",                             \
      "The rest segment's end, world frame; in Blender, the bone's rest tail",                         \
      "finite, in metres")                                                                             \
    X(bone_radius, HH_KIND_DOUBLE, 1, "hand.skeleton[].radius", "m", HH_V(0.01), 0, HH_INF,            \
      HH_OPEN_MIN | HH_NULLABLE | HH_UI_DERIVED, 0.001, 0.05, "Bone radius", "",       \
      "Capsule radius: the bone holds the tet nodes nearer its segment than this and nearer it than "  \
      "any other bone's (null: it holds its nodes only); in Blender, the bone's Radius in Rig > "       \
      "Skeleton",                                                                                      \
      "a little more than the limb's own radius, so it holds 4 nodes off its axis")                    \
    X(bone_nodes, HH_KIND_JSON, 0, "hand.skeleton[].nodes", "", HH_V(0), 0, 0,                         \
      HH_NULLABLE | HH_UI_DERIVED, 0, 0, "Bone nodes", "null",                         \
      "The tet node indices the bone holds, instead of a capsule (null: by its radius); in Blender, "  \
      "from the vertex group named like the bone (Capture: Vertex group in Rig > Skeleton)",          \
      "at least 4 node indices, none held by another bone")                                           \
    X(bone_drive_scale, HH_KIND_DOUBLE, 1, "hand.skeleton[].drive_scale", "", HH_V(1), 0, HH_INF,      \
      HH_UI_DERIVED, 0, 4, "Bone drive scale", "",                                         \
      "Multiplies the gains of the bone's drive to its target (0: the bone is free, carried by the "   \
      "flesh); in Blender, the bone's Drive scale in Rig > Skeleton",                                  \
      "1; 0 frees the bone")                                                                           \
    X(bone_limits, HH_KIND_JSON, 0, "hand.skeleton[].limits", "rad", HH_V(0), 0, 0,                     \
      HH_NULLABLE | HH_UI_DERIVED, 0, 0, "Bone limits", "null",                                        \
      "Angular limits: the range of the bone's rotation relative to its parent, as a rotation vector " \
      "in its rest axes, {\"min\": [x, y, z], \"max\": [x, y, z]} (null: no limits; an axis null "      \
      "or +-inf: free; skeleton.joints.limit_stiffness makes them act; docs/skeleton.md, Section 5); "  \
      "in Blender, the pose bone's IK limits",                                                         \
      "min <= 0 <= max per axis (the rest pose within its range); none on a root")                     \
    X(bone_axes, HH_KIND_JSON, 0, "hand.skeleton[].axes", "", HH_V(0), 0, 0,                           \
      HH_NULLABLE | HH_UI_DERIVED, 0, 0, "Bone axes", "null",                                          \
      "The bone's rest axes, the frame its limits are in: three rows of the rotation matrix whose "    \
      "columns are its x, y, z axes (world frame; null: the world axes); in Blender, the bone's rest " \
      "matrix", "a rotation matrix (orthonormal, right-handed)")                                       \
    X(bodies, HH_KIND_JSON, 0, "bodies", "", HH_V(0), 0, 0, HH_UI_DERIVED, 0, 0, "Bodies", "[]",       \
      "The other bodies (docs/contact.md); in Blender, the objects with a role", "a list")             \
    X(name, HH_KIND_STRING, 0, "bodies[].name", "", HH_V(0), 0, 0,                                \
      HH_NULLABLE | HH_UI_DERIVED | HH_FOR_ALL, 0, 0, "Name", "null",                                  \
      "A unique name (null: body<index>); in Blender, the object's name", "unique")                    \
    X(type, HH_KIND_ENUM, 1, "bodies[].type", "", HH_V(0), 0, 4,                                  \
      HH_REQUIRED | HH_UI_DERIVED | HH_FOR_ALL, 0, 4, "Type", "soft|rigid|kinematic|static|plane",     \
      "What the body is: deformable, free rigid, moved by a script, still, or an infinite plane; in "  \
      "Blender, the object's role",                                                                    \
      "one of the five types")                                                                         \
    X(mesh, HH_KIND_PATH, 0, "bodies[].mesh", "", HH_V(0), 0, 0,                                  \
      HH_NULLABLE | HH_UI_DERIVED | HH_FOR_MESHES, 0, 0, "Mesh", "null",                               \
      "procedural:bunny, procedural:letter:<A>, box, or an .obj path relative to the scene file",      \
      "a closed mesh")                                                                                 \
    X(size, HH_KIND_DOUBLE, 3, "bodies[].size", "m", HH_V3(0.1, 0.1, 0.1), 0, HH_INF,                  \
      HH_OPEN_MIN | HH_UI_DERIVED | HH_FOR_MESHES, 0.01, 1, "Box size", "",                            \
      "The box mesh's edge lengths (mesh \"box\")", "positive lengths")                                \
    X(cells, HH_KIND_INT, 3, "bodies[].cells", "", HH_V3(4, 4, 4), 1, 1000,                            \
      HH_UI_DERIVED | HH_FOR_MESHES, 1, 50, "Box cells", "",                                           \
      "The box mesh's cells along each edge (mesh \"box\"; 6 tets a cell)", "whole numbers of at least 1") \
    X(tets, HH_KIND_PATH, 0, "bodies[].tets", "", HH_V(0), 0, 0,                                  \
      HH_NULLABLE | HH_UI_DERIVED | HH_FOR_SOFT, 0, 0, "Tets", "null",                                 \
      "An .npz (nodes, tets) for a soft body; null: the shape's own tets, or pytetwild's",             \
      "tets that contain the body's surface")                                                          \
    HH_TETRAHEDRALIZE_ROWS(X, "bodies[].tetrahedralize.", HH_UI_OBJECT | HH_FOR_SOFT)                  \
    X(position, HH_KIND_DOUBLE, 3, "bodies[].position", "m", HH_V3(0, 0, 0), -HH_INF, HH_INF,          \
      HH_UI_DERIVED | HH_FOR_MESHES, -1, 1, "Position", "",                                            \
      "Where the body's mesh is placed (an offset of its vertices)", "finite, in metres")              \
    X(density, HH_KIND_DOUBLE, 1, "bodies[].density", "kg/m^3", HH_V(1000), 0, HH_INF,           \
      HH_OPEN_MIN | HH_UI_OBJECT | HH_FOR_RIGID, 10, 1e4, "Density", "",                               \
      "A rigid body's mass per volume (its mass and inertia come from its closed mesh)",               \
      "wood is about 500-800 kg/m^3, water 1000")                                                      \
    X(friction, HH_KIND_DOUBLE, 1, "bodies[].friction", "", HH_V(0.5), 0, HH_INF,                 \
      HH_UI_OBJECT | HH_FOR_ALL, 0, 2, "Friction", "",                                                 \
      "Static Coulomb coefficient of the body's surface (a pair uses the geometric mean)",             \
      "about 0.3-1")                                                                                   \
    X(kinetic_friction, HH_KIND_DOUBLE, 1, "bodies[].kinetic_friction", "", HH_V(0.5), 0, HH_INF, \
      HH_NULLABLE | HH_UI_OBJECT | HH_UI_ADVANCED | HH_FOR_ALL, 0, 2, "Kinetic friction", "",          \
      "Sliding Coulomb coefficient of the body's surface (null: the static one)",                      \
      "at most the static coefficient")                                                                \
    X(fixed, HH_KIND_JSON, 0, "bodies[].fixed", "", HH_V(0), 0, 0,                                     \
      HH_NULLABLE | HH_UI_OBJECT | HH_FOR_SOFT, 0, 0, "Fix bottom", "null",                            \
      "Soft-body nodes held still: null, \"bottom\" (the lowest), or a list of node indices",          \
      "null, \"bottom\" or node indices")                                                              \
    X(point, HH_KIND_DOUBLE, 3, "bodies[].point", "m", HH_V3(0, 0, 0), -HH_INF, HH_INF,                \
      HH_UI_DERIVED | HH_FOR_PLANE, -1, 1, "Point", "", "A point of the plane (in Blender, the "        \
      "object's origin)", "finite, in metres")                                                         \
    X(normal, HH_KIND_DOUBLE, 3, "bodies[].normal", "", HH_V3(0, 0, 1), -HH_INF, HH_INF,               \
      HH_UI_DERIVED | HH_FOR_PLANE, -1, 1, "Normal", "",                                               \
      "The plane's normal, towards the free side (in Blender, the object's local Z)", "non-zero")      \
    X(trajectory, HH_KIND_JSON, 0, "bodies[].trajectory", "", HH_V(0), 0, 0,                           \
      HH_UI_DERIVED | HH_FOR_KINEMATIC, 0, 0, "Trajectory", "[]",                                      \
      "A kinematic body's timed offsets from where it starts: [{t, position, quaternion}] (in "        \
      "Blender, its animation)",                                                                       \
      "strictly increasing times")                                                                     \
    X(solver, HH_KIND_ENUM, 1, "bodies[].solver.name", "", HH_V(3), 0, 3,                              \
      HH_UI_OBJECT | HH_FOR_SOFT, 0, 3, "Solver", "cholesky|cg|reused_cholesky|auto",                  \
      "A soft body's solver: a Cholesky factor every step; an earlier step's factor preconditioning "  \
      "CG, its contact responses kept (large bodies in long contact); or auto: the first below 1000 "  \
      "tets, the second from there on; not cg",                                                       \
      "auto, cholesky or reused_cholesky (cg would solve every contact response on its own)")         \
    X(cg_tolerance, HH_KIND_DOUBLE, 1, "bodies[].solver.cg_tolerance", "", HH_V(1e-6), 0, 1,      \
      HH_OPEN_MIN | HH_OPEN_MAX | HH_UI_OBJECT | HH_UI_ADVANCED | HH_FOR_SOFT, 1e-12, 1e-3,            \
      "CG tolerance", "", "Relative residual at which a soft body's CG stops (reused_cholesky)",       \
      "about 1e-6")                                                                                    \
    X(cg_max_iterations, HH_KIND_INT, 1, "bodies[].solver.cg_max_iterations", "", HH_V(5000), 1,  \
      1e8, HH_UI_OBJECT | HH_UI_ADVANCED | HH_FOR_SOFT, 10, 20000, "CG iterations", "",                \
      "Most iterations a soft body's CG may take per solve", "a few thousand")                         \
    X(frames, HH_KIND_INT, 1, "frames", "", HH_V(60), 1, 1e6, HH_UI_DERIVED, 1, 10000, "Frames", "",   \
      "How many visual-loop steps a run takes; in Blender, the bake's frame range",                    \
      "at most 1e6 (about 9 hours at 30 Hz)")                                                          \
    X(haptics_enabled, HH_KIND_BOOL, 1, "haptics.enabled", "", HH_V(0), 0, 1, HH_UI_SCENE, 0, 1,       \
      "Haptic loop", "",                                                                               \
      "Run the haptic loop (proxy handle, two-way coupling to the device) between visual steps; off: " \
      "the device drives the handle through the virtual coupling",                                     \
      "true or false")                                                                                 \
    X(haptic_device, HH_KIND_STRING, 0, "haptics.device", "", HH_V(0), 0, 0, HH_UI_DERIVED, 0, 0,      \
      "Device", "\"simulated\"",                                                                       \
      "simulated (a user's arm follows the trajectory), playback:<file>, openhaptics, hid or "         \
      "external; in Blender, the Device menu",                                                         \
      "one of the devices named")                                                                      \
    X(arm_mass, HH_KIND_DOUBLE, 1, "haptics.arm.mass", "kg", HH_V(1), 0, HH_INF,                       \
      HH_OPEN_MIN | HH_UI_SCENE | HH_UI_ADVANCED, 0.1, 10, "Arm mass", "",                             \
      "The simulated user's arm: the mass that follows the device trajectory", "about 1 kg")           \
    X(arm_stiffness, HH_KIND_DOUBLE, 1, "haptics.arm.stiffness", "N/m", HH_V(300), 0, HH_INF,          \
      HH_UI_SCENE | HH_UI_ADVANCED, 0, 5000, "Arm stiffness", "",                                      \
      "How stiffly the simulated arm tracks its trajectory", "a few hundred N/m")                      \
    X(arm_damping, HH_KIND_DOUBLE, 1, "haptics.arm.damping", "N s/m", HH_V(20), 0, HH_INF,             \
      HH_UI_SCENE | HH_UI_ADVANCED, 0, 200, "Arm damping", "", "Damping of the simulated arm",         \
      "about 2 sqrt(mass x stiffness) for no overshoot")                                               \
    X(haptic_feedback, HH_KIND_ENUM, 1, "haptics.feedback", "", HH_V(0), 0, 2, 0, 0, 2, "Feedback",    \
      "palm|bones|groups",                                                                             \
      "What the haptic loop renders: the palm's wrench (a skeleton's root bone; its other bones' "     \
      "frames are posed); each bone's own, on a skeleton hand; or each bone's and their sums per "     \
      "group (haptics.groups), which a run logs too",                                                  \
      "palm; bones or groups need a skeleton hand of several bones (hand.skeleton)")                   \
    X(haptic_groups, HH_KIND_JSON, 0, "haptics.groups", "", HH_V(0), 0, 0, HH_NULLABLE, 0, 0,          \
      "Feedback groups", "null",                                                                       \
      "The groups of haptics.feedback \"groups\", {name: [bone names]}, each bone in at most one; a "  \
      "group's torque is about its first bone's frame (null: the wrist, then one per digit: each "     \
      "chain of bones leaving a root)",                                                                \
      "an object of group names to lists of bone names of hand.skeleton")                              \
    X(glove_mass, HH_KIND_DOUBLE, 1, "haptics.glove.mass", "kg", HH_V(0.02), 0, HH_INF,                \
      HH_OPEN_MIN, 0.005, 1, "Glove finger mass", "",                                                  \
      "The simulated glove user's finger: the mass that follows each finger bone's targets (the "      \
      "root's frame is the simulated arm's, haptics.arm.*)",                                           \
      "about 0.02 kg")                                                                                 \
    X(glove_stiffness, HH_KIND_DOUBLE, 1, "haptics.glove.stiffness", "N/m", HH_V(50), 0, HH_INF,       \
      0, 0, 30000, "Glove finger stiffness", "",                                                       \
      "How stiffly each simulated finger tracks its bone's targets",                                   \
      "about 50 N/m for a relaxed finger; 3e4 holds every bone at its target (docs/haptics.md)")       \
    X(glove_damping, HH_KIND_DOUBLE, 1, "haptics.glove.damping", "N s/m", HH_V(2), 0, HH_INF,          \
      0, 0, 500, "Glove finger damping", "",                                                           \
      "Damping of each simulated finger", "about 2 sqrt(mass x stiffness) for no overshoot")          \
    X(fail_at, HH_KIND_DOUBLE, 1, "haptics.fail_at", "s", HH_V(0), 0, HH_INF, HH_NULLABLE, 0, 10,      \
      "Fail at", "", "The device reports a disconnection at this time (tests; null: never)",           \
      "a time of at least 0 s, or null")                                                               \
    X(external_timeout, HH_KIND_DOUBLE, 1, "haptics.external_timeout", "s", HH_V(5), 0, HH_INF,        \
      HH_OPEN_MIN | HH_UI_SCENE | HH_UI_ADVANCED, 0.5, 60, "External timeout", "",                     \
      "How long an external device (HID, the viewport target, a script) may take to send its first "   \
      "pose before the session stops with a message",                                                  \
      "a few seconds")                                                                                 \
    X(openhaptics_library, HH_KIND_PATH, 0, "haptics.openhaptics.library", "", HH_V(0), 0, 0,          \
      HH_NULLABLE | HH_UI_SCENE | HH_UI_ADVANCED, 0, 0, "OpenHaptics library", "null",                 \
      "Path of libHD.so (null: the system's)", "the path of OpenHaptics' libHD.so")                    \
    X(workspace_scale, HH_KIND_DOUBLE, 1, "haptics.openhaptics.workspace_scale", "", HH_V(1), 0,       \
      HH_INF, HH_OPEN_MIN | HH_UI_SCENE | HH_UI_ADVANCED, 0.1, 10, "Workspace scale", "",              \
      "Scene metres per device metre", "1 maps the device's workspace one to one")                     \
    X(device_enabled, HH_KIND_BOOL, 1, "device.enabled", "", HH_V(1), 0, 1, HH_UI_SCENE, 0, 1,         \
      "Device coupled", "", "Couple the handle to the device (off: the hand flies free)",              \
      "true or false")                                                                                 \
    X(device_frame, HH_KIND_ENUM, 1, "device.frame", "", HH_V(0), 0, 1, HH_UI_DERIVED, 0, 1,           \
      "Device frame", "handle_rest|world",                                                             \
      "Trajectory positions relative to the handle's rest centre, or in the world", "handle_rest or world") \
    X(device_trajectory, HH_KIND_JSON, 0, "device.trajectory", "", HH_V(0), 0, 0, HH_UI_DERIVED, 0, 0, \
      "Device trajectory",                                                                             \
      "[{\"t\": 0.0, \"position\": [0.0, 0.0, 0.0], \"quaternion\": [0.0, 0.0, 0.0, 1.0]}]",           \
      "Timed device poses [{t, position, quaternion (x, y, z, s)}], linear and slerp between (in "     \
      "Blender, the target empty's animation)",                                                        \
      "a non-empty list with strictly increasing times")                                            \
    X(drive_prescribed, HH_KIND_BOOL, 1, "skeleton.drive.prescribed", "", HH_V(0), 0, 1,                 \
      HH_UI_SCENE | HH_UI_ADVANCED, 0, 1,                                                              \
      "Prescribed bones", "",                                                                          \
      "Every driven bone but a root on the device reaches its target pose at the end of each step "    \
      "(the flesh and contacts never push it back); off: each follows its target through its own "     \
      "virtual coupling (docs/skeleton.md, Section 4)",                                                \
      "true or false")                                                                                 \
    X(skeleton_targets, HH_KIND_JSON, 0, "skeleton.targets", "", HH_V(0), 0, 0, HH_UI_DERIVED, 0, 0,   \
      "Bone targets", "[]",                                                                            \
      "Timed bone poses [{t, bones: {name: {position, quaternion}}}]: each bone's head offset from "   \
      "rest and its turn from rest, world frame; linear and slerp between keys (docs/skeleton.md, "    \
      "Section 8); in Blender, the armature's animation, sampled every frame",                         \
      "a list of keys with strictly increasing times naming bones of the skeleton")                    \
    X(skeleton_tracking, HH_KIND_PATH, 0, "skeleton.tracking", "", HH_V(0), 0, 0,                      \
      HH_NULLABLE | HH_UI_SCENE, 0, 0, "Tracking stream", "null",                      \
      "A hand-tracking stream (haptic_hand.tracking/1, .csv or .json; OpenXR or MANO joints) that "    \
      "drives the bones, relative to the scene file (null: none)",                                     \
      "a .csv or .json tracking stream")                                                               \
    X(tracking_map, HH_KIND_JSON, 0, "skeleton.tracking_map", "", HH_V(0), 0, 0,                       \
      HH_NULLABLE | HH_UI_SCENE, 0, 0, "Tracking map", "null",                         \
      "Which bone each tracked joint drives, {joint: bone} (null: the layout's map onto the "          \
      "procedural hand's bones)",                                                                      \
      "an object of joint names to bone names")                                                        \
    X(root_device, HH_KIND_BOOL, 1, "skeleton.root_device", "", HH_V(0), 0, 1, HH_UI_SCENE, 0, 1,   \
      "Root follows device", "",                                                                       \
      "The root bone follows the device trajectory through the coupling; the other bones keep their "  \
      "targets' pose relative to the root (off: the root follows its own targets). In a haptic "      \
      "session the device, of any kind, is one frame on the wrist carrying the other bones, and it "   \
      "feels the whole hand's wrench",                                                                 \
      "true or false")

#endif
