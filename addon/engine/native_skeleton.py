"""ctypes bindings of the native skeleton of many handles (native/include/haptic_hand.h, the
skeleton section; docs/skeleton.md): a hand model whose handles are the bones of a
skeleton.Skeleton, their capture, info, states, targets and wrenches.

The structures hh_skeleton_desc and hh_bone_info are checked against hh_struct_size when first
used, as every structure the bindings pass is (engine/native_library.py)."""

from __future__ import annotations

import ctypes

import numpy as np

from . import native
from . import params as table
from .native_library import InvalidInput, _check, _f64, _ptr, binding
from .skeleton import Skeleton

FREE, COUPLED, PRESCRIBED = 0, 1, 2  # HH_BONE_*

_pd, _pi = ctypes.POINTER(ctypes.c_double), ctypes.POINTER(ctypes.c_int)


class SkeletonDesc(ctypes.Structure):
    _fields_ = [("struct_size", ctypes.c_int), ("n_bones", ctypes.c_int), ("parents", _pi), ("heads", _pd),
                ("tails", _pd), ("radii", _pd), ("set_offsets", _pi), ("set_nodes", _pi),
                ("names", ctypes.POINTER(ctypes.c_char_p)), ("drive_scales", _pd), ("axes", _pd),
                ("limit_min", _pd), ("limit_max", _pd)]


class BoneInfo(ctypes.Structure):
    _fields_ = [("struct_size", ctypes.c_int), ("parent", ctypes.c_int), ("n_nodes", ctypes.c_int),
                ("mass", ctypes.c_double), ("com", ctypes.c_double * 3), ("inertia", ctypes.c_double * 9),
                ("drive", ctypes.c_double * 4)]


_i, _vp = ctypes.c_int, ctypes.c_void_p
_pdesc = ctypes.POINTER(SkeletonDesc)
# the structs, checked against the library's sizes when it is first used
LAYOUTS = {SkeletonDesc: "hh_skeleton_desc", BoneInfo: "hh_bone_info"}
library = binding({
    "hh_skeleton_capture": ([_pd, _i, _pdesc, _pi, _pi], _i),
    "hh_model_create_skeleton": ([_pd, _i, _pi, _i, _vp, _pdesc, ctypes.POINTER(_vp)], _i),
    "hh_model_bone_count": ([_vp, _pi], _i),
    "hh_model_bone_info": ([_vp, _i, ctypes.POINTER(BoneInfo)], _i),
    "hh_model_bone_nodes": ([_vp, _i, _pi, _i, _pi], _i),
    "hh_model_node_bones": ([_vp, _pi, _i], _i),
    "hh_get_bone_states": ([_vp, _vp, _i, _pd, _pd, _pd, _pd], _i),
    "hh_set_bone_states": ([_vp, _vp, _i, _pd, _pd, _pd, _pd], _i),
    "hh_set_bone_targets": ([_vp, _vp, _i, _pi, _pd, _pd, _pd, _pd], _i),
    "hh_bone_wrenches": ([_vp, _vp, _i, _pd], _i),
    "hh_bone_linear_model": ([_vp, _vp, _i, _pd, _pd], _i),
    "hh_bone_response": ([_vp, _vp, _i, _pd, _pd], _i),
    # a skeleton hand in a world (native_world.World's bone methods)
    "hh_world_bone_velocities": ([_vp, _i, _i, _pd, _pd], _i),
    "hh_world_set_bone_states": ([_vp, _i, _i, _pd, _pd, _pd, _pd], _i),
    "hh_world_bone_coupling_model": ([_vp, _i, _i, _pd, _pd, _pi], _i),
}, LAYOUTS)


class _Desc:
    """A skeleton.Skeleton as hh_skeleton_desc, with the arrays it points into kept alive."""

    def __init__(self, skeleton: Skeleton, drive_scales=None):
        bones = skeleton.bones
        b = len(bones)
        self.parents = np.ascontiguousarray(skeleton.parents, dtype=np.int32)
        self.heads = _f64([bone.head for bone in bones], (b, 3), "bone heads")
        self.tails = _f64([bone.tail for bone in bones], (b, 3), "bone tails")
        self.radii = _f64([bone.radius for bone in bones], (b,), "bone radii")
        sets = [np.asarray([] if bone.nodes is None else bone.nodes) for bone in bones]
        for bone, nodes in zip(bones, sets):
            if nodes.size and nodes.dtype.kind not in "iu":
                raise InvalidInput(f"bone '{bone.name}': its node set must be integer node indices")
        self.offsets = np.ascontiguousarray(np.concatenate([[0], np.cumsum([s.size for s in sets])]), dtype=np.int32)
        self.nodes = np.ascontiguousarray(np.concatenate(sets + [np.zeros(0)]), dtype=np.int32)
        self.names = (ctypes.c_char_p * b)(*[bone.name.encode() for bone in bones])
        self.scales = None if drive_scales is None else _f64(drive_scales, (b,), "drive scales")
        self.axes, self.lo, self.hi = _limits(bones)
        self.desc = SkeletonDesc(ctypes.sizeof(SkeletonDesc), b, _ptr(self.parents, ctypes.c_int), _ptr(self.heads),
                                 _ptr(self.tails), _ptr(self.radii), _ptr(self.offsets, ctypes.c_int),
                                 _ptr(self.nodes, ctypes.c_int), self.names, _ptr(self.scales), _ptr(self.axes),
                                 _ptr(self.lo), _ptr(self.hi))


def _limits(bones) -> tuple:
    """The bones' rest axes (B, 3, 3) and limits (B, 3) each, or None when no bone has them."""
    if all(bone.limits is None and bone.axes is None for bone in bones):
        return None, None, None
    free = np.array([[-np.inf] * 3, [np.inf] * 3])
    axes = np.stack([_f64(np.eye(3) if bone.axes is None else bone.axes, (3, 3), f"bone '{bone.name}': its axes")
                     for bone in bones])
    limits = np.stack([_f64(free if bone.limits is None else bone.limits, (2, 3),
                            f"bone '{bone.name}': its limits (min and max rows)") for bone in bones])
    return axes, np.ascontiguousarray(limits[:, 0]), np.ascontiguousarray(limits[:, 1])


def capture(nodes, skeleton: Skeleton) -> tuple[np.ndarray, np.ndarray]:
    """The native capture rule: each node's bone (-1: flesh only) and each bone's node count."""
    return _capture(nodes, _Desc(skeleton))


def _capture(nodes, desc: _Desc) -> tuple[np.ndarray, np.ndarray]:
    x = native._points(nodes, "nodes")
    owner = np.empty(len(x), dtype=np.int32)
    counts = np.empty(desc.desc.n_bones, dtype=np.int32)
    _check(library().hh_skeleton_capture(_ptr(x), len(x), ctypes.byref(desc.desc), _ptr(owner, ctypes.c_int),
                                         _ptr(counts, ctypes.c_int)))
    return owner, counts


class SkeletonModel(native.HandModel):
    """hh_model built by hh_model_create_skeleton: the bones of `skeleton` are the handles
    (params palm_seed and handle_radius are not read)."""

    def __init__(self, nodes, tets, skeleton: Skeleton, drive_scales=None, **params):
        self.nodes = native._points(nodes, "nodes")
        self.tets = native._indices(tets, 4, "tets")
        self.skeleton = skeleton
        desc = _Desc(skeleton, drive_scales)
        p = table.new_struct(table.STRUCT_PARAMS, native._solver_index(params))
        handle = ctypes.c_void_p()
        _check(library().hh_model_create_skeleton(
            _ptr(self.nodes), self.nodes.shape[0], _ptr(self.tets, ctypes.c_int), self.tets.shape[0],
            ctypes.byref(p), ctypes.byref(desc.desc), ctypes.byref(handle)))
        self._handle = handle

    @property
    def n_bones(self) -> int:
        out = ctypes.c_int()
        _check(library().hh_model_bone_count(self._handle, ctypes.byref(out)))
        return out.value

    def bone_info(self, bone: int) -> dict:
        i = BoneInfo()
        i.struct_size = ctypes.sizeof(BoneInfo)
        _check(library().hh_model_bone_info(self._handle, int(bone), ctypes.byref(i)))
        return {"parent": i.parent, "n_nodes": i.n_nodes, "mass": i.mass, "com": np.array(i.com),
                "inertia": np.array(i.inertia).reshape(3, 3), "drive": np.array(i.drive)}

    def bone_nodes(self, bone: int) -> np.ndarray:
        n = self.bone_info(bone)["n_nodes"]
        out = np.empty(n, dtype=np.int32)
        count = ctypes.c_int()
        _check(library().hh_model_bone_nodes(self._handle, int(bone), _ptr(out, ctypes.c_int), n, ctypes.byref(count)))
        return out

    def node_bones(self) -> np.ndarray:
        out = np.empty(self.n_nodes, dtype=np.int32)
        _check(library().hh_model_node_bones(self._handle, _ptr(out, ctypes.c_int), self.n_nodes))
        return out


class SkeletonSimulation(native.HandSimulation):
    """hh_data of a SkeletonModel: the HandSimulation calls address the root bone; these all bones."""

    def bone_states(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(positions (B, 3), quaternions (B, 4), velocities (B, 3), angular velocities (B, 3))."""
        b = self.model.n_bones
        p, q, v, w = np.empty((b, 3)), np.empty((b, 4)), np.empty((b, 3)), np.empty((b, 3))
        _check(library().hh_get_bone_states(self.model._handle, self._handle, b, _ptr(p), _ptr(q), _ptr(v), _ptr(w)))
        return p, q, v, w

    def set_bone_states(self, positions=None, quaternions=None, velocities=None, angular_velocities=None) -> None:
        b = self.model.n_bones
        args = [None if a is None else _f64(a, (b, k), name)
                for a, k, name in ((positions, 3, "bone positions"), (quaternions, 4, "bone quaternions"),
                                   (velocities, 3, "bone velocities"), (angular_velocities, 3, "bone angular velocities"))]
        _check(library().hh_set_bone_states(self.model._handle, self._handle, b, *(_ptr(a) for a in args)))

    def set_bone_targets(self, modes, positions=None, quaternions=None, velocities=None,
                         angular_velocities=None) -> None:
        """Each bone's target at the end of the next step: modes (B,) FREE, COUPLED or PRESCRIBED."""
        b = self.model.n_bones
        m = np.asarray(modes)
        if m.shape != (b,) or m.dtype.kind not in "iu":
            raise InvalidInput(f"bone modes must be {b} integers (FREE 0, COUPLED 1, PRESCRIBED 2), got {m!r}")
        m = np.ascontiguousarray(m, dtype=np.int32)
        args = [None if a is None else _f64(a, (b, k), name)
                for a, k, name in ((positions, 3, "target positions"), (quaternions, 4, "target quaternions"),
                                   (velocities, 3, "target velocities"), (angular_velocities, 3, "target angular velocities"))]
        _check(library().hh_set_bone_targets(self.model._handle, self._handle, b, _ptr(m, ctypes.c_int),
                                             *(_ptr(a) for a in args)))

    def bone_wrenches(self) -> np.ndarray:
        """(B, 6): each bone's springs' (force, torque about its centre of mass)."""
        b = self.model.n_bones
        out = np.empty((b, 6))
        _check(library().hh_bone_wrenches(self.model._handle, self._handle, b, _ptr(out)))
        return out

    def bone_linear_model(self) -> tuple[np.ndarray, np.ndarray]:
        """(wrench0 (6B,), response (6B, 6B)): every bone's springs' wrench at the end of the next
        step, with every bone driven at the end velocity v_h (6B), is wrench0 + response @ v_h."""
        b = self.model.n_bones
        w0, r = np.empty(6 * b), np.empty((6 * b, 6 * b))
        _check(library().hh_bone_linear_model(self.model._handle, self._handle, b, _ptr(w0), _ptr(r)))
        return w0, r

    def bone_response(self, velocities) -> np.ndarray:
        """The same wrenches (6B,) without linearizing, for the bones' end velocities (6B,)."""
        b = self.model.n_bones
        v = _f64(velocities, (6 * b,), "bone end velocities")
        out = np.empty(6 * b)
        _check(library().hh_bone_response(self.model._handle, self._handle, b, _ptr(v), _ptr(out)))
        return out
