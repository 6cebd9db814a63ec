"""The JSON scene format (docs/scene_format.md): reading, validation with messages that name
the field and the fix, and turning a scene into a ready HandModel.

Distances in metres, times in seconds, quaternions (x, y, z, s).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import bodies as bodies_module
from . import mesh as meshing
from . import native

FORMAT = "haptic_hand.scene/1"


class SceneError(ValueError):
    """A scene file that cannot be used; the message names the field and the fix."""


DEFAULTS = {
    "format": FORMAT,
    "hand": {
        "mesh": "procedural",
        "tets": None,
        "tetrahedralize": {"edge_length_fac": 0.1, "coarsen": False, "epsilon": 1e-3},
        "palm_seed": None,
        "handle_radius": 0.03,
        "friction": 0.5,
        "kinetic_friction": None,
        "self_collision": True,
    },
    "contact": {"thickness": 1e-3, "patch": 4e-3, "max_iterations": 300, "tolerance": 1e-5, "stall_factor": 4.0,
                "threads": 2},
    "bodies": [],
    "material": {"young_modulus": 5e4, "poisson_ratio": 0.3, "density": 1000.0,
                 "rayleigh_alpha": 0.0, "rayleigh_beta": 0.01},
    "springs": {"stiffness": 1e4, "damping": 10.0},
    "coupling": {"stiffness": 2e3, "damping": 20.0, "angular_stiffness": 20.0, "angular_damping": 0.2},
    "dt": 1.0 / 30.0,
    "frames": 60,
    "gravity": [0.0, 0.0, -9.81],
    "solver": {"name": "cholesky", "cg_tolerance": 1e-8, "cg_max_iterations": 5000},
    "device": {"enabled": True, "frame": "handle_rest", "trajectory": [
        {"t": 0.0, "position": [0.0, 0.0, 0.0], "quaternion": [0.0, 0.0, 0.0, 1.0]}]},
    # haptic rendering (docs/haptics.md): off, the device trajectory drives the handle through
    # the virtual coupling directly; on, a haptic loop runs a proxy handle between visual steps
    "haptics": {
        "enabled": False,
        "rate": 1000.0,          # Hz
        "linearized": True,      # False: feedback from the last visual-loop handle only
        "device": "simulated",   # simulated | playback:<file> | openhaptics | hid | external
        "arm": {"mass": 1.0, "stiffness": 300.0, "damping": 20.0},  # the simulated user's arm
        "max_force": 1e9, "max_torque": 1e9,
        "fail_at": None,         # s: the device reports a disconnection then (tests)
        "openhaptics": {"library": None, "workspace_scale": 1.0},
    },
}

MAX_COUPLING_STIFFNESS = 3e4  # N/m: the stiffest virtual coupling the haptic loop is tested at


def _merge(defaults: dict, given: dict, where: str) -> dict:
    out = dict(defaults)
    for key, value in given.items():
        if key not in defaults:
            raise SceneError(f"unknown field '{where}{key}'; known fields here: {', '.join(defaults)}")
        if isinstance(defaults[key], dict) and isinstance(value, dict):
            out[key] = _merge(defaults[key], value, f"{where}{key}.")
        else:
            out[key] = value
    return out


@dataclass
class Trajectory:
    """Timed device poses; linear in position, slerp in orientation, held at both ends."""

    times: np.ndarray
    positions: np.ndarray
    quaternions: np.ndarray

    def pose(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        k = int(np.searchsorted(self.times, t, side="right")) - 1
        if k < 0:
            return self.positions[0].copy(), self.quaternions[0].copy()
        if k >= len(self.times) - 1:
            return self.positions[-1].copy(), self.quaternions[-1].copy()
        a = (t - self.times[k]) / (self.times[k + 1] - self.times[k])
        p = (1 - a) * self.positions[k] + a * self.positions[k + 1]
        return p, slerp(self.quaternions[k], self.quaternions[k + 1], a)

    def velocity(self, t: float, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """Linear and angular velocity over [t - dt, t] (the step that ends at t)."""
        p1, q1 = self.pose(t)
        p0, q0 = self.pose(t - dt)
        return (p1 - p0) / dt, rotation_vector(quat_multiply(q1, quat_conjugate(q0))) / dt


def quat_multiply(a, b):
    av, aw, bv, bw = a[:3], a[3], b[:3], b[3]
    return np.concatenate([aw * bv + bw * av + np.cross(av, bv), [aw * bw - av @ bv]])


def quat_conjugate(q):
    return np.array([-q[0], -q[1], -q[2], q[3]])


def rotation_vector(q):
    q = q if q[3] >= 0 else -q
    vn = np.linalg.norm(q[:3])
    if vn < 1e-12:
        return 2.0 * q[:3]
    return 2.0 * math.atan2(vn, q[3]) / vn * q[:3]


def slerp(q0, q1, a):
    if q0 @ q1 < 0:
        q1 = -q1
    cos = min(1.0, float(q0 @ q1))
    angle = math.acos(cos)
    if angle < 1e-9:
        q = (1 - a) * q0 + a * q1
    else:
        q = (math.sin((1 - a) * angle) * q0 + math.sin(a * angle) * q1) / math.sin(angle)
    return q / np.linalg.norm(q)


def body_trajectory(spec: dict, start: np.ndarray) -> Trajectory:
    """A kinematic body's script: timed offsets of its centre from where it starts."""
    points = spec["trajectory"] or [{"t": 0.0, "position": [0, 0, 0], "quaternion": [0, 0, 0, 1]}]
    times = np.array([float(p.get("t", math.nan)) for p in points])
    if not np.all(np.isfinite(times)) or np.any(np.diff(times) <= 0):
        raise SceneError(f"body '{spec['name']}': trajectory times 't' must be finite and strictly increasing")
    pos = np.array([_vector(p.get("position", [0, 0, 0]), 3, f"{spec['name']}.trajectory[].position") for p in points])
    quat = np.array([_vector(p.get("quaternion", [0, 0, 0, 1]), 4, f"{spec['name']}.trajectory[].quaternion")
                     for p in points])
    return Trajectory(times, pos + start, quat / np.linalg.norm(quat, axis=1)[:, None])


@dataclass
class Scene:
    data: dict
    base_dir: Path
    bodies: list = field(default_factory=list)
    surface_vertices: np.ndarray = field(default=None, repr=False)
    surface_faces: np.ndarray = field(default=None, repr=False)
    nodes: np.ndarray = field(default=None, repr=False)
    tets: np.ndarray = field(default=None, repr=False)

    @property
    def dt(self) -> float:
        return float(self.data["dt"])

    @property
    def frames(self) -> int:
        return int(self.data["frames"])

    def palm_seed(self) -> np.ndarray:
        seed = self.data["hand"]["palm_seed"]
        if seed is None:
            if self.data["hand"]["mesh"] != "procedural":
                raise SceneError("hand.palm_seed is missing: give a point inside the palm, in metres")
            return meshing.procedural_hand_palm_seed()
        return _vector(seed, 3, "hand.palm_seed")

    def engine_params(self) -> dict:
        d = self.data
        m, s, c, solver = d["material"], d["springs"], d["coupling"], d["solver"]
        return {
            "young_modulus": m["young_modulus"], "poisson_ratio": m["poisson_ratio"],
            "density": m["density"], "rayleigh_alpha": m["rayleigh_alpha"], "rayleigh_beta": m["rayleigh_beta"],
            "palm_seed": self.palm_seed(), "handle_radius": d["hand"]["handle_radius"],
            "spring_stiffness": s["stiffness"], "spring_damping": s["damping"],
            "coupling_stiffness": c["stiffness"], "coupling_damping": c["damping"],
            "coupling_angular_stiffness": c["angular_stiffness"], "coupling_angular_damping": c["angular_damping"],
            "gravity": _vector(d["gravity"], 3, "gravity"), "dt": d["dt"],
            "solver": solver["name"], "cg_tolerance": solver["cg_tolerance"],
            "cg_max_iterations": solver["cg_max_iterations"],
        }

    def trajectory(self, handle_rest_com: np.ndarray) -> Trajectory:
        dev = self.data["device"]
        points = dev["trajectory"]
        if not isinstance(points, list) or not points:
            raise SceneError("device.trajectory must be a non-empty list of {t, position, quaternion}")
        times = np.array([float(p.get("t", math.nan)) for p in points])
        if not np.all(np.isfinite(times)) or np.any(np.diff(times) <= 0):
            raise SceneError("device.trajectory times 't' must be finite and strictly increasing")
        pos = np.array([_vector(p.get("position", [0, 0, 0]), 3, "device.trajectory[].position") for p in points])
        quat = np.array([_vector(p.get("quaternion", [0, 0, 0, 1]), 4, "device.trajectory[].quaternion")
                         for p in points])
        norms = np.linalg.norm(quat, axis=1)
        if np.any(norms < 1e-9):
            raise SceneError("a device.trajectory quaternion is zero: use (x, y, z, s) with s = 1 for no rotation")
        quat /= norms[:, None]
        if dev["frame"] == "handle_rest":
            pos = pos + handle_rest_com
        elif dev["frame"] != "world":
            raise SceneError(f"device.frame '{dev['frame']}' is unknown: use 'handle_rest' or 'world'")
        return Trajectory(times, pos, quat)


def _vector(value, n: int, name: str) -> np.ndarray:
    try:
        v = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise SceneError(f"{name} must be a list of {n} numbers, got {value!r}") from None
    if v.shape != (n,) or not np.all(np.isfinite(v)):
        raise SceneError(f"{name} must be {n} finite numbers, got {value!r}")
    return v


def _positive(value, name: str, integer: bool = False) -> None:
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value) and value > 0
    if not ok or (integer and int(value) != value):
        kind = "a positive integer" if integer else "a positive number"
        raise SceneError(f"{name} = {value!r} is invalid: it must be {kind}")


def from_dict(data: dict, base_dir: Path | str = ".") -> Scene:
    if not isinstance(data, dict):
        raise SceneError("a scene is a JSON object")
    merged = _merge(DEFAULTS, data, "")
    if merged["format"] != FORMAT:
        raise SceneError(f"format '{merged['format']}' is not supported: this version reads '{FORMAT}'")
    _positive(merged["dt"], "dt")
    _positive(merged["frames"], "frames", integer=True)
    _positive(merged["hand"]["handle_radius"], "hand.handle_radius")
    for key in ("thickness", "patch", "tolerance"):
        _positive(merged["contact"][key], f"contact.{key}")
    _positive(merged["contact"]["max_iterations"], "contact.max_iterations", integer=True)
    stall = merged["contact"]["stall_factor"]
    if not (isinstance(stall, (int, float)) and not isinstance(stall, bool) and math.isfinite(stall)
            and (stall == 0 or stall >= 1)):
        raise SceneError(f"contact.stall_factor = {stall!r} is invalid: use 0 (the sweeps go on to contact.tolerance "
                         "or contact.max_iterations) or a factor of at least 1 (default 4: they may end once within "
                         "4x the tolerance and no longer on course to reach it)")
    if isinstance(merged["contact"]["threads"], bool) or merged["contact"]["threads"] not in (1, 2):
        raise SceneError(f"contact.threads = {merged['contact']['threads']!r} is invalid: use 1 (the visual loop on "
                         "one thread) or 2 (collision detection and a share of the solves on a second one)")
    h = merged["haptics"]
    _positive(h["rate"], "haptics.rate")
    if not 100 <= h["rate"] <= 10000:
        raise SceneError(f"haptics.rate = {h['rate']} Hz is out of range: choose 100 to 10000 (1000 is usual)")
    for key in ("mass",):
        _positive(h["arm"][key], f"haptics.arm.{key}")
    _positive(h["max_force"], "haptics.max_force")
    _positive(h["max_torque"], "haptics.max_torque")
    k = merged["coupling"]["stiffness"]
    if h["enabled"] and not (isinstance(k, (int, float)) and 0 < k <= MAX_COUPLING_STIFFNESS):
        raise SceneError(f"coupling.stiffness = {k!r} N/m: with haptics on it must be in (0, "
                         f"{MAX_COUPLING_STIFFNESS:g}] N/m, the range the haptic loop is tested stable in")
    name = str(h["device"])
    if name.split(":", 1)[0] not in ("simulated", "playback", "openhaptics", "hid", "external"):
        raise SceneError(f"haptics.device '{name}' is unknown: use simulated, playback:<file>, openhaptics, "
                         "hid or external")
    try:
        parsed = bodies_module.parse(merged["bodies"], Path(base_dir))
    except bodies_module.BodyError as e:
        raise SceneError(str(e)) from None
    return Scene(merged, Path(base_dir), parsed)


def load(path: Path | str) -> Scene:
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise SceneError(f"scene file {path} does not exist") from None
    except json.JSONDecodeError as e:
        raise SceneError(f"{path} is not valid JSON: {e}") from None
    return from_dict(data, path.parent)


def load_hand_geometry(scene: Scene, progress=None) -> None:
    """Fills the scene's surface and tet mesh: from stored tets when given (pytetwild is not
    deterministic, so a scene that must replay exactly stores its tets), else by
    tetrahedralizing the surface."""
    hand = scene.data["hand"]
    source = hand["mesh"]
    if source == "procedural":
        v, f = meshing.procedural_hand()
    else:
        path = scene.base_dir / source
        if not path.is_file():
            raise SceneError(f"hand.mesh file {path} does not exist: give a path relative to the scene file")
        v, f = meshing.load_obj(path)
    scene.surface_vertices, scene.surface_faces = v, f
    tets_file = hand.get("tets")
    if tets_file:
        stored = np.load(scene.base_dir / tets_file)
        scene.nodes, scene.tets = stored["nodes"], stored["tets"]
        return
    opts = hand["tetrahedralize"]
    scene.nodes, scene.tets = meshing.tetrahedralize(
        v, f, edge_length_fac=float(opts["edge_length_fac"]), coarsen=bool(opts["coarsen"]),
        epsilon=float(opts["epsilon"]), progress=progress)


def build_model(scene: Scene, progress=None) -> native.HandModel:
    if scene.nodes is None:
        load_hand_geometry(scene, progress)
    return native.HandModel(scene.nodes, scene.tets, **scene.engine_params())
