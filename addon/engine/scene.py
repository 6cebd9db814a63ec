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
#: The least slack a surface has outside its stored tets, as a fraction of their diagonal
#: (the paper's 271-tet bunny cage lies within 0.33% of its bunny).
EMBEDDING_SLACK = 0.01
HAPTIC_LOG_COLUMNS = 23  # HH_LOG_COLUMNS

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


def timed_poses(points, where: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(times, positions, unit quaternions) of a JSON list of {t, position, quaternion} objects;
    SceneError naming `where` (e.g. device.trajectory) for anything else."""
    shape = f"{where} must be a non-empty list of {{t, position, quaternion}} objects"
    if not isinstance(points, list) or not points:
        raise SceneError(f"{shape}, got {json.dumps(points)[:60]}")
    for i, p in enumerate(points):
        if not isinstance(p, dict):
            raise SceneError(f"{where}[{i}] = {json.dumps(p)[:60]} is not an object: give each point as "
                             "{\"t\": seconds, \"position\": [x, y, z], \"quaternion\": [x, y, z, s]}")
        unknown = set(p) - {"t", "position", "quaternion"}
        if unknown:
            raise SceneError(f"{where}[{i}] has unknown fields {', '.join(sorted(unknown))}: use t, position, quaternion")
        t = p.get("t")
        if isinstance(t, bool) or not isinstance(t, (int, float)) or not math.isfinite(t):
            raise SceneError(f"{where}[{i}].t = {json.dumps(t)} is invalid: it must be a finite number of seconds")
    times = np.array([float(p["t"]) for p in points])
    if np.any(np.diff(times) <= 0):
        k = int(np.argmax(np.diff(times) <= 0)) + 1
        raise SceneError(f"{where} times 't' must increase strictly: point {k} has t = {times[k]:g} s after "
                         f"{times[k - 1]:g} s")
    pos = np.array([_vector(p.get("position", [0, 0, 0]), 3, f"{where}[{i}].position") for i, p in enumerate(points)])
    quat = np.array([_vector(p.get("quaternion", [0, 0, 0, 1]), 4, f"{where}[{i}].quaternion")
                     for i, p in enumerate(points)])
    norms = np.linalg.norm(quat, axis=1)
    if np.any(norms < 1e-9):
        k = int(np.argmax(norms < 1e-9))
        raise SceneError(f"{where}[{k}].quaternion is zero: use (x, y, z, s) with s = 1 for no rotation")
    return times, pos, quat / norms[:, None]


def body_trajectory(spec: dict, start: np.ndarray) -> Trajectory:
    """A kinematic body's script: timed offsets of its centre from where it starts."""
    points = spec["trajectory"] or [{"t": 0.0, "position": [0, 0, 0], "quaternion": [0, 0, 0, 1]}]
    times, pos, quat = timed_poses(points, f"body '{spec['name']}': trajectory")
    return Trajectory(times, pos + start, quat)


@dataclass
class Scene:
    data: dict
    base_dir: Path
    bodies: list = field(default_factory=list)
    surface_vertices: np.ndarray = field(default=None, repr=False)
    surface_faces: np.ndarray = field(default=None, repr=False)
    nodes: np.ndarray = field(default=None, repr=False)
    tets: np.ndarray = field(default=None, repr=False)
    # what is suspicious but not refused (a hand far outside the human size range): shown by the
    # command line, check-rig and Blender
    warnings: list = field(default_factory=list)

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
        times, pos, quat = timed_poses(dev["trajectory"], "device.trajectory")
        if dev["frame"] == "handle_rest":
            pos = pos + handle_rest_com
        elif dev["frame"] != "world":
            raise SceneError(f"device.frame '{dev['frame']}' is unknown: use 'handle_rest' or 'world'")
        return Trajectory(times, pos, quat)


def _vector(value, n: int, name: str) -> np.ndarray:
    numbers = isinstance(value, (list, tuple)) and all(
        isinstance(x, (int, float)) and not isinstance(x, bool) for x in value)
    if not numbers:
        raise SceneError(f"{name} must be a list of {n} numbers, got {json.dumps(value, default=str)[:60]}")
    v = np.asarray(value, dtype=np.float64)
    if v.shape != (n,) or not np.all(np.isfinite(v)):
        raise SceneError(f"{name} must be {n} finite numbers, got {json.dumps(value, default=str)[:60]}")
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
        raise SceneError(f"the scene is {json.dumps(data)[:40]}, not a JSON object: a scene file holds one object, "
                         f'{{"format": "{format_name()}", "hand": {{...}}, ...}} (docs/scene_format.md)')
    if "format" not in data:
        raise SceneError(f'the scene has no "format": add "format": "{format_name()}" (docs/scene_format.md)')
    merged = _merge(defaults(), data, "")
    if merged["format"] != format_name():
        raise SceneError(f"format {merged['format']!r} is not supported: this version reads '{format_name()}'")
    check_fields(merged)
    timed_poses(merged["device"]["trajectory"], "device.trajectory")
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
    if path.is_dir():
        found = sorted(p.name for p in path.glob("*.json"))[:3]
        raise SceneError(f"scene file {path} is a directory: give the path of a scene .json file"
                         + (f" (it holds {', '.join(found)})" if found else ""))
    try:
        data = json.loads(path.read_text(encoding="utf-8-sig"))  # a BOM (Notepad) is allowed
    except FileNotFoundError:
        raise SceneError(f"scene file {path} does not exist: give the path of a scene .json file") from None
    except UnicodeDecodeError as e:
        raise SceneError(f"scene file {path} is not UTF-8 text (byte 0x{e.object[e.start]:02x} at offset {e.start}): "
                         "a scene is a JSON text file; save it as UTF-8") from None
    except OSError as e:  # permissions, a device, a broken disk
        reason = e.strerror or str(e)
        raise SceneError(f"scene file {path} cannot be read ({reason}): check that it is a readable file") from None
    except json.JSONDecodeError as e:
        raise SceneError(f"{path} is not valid JSON: {e}") from None
    return from_dict(data, path.parent)


def load_hand_geometry(scene: Scene, progress=None) -> None:
    """Fills the scene's surface and tet mesh: from stored tets when given (pytetwild is not
    deterministic, so a scene that must replay exactly stores its tets), else by
    tetrahedralizing the surface. The surface is checked either way, and stored tets must hold
    it (embedding_tolerance)."""
    hand = scene.data["hand"]
    source = hand["mesh"]
    if source == "procedural":
        v, f = meshing.procedural_hand()
    else:
        path = scene.base_dir / source
        if not path.is_file():
            raise SceneError(f"hand.mesh file {path} does not exist: give a path relative to the scene file")
        v, f = meshing.load_obj(path)
    warning = meshing.scale_warning(v, "hand")
    if warning and warning not in scene.warnings:
        scene.warnings.append(warning)
    scene.surface_vertices, scene.surface_faces = v, f
    opts = hand["tetrahedralize"]
    tets_file = hand.get("tets")
    if tets_file:  # (tetrahedralize checks the surface itself)
        meshing.check_closed_surface(v, f)
        scene.nodes, scene.tets = meshing.load_tets(scene.base_dir / tets_file, "hand.tets")
        check_embedding(scene.nodes, scene.tets, v, float(opts["epsilon"]), "the hand", "hand.tets")
        return
    scene.nodes, scene.tets = meshing.tetrahedralize(
        v, f, edge_length_fac=float(opts["edge_length_fac"]), coarsen=bool(opts["coarsen"]),
        epsilon=float(opts["epsilon"]), progress=progress)


def embedding_tolerance(nodes: np.ndarray, epsilon: float) -> float:
    """How far (m) a surface may lie outside its tets: twice the envelope pytetwild keeps at this
    epsilon, or 1% of the tets' diagonal (a coarse cage like the paper's bunny), the larger."""
    return max(2.0 * epsilon, EMBEDDING_SLACK) * float(np.linalg.norm(np.ptp(nodes, axis=0)))


def check_embedding(nodes, tets, surface, epsilon: float, who: str, field_name: str) -> tuple:
    """The surface embedded in the tets, refused when a vertex lies outside them by more than
    embedding_tolerance: the surface would ride on extrapolated weights, far from its flesh."""
    tet_index, weights, gap = meshing.embed_points(nodes, tets, surface, return_gap=True)
    tolerance = embedding_tolerance(nodes, epsilon)
    if gap.max() > tolerance:
        worst = int(np.argmax(gap))
        raise meshing.MeshError(
            f"{who}'s surface lies outside its tets ({field_name}): {int((gap > tolerance).sum())} vertices by more "
            f"than {tolerance * 1e3:.3g} mm, vertex {worst} by {gap[worst] * 1e3:.3g} mm; the tets were made for "
            "another surface or placement: tetrahedralize this surface again (or store tets made from it)")
    return tet_index, weights


def build_model(scene: Scene, progress=None) -> native.HandModel:
    if scene.nodes is None:
        load_hand_geometry(scene, progress)
    try:
        return native.HandModel(scene.nodes, scene.tets, **scene.engine_params())
    except native.InvalidInput as e:
        if scene.warnings and "node(s)" in str(e):  # a handle catching too few nodes on a hand of the wrong size
            raise native.InvalidInput(f"{e}; {scene.warnings[0]}") from None
        raise


def result_bytes(scene: Scene, n_nodes: int) -> int:
    """What a run of the scene stores in memory before it is written (bytes): every frame's node
    positions of the hand and the soft bodies, poses, and the haptic log."""
    frames = scene.frames
    per_frame = 8 * (3 * n_nodes + 7 * 3 + 6 + 14)
    for spec in scene.bodies:
        if spec["type"] == "soft" and spec["mesh"] == "box":
            per_frame += 8 * 3 * int(np.prod(np.asarray(spec["cells"]) + 1))
        else:
            per_frame += 8 * 7
    total = (frames + 1) * per_frame
    if scene.data["haptics"]["enabled"]:
        steps = max(1, round(scene.dt * scene.data["haptics"]["rate"]))
        total += (frames * steps + 1) * 8 * HAPTIC_LOG_COLUMNS * 2  # the native ring and its copy
    return total


def check_memory(scene: Scene, n_nodes: int, available: int | None = None) -> None:
    """SceneError when a run would need more memory than the machine has free, before anything
    is allocated (frames at 1e6 on a 1000-node hand is ~24 GB)."""
    need = result_bytes(scene, n_nodes)
    free = available_memory() if available is None else available
    if free is not None and need > 0.8 * free:
        per_frame = need / max(scene.frames, 1)
        raise SceneError(
            f"frames = {scene.frames} would need about {_gib(need)} of memory for the result ({n_nodes} hand nodes"
            f"{', the haptic log' if scene.data['haptics']['enabled'] else ''}) but {_gib(free)} is free: lower "
            f"frames to at most {int(0.8 * free / per_frame)}, or split the run")


def available_memory() -> int | None:
    """Free memory (bytes) as the kernel counts it (MemAvailable), None when unknown."""
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def _gib(n: float) -> str:
    return f"{n / 2**30:.1f} GiB" if n >= 2**30 else f"{n / 2**20:.0f} MiB"


def input_files(scene: Scene) -> list[tuple[str, Path]]:
    """(field, path) of every file a run of the scene reads: the meshes, stored tets and a
    playback recording (the scene file itself is the caller's)."""
    out = []
    hand = scene.data["hand"]
    if hand["mesh"] != "procedural":
        out.append(("hand.mesh", scene.base_dir / hand["mesh"]))
    if hand["tets"]:
        out.append(("hand.tets", scene.base_dir / hand["tets"]))
    for i, spec in enumerate(scene.bodies):
        mesh = spec["mesh"]
        if isinstance(mesh, str) and mesh != "box" and not mesh.startswith("procedural:"):
            out.append((f"bodies[{i}].mesh", scene.base_dir / mesh))
        if spec["tets"]:
            out.append((f"bodies[{i}].tets", scene.base_dir / spec["tets"]))
    kind, _, arg = scene.data["haptics"]["device"].partition(":")
    if kind == "playback" and arg:
        out.append(("haptics.device", scene.base_dir / arg))
    return out
