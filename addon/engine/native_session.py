"""ctypes bindings of haptic sessions (native/include/haptic_hand.h, haptic rendering part):
the visual loop and the 1 kHz haptic loop around a World, with their device backends."""

from __future__ import annotations

import ctypes
import math

import numpy as np

from . import params as table
from .native_library import NativeError, _check, _f64, _ptr, _timed_poses, binding
from .native_world import World

# the haptic log's columns (native/src/haptics/haptic_log.h): (name, width) in row order
_LOG_LAYOUT = (("t", 1), ("period", 1), ("cost", 1), ("device_position", 3), ("device_quaternion", 4),
               ("proxy_position", 3), ("proxy_quaternion", 4), ("force", 3), ("torque", 3))
LOG_COLUMNS = sum(width for _, width in _LOG_LAYOUT)  # checked against the library's HH_LOG_COLUMNS


def _log_fields() -> dict:
    out, start = {}, 0
    for name, width in _LOG_LAYOUT:
        out[name] = slice(start, start + width)
        start += width
    return out


LOG_FIELDS = _log_fields()


class SessionStatus(ctypes.Structure):
    _fields_ = [
        ("running", ctypes.c_int),
        ("failed", ctypes.c_int),
        ("haptic_steps", ctypes.c_double),
        ("visual_steps", ctypes.c_double),
        ("log_unread", ctypes.c_double),
        ("log_dropped", ctypes.c_double),
        ("realtime", ctypes.c_int),
        ("message", ctypes.c_char * 512),
    ]


class SessionFrame(ctypes.Structure):
    _fields_ = [
        ("time", ctypes.c_double),
        ("visual_steps", ctypes.c_double),
        ("handle", ctypes.c_double * 7),
        ("proxy", ctypes.c_double * 7),
        ("device", ctypes.c_double * 7),
        ("feedback", ctypes.c_double * 6),
        ("wrench", ctypes.c_double * 6),
        ("contacts", ctypes.c_int),
        ("held_rows", ctypes.c_int),
    ]


def _check_log_columns(lib: ctypes.CDLL) -> None:
    if lib.hh_log_columns() != LOG_COLUMNS:
        raise NativeError(f"the native library's haptic log rows are {lib.hh_log_columns()} numbers wide and these "
                          f"bindings read {LOG_COLUMNS}: they are from different versions; rebuild it with "
                          "`make native`")


_d, _i, _vp = ctypes.c_double, ctypes.c_int, ctypes.c_void_p
_pd, _pi = ctypes.POINTER(_d), ctypes.POINTER(_i)
# the output structs, checked against the library's sizes when it is first used
LAYOUTS = {SessionStatus: "hh_session_status", SessionFrame: "hh_session_frame"}
_lib = binding({
    "hh_log_columns": ([], _i),
    "hh_session_create": ([_vp, _i, _vp, ctypes.POINTER(_vp)], _i),
    "hh_session_params_check": ([_vp], _i),
    "hh_session_free": ([_vp], None),
    "hh_session_device_simulated": ([_vp, _pd, _pd, _pd, _i, _d, _d, _d, _d], _i),
    "hh_session_device_playback": ([_vp, _pd, _pd, _pd, _i, _d], _i),
    "hh_session_device_external": ([_vp, _d], _i),
    "hh_session_push_device_pose": ([_vp, _pd, _pd], _i),
    "hh_session_device_openhaptics": ([_vp, ctypes.c_char_p, _d, _pd, _d], _i),
    "hh_session_run_offline": ([_vp, _i], _i),
    "hh_session_start": ([_vp], _i),
    "hh_session_stop": ([_vp], _i),
    "hh_session_get_status": ([_vp, ctypes.POINTER(SessionStatus)], _i),
    "hh_session_loop_info": ([_vp, _pi, _pi, _pd, _pd, _pd, _pd], _i),
    "hh_session_fetch_frame": ([_vp, _pi, ctypes.POINTER(SessionFrame)], _i),
    "hh_session_frame_surface": ([_vp, _i, _pd, _i], _i),
    "hh_session_read_log": ([_vp, _pd, _i, _pi], _i),
    "hh_session_frame_pose": ([_vp, _i, _pd], _i),
    "hh_session_coupling_model": ([_vp, _pd, _pd, _pi], _i),
    # a skeleton hand's session (docs/skeleton.md, Section 6)
    "hh_session_bone_count": ([_vp, _pi], _i),
    "hh_session_device_external_frames": ([_vp, _i, _d], _i),
    "hh_session_push_device_frames": ([_vp, _i, _pd, _pd], _i),
    "hh_session_device_feedback": ([_vp, _i, _pd, _i, _pd, _pd], _i),
    "hh_session_device_simulated_glove": ([_vp, _i, _pd, _pd, _pd, _i, _d, _d, _d, _d], _i),
    "hh_session_device_simulated_glove_arms": ([_vp, _i, _pd, _pd, _pd, _i, _pd, _pi, _d], _i),
    "hh_session_pose_fingers": ([_vp, _i, _pd, _pd, _pd, _i], _i),
    "hh_session_set_feedback_groups": ([_vp, _i, _pi, _i], _i),
    "hh_session_frame_bones": ([_vp, _i, _pd, _pd, _pd, _pd], _i),
    "hh_session_frame_groups": ([_vp, _i, _pd], _i),
    "hh_session_bone_coupling_model": ([_vp, _i, _pd, _pd, _pi], _i),
}, LAYOUTS, _check_log_columns)



def log_arrays(rows: np.ndarray) -> dict:
    """The haptic log rows (k, LOG_COLUMNS) as named arrays (one row per haptic step)."""
    rows = np.asarray(rows).reshape(-1, LOG_COLUMNS)
    out = {}
    for name, sl in LOG_FIELDS.items():
        a = rows[:, sl]
        out[name] = a[:, 0].copy() if a.shape[1] == 1 else a.copy()
    return out


def check_params(**params) -> None:
    """The checks a session's creation makes on its parameters (C names), without a world."""
    p = table.new_struct(table.STRUCT_SESSION_PARAMS, params)
    _check(_lib().hh_session_params_check(ctypes.byref(p)))


class NativeSession:
    """hh_session: owns the loops around a World (kept alive by this object)."""

    def __init__(self, world: World, hand: int, **params):
        """params: fields of hh_session_params by C name (haptic_rate, coupling_stiffness,
        max_force, linearized, log_capacity, ...); the others take the table's defaults."""
        lib = _lib()
        p = table.new_struct(table.STRUCT_SESSION_PARAMS, params)
        handle = ctypes.c_void_p()
        _check(lib.hh_session_create(world._handle, int(hand), ctypes.byref(p), ctypes.byref(handle)))
        self._handle = handle
        self.world = world  # the session borrows the world: keep it alive
        self.hand = hand
        self.params = p
        self.frame_info = SessionFrame()

    def close(self) -> None:
        if getattr(self, "_handle", None):
            _lib().hh_session_free(self._handle)
            self._handle = None

    def __del__(self):
        self.close()

    # --- devices ---
    def device_simulated(self, times, positions, quaternions=None, arm_mass=None, arm_stiffness=None,
                         arm_damping=None, fail_at=math.inf) -> None:
        """The simulated user's arm follows the timed poses; arm settings left None take the
        parameter table's defaults (haptics.arm.*)."""
        arm = table.defaults()["haptics"]["arm"]
        arm_mass = arm["mass"] if arm_mass is None else arm_mass
        arm_stiffness = arm["stiffness"] if arm_stiffness is None else arm_stiffness
        arm_damping = arm["damping"] if arm_damping is None else arm_damping
        t, p, q = _timed_poses(times, positions, quaternions)
        _check(_lib().hh_session_device_simulated(self._handle, _ptr(t), _ptr(p), _ptr(q), len(t), float(arm_mass),
                                                  float(arm_stiffness), float(arm_damping), float(fail_at)))

    def device_playback(self, times, positions, quaternions=None, fail_at=math.inf) -> None:
        t, p, q = _timed_poses(times, positions, quaternions)
        _check(_lib().hh_session_device_playback(self._handle, _ptr(t), _ptr(p), _ptr(q), len(t), float(fail_at)))

    def device_external(self, timeout=None) -> None:
        """The host pushes the poses (push_device_pose); timeout (s, None: the table's
        haptics.external_timeout) bounds the wait for the first one."""
        timeout = table.defaults()["haptics"]["external_timeout"] if timeout is None else timeout
        _check(_lib().hh_session_device_external(self._handle, float(timeout)))

    def push_device_pose(self, position, quaternion=(0, 0, 0, 1)) -> None:
        _check(_lib().hh_session_push_device_pose(self._handle, _ptr(_f64(position, (3,), "position")),
                                                  _ptr(_f64(quaternion, (4,), "quaternion"))))

    def device_openhaptics(self, library_path: str | None = None, workspace_scale: float = 1.0,
                           workspace_origin=(0.0, 0.0, 0.0), max_force: float = 3.3) -> None:
        name = None if library_path is None else str(library_path).encode()
        _check(_lib().hh_session_device_openhaptics(self._handle, name, float(workspace_scale),
                                                    _ptr(_f64(workspace_origin, (3,), "workspace origin")),
                                                    float(max_force)))

    # --- running ---
    def run_offline(self, visual_steps: int = 1) -> None:
        _check(_lib().hh_session_run_offline(self._handle, int(visual_steps)))

    def start(self) -> None:
        _check(_lib().hh_session_start(self._handle))

    def stop(self) -> None:
        _check(_lib().hh_session_stop(self._handle))

    def status(self) -> dict:
        s = SessionStatus()
        _check(_lib().hh_session_get_status(self._handle, ctypes.byref(s)))
        return {"running": bool(s.running), "failed": bool(s.failed), "haptic_steps": int(s.haptic_steps),
                "visual_steps": int(s.visual_steps), "log_unread": int(s.log_unread),
                "log_dropped": int(s.log_dropped), "realtime": bool(s.realtime),
                "message": s.message.decode("utf-8", "replace")}

    def loop_info(self) -> dict:
        """How the last live haptic thread ran (after stop): the CPU it was pinned to (-1: none)
        and whether it is isolated, its memory locked and refused (bytes), the page faults in its loop."""
        cpu, isolated = ctypes.c_int(), ctypes.c_int()
        locked, refused, minor, major = (ctypes.c_double() for _ in range(4))
        _check(_lib().hh_session_loop_info(self._handle, ctypes.byref(cpu), ctypes.byref(isolated), ctypes.byref(locked),
                                           ctypes.byref(refused), ctypes.byref(minor), ctypes.byref(major)))
        return {"cpu": cpu.value, "cpu_isolated": bool(isolated.value), "locked_bytes": locked.value,
                "unlocked_bytes": refused.value, "minor_faults": int(minor.value), "major_faults": int(major.value)}

    def fetch_frame(self) -> bool:
        """Takes the newest frame (True when it is new); its scalars are in frame_info."""
        new = ctypes.c_int()
        _check(_lib().hh_session_fetch_frame(self._handle, ctypes.byref(new), ctypes.byref(self.frame_info)))
        return bool(new.value)

    def frame_surface(self, body: int, n_vertices: int) -> np.ndarray:
        out = np.empty((n_vertices, 3))
        _check(_lib().hh_session_frame_surface(self._handle, int(body), _ptr(out), int(n_vertices)))
        return out

    def frame_pose(self, body: int) -> np.ndarray:
        """The fetched frame's pose (centre, quaternion) of a rigid, kinematic or static body."""
        out = np.empty(7)
        _check(_lib().hh_session_frame_pose(self._handle, int(body), _ptr(out)))
        return out

    def read_log(self, max_rows: int | None = None) -> np.ndarray:
        """Unread haptic log rows, (k, LOG_COLUMNS), oldest first."""
        chunks = []
        while True:
            cap = 4096 if max_rows is None else max(0, max_rows - sum(len(c) for c in chunks))
            if cap == 0:
                break
            buf = np.empty((cap, LOG_COLUMNS))
            n = ctypes.c_int()
            _check(_lib().hh_session_read_log(self._handle, _ptr(buf), cap, ctypes.byref(n)))
            chunks.append(buf[: n.value])
            if n.value < cap:
                break
        return np.concatenate(chunks) if chunks else np.empty((0, LOG_COLUMNS))

    def coupling_model(self) -> tuple[np.ndarray, np.ndarray, int]:
        """F_c0 (6,), stiffness (6, 6) and held contact rows of the fetched frame's model."""
        w, k, held = np.empty(6), np.empty((6, 6)), ctypes.c_int()
        _check(_lib().hh_session_coupling_model(self._handle, _ptr(w), _ptr(k), ctypes.byref(held)))
        return w, k, held.value

    # --- a skeleton hand's session: one proxy and device frame per bone (docs/skeleton.md, Section 6) ---
    @property
    def n_bones(self) -> int:
        out = ctypes.c_int()
        _check(_lib().hh_session_bone_count(self._handle, ctypes.byref(out)))
        return out.value

    def device_external_frames(self, timeout=None) -> None:
        """A glove of one frame per bone whose poses the host pushes (push_device_frames) and
        whose feedback it reads (device_feedback); timeout as device_external's."""
        timeout = table.defaults()["haptics"]["external_timeout"] if timeout is None else timeout
        _check(_lib().hh_session_device_external_frames(self._handle, self.n_bones, float(timeout)))

    def push_device_frames(self, positions, quaternions) -> None:
        """Every bone's device frame: positions (B, 3), quaternions (B, 4) (x, y, z, w)."""
        b = self.n_bones
        _check(_lib().hh_session_push_device_frames(self._handle, b, _ptr(_f64(positions, (b, 3), "frame positions")),
                                                    _ptr(_f64(quaternions, (b, 4), "frame quaternions"))))

    def device_feedback(self) -> tuple[np.ndarray, np.ndarray, float]:
        """The external glove's newest feedback: per bone (B, 6) and per group (G, 6) (force N,
        torque N m), and the haptic time it was commanded at."""
        b, g = self.n_bones, self._groups
        bones, groups, t = np.empty((b, 6)), np.empty((g, 6)), ctypes.c_double()
        _check(_lib().hh_session_device_feedback(self._handle, b, _ptr(bones), g, _ptr(groups) if g else None,
                                                 ctypes.byref(t)))
        return bones, groups, t.value

    def device_simulated_glove(self, times, positions, quaternions=None, arm_mass=None, arm_stiffness=None,
                               arm_damping=None, fail_at=math.inf, arms=None, posed=None) -> None:
        """The simulated glove user: one simulated arm per bone following timed poses positions
        (n, B, 3), quaternions (n, B, 4) or None. Every arm alike (settings None: the table's
        haptics.glove.*), or arms (B, 3) of their own (mass, stiffness, damping); posed (B,) bools
        (None: none): frames that follow their poses exactly and feel nothing."""
        glove = table.defaults()["haptics"]["glove"]
        b = self.n_bones
        t = _f64(times, None, "times").reshape(-1)
        p = _f64(positions, (len(t), b, 3), "glove positions")
        q = None if quaternions is None else _f64(quaternions, (len(t), b, 4), "glove quaternions")
        if arms is None:
            arm = [glove[k] if v is None else v for k, v in (("mass", arm_mass), ("stiffness", arm_stiffness),
                                                             ("damping", arm_damping))]
            arms = np.tile(np.array(arm, dtype=float), (b, 1))
        arms = _f64(arms, (b, 3), "glove arms")
        flags = None if posed is None else np.ascontiguousarray(np.asarray(posed).reshape(b), dtype=np.int32)
        _check(_lib().hh_session_device_simulated_glove_arms(
            self._handle, b, _ptr(t), _ptr(p), _ptr(q), len(t), _ptr(arms),
            None if flags is None else _ptr(flags, ctypes.c_int), float(fail_at)))

    def pose_fingers(self, times, rel_positions, rel_quaternions) -> None:
        """Poses bones 1 .. B-1 on a one-frame device on the wrist: each bone's pose relative to
        the root, T_root^-1 T_b, at times (n,): rel_positions (n, B, 3) in the root's frame,
        rel_quaternions (n, B, 4) unit (x, y, z, w) (the root's entries unread). A one-frame
        device given afterwards (device_simulated, _playback, _external, _openhaptics) drives the
        root and carries the others, and is commanded the whole hand's wrench."""
        b = self.n_bones
        t = _f64(times, None, "times").reshape(-1)
        p = _f64(rel_positions, (len(t), b, 3), "finger positions relative to the root")
        q = _f64(rel_quaternions, (len(t), b, 4), "finger quaternions relative to the root")
        _check(_lib().hh_session_pose_fingers(self._handle, b, _ptr(t), _ptr(p), _ptr(q), len(t)))

    def set_feedback_groups(self, group_of_bone, n_groups: int | None = None) -> None:
        """Groups of bones whose feedback is summed (each bone's group 0..G-1, or -1 for none;
        skeleton.Skeleton.feedback_groups gives the wrist and the digits)."""
        groups = np.ascontiguousarray(group_of_bone, dtype=np.int32).reshape(-1)
        n = int(groups.max()) + 1 if n_groups is None else int(n_groups)
        _check(_lib().hh_session_set_feedback_groups(self._handle, len(groups), _ptr(groups, ctypes.c_int), n))
        self._n_groups = n

    @property
    def _groups(self) -> int:
        """How many feedback groups set_feedback_groups set (0: none)."""
        return getattr(self, "_n_groups", 0)

    def frame_bones(self) -> dict:
        """The fetched frame's bones: handles, proxies and devices (B, 7) (position, quaternion),
        feedback (B, 6)."""
        b = self.n_bones
        out = {name: np.empty((b, 7)) for name in ("handles", "proxies", "devices")}
        out["feedback"] = np.empty((b, 6))
        _check(_lib().hh_session_frame_bones(self._handle, b, *(_ptr(out[k]) for k in ("handles", "proxies", "devices",
                                                                                      "feedback"))))
        return out

    def frame_groups(self) -> np.ndarray:
        """The fetched frame's feedback per group (G, 6)."""
        out = np.empty((self._groups, 6))
        _check(_lib().hh_session_frame_groups(self._handle, self._groups, _ptr(out) if self._groups else None))
        return out

    def bone_coupling_model(self) -> tuple[np.ndarray, np.ndarray, int]:
        """The fetched frame's bones' model: wrench (6B,), stiffness (6B, 6B), held contact rows."""
        b = self.n_bones
        w, k, held = np.empty(6 * b), np.empty((6 * b, 6 * b)), ctypes.c_int()
        _check(_lib().hh_session_bone_coupling_model(self._handle, b, _ptr(w), _ptr(k), ctypes.byref(held)))
        return w, k, held.value
