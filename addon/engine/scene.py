"""The JSON scene format (docs/scene_format.md): reading, validation with messages that name
the field and the fix, and turning a scene into a ready HandModel.

Distances in metres, times in seconds, quaternions (x, y, z, s).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

from . import bodies as bodies_module
from . import devices
from . import mesh as meshing
from . import native, native_session, native_skeleton, params, scene_feedback, scene_skeleton
from .embedding import check_embedding
from .scene_fields import SceneError, check_fields, merge, timed_poses, vector
from .trajectory import Trajectory


@lru_cache(maxsize=None)
def _defaults() -> str:
    return json.dumps(params.defaults())


def defaults() -> dict:
    """The scene's defaults (a fresh copy), from the parameter table."""
    return json.loads(_defaults())


def format_name() -> str:
    return json.loads(params.by_json("format").text)


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
    # the hand's bones and what drives them (hand.skeleton, skeleton.*); None: the palm handle
    skeleton: scene_skeleton.SceneSkeleton | None = None
    # what the haptic loop renders and a run logs (haptics.feedback, haptics.groups)
    feedback: scene_feedback.Feedback = field(default_factory=scene_feedback.Feedback)

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
        return vector(seed, 3, "hand.palm_seed")

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


def __getattr__(name: str):
    if name == "FORMAT":  # the format's name, from the table
        return format_name()
    raise AttributeError(name)


def _check_haptics(scene: "Scene") -> None:
    """The haptic loop's settings as the library checks them when a session starts."""
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
    merged = merge(defaults(), data, "")
    if merged["format"] != format_name():
        raise SceneError(f"format {merged['format']!r} is not supported: this version reads '{format_name()}'")
    check_fields(merged)
    timed_poses(merged["device"]["trajectory"], "device.trajectory")
    scene = Scene(merged, Path(base_dir))
    if merged["haptics"]["enabled"]:
        _check_haptics(scene)
    name = merged["haptics"]["device"]
    if name.split(":", 1)[0] not in devices.NAMES:
        raise SceneError(f"haptics.device '{name}' is unknown: use {', '.join(devices.NAMES)} (playback:<file>)")
    try:
        parsed = bodies_module.parse(merged["bodies"], Path(base_dir))
    except bodies_module.BodyError as e:
        raise SceneError(str(e)) from None
    scene.bodies = parsed
    scene.skeleton = scene_skeleton.parse(merged, Path(base_dir))
    scene.feedback = scene_feedback.parse(merged, scene.skeleton)
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


def build_model(scene: Scene, progress=None) -> native.HandModel:
    """The hand model: the palm handle's, or a native_skeleton.SkeletonModel for a skeleton."""
    if scene.nodes is None:
        load_hand_geometry(scene, progress)
    if scene.skeleton is not None:
        rig = scene.struct_values(params.STRUCT_PARAMS)  # (the palm seed and handle radius are not read)
        scene_skeleton.check_node_indices(scene.skeleton.skeleton, len(scene.nodes))
        try:
            return native_skeleton.SkeletonModel(scene.nodes, scene.tets, scene.skeleton.skeleton,
                                                 scene.skeleton.drive_scales, **rig)
        except native.InvalidInput as e:
            raise scene_skeleton.capture_error(e) from None
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
    if scene.skeleton is not None:  # each bone's pose, target, wrench and contact force
        b = len(scene.skeleton.skeleton)
        per_frame += 8 * b * (7 + 7 + 6 + 3)
        if scene.data["haptics"]["enabled"]:  # each bone's device frame and felt wrench, each group's
            per_frame += 8 * (b * (7 + 6) + 6 * len(scene.feedback.group_names))
    for spec in scene.bodies:
        if spec["type"] == "soft" and spec["mesh"] == "box":
            per_frame += 8 * 3 * int(np.prod(np.asarray(spec["cells"]) + 1))
        else:
            per_frame += 8 * 7
    total = (frames + 1) * per_frame
    if scene.data["haptics"]["enabled"]:
        steps = max(1, round(scene.dt * scene.data["haptics"]["rate"]))
        total += (frames * steps + 1) * 8 * native_session.LOG_COLUMNS * 2  # the native ring and its copy
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
    """(field, path) of every file a run of the scene reads: the meshes, stored tets, a tracking
    stream and a playback recording (the scene file itself is the caller's)."""
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
    if scene.data["skeleton"]["tracking"]:
        out.append(("skeleton.tracking", scene.base_dir / scene.data["skeleton"]["tracking"]))
    kind, _, arg = scene.data["haptics"]["device"].partition(":")
    if kind == "playback" and arg:
        out.append(("haptics.device", scene.base_dir / arg))
    return out
