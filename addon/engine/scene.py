"""The JSON scene format (docs/scene_format.md): reading, validation with messages that name
the field and the fix, and turning a scene into a ready HandModel.

Distances in metres, times in seconds, quaternions (x, y, z, s).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

from . import bodies as bodies_module
from . import mesh as meshing
from . import native, params, quaternion

DEVICES = ("simulated", "playback", "openhaptics", "hid", "external")

class SceneError(ValueError):
    """A scene file that cannot be used; the message names the field and the fix."""


@lru_cache(maxsize=None)
def _defaults() -> str:
    return json.dumps(params.defaults())


def defaults() -> dict:
    """The scene's defaults (a fresh copy), from the parameter table."""
    return json.loads(_defaults())


def format_name() -> str:
    return json.loads(params.by_json("format").text)


def _merge(defaults: dict, given: dict, where: str) -> dict:
    out = dict(defaults)
    for key, value in given.items():
        if key not in defaults:
            raise SceneError(f"unknown field '{where}{key}'; known fields here: {', '.join(defaults)}")
        if isinstance(defaults[key], dict) and isinstance(value, dict):
            out[key] = _merge(defaults[key], value, f"{where}{key}.")
        elif isinstance(defaults[key], dict):
            raise SceneError(f"{where}{key} = {json.dumps(value)} is invalid: it must be an object with the fields "
                             f"{', '.join(defaults[key])}")
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
        return p, quaternion.slerp(self.quaternions[k], self.quaternions[k + 1], a)

    def velocity(self, t: float, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """Linear and angular velocity over [t - dt, t] (the step that ends at t)."""
        p1, q1 = self.pose(t)
        p0, q0 = self.pose(t - dt)
        return (p1 - p0) / dt, quaternion.rotation_vector(quaternion.multiply(q1, quaternion.conjugate(q0))) / dt


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
        """The hand rig's parameters (hh_params) by C name, from the scene."""
        out = self.struct_values(params.STRUCT_PARAMS)
        out["palm_seed"] = self.palm_seed()
        return out

    def struct_values(self, struct_id: int) -> dict:
        """The fields of a C parameter struct by C name, from the scene (enums as indices)."""
        out = {}
        for p in params.structure(struct_id).rows:
            if p.flags & params.INTERNAL:
                continue
            value = params.get(self.data, p)
            if value is not None:
                out[p.name] = [float(v) for v in value] if p.count > 1 else p.to_number(value)
        return out

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


def __getattr__(name: str):
    if name == "FORMAT":  # the format's name, from the table
        return format_name()
    raise AttributeError(name)


def check_fields(data: dict, body: bool = False, where=None) -> None:
    """Every table field of a scene (or of one body, body=True) against its JSON type and range;
    `where` turns a field's path into the name the message gives."""
    for p in params.table():
        if p.body == body and not p.flags & params.INTERNAL:
            try:
                params.check(p, params.get(data, p), where(p) if where else None)
            except params.ParamError as e:
                raise SceneError(str(e)) from None


def _check_haptics(scene: "Scene") -> None:
    """The haptic loop's settings as the library checks them when a session starts."""
    from . import native_session

    values = scene.struct_values(params.STRUCT_SESSION_PARAMS)
    try:
        native_session.check_params(**values)
    except native.InvalidInput as e:
        raise SceneError(str(e)) from None


def from_dict(data: dict, base_dir: Path | str = ".") -> Scene:
    if not isinstance(data, dict):
        raise SceneError("a scene is a JSON object")
    if "format" not in data:
        raise SceneError(f'the scene has no "format": add "format": "{format_name()}" (docs/scene_format.md)')
    merged = _merge(defaults(), data, "")
    if merged["format"] != format_name():
        raise SceneError(f"format {merged['format']!r} is not supported: this version reads '{format_name()}'")
    check_fields(merged)
    scene = Scene(merged, Path(base_dir))
    if merged["haptics"]["enabled"]:
        _check_haptics(scene)
    name = merged["haptics"]["device"]
    if name.split(":", 1)[0] not in DEVICES:
        raise SceneError(f"haptics.device '{name}' is unknown: use {', '.join(DEVICES)} (playback:<file>)")
    try:
        parsed = bodies_module.parse(merged["bodies"], Path(base_dir))
    except bodies_module.BodyError as e:
        raise SceneError(str(e)) from None
    scene.bodies = parsed
    return scene


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
