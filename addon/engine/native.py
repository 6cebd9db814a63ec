"""ctypes bindings of the native engine (native/include/haptic_hand.h).

Arrays cross as contiguous float64 / int32 numpy buffers whose sizes are checked here and
again in C; a native status becomes a Python exception carrying the native message.
"""

from __future__ import annotations

import ctypes
from dataclasses import dataclass

import numpy as np

from . import params as table
# (the errors and helpers every binding shares, also reached as native.*)
from .native_library import (HH_OK, InvalidInput, NativeError, NumericalFailure, _candidates, _check,  # noqa: F401
                             _f64, _indices, _points, _ptr, _timed_poses, binding)


class ModelInfo(ctypes.Structure):
    _fields_ = [
        ("n_nodes", ctypes.c_int),
        ("n_tets", ctypes.c_int),
        ("n_handle_nodes", ctypes.c_int),
        ("total_mass", ctypes.c_double),
        ("handle_mass", ctypes.c_double),
        ("handle_com", ctypes.c_double * 3),
        ("handle_inertia", ctypes.c_double * 9),
        ("min_tet_volume", ctypes.c_double),
        ("max_tet_volume", ctypes.c_double),
    ]


class StepStats(ctypes.Structure):
    _fields_ = [
        ("t_assembly", ctypes.c_double),
        ("t_deformable", ctypes.c_double),
        ("t_schur", ctypes.c_double),
        ("t_total", ctypes.c_double),
        ("cg_iterations", ctypes.c_int),
        ("max_residual", ctypes.c_double),
    ]

    def as_dict(self) -> dict:
        return {name: getattr(self, name) for name, _ in self._fields_}


class WorldStats(ctypes.Structure):
    _fields_ = [
        ("contacts", ctypes.c_int),
        ("self_contacts", ctypes.c_int),
        ("max_penetration", ctypes.c_double),
        ("min_distance", ctypes.c_double),
        ("residual", ctypes.c_double),
        ("iterations", ctypes.c_int),
        ("t_detection", ctypes.c_double),
        ("t_dynamics", ctypes.c_double),
        ("t_contact", ctypes.c_double),
        ("t_total", ctypes.c_double),
    ]

    def as_dict(self) -> dict:
        return {name: getattr(self, name) for name, _ in self._fields_}


_d, _i, _vp = ctypes.c_double, ctypes.c_int, ctypes.c_void_p
_pd, _pi = ctypes.POINTER(_d), ctypes.POINTER(_i)
# the output structs, checked against the library's sizes when it is first used
LAYOUTS = {ModelInfo: "hh_model_info", StepStats: "hh_step_stats", WorldStats: "hh_world_stats"}
library = binding({
    "hh_model_create": ([_pd, _i, _pi, _i, _vp, ctypes.POINTER(_vp)], _i),
    "hh_model_free": ([_vp], None),
    "hh_model_info_get": ([_vp, ctypes.POINTER(ModelInfo)], _i),
    "hh_model_handle_nodes": ([_vp, _pi, _i], _i),
    "hh_model_lumped_masses": ([_vp, _pd, _i], _i),
    "hh_model_params": ([_vp, _vp], _i),
    "hh_count_captured": ([_pd, _i, _pd, _d, _pi], _i),
    "hh_check_handle": ([_pd, _i, _pd, _d, _pi], _i),
    "hh_trajectory_check": ([_pd, _pd, _pd, _i], _i),
    "hh_box_cells_check": ([_pd], _i),
    "hh_data_create": ([_vp, ctypes.POINTER(_vp)], _i),
    "hh_data_free": ([_vp], None),
    "hh_data_reset": ([_vp, _vp], _i),
    "hh_get_state": ([_vp, _vp, _pd, _pd, _i, _pd, _pd, _pd, _pd], _i),
    "hh_set_state": ([_vp, _vp, _pd, _pd, _i, _pd, _pd, _pd, _pd], _i),
    "hh_set_device": ([_vp, _i, _pd, _pd, _pd, _pd], _i),
    "hh_set_solver": ([_vp, _i, _d, _i], _i),
    "hh_step": ([_vp, _vp, ctypes.POINTER(StepStats)], _i),
    "hh_step_monolithic": ([_vp, _vp, ctypes.POINTER(StepStats)], _i),
    "hh_compare_solvers": ([_vp, _vp, _pd], _i),
    "hh_coupling_wrench": ([_vp, _vp, _pd, _pd], _i),
    "hh_coupling_linear_model": ([_vp, _vp, _pd, _pd], _i),
    "hh_coupling_response": ([_vp, _vp, _pd, _pd], _i),
    "hh_coupling_model": ([_vp, _vp, _pd, _pd], _i),
    "hh_energies": ([_vp, _vp, _pd, _pd, _pd], _i),
    "hh_linear_momentum": ([_vp, _vp, _pd], _i),
    # worlds (scenes with contact)
    "hh_world_create": ([_vp, ctypes.POINTER(_vp)], _i),
    "hh_world_free": ([_vp], None),
    "hh_world_add_hand": ([_vp, _vp, _pi, _pd, _i, _pi, _i, _d, _i, _pi], _i),
    "hh_world_add_soft_body": ([_vp, _pd, _i, _pi, _i, _vp, _pi, _i, _pi, _pd, _i, _pi, _i, _d, _pi], _i),
    "hh_world_add_mesh_body": ([_vp, _i, _pd, _i, _pi, _i, _d, _d, _pi], _i),
    "hh_world_add_plane": ([_vp, _pd, _pd, _d, _pi], _i),
    "hh_world_set_pose": ([_vp, _i, _pd, _pd, _pd, _pd], _i),
    "hh_world_set_friction": ([_vp, _i, _d, _d], _i),
    "hh_world_set_body_solver": ([_vp, _i, _i, _d, _i], _i),
    "hh_world_get_pose": ([_vp, _i, _pd, _pd, _pd, _pd], _i),
    "hh_world_set_device": ([_vp, _i, _i, _pd, _pd, _pd, _pd], _i),
    "hh_world_step": ([_vp, ctypes.POINTER(WorldStats)], _i),
    "hh_world_body_kind": ([_vp, _i, _pi, _pi, _pi], _i),
    "hh_world_body_nodes": ([_vp, _i, _pd, _pd, _i], _i),
    "hh_world_set_body_nodes": ([_vp, _i, _pd, _pd, _i], _i),
    "hh_world_surface_positions": ([_vp, _i, _pd, _i], _i),
    "hh_world_contact_force": ([_vp, _i, _pd], _i),
    "hh_world_hand_state": ([_vp, _i, _pd, _pd, _pd, _pd], _i),
    "hh_world_linear_momentum": ([_vp, _pd], _i),
    "hh_world_set_bone_targets": ([_vp, _i, _i, _pi, _pd, _pd, _pd, _pd], _i),
    "hh_world_bone_states": ([_vp, _i, _i, _pd, _pd, _pd], _i),
    "hh_world_node_contact_forces": ([_vp, _i, _pd, _i], _i),
    "hh_world_hand_step_stats": ([_vp, _i, ctypes.POINTER(StepStats)], _i),
    "hh_world_set_script": ([_vp, _i, _pd, _pd, _pd, _i], _i),
    "hh_world_time": ([_vp, _pd], _i),
    "hh_world_last_stats": ([_vp, ctypes.POINTER(WorldStats)], _i),
    "hh_world_coupling_model": ([_vp, _i, _pd, _pd, _pi], _i),
}, LAYOUTS)


def default_params() -> dict:
    """The hand rig's defaults as {C field name: value} (the solver as its index)."""
    return table.struct_values(table.new_struct(table.STRUCT_PARAMS))


def count_captured(nodes: np.ndarray, seed, radius: float) -> int:
    """How many nodes a handle sphere of this radius around seed captures."""
    x = _points(nodes, "nodes")
    s = _f64(seed, (3,), "palm_seed")
    out = ctypes.c_int()
    _check(library().hh_count_captured(_ptr(x), x.shape[0], _ptr(s), float(radius), ctypes.byref(out)))
    return out.value


def solver_code(name: str, field: str = "solver.name") -> int:
    """The C code of a solver named as the parameter table names it (the hand's solver.name, or
    a soft body's bodies[].solver.name, whose choices add auto)."""
    choices = table.by_json(field).choices
    if name not in choices:
        raise InvalidInput(f"solver '{name}' is unknown: use one of {', '.join(choices)}")
    return choices.index(name)


def _solver_index(values: dict) -> dict:
    """The hand's parameters with the solver given by name turned into its C code."""
    out = dict(values)
    if isinstance(out.get("solver"), str):
        out["solver"] = solver_code(out["solver"])
    return out


def check_handle(nodes: np.ndarray, seed, radius: float) -> int:
    """The nodes a handle sphere captures; InvalidInput (the model's own message) when it would
    hold fewer than 4 nodes or all of them."""
    x = _points(nodes, "nodes")
    s = _f64(seed, (3,), "palm_seed")
    out = ctypes.c_int()
    _check(library().hh_check_handle(_ptr(x), x.shape[0], _ptr(s), float(radius), ctypes.byref(out)))
    return out.value


def check_trajectory(times, positions, quaternions) -> None:
    """InvalidInput (the library's message, naming the pose and the fix) unless these timed poses
    ((n,), (n, 3), (n, 4)) have finite values, strictly increasing times and non-zero quaternions."""
    t, p, q = _timed_poses(times, positions, quaternions)
    _check(library().hh_trajectory_check(_ptr(t), _ptr(p), _ptr(q), len(t)))


def check_box_cells(cells) -> None:
    """InvalidInput (the library's message) unless a box body's cells are in range and make no
    more tets than a step can take."""
    _check(library().hh_box_cells_check(_ptr(_f64(cells, (3,), "cells"))))


@dataclass
class HandleState:
    position: np.ndarray
    quaternion: np.ndarray  # (x, y, z, s)
    velocity: np.ndarray
    angular_velocity: np.ndarray


class HandModel:
    """hh_model: the rest mesh, material, handle and springs (static)."""

    def __init__(self, nodes: np.ndarray, tets: np.ndarray, **params):
        self.nodes = _f64(nodes)
        if self.nodes.ndim != 2 or self.nodes.shape[1] != 3:
            raise InvalidInput(f"nodes must be an (n, 3) array, got shape {self.nodes.shape}")
        self.tets = _indices(tets, 4, "tets")
        p = table.new_struct(table.STRUCT_PARAMS, _solver_index(params))
        handle = ctypes.c_void_p()
        _check(
            library().hh_model_create(
                _ptr(self.nodes), self.nodes.shape[0], _ptr(self.tets, ctypes.c_int), self.tets.shape[0],
                ctypes.byref(p), ctypes.byref(handle),
            )
        )
        self._handle = handle

    def __del__(self):
        if getattr(self, "_handle", None):
            library().hh_model_free(self._handle)
            self._handle = None

    @property
    def n_nodes(self) -> int:
        return self.nodes.shape[0]

    def info(self) -> dict:
        i = ModelInfo()
        _check(library().hh_model_info_get(self._handle, ctypes.byref(i)))
        return {
            "n_nodes": i.n_nodes,
            "n_tets": i.n_tets,
            "n_handle_nodes": i.n_handle_nodes,
            "total_mass": i.total_mass,
            "handle_mass": i.handle_mass,
            "handle_com": list(i.handle_com),
            "handle_inertia": np.array(i.handle_inertia).reshape(3, 3).tolist(),
            "min_tet_volume": i.min_tet_volume,
            "max_tet_volume": i.max_tet_volume,
        }

    def handle_nodes(self) -> np.ndarray:
        n = self.info()["n_handle_nodes"]
        out = np.empty(n, dtype=np.int32)
        _check(library().hh_model_handle_nodes(self._handle, _ptr(out, ctypes.c_int), n))
        return out

    def lumped_masses(self) -> np.ndarray:
        out = np.empty(self.n_nodes)
        _check(library().hh_model_lumped_masses(self._handle, _ptr(out), self.n_nodes))
        return out

    def params(self) -> dict:
        """The model's parameters as {C field name: value}, the solver by name."""
        p = table.structure(table.STRUCT_PARAMS)()
        _check(library().hh_model_params(self._handle, ctypes.byref(p)))
        out = table.struct_values(p)
        out["solver"] = table.by_json("solver.name").choices[out["solver"]]
        return out

    def set_solver(self, solver: str, cg_tolerance: float | None = None, cg_max_iterations: int | None = None) -> None:
        """The hand's solver by name; a tolerance or iteration cap left out takes the table's default."""
        tol = table.by_json("solver.cg_tolerance").default if cg_tolerance is None else cg_tolerance
        cap = table.by_json("solver.cg_max_iterations").default if cg_max_iterations is None else cg_max_iterations
        _check(library().hh_set_solver(self._handle, solver_code(solver), float(tol), int(cap)))


class HandSimulation:
    """hh_data: the state of one simulation of a HandModel."""

    def __init__(self, model: HandModel):
        self.model = model
        handle = ctypes.c_void_p()
        _check(library().hh_data_create(model._handle, ctypes.byref(handle)))
        self._handle = handle
        self.last_stats = StepStats()

    def __del__(self):
        if getattr(self, "_handle", None):
            library().hh_data_free(self._handle)
            self._handle = None

    def reset(self) -> None:
        _check(library().hh_data_reset(self.model._handle, self._handle))

    def positions(self) -> np.ndarray:
        x = np.empty((self.model.n_nodes, 3))
        _check(library().hh_get_state(self.model._handle, self._handle, _ptr(x), None, self.model.n_nodes,
                                      None, None, None, None))
        return x

    def velocities(self) -> np.ndarray:
        v = np.empty((self.model.n_nodes, 3))
        _check(library().hh_get_state(self.model._handle, self._handle, None, _ptr(v), self.model.n_nodes,
                                      None, None, None, None))
        return v

    def handle(self) -> HandleState:
        p, q, v, w = np.empty(3), np.empty(4), np.empty(3), np.empty(3)
        _check(library().hh_get_state(self.model._handle, self._handle, None, None, self.model.n_nodes,
                                      _ptr(p), _ptr(q), _ptr(v), _ptr(w)))
        return HandleState(p, q, v, w)

    def set_state(self, positions=None, velocities=None, handle_position=None, handle_quaternion=None,
                  handle_velocity=None, handle_angular_velocity=None) -> None:
        n = self.model.n_nodes
        x = None if positions is None else _f64(positions, (n, 3), "positions")
        v = None if velocities is None else _f64(velocities, (n, 3), "velocities")
        hp = None if handle_position is None else _f64(handle_position, (3,), "handle_position")
        hq = None if handle_quaternion is None else _f64(handle_quaternion, (4,), "handle_quaternion")
        hv = None if handle_velocity is None else _f64(handle_velocity, (3,), "handle_velocity")
        hw = None if handle_angular_velocity is None else _f64(handle_angular_velocity, (3,), "handle_angular_velocity")
        _check(library().hh_set_state(self.model._handle, self._handle, _ptr(x), _ptr(v), n,
                                      _ptr(hp), _ptr(hq), _ptr(hv), _ptr(hw)))

    def set_device(self, position=None, quaternion=None, velocity=None, angular_velocity=None,
                   enabled: bool = True) -> None:
        """The tracked device frame at the end of the next step; enabled=False detaches it."""
        args = [
            None if a is None else _f64(a, (k,), name)
            for a, k, name in ((position, 3, "device position"), (quaternion, 4, "device quaternion"),
                               (velocity, 3, "device velocity"), (angular_velocity, 3, "device angular velocity"))
        ]
        _check(library().hh_set_device(self._handle, int(enabled), *(_ptr(a) for a in args)))

    def step(self, monolithic: bool = False) -> dict:
        fn = library().hh_step_monolithic if monolithic else library().hh_step
        _check(fn(self.model._handle, self._handle, ctypes.byref(self.last_stats)))
        return self.last_stats.as_dict()

    def compare_solvers(self) -> float:
        """max|v_schur - v_monolithic| / max|v_monolithic| for the step from the current state."""
        out = ctypes.c_double()
        _check(library().hh_compare_solvers(self.model._handle, self._handle, ctypes.byref(out)))
        return out.value

    def coupling_wrench(self) -> tuple[np.ndarray, np.ndarray]:
        """Total spring force and torque on the handle (N, N m)."""
        f, t = np.empty(3), np.empty(3)
        _check(library().hh_coupling_wrench(self.model._handle, self._handle, _ptr(f), _ptr(t)))
        return f, t

    def coupling_linear_model(self) -> tuple[np.ndarray, np.ndarray]:
        """(wrench0 (6,), response (6, 6)): the springs' wrench on the handle at the end of the
        next step is wrench0 + response @ v_h for a handle end velocity v_h = (v, omega)."""
        w0, r = np.empty(6), np.empty((6, 6))
        _check(library().hh_coupling_linear_model(self.model._handle, self._handle, _ptr(w0), _ptr(r)))
        return w0, r

    def coupling_response(self, handle_velocity) -> np.ndarray:
        """The same wrench without linearizing the springs, for a prescribed handle velocity."""
        v = _f64(handle_velocity, (6,), "handle velocity")
        out = np.empty(6)
        _check(library().hh_coupling_response(self.model._handle, self._handle, _ptr(v), _ptr(out)))
        return out

    def coupling_model(self) -> tuple[np.ndarray, np.ndarray]:
        """After a step with the handle prescribed (set_device(..., enabled=2)): (wrench0 (6,),
        stiffness (6, 6)), the springs' wrench at the handle's end pose and its derivative with
        respect to a displacement (dx, dtheta) of the prescribed pose."""
        w0, k = np.empty(6), np.empty((6, 6))
        _check(library().hh_coupling_model(self.model._handle, self._handle, _ptr(w0), _ptr(k)))
        return w0, k

    def energies(self) -> dict:
        k, e, s = ctypes.c_double(), ctypes.c_double(), ctypes.c_double()
        _check(library().hh_energies(self.model._handle, self._handle, ctypes.byref(k), ctypes.byref(e),
                                     ctypes.byref(s)))
        return {"kinetic": k.value, "elastic": e.value, "spring": s.value}

    def linear_momentum(self) -> np.ndarray:
        p = np.empty(3)
        _check(library().hh_linear_momentum(self.model._handle, self._handle, _ptr(p)))
        return p
