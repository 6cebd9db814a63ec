"""Haptic devices as the user chooses them (docs/haptics.md): discovery of what is connected,
reading recorded trajectories for playback, and 3Dconnexion SpaceMouse input over HID
(decoded here, integrated into a pose and pushed to the session's external device).

HID devices are input only: there is no HID standard for force output on haptic arms."""

from __future__ import annotations

import csv
import ctypes.util
import math
import struct
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import quaternion

SPACEMOUSE_VENDORS = (0x046D, 0x256F)  # Logitech (older 3Dconnexion devices), 3Dconnexion
SPACEMOUSE_FULL_SCALE = 350.0           # a full deflection reports about +-350 on each axis
OPENHAPTICS_LIBRARY = "libHD.so"


class DeviceError(RuntimeError):
    """A device that cannot be used; the message says what to do."""


@dataclass(frozen=True)
class DeviceKind:
    """One choice of device, as every layer names it."""

    name: str         # haptics.device in the scene file (playback and hid add ":<source>")
    menu_id: str      # the identifier Blender's Device menu stores in a .blend file
    label: str
    description: str  # the menu's tooltip


# The devices a scene can name, in the order menus show them: the one list every layer uses.
KINDS = (
    DeviceKind("simulated", "SIMULATED", "Simulated", "A simulated user's arm follows the target empty's animation"),
    DeviceKind("playback", "PLAYBACK", "Playback", "Replay a recorded haptic log (.npz)"),
    DeviceKind("openhaptics", "OPENHAPTICS", "OpenHaptics",
               "Phantom Omni / Touch through OpenHaptics (libHD), when installed"),
    DeviceKind("hid", "HID", "HID device", "A 6-DoF HID input device (SpaceMouse) through hidapi"),
    DeviceKind("external", "TARGET", "Viewport target",
               "Move the target empty with the mouse; it stands for the device"),
)
NAMES = tuple(k.name for k in KINDS)
#: Blender's Device menu identifier -> the scene file's device name
MENU_NAMES = {k.menu_id: k.name for k in KINDS}


# --- discovery ---
def openhaptics_library() -> str | None:
    """Path or name of the OpenHaptics HD library when one can be loaded, else None."""
    try:
        ctypes.CDLL(OPENHAPTICS_LIBRARY)
        return OPENHAPTICS_LIBRARY
    except OSError:
        pass
    found = ctypes.util.find_library("HD")
    return found


def hid_devices() -> list[dict]:
    """6-DoF HID input devices (3Dconnexion) that hidapi can see, with a path to open."""
    try:
        import hid  # the hidapi wheel
    except ImportError:
        return []
    out = []
    for info in hid.enumerate():
        if info.get("vendor_id") in SPACEMOUSE_VENDORS:
            out.append({"path": info.get("path"), "vendor_id": info["vendor_id"], "product_id": info["product_id"],
                        "product": info.get("product_string") or "3Dconnexion device"})
    return out


def discover() -> list[dict]:
    """Every device choice with whether it can be used here and whether it displays force."""
    choices = [
        {"name": "simulated", "label": "Simulated user (arm model following the scene's trajectory)",
         "available": True, "outputs_force": True},
        {"name": "playback", "label": "Playback of a recorded trajectory file", "available": True,
         "outputs_force": False},
        {"name": "external", "label": "Viewport target (an empty you move stands for the device)",
         "available": True, "outputs_force": False},
    ]
    lib = openhaptics_library()
    choices.append({"name": "openhaptics", "label": "Touch / Phantom Omni (OpenHaptics)", "available": lib is not None,
                    "outputs_force": True,
                    "why": None if lib else "OpenHaptics (libHD.so) is not installed: install the OpenHaptics "
                                            "runtime and Touch driver from 3D Systems"})
    for d in hid_devices():
        choices.append({"name": "hid", "label": f"{d['product']} (HID, input only: no force feedback)",
                        "available": True, "outputs_force": False, "path": d["path"]})
    return choices


# --- playback files ---
def load_recording(path: Path | str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(times, positions, quaternions) from a .csv (t, x, y, z[, qx, qy, qz, qs] per line, a header
    line allowed), an .npz with arrays t/position[/quaternion], or a result file's haptic log."""
    path = Path(path)
    if not path.is_file():
        what = "is a directory" if path.is_dir() else "does not exist"
        raise DeviceError(f"playback file {path} {what}: record one, or give its full path")
    if path.suffix == ".npz":
        t, p, q = _npz_recording(path)
    else:
        rows = []
        with open(path, newline="", errors="replace") as f:
            for line in csv.reader(f):
                if not line:
                    continue
                try:
                    rows.append([float(x) for x in line])
                except ValueError:
                    if rows:
                        raise DeviceError(f"{path}: line {len(rows) + 1} is not numbers") from None
        if not rows:
            raise DeviceError(f"{path} holds no rows: record it again, or give a .csv of t, x, y, z lines")
        if len({len(r) for r in rows}) != 1 or len(rows[0]) not in (4, 8):
            raise DeviceError(f"{path}: every line must be t, x, y, z or t, x, y, z, qx, qy, qz, qs")
        a = np.array(rows)
        t, p = a[:, 0], a[:, 1:4]
        q = a[:, 4:8] if a.shape[1] == 8 else None
    if q is None:
        q = np.tile([0.0, 0.0, 0.0, 1.0], (len(t), 1))
    if len(t) < 1:
        raise DeviceError(f"{path} holds no rows: record it again")
    if p.shape != (len(t), 3) or q.shape != (len(t), 4):
        raise DeviceError(f"{path}: needs one position (3) and quaternion (4) per time, got {len(t)} times, "
                          f"positions {p.shape}, quaternions {q.shape}: record it again")
    finite = np.isfinite(t) & np.isfinite(p).all(axis=1) & np.isfinite(q).all(axis=1)
    if not finite.all():
        k = int(np.argmin(finite))
        raise DeviceError(f"{path}: times, positions and quaternions must be finite (no NaN or inf); row {k} is "
                          f"not: record it again, or remove or fix the {int((~finite).sum())} such rows")
    if np.any(np.diff(t) <= 0):
        k = int(np.argmax(np.diff(t) <= 0)) + 1
        raise DeviceError(f"{path}: times must increase strictly (row {k}: {t[k]:g} s after {t[k - 1]:g} s): sort "
                          "the rows by time and drop repeated times")
    return t, p, q


def _npz_recording(path: Path):
    import zipfile

    try:
        with np.load(path, allow_pickle=False) as data:
            if "haptic_t" in data:
                keys = ("haptic_t", "haptic_device_position", "haptic_device_quaternion")
            elif "t" in data and "position" in data:
                keys = ("t", "position", "quaternion")
            else:
                raise DeviceError(f"{path} has neither t/position arrays nor a haptic log (haptic_t ...)")
            t, p, q = (np.asarray(data[k], dtype=float) if k in data else None for k in keys)
    except DeviceError:
        raise
    except (OSError, ValueError, TypeError, EOFError, AttributeError, zipfile.BadZipFile) as e:
        raise DeviceError(f"{path} is not a readable .npz recording ({type(e).__name__}: {e}): record it again") from None
    return t.reshape(-1), p, q


# --- SpaceMouse over HID ---
@dataclass
class SpaceMouseState:
    """Latest axes (each about -1..1 of full deflection) and button bits of a SpaceMouse."""
    translation: np.ndarray = field(default_factory=lambda: np.zeros(3))
    rotation: np.ndarray = field(default_factory=lambda: np.zeros(3))
    buttons: int = 0


def decode_spacemouse_report(report: bytes | list[int], state: SpaceMouseState) -> SpaceMouseState:
    """Updates state from one HID input report. Report 1 carries translation (three little-endian
    int16), or all six axes on newer devices (13 bytes); report 2 rotation; report 3 buttons."""
    data = bytes(report)
    if not data:
        return state
    rid = data[0]
    if rid == 1 and len(data) >= 13:
        axes = struct.unpack("<6h", data[1:13])
        state.translation = np.array(axes[:3]) / SPACEMOUSE_FULL_SCALE
        state.rotation = np.array(axes[3:]) / SPACEMOUSE_FULL_SCALE
    elif rid == 1 and len(data) >= 7:
        state.translation = np.array(struct.unpack("<3h", data[1:7])) / SPACEMOUSE_FULL_SCALE
    elif rid == 2 and len(data) >= 7:
        state.rotation = np.array(struct.unpack("<3h", data[1:7])) / SPACEMOUSE_FULL_SCALE
    elif rid == 3:
        state.buttons = int.from_bytes(data[1:], "little")
    return state


# SpaceMouse axes as reported (x right, y toward the user, z down; rotations about them) to the
# scene's (x right, y away from the user, z up): a push away from you moves the hand away.
SPACEMOUSE_TO_SCENE = np.diag([1.0, -1.0, -1.0])


class SpaceMouseIntegrator:
    """A rate-controlled pose: the axes are velocities (full deflection = max_speed m/s and
    max_rate rad/s), integrated over the time between updates."""

    def __init__(self, position, quaternion=(0, 0, 0, 1), max_speed: float = 0.1, max_rate: float = 1.0):
        self.position = np.array(position, dtype=float)
        self.quaternion = np.array(quaternion, dtype=float)
        self.max_speed, self.max_rate = max_speed, max_rate

    def advance(self, state: SpaceMouseState, dt: float) -> tuple[np.ndarray, np.ndarray]:
        v = self.max_speed * (SPACEMOUSE_TO_SCENE @ state.translation)
        w = self.max_rate * (SPACEMOUSE_TO_SCENE @ state.rotation)
        self.position = self.position + dt * v
        q = quaternion.multiply(quaternion.from_rotation_vector(dt * w), self.quaternion)
        self.quaternion = q / np.linalg.norm(q)
        return self.position.copy(), self.quaternion.copy()


class HidSpaceMouse:
    """Reads a SpaceMouse on a Python thread and pushes the integrated pose to a session's
    external device. Input only. A read error (device unplugged) stops it and sets `error`."""

    def __init__(self, path, push, start_position, rate: float = 250.0):
        try:
            import hid
        except ImportError:
            raise DeviceError("the hidapi package is missing: `pip install hidapi` in Blender's Python") from None
        self._dev = hid.device()
        try:
            self._dev.open_path(path)
        except OSError as e:
            raise DeviceError(f"could not open the HID device ({e}): check it is plugged in and that you may read "
                              "/dev/hidraw* (a udev rule for 3Dconnexion devices)") from None
        self._dev.set_nonblocking(True)
        self._push = push
        self._state = SpaceMouseState()
        self._pose = SpaceMouseIntegrator(start_position)
        self._period = 1.0 / rate
        self._stop = threading.Event()
        self.error: str | None = None
        self._thread = threading.Thread(target=self._run, name="spacemouse", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        last = time.monotonic()
        try:
            while not self._stop.is_set():
                while True:
                    report = self._dev.read(64)
                    if not report:
                        break
                    decode_spacemouse_report(report, self._state)
                now = time.monotonic()
                p, q = self._pose.advance(self._state, now - last)
                last = now
                self._push(p, q)
                time.sleep(self._period)
        except (OSError, ValueError) as e:
            self.error = f"the SpaceMouse stopped answering ({e}): it was unplugged or lost power"
        finally:
            self._dev.close()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=1.0)
