"""ctypes bindings of the native engine (native/include/haptic_hand.h).

Arrays cross as contiguous float64 / int32 numpy buffers whose sizes are checked here and
again in C; a native status becomes a Python exception carrying the native message.
"""

from __future__ import annotations

import ctypes
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

HH_OK = 0
HH_ERR_INVALID_ARGUMENT = -1
HH_ERR_NUMERICAL = -2
API_VERSION = 3

_HERE = Path(__file__).resolve().parent
LIBRARY_NAME = "libhaptic_hand.so"


class NativeError(RuntimeError):
    """The native engine reported a failure; the message says what and how to fix it."""


class InvalidInput(NativeError, ValueError):
    """Bad input (mesh, parameters, array sizes) rejected by the native engine."""


class NumericalFailure(NativeError):
    """A solve failed or produced non-finite values."""


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


def _candidates() -> list[Path]:
    found = []
    if os.environ.get("HAPTIC_HAND_LIB"):
        found.append(Path(os.environ["HAPTIC_HAND_LIB"]))
    found.append(_HERE.parent / "lib" / LIBRARY_NAME)  # inside a built extension zip
    found.append(_HERE.parents[1] / "build" / "native" / LIBRARY_NAME)  # a source checkout
    return found


_lib = None


def library() -> ctypes.CDLL:
    """Loads the native library once, declaring every signature."""
    global _lib
    if _lib is not None:
        return _lib
    tried = _candidates()
    path = next((p for p in tried if p.is_file()), None)
    if path is None:
        raise NativeError(
            "the native library libhaptic_hand.so was not found (looked in: "
            + ", ".join(str(p) for p in tried)
            + "); build it with `make native` or set HAPTIC_HAND_LIB to its path"
        )
    lib = ctypes.CDLL(str(path))
    _declare(lib)
    if lib.hh_api_version() != API_VERSION:
        raise NativeError(
            f"{path} implements API version {lib.hh_api_version()}, these bindings need "
            f"{API_VERSION}: rebuild it with `make native`"
        )
    _lib = lib
    return lib


def _declare(lib: ctypes.CDLL) -> None:
    d, i = ctypes.c_double, ctypes.c_int
    pd, pi, vp = ctypes.POINTER(d), ctypes.POINTER(i), ctypes.c_void_p
    sig = {
        "hh_last_error": ([], ctypes.c_char_p),
        "hh_api_version": ([], i),
        "hh_param_count": ([], i),
        "hh_param_info_get": ([i, vp], i),
        "hh_struct_size": ([i, pi], i),
        "hh_param_check": ([ctypes.c_char_p, pd, i], i),
        "hh_default_params": ([vp], None),
        "hh_model_create": ([pd, i, pi, i, vp, ctypes.POINTER(vp)], i),
        "hh_model_free": ([vp], None),
        "hh_model_info_get": ([vp, ctypes.POINTER(ModelInfo)], i),
        "hh_model_handle_nodes": ([vp, pi, i], i),
        "hh_model_lumped_masses": ([vp, pd, i], i),
        "hh_model_params": ([vp, vp], i),
        "hh_count_captured": ([pd, i, pd, d, pi], i),
        "hh_check_handle": ([pd, i, pd, d, pi], i),
        "hh_data_create": ([vp, ctypes.POINTER(vp)], i),
        "hh_data_free": ([vp], None),
        "hh_data_reset": ([vp, vp], i),
        "hh_get_state": ([vp, vp, pd, pd, i, pd, pd, pd, pd], i),
        "hh_set_state": ([vp, vp, pd, pd, i, pd, pd, pd, pd], i),
        "hh_set_device": ([vp, i, pd, pd, pd, pd], i),
        "hh_set_solver": ([vp, i, d, i], i),
        "hh_step": ([vp, vp, ctypes.POINTER(StepStats)], i),
        "hh_step_monolithic": ([vp, vp, ctypes.POINTER(StepStats)], i),
        "hh_compare_solvers": ([vp, vp, pd], i),
        "hh_coupling_wrench": ([vp, vp, pd, pd], i),
        "hh_coupling_linear_model": ([vp, vp, pd, pd], i),
        "hh_coupling_response": ([vp, vp, pd, pd], i),
        "hh_coupling_model": ([vp, vp, pd, pd], i),
        "hh_energies": ([vp, vp, pd, pd, pd], i),
        "hh_linear_momentum": ([vp, vp, pd], i),
        # worlds (scenes with contact)
        "hh_default_world_params": ([vp], None),
        "hh_default_material": ([vp], None),
        "hh_world_create": ([vp, ctypes.POINTER(vp)], i),
        "hh_world_free": ([vp], None),
        "hh_world_add_hand": ([vp, vp, pi, pd, i, pi, i, d, i, pi], i),
        "hh_world_add_soft_body": ([vp, pd, i, pi, i, vp, pi, i, pi, pd, i, pi, i, d, pi], i),
        "hh_world_add_mesh_body": ([vp, i, pd, i, pi, i, d, d, pi], i),
        "hh_world_add_plane": ([vp, pd, pd, d, pi], i),
        "hh_world_set_pose": ([vp, i, pd, pd, pd, pd], i),
        "hh_world_set_friction": ([vp, i, d, d], i),
        "hh_world_set_body_solver": ([vp, i, i, d, i], i),
        "hh_world_get_pose": ([vp, i, pd, pd, pd, pd], i),
        "hh_world_set_device": ([vp, i, i, pd, pd, pd, pd], i),
        "hh_world_step": ([vp, ctypes.POINTER(WorldStats)], i),
        "hh_world_body_kind": ([vp, i, pi, pi, pi], i),
        "hh_world_body_nodes": ([vp, i, pd, pd, i], i),
        "hh_world_set_body_nodes": ([vp, i, pd, pd, i], i),
        "hh_world_surface_positions": ([vp, i, pd, i], i),
        "hh_world_contact_force": ([vp, i, pd], i),
        "hh_world_hand_state": ([vp, i, pd, pd, pd, pd], i),
        "hh_world_linear_momentum": ([vp, pd], i),
        "hh_world_set_bone_targets": ([vp, i, i, ctypes.POINTER(i), pd, pd, pd, pd], i),
        "hh_world_bone_states": ([vp, i, i, pd, pd, pd], i),
        "hh_world_node_contact_forces": ([vp, i, pd, i], i),
        "hh_world_hand_step_stats": ([vp, i, ctypes.POINTER(StepStats)], i),
        "hh_world_set_script": ([vp, i, pd, pd, pd, i], i),
        "hh_world_time": ([vp, pd], i),
        "hh_world_last_stats": ([vp, ctypes.POINTER(WorldStats)], i),
        "hh_world_coupling_model": ([vp, i, pd, pd, pi], i),
    }
    for name, (args, res) in sig.items():
        fn = getattr(lib, name)
        fn.argtypes = args
        fn.restype = res


def _check(status: int) -> None:
    if status == HH_OK:
        return
    message = library().hh_last_error().decode("utf-8", "replace")
    if status == HH_ERR_INVALID_ARGUMENT:
        raise InvalidInput(message)
    if status == HH_ERR_NUMERICAL:
        raise NumericalFailure(message)
    raise NativeError(message)


def _f64(a, shape=None, name="array") -> np.ndarray:
    try:
        out = np.ascontiguousarray(a, dtype=np.float64)
    except (TypeError, ValueError):
        raise InvalidInput(f"{name} must be numbers (float64), got {type(a).__name__}") from None
    if shape is not None and out.shape != shape:
        raise InvalidInput(f"{name} has shape {out.shape}, expected {shape}")
    return out


def _indices(a, columns: int, name: str) -> np.ndarray:
    """An (m, columns) int32 index array; floats are refused rather than truncated, indices
    beyond 32 bits rather than wrapped."""
    a = np.asarray(a)
    if a.size == 0:
        a = a.astype(np.int32)
    if a.dtype.kind not in "iu":
        raise InvalidInput(f"{name} must be integer indices, got {a.dtype} values (floats are refused, not truncated)")
    if a.ndim != 2 or a.shape[1] != columns:
        raise InvalidInput(f"{name} must be an (m, {columns}) integer array, got shape {a.shape}")
    if a.size and (a.min() < -2**31 or a.max() > 2**31 - 1):
        raise InvalidInput(f"{name} holds an index beyond 32 bits ({a.max()}): it is refused, not wrapped")
    return np.ascontiguousarray(a, dtype=np.int32)


def _ptr(a: np.ndarray | None, ctype=ctypes.c_double):
    return None if a is None else a.ctypes.data_as(ctypes.POINTER(ctype))


def default_params() -> dict:
    """The hand rig's defaults as {C field name: value} (the solver as its index)."""
    from . import params

    return params.struct_values(params.new_struct(params.STRUCT_PARAMS))


def _points(a, name: str) -> np.ndarray:
    """An (n, 3) float64 array (the C side reads 3 n numbers)."""
    out = _f64(a, None, name)
    if out.ndim != 2 or out.shape[1] != 3:
        raise InvalidInput(f"{name} must be an (n, 3) array, got shape {out.shape}")
    return out


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
    from . import params

    choices = params.by_json(field).choices
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
        from . import params as table

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
        from . import params as table

        p = table.structure(table.STRUCT_PARAMS)()
        _check(library().hh_model_params(self._handle, ctypes.byref(p)))
        out = table.struct_values(p)
        out["solver"] = table.by_json("solver.name").choices[out["solver"]]
        return out

    def set_solver(self, solver: str, cg_tolerance: float | None = None, cg_max_iterations: int | None = None) -> None:
        """The hand's solver by name; a tolerance or iteration cap left out takes the table's default."""
        from . import params as table

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
