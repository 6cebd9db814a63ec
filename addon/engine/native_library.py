"""The native library (native/include/haptic_hand.h) as every binding finds and trusts it: where
it is, its status codes and errors, the declaration of signatures, the check of each ctypes
structure against the library's size of its C struct, and the numpy conversions of arguments.

The bindings of each part (native, native_world, native_session, native_skeleton, params) build
on this module; it imports none of them."""

from __future__ import annotations

import ctypes
import os
from pathlib import Path

import numpy as np

HH_OK = 0
HH_ERR_INVALID_ARGUMENT = -1
HH_ERR_NUMERICAL = -2
API_VERSION = 3

LIBRARY_NAME = "libhaptic_hand.so"
_HERE = Path(__file__).resolve().parent

# The structs hh_struct_size knows, at their HH_STRUCT_* index ("" for HH_STRUCT_NONE).
STRUCT_NAMES = ("", "hh_params", "hh_world_params", "hh_material", "hh_session_params", "hh_skeleton_desc",
                "hh_bone_info", "hh_model_info", "hh_step_stats", "hh_world_stats", "hh_session_status",
                "hh_session_frame")


class NativeError(RuntimeError):
    """The native engine reported a failure; the message says what and how to fix it."""


class InvalidInput(NativeError, ValueError):
    """Bad input (mesh, parameters, array sizes) rejected by the native engine."""


class NumericalFailure(NativeError):
    """A solve failed or produced non-finite values."""


def _candidates() -> list[Path]:
    found = []
    if os.environ.get("HAPTIC_HAND_LIB"):
        found.append(Path(os.environ["HAPTIC_HAND_LIB"]))
    found.append(_HERE.parent / "lib" / LIBRARY_NAME)  # inside a built extension zip
    found.append(_HERE.parents[1] / "build" / "native" / LIBRARY_NAME)  # a source checkout
    return found


_lib = None


def library() -> ctypes.CDLL:
    """Loads the native library once, checks its version and declares the signatures this
    module and the parameter table use (each binding declares its own: `binding`)."""
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
    declare(lib, {"hh_api_version": ([], ctypes.c_int)})
    if lib.hh_api_version() != API_VERSION:
        raise NativeError(
            f"{path} implements API version {lib.hh_api_version()}, these bindings need "
            f"{API_VERSION}: rebuild it with `make native`"
        )
    d, i, pd, pi, vp = ctypes.c_double, ctypes.c_int, ctypes.POINTER(ctypes.c_double), ctypes.POINTER(ctypes.c_int), \
        ctypes.c_void_p
    declare(lib, {
        "hh_last_error": ([], ctypes.c_char_p),
        "hh_param_count": ([], i),
        "hh_param_info_get": ([i, vp], i),
        "hh_struct_size": ([i, pi], i),
        "hh_param_check": ([ctypes.c_char_p, pd, i], i),
        "hh_default_params": ([vp], None),
        "hh_default_world_params": ([vp], None),
        "hh_default_material": ([vp], None),
        "hh_default_session_params": ([vp], None),
    })
    _lib = lib
    return lib


def declare(lib: ctypes.CDLL, signatures: dict) -> None:
    """Sets argtypes and restype of each function {name: ([argument types], result type)}."""
    for name, (args, result) in signatures.items():
        try:
            fn = getattr(lib, name)
        except AttributeError:
            raise NativeError(f"the native library has no {name}: it is older than these bindings; rebuild it with "
                              "`make native`") from None
        fn.argtypes = args
        fn.restype = result


def struct_size(c_name: str) -> int:
    """sizeof the C struct of that name, as the library was built."""
    size = ctypes.c_int()
    _check(library().hh_struct_size(STRUCT_NAMES.index(c_name), ctypes.byref(size)))
    return size.value


def check_layout(structure: type, c_name: str) -> None:
    """NativeError unless the ctypes structure is as large as the library's C struct: one of them
    is from another version of haptic_hand.h."""
    ours, theirs = ctypes.sizeof(structure), struct_size(c_name)
    if ours != theirs:
        raise NativeError(f"{c_name} is {theirs} bytes in the native library and {ours} bytes in these bindings "
                          f"({structure.__name__}): they are from different versions; rebuild it with `make native`")


def binding(signatures: dict, layouts: dict | None = None, check=None):
    """The loader of one part of the bindings: the library with these signatures declared, these
    structures {ctypes structure: C struct name} checked and check(library) passed, once, on
    first use."""
    state = {}

    def load() -> ctypes.CDLL:
        lib = library()
        if state.get("lib") is not lib:
            declare(lib, signatures)
            for structure, c_name in (layouts or {}).items():
                check_layout(structure, c_name)
            if check is not None:
                check(lib)
            state["lib"] = lib
        return lib

    return load


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


def _points(a, name: str) -> np.ndarray:
    """An (n, 3) float64 array (the C side reads 3 n numbers)."""
    out = _f64(a, None, name)
    if out.ndim != 2 or out.shape[1] != 3:
        raise InvalidInput(f"{name} must be an (n, 3) array, got shape {out.shape}")
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


def _timed_poses(times, positions, quaternions=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Timed poses as the C side reads them: times (n,), positions (n, 3), quaternions (n, 4)
    (None: no rotation)."""
    t = _f64(times, None, "times").reshape(-1)
    p = _f64(positions, (len(t), 3), "positions")
    q = _f64(quaternions if quaternions is not None else np.tile([0, 0, 0, 1.0], (len(t), 1)), (len(t), 4),
             "quaternions")
    return t, p, q


def _ptr(a: np.ndarray | None, ctype=ctypes.c_double):
    return None if a is None else a.ctypes.data_as(ctypes.POINTER(ctype))
