"""Haptic sessions from a scene (docs/haptics.md): the native visual and haptic loops around
the scene's world, its device chosen by name, and what a host (the Blender add-on, a script)
reads back: frames of deformed surfaces and the haptic log.

    s = LiveSession(scene, device="simulated")
    s.start()
    while s.running:
        frame = s.poll()          # newest visual frame, or None; never blocks
        ...
    s.stop()
    log = s.haptic_log()          # numpy arrays, one row per haptic step
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from . import devices, glove
from . import native_world, params, scene_feedback
from . import scene as scenes
from .native_session import LOG_COLUMNS, NativeSession, log_arrays
from .scene_world import build_world


def create(world, hand: int, scene: scenes.Scene, log_capacity: int = 1 << 16) -> NativeSession:
    """The native session of a scene's world with the scene's haptics settings."""
    return NativeSession(world, hand, log_capacity=log_capacity,
                         **scene.struct_values(params.STRUCT_SESSION_PARAMS))


def attach_device(session: NativeSession, scene: scenes.Scene, model, name: str | None = None):
    """Gives the session the device named in the scene (or `name`); returns a host-side helper
    that must be stopped with the session (the HID reader), or None. A skeleton hand's is a glove
    of one frame per bone, or with skeleton.root_device this one-frame device on the wrist with
    the other bones posed on it (glove.py)."""
    h = scene.data["haptics"]
    kind, _, arg = str(name or h["device"]).partition(":")
    fail_at = math.inf if h["fail_at"] is None else float(h["fail_at"])
    if scene.skeleton is not None and session.n_bones > 1:
        scene_feedback.check_glove_session(kind, scene.skeleton, scene.feedback.mode)
        if not scene.skeleton.root_device:
            glove.attach(session, scene, model, kind, fail_at)
            return None
        glove.pose_fingers(session, scene, model)  # the device below drives the wrist and carries them
    elif scene.skeleton is not None and kind == "simulated":
        glove.attach(session, scene, model, kind, fail_at)
        return None
    handle_com = np.array(model.info()["handle_com"])
    if kind == "simulated":
        traj = scene.trajectory(handle_com)
        arm = h["arm"]
        session.device_simulated(traj.times, traj.positions, traj.quaternions, arm["mass"], arm["stiffness"],
                                 arm["damping"], fail_at)
        return None
    if kind == "playback":
        if not arg:
            raise devices.DeviceError("playback needs a file: device 'playback:<path to .csv or .npz>'")
        path = scene.base_dir / arg
        t, p, q = devices.load_recording(path)
        session.device_playback(t, p, q, fail_at)
        return None
    if kind == "openhaptics":
        oh = h["openhaptics"]
        session.device_openhaptics(oh["library"] or devices.OPENHAPTICS_LIBRARY, oh["workspace_scale"], handle_com,
                                   min(3.3, h["max_force"]))
        return None
    if kind == "hid":
        found = devices.hid_devices()
        path = arg.encode() if arg else (found[0]["path"] if found else None)
        if path is None:
            raise devices.DeviceError("no 3Dconnexion HID device is connected: plug one in, or choose another device")
        session.device_external(h["external_timeout"])
        return devices.HidSpaceMouse(path, session.push_device_pose, handle_com)
    if kind == "external":
        session.device_external(h["external_timeout"])
        return None
    raise devices.DeviceError(f"unknown device '{kind}': use simulated, playback:<file>, openhaptics, hid or external")


@dataclass
class Frame:
    """One visual-loop frame of a live session (SI units, quaternions (x, y, z, s))."""
    time: float
    visual_steps: int
    surfaces: dict = field(default_factory=dict)  # name -> (n, 3) render-surface vertices (hand, soft bodies)
    poses: dict = field(default_factory=dict)     # name -> (7,) centre and quaternion (rigid, kinematic)
    handle_position: np.ndarray = None
    handle_quaternion: np.ndarray = None
    device_position: np.ndarray = None
    device_quaternion: np.ndarray = None
    proxy_position: np.ndarray = None
    proxy_quaternion: np.ndarray = None
    force: np.ndarray = None
    torque: np.ndarray = None
    contacts: int = 0


class LiveSession:
    """A scene simulated live: the visual loop and the haptic loop on their own native threads,
    paced by the wall clock. The host never steps the simulation; it polls frames."""

    def __init__(self, scene: scenes.Scene, device: str | None = None, haptic_rate: float | None = None,
                 progress=None):
        if haptic_rate is not None:
            scene.data["haptics"]["rate"] = float(haptic_rate)
        self.world, self.hand, self.model, others, _ = build_world(scene, progress=progress)
        self.native = create(self.world, self.hand, scene)
        self._helper = attach_device(self.native, scene, self.model, device)
        self.body_names = ["hand"] + [b.name for b in others]
        self._index = {"hand": self.hand, **{b.name: b.index for b in others}}
        self._kinds = {name: self.world.body_kind(i) for name, i in self._index.items()}
        self._log = []
        self.error: str | None = None

    @property
    def running(self) -> bool:
        st = self.native.status()
        if st["failed"]:
            self.error = st["message"]
        if self._helper is not None and getattr(self._helper, "error", None):
            self.error = self._helper.error
            return False
        return st["running"] and not st["failed"]

    def start(self) -> None:
        self.native.start()

    def set_device_pose(self, position, quaternion=(0.0, 0.0, 0.0, 1.0)) -> None:
        """For the 'external' device: where the device (e.g. Blender's target empty) is now."""
        self.native.push_device_pose(position, quaternion)

    def _drain_log(self) -> None:
        rows = self.native.read_log()
        if len(rows):
            self._log.append(rows)

    def poll(self) -> Frame | None:
        """The newest visual frame since the last poll, or None. Never blocks."""
        self._drain_log()
        if not self.native.fetch_frame():
            return None
        fi = self.native.frame_info
        f = Frame(time=fi.time, visual_steps=int(fi.visual_steps))
        for name, i in self._index.items():
            kind, _, n_surface = self._kinds[name]
            if kind in (native_world.HAND, native_world.SOFT):
                f.surfaces[name] = self.native.frame_surface(i, n_surface)
            elif kind in (native_world.RIGID, native_world.KINEMATIC, native_world.STATIC):
                f.poses[name] = self.native.frame_pose(i)
        handle, proxy, dev = (np.array(fi.handle), np.array(fi.proxy), np.array(fi.device))
        f.handle_position, f.handle_quaternion = handle[:3], handle[3:]
        f.proxy_position, f.proxy_quaternion = proxy[:3], proxy[3:]
        f.device_position, f.device_quaternion = dev[:3], dev[3:]
        fb = np.array(fi.feedback)
        f.force, f.torque = fb[:3], fb[3:]
        f.contacts = fi.contacts
        return f

    def stop(self) -> None:
        """Joins the loops; never raises. The last frame and the log so far stay readable."""
        try:
            if self._helper is not None:
                self._helper.stop()
            self.native.stop()
            self._drain_log()
            st = self.native.status()
            if st["failed"]:
                self.error = st["message"]
        except Exception as e:  # stopping must never take the host down
            self.error = self.error or f"stopping the session failed: {e}"

    def haptic_log(self) -> dict:
        """The haptic log so far: t, period, cost (s), device/proxy position and quaternion,
        force (N) and torque (N m), one row per haptic step."""
        self._drain_log()
        rows = np.concatenate(self._log) if self._log else np.empty((0, LOG_COLUMNS))
        return log_arrays(rows)
