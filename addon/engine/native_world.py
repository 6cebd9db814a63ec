"""ctypes bindings of worlds: the hand together with soft, rigid, kinematic and static bodies,
stepped with contact and Coulomb friction (native/include/haptic_hand.h, second part)."""

from __future__ import annotations

import ctypes

import numpy as np

from . import params as table
from .native import HandModel, InvalidInput, StepStats, WorldStats, _check, _f64, _indices, _points, _ptr, library, solver_code

HAND, SOFT, RIGID, KINEMATIC, STATIC, PLANE = range(6)
KIND_NAMES = {HAND: "hand", SOFT: "soft", RIGID: "rigid", KINEMATIC: "kinematic", STATIC: "static", PLANE: "plane"}


def _i32(a, shape_tail: int, name: str) -> np.ndarray:
    return _indices(a, shape_tail, name)


def _default(value, json_path: str):
    """value, or the table's default of that scene field when None."""
    return table.by_json(json_path).default if value is None else value


def _friction(value) -> float:
    return float(_default(value, "bodies[].friction"))


def vertex_surface(n_vertices: int) -> tuple[np.ndarray, np.ndarray]:
    """Surface whose vertices are the body's points themselves (weight 1)."""
    nodes = np.zeros((n_vertices, 4), dtype=np.int32)
    nodes[:, 0] = np.arange(n_vertices)
    weights = np.zeros((n_vertices, 4))
    weights[:, 0] = 1.0
    return nodes, weights


def embedded_surface(tets: np.ndarray, tet_index: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Surface vertices embedded in tets (mesh.embed_points) as node indices and weights."""
    return np.ascontiguousarray(np.asarray(tets)[tet_index], dtype=np.int32), np.ascontiguousarray(weights, dtype=np.float64)


class World:
    """hh_world: bodies stepped together with contact. Body indices are returned by add_*."""

    def __init__(self, **params):
        """params: fields of hh_world_params by C name (dt, gravity, contact_thickness, ...);
        the others take the table's defaults."""
        p = table.new_struct(table.STRUCT_WORLD_PARAMS, params)
        handle = ctypes.c_void_p()
        _check(library().hh_world_create(ctypes.byref(p), ctypes.byref(handle)))
        self._handle = handle
        self.dt = float(p.dt)
        self.last_stats = WorldStats()
        self._bones = {}  # per hand body: its bones' count

    def __del__(self):
        if getattr(self, "_handle", None):
            library().hh_world_free(self._handle)
            self._handle = None

    # --- building ---
    def add_hand(self, model: HandModel, surface_nodes, surface_weights, faces, friction=None,
                 self_collision=None) -> int:
        """model: a HandModel (the palm handle) or a native_skeleton.SkeletonModel (B bones, driven
        by set_bone_targets). friction, self_collision: None takes the table's default."""
        friction = _default(friction, "hand.friction")
        self_collision = _default(self_collision, "hand.self_collision")
        n4 = _i32(surface_nodes, 4, "surface_nodes")
        w4 = _f64(surface_weights, (len(n4), 4), "surface_weights")
        f3 = _i32(faces, 3, "faces")
        out = ctypes.c_int()
        _check(library().hh_world_add_hand(self._handle, model._handle, _ptr(n4, ctypes.c_int), _ptr(w4), len(n4),
                                           _ptr(f3, ctypes.c_int), len(f3), float(friction), int(self_collision),
                                           ctypes.byref(out)))
        self._bones[out.value] = getattr(model, "n_bones", 1)
        return out.value

    def add_soft_body(self, nodes, tets, surface_nodes, surface_weights, faces, fixed_nodes=(), friction=None,
                      **material) -> int:
        """material: fields of hh_material by C name (young_modulus, ...); the others and the
        friction take the table's defaults."""
        x = _points(nodes, "nodes")
        t = _i32(tets, 4, "tets")
        n4 = _i32(surface_nodes, 4, "surface_nodes")
        w4 = _f64(surface_weights, (len(n4), 4), "surface_weights")
        f3 = _i32(faces, 3, "faces")
        fixed = np.ascontiguousarray(fixed_nodes, dtype=np.int32).reshape(-1)
        m = table.new_struct(table.STRUCT_MATERIAL, material)
        out = ctypes.c_int()
        _check(library().hh_world_add_soft_body(
            self._handle, _ptr(x), len(x), _ptr(t, ctypes.c_int), len(t), ctypes.byref(m),
            _ptr(fixed, ctypes.c_int) if len(fixed) else None, len(fixed), _ptr(n4, ctypes.c_int), _ptr(w4), len(n4),
            _ptr(f3, ctypes.c_int), len(f3), _friction(friction), ctypes.byref(out)))
        return out.value

    def add_mesh_body(self, kind: int, vertices, faces, density=None, friction=None) -> int:
        density = _default(density, "bodies[].density")
        v = _points(vertices, "vertices")
        f3 = _i32(faces, 3, "faces")
        out = ctypes.c_int()
        _check(library().hh_world_add_mesh_body(self._handle, int(kind), _ptr(v), len(v), _ptr(f3, ctypes.c_int),
                                                len(f3), float(density), _friction(friction), ctypes.byref(out)))
        return out.value

    def add_plane(self, point, normal, friction=None) -> int:
        p, n = _f64(point, (3,), "plane point"), _f64(normal, (3,), "plane normal")
        out = ctypes.c_int()
        _check(library().hh_world_add_plane(self._handle, _ptr(p), _ptr(n), _friction(friction), ctypes.byref(out)))
        return out.value

    def set_friction(self, body: int, static: float, kinetic: float | None = None) -> None:
        """Static and kinetic Coulomb coefficients (kinetic defaults to static)."""
        _check(library().hh_world_set_friction(self._handle, body, float(static),
                                               float(static if kinetic is None else kinetic)))

    def set_body_solver(self, body: int, solver: str, cg_tolerance: float | None = None,
                        cg_max_iterations: int | None = None) -> None:
        """A soft body's solver: "cholesky" (factored every step, the default) or
        "reused_cholesky" (an earlier step's factor preconditions CG and is the contact response
        operator, its columns kept between factorizations: for large soft bodies)."""
        tol = _default(cg_tolerance, "bodies[].solver.cg_tolerance")
        iterations = _default(cg_max_iterations, "bodies[].solver.cg_max_iterations")
        _check(library().hh_world_set_body_solver(self._handle, body, solver_code(solver, "bodies[].solver.name"), float(tol),
                                                  int(iterations)))

    # --- driving ---
    def set_pose(self, body: int, position=None, quaternion=None, velocity=None, angular_velocity=None) -> None:
        args = [None if a is None else _f64(a, (k,), "pose") for a, k in
                ((position, 3), (quaternion, 4), (velocity, 3), (angular_velocity, 3))]
        _check(library().hh_world_set_pose(self._handle, body, *(_ptr(a) for a in args)))

    def set_device(self, hand: int, position=None, quaternion=None, velocity=None, angular_velocity=None,
                   enabled=True) -> None:
        args = [None if a is None else _f64(a, (k,), "device") for a, k in
                ((position, 3), (quaternion, 4), (velocity, 3), (angular_velocity, 3))]
        _check(library().hh_world_set_device(self._handle, hand, int(enabled), *(_ptr(a) for a in args)))

    def set_script(self, body: int, times, positions, quaternions=None) -> None:
        """A kinematic body moved by the world along timed poses (absolute, world frame)."""
        t = _f64(times, None, "times").reshape(-1)
        p = _f64(positions, (len(t), 3), "positions")
        q = None if quaternions is None else _f64(quaternions, (len(t), 4), "quaternions")
        _check(library().hh_world_set_script(self._handle, body, _ptr(t), _ptr(p), _ptr(q), len(t)))

    def time(self) -> float:
        out = ctypes.c_double()
        _check(library().hh_world_time(self._handle, ctypes.byref(out)))
        return out.value

    def step(self) -> dict:
        _check(library().hh_world_step(self._handle, ctypes.byref(self.last_stats)))
        return self.last_stats.as_dict()

    def coupling_model(self, hand: int) -> tuple[np.ndarray, np.ndarray, int]:
        """After a step with the handle prescribed: F_c0 (6,), the stiffness (6, 6) of the
        springs' wrench with respect to the handle's displacement (dx, dtheta), and how many
        contact rows the model holds."""
        w, k, held = np.empty(6), np.empty((6, 6)), ctypes.c_int()
        _check(library().hh_world_coupling_model(self._handle, hand, _ptr(w), _ptr(k), ctypes.byref(held)))
        return w, k, held.value

    def stats(self) -> dict:
        """The statistics of the last step (also one a haptic session made)."""
        _check(library().hh_world_last_stats(self._handle, ctypes.byref(self.last_stats)))
        return self.last_stats.as_dict()

    # --- reading ---
    def body_kind(self, body: int) -> tuple[int, int, int]:
        k, n, s = ctypes.c_int(), ctypes.c_int(), ctypes.c_int()
        _check(library().hh_world_body_kind(self._handle, body, ctypes.byref(k), ctypes.byref(n), ctypes.byref(s)))
        return k.value, n.value, s.value

    def pose(self, body: int):
        p, q, v, w = np.empty(3), np.empty(4), np.empty(3), np.empty(3)
        _check(library().hh_world_get_pose(self._handle, body, _ptr(p), _ptr(q), _ptr(v), _ptr(w)))
        return p, q, v, w

    def nodes(self, body: int) -> tuple[np.ndarray, np.ndarray]:
        n = self.body_kind(body)[1]
        x, v = np.empty((n, 3)), np.empty((n, 3))
        _check(library().hh_world_body_nodes(self._handle, body, _ptr(x), _ptr(v), n))
        return x, v

    def set_nodes(self, body: int, positions=None, velocities=None) -> None:
        n = self.body_kind(body)[1]
        x = None if positions is None else _f64(positions, (n, 3), "positions")
        v = None if velocities is None else _f64(velocities, (n, 3), "velocities")
        _check(library().hh_world_set_body_nodes(self._handle, body, _ptr(x), _ptr(v), n))

    def surface(self, body: int) -> np.ndarray:
        n = self.body_kind(body)[2]
        x = np.empty((n, 3))
        _check(library().hh_world_surface_positions(self._handle, body, _ptr(x), n))
        return x

    def contact_force(self, body: int) -> np.ndarray:
        f = np.empty(3)
        _check(library().hh_world_contact_force(self._handle, body, _ptr(f)))
        return f

    def hand_state(self, hand: int):
        """Handle position, quaternion, and the springs' force and torque on the handle."""
        p, q, f, t = np.empty(3), np.empty(4), np.empty(3), np.empty(3)
        _check(library().hh_world_hand_state(self._handle, hand, _ptr(p), _ptr(q), _ptr(f), _ptr(t)))
        return p, q, f, t

    def n_bones(self, hand: int) -> int:
        """How many bones drive the hand (1: the palm handle)."""
        if hand not in self._bones:
            raise InvalidInput(f"body {hand} is not the hand: give the index add_hand returned")
        return self._bones[hand]

    def set_bone_targets(self, hand: int, modes, positions=None, quaternions=None, velocities=None,
                         angular_velocities=None) -> None:
        """Each bone's target at the end of the next step (docs/skeleton.md, Section 4): modes (B,)
        FREE 0, COUPLED 1 or PRESCRIBED 2, positions (B, 3) of the bones' centres of mass,
        quaternions (B, 4) (x, y, z, w); None keeps a pose and makes a velocity zero."""
        b = self.n_bones(hand)
        m = np.asarray(modes)
        if m.shape != (b,) or m.dtype.kind not in "iu":
            raise InvalidInput(f"bone modes must be {b} integers (FREE 0, COUPLED 1, PRESCRIBED 2), got {m!r}")
        m = np.ascontiguousarray(m, dtype=np.int32)
        args = [None if a is None else _f64(a, (b, k), name)
                for a, k, name in ((positions, 3, "target positions"), (quaternions, 4, "target quaternions"),
                                   (velocities, 3, "target velocities"), (angular_velocities, 3, "target angular velocities"))]
        _check(library().hh_world_set_bone_targets(self._handle, hand, b, _ptr(m, ctypes.c_int), *(_ptr(a) for a in args)))

    def bone_states(self, hand: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(positions (B, 3) of the bones' centres of mass, quaternions (B, 4), wrenches (B, 6): each
        bone's springs' force and torque about its centre of mass)."""
        b = self.n_bones(hand)
        p, q, w = np.empty((b, 3)), np.empty((b, 4)), np.empty((b, 6))
        _check(library().hh_world_bone_states(self._handle, hand, b, _ptr(p), _ptr(q), _ptr(w)))
        return p, q, w

    def bone_velocities(self, hand: int) -> tuple[np.ndarray, np.ndarray]:
        """(velocities (B, 3) of the bones' centres of mass, angular velocities (B, 3))."""
        from .native_skeleton import library as skeleton_library

        b = self.n_bones(hand)
        v, w = np.empty((b, 3)), np.empty((b, 3))
        _check(skeleton_library().hh_world_bone_velocities(self._handle, hand, b, _ptr(v), _ptr(w)))
        return v, w

    def set_bone_states(self, hand: int, positions=None, quaternions=None, velocities=None,
                        angular_velocities=None) -> None:
        """Every bone's state at once (None keeps that part): positions (B, 3) of the centres of
        mass, quaternions (B, 4), velocities (B, 3), angular velocities (B, 3)."""
        from .native_skeleton import library as skeleton_library

        b = self.n_bones(hand)
        args = [None if a is None else _f64(a, (b, k), name)
                for a, k, name in ((positions, 3, "bone positions"), (quaternions, 4, "bone quaternions"),
                                   (velocities, 3, "bone velocities"), (angular_velocities, 3, "bone angular velocities"))]
        _check(skeleton_library().hh_world_set_bone_states(self._handle, hand, b, *(_ptr(a) for a in args)))

    def bone_coupling_model(self, hand: int) -> tuple[np.ndarray, np.ndarray, int]:
        """After a step with every bone prescribed: each bone's springs' wrench (6B,) at the end of
        the step, its stiffness (6B, 6B) with respect to displacements (dx_b, dtheta_b) of the
        prescribed poses with the step's contacts held (docs/skeleton.md, Section 6), and how
        many contact rows it holds. One bone: coupling_model's."""
        from .native_skeleton import library as skeleton_library

        b = self.n_bones(hand)
        w, k, held = np.empty(6 * b), np.empty((6 * b, 6 * b)), ctypes.c_int()
        _check(skeleton_library().hh_world_bone_coupling_model(self._handle, hand, b, _ptr(w), _ptr(k),
                                                               ctypes.byref(held)))
        return w, k, held.value

    def node_contact_forces(self, body: int) -> np.ndarray:
        """(n, 3): the force (N) the last step's contacts put on each node of the hand or a soft body."""
        n = self.body_kind(body)[1]
        out = np.empty((n, 3))
        _check(library().hh_world_node_contact_forces(self._handle, body, _ptr(out), n))
        return out

    def hand_step_stats(self, hand: int) -> dict:
        """Assembly / deformable solves / Schur split of the hand's implicit step (last step)."""
        s = StepStats()
        _check(library().hh_world_hand_step_stats(self._handle, hand, ctypes.byref(s)))
        return s.as_dict()

    def linear_momentum(self) -> np.ndarray:
        p = np.empty(3)
        _check(library().hh_world_linear_momentum(self._handle, _ptr(p)))
        return p
