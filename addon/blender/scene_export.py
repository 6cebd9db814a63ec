"""Blender scene -> the engine's scene (haptic_hand.engine.scene.Scene).

Everything the engine gets is in metres, world space, as the objects stand at the first
frame of the range; meshes are triangulated by Blender's loop triangulation, which keeps the
vertex order, so results map back onto the same vertices. Modifiers and shape keys are not
applied: the engine sees each object's base mesh.

The export is also written as a standalone scene folder (scene.json, one .obj per mesh, one
.npz per tet mesh, docs/scene_format.md) so the command line can replay it:
`python -m haptic_hand simulate <folder>/scene.json --out result.npz`.
"""

from __future__ import annotations

import json
import re
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import bpy
import numpy as np

from ..engine import mesh as meshing
from ..engine import native, native_world
from ..engine import devices, params
from ..engine import scene as scenes
from . import armature, armature_motion, meshdata, param_props
from .hand_source import ExportError, check_hand, hand_tets_world, seed_world

# Blender's roles as the scene file's body types
BODY_TYPES = {"SOFT": "soft", "RIGID": "rigid", "MOVING": "kinematic", "STATIC": "static", "PLANE": "plane"}
# Blender's device menu as the scene file's haptics.device (PLAYBACK and HID add their source)
DEVICE_NAMES = devices.MENU_NAMES


def device_to_scene(s) -> str:
    """haptics.device from the Device menu (a playback's recording as an absolute path)."""
    name = DEVICE_NAMES[s.device]
    if s.device == "PLAYBACK" and s.device_file:
        return f"{name}:{bpy.path.abspath(s.device_file)}"
    if s.device == "HID" and s.hid_device not in ("", "NONE"):
        return f"{name}:{s.hid_device}"
    return name


def device_from_scene(s, name: str) -> None:
    """The Device menu from haptics.device."""
    kind, _, arg = name.partition(":")
    s.device = {v: k for k, v in DEVICE_NAMES.items()}[kind]
    if kind == "playback":
        s.device_file = arg
    elif kind == "hid":
        s.hid_path = arg


@dataclass
class BodyLink:
    name: str          # engine body name (the object's name)
    obj: object        # bpy.types.Object
    role: str          # SOFT, RIGID, MOVING, STATIC, PLANE
    rest_matrix: np.ndarray = None


@dataclass
class Export:
    scene: scenes.Scene
    hand: object
    hand_rest_matrix: np.ndarray
    bodies: list = field(default_factory=list)
    scale: float = 1.0
    frame_start: int = 1
    frame_end: int = 1
    fps: float = 30.0
    folder: Path = None
    handle_rest_com: np.ndarray = None   # m, filled by handle_com()
    target_rest: tuple = None            # (position m, quaternion) of the target at frame_start
    # the hand object's world matrix at every frame of the range when it moves (a hand parented
    # to its moving armature), else None: a bake's meshes are written in the frame's own space
    hand_matrices: np.ndarray = None

    def cleanup(self) -> None:
        if self.folder is not None:
            shutil.rmtree(self.folder, ignore_errors=True)
            self.folder = None


def fps(scene) -> float:
    return scene.render.fps / scene.render.fps_base


def rest_matrix(obj) -> np.ndarray:
    """obj's world matrix; for a rigid body whose transform a bake keyed, where it stood
    before the bake (the keyed motion is the bake's, not the scene's)."""
    o = obj.haptic_hand
    if o.baked and o.bake_keyed_transform:
        return np.array(o.rest_matrix, dtype=np.float64).reshape(4, 4).T
    return meshdata.matrix(obj)


def rest_vertices(obj, scene) -> np.ndarray:
    """obj's mesh (no modifiers, no shape keys) in metres, world space, at its rest_matrix."""
    return meshdata.transform(rest_matrix(obj), meshdata.local_vertices(obj.data)) * meshdata.unit_scale(scene)


def _objects_with_roles(scene):
    out = []
    for obj in sorted(scene.objects, key=lambda o: o.name):
        role = obj.haptic_hand.role
        if role in ("NONE", "HAND") or obj.haptic_hand.is_tet_mesh or obj == scene.haptic_hand.hand:
            continue
        out.append((obj, role))
    return out


def check_seed(scene, nodes, tets, scale_warning: str | None = None) -> np.ndarray:
    """The seed (m) if it lies inside the hand's tets and the handle catches a usable number
    of nodes; else ExportError with the fix (and the hand's scale warning, the likely cause
    of a handle that catches too few)."""
    s = scene.haptic_hand
    seed = seed_world(scene)
    tet_index, weights = meshing.embed_points(nodes, tets, seed[None])
    if weights.min() < -1e-9:
        # distance outside the nearest tet, for the message
        corners = nodes[tets[tet_index[0]]]
        gap = np.linalg.norm(seed - corners.mean(axis=0)) - np.linalg.norm(corners - corners.mean(0), axis=1).max()
        raise ExportError(
            f"The palm seed '{s.seed.name}' is outside the hand's tet mesh (about {max(gap, 0) * 1000:.0f} mm out): "
            "move it inside the palm, or press Place Seed to snap it in")
    try:
        native.check_handle(nodes, seed, s.handle_radius_si)
    except native.InvalidInput as e:
        cause = f"; {scale_warning}" if scale_warning else ""
        raise ExportError(f"The palm seed '{s.seed.name}': {e} (Haptic Hand > Rig > Handle radius){cause}") from None
    return seed


def _write_obj(folder: Path, name: str, v: np.ndarray, f: np.ndarray) -> str:
    fname = f"{_safe(name)}.obj"
    meshing.save_obj(folder / fname, v, f)
    return fname


def _write_tets(folder: Path, name: str, nodes: np.ndarray, tets: np.ndarray) -> str:
    fname = f"{_safe(name)}_tets.npz"
    np.savez(folder / fname, nodes=nodes, tets=tets)
    return fname


def _safe(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in name)


def _relative_motion(m_t: np.ndarray, m_0: np.ndarray) -> np.ndarray:
    """The rigid motion taking the frame at m_0 to m_t (scale removed), as a 4x4 matrix."""
    def unscaled(m):
        r = m[:3, :3] / np.linalg.norm(m[:3, :3], axis=0)
        out = np.eye(4)
        out[:3, :3], out[:3, 3] = r, m[:3, 3]
        return out
    return unscaled(m_t) @ np.linalg.inv(unscaled(m_0))


def _kinematic_centre(v: np.ndarray, f: np.ndarray, kind: int = native_world.KINEMATIC) -> np.ndarray:
    """Where the engine puts a mesh body's centre (its pose origin), asked from the engine."""
    world = native_world.World()
    index = world.add_mesh_body(kind, v, f)
    return np.array(world.pose(index)[0])


def export(context, frame_start: int | None = None, frame_end: int | None = None) -> Export:
    """The engine scene of the Blender scene over [frame_start, frame_end] (default: the bake
    range). Leaves the Blender scene as it was (the current frame is restored)."""
    bscene = context.scene
    s = bscene.haptic_hand
    f0 = s.bake_frame_start if frame_start is None else int(frame_start)
    f1 = s.bake_frame_end if frame_end is None else int(frame_end)
    if f1 <= f0:
        raise ExportError(f"The frame range {f0}-{f1} is empty: set End after Start in Haptic Hand > Bake")
    rate = fps(bscene)
    scale = meshdata.unit_scale(bscene)
    hand, tet_obj, seed_obj = check_hand(bscene, need_seed=s.armature is None)
    if hand.data.shape_keys is not None and not hand.haptic_hand.baked:
        raise ExportError(f"The hand '{hand.name}' has shape keys: the engine uses the base mesh; remove them "
                          "(Object Data > Shape Keys) or apply them first")
    folder = Path(tempfile.mkdtemp(prefix="haptic_hand_scene_"))
    current = bscene.frame_current
    try:
        bscene.frame_set(f0)
        out = _export_at_start(context, bscene, s, hand, tet_obj, f0, f1, rate, scale, folder)
    except Exception:
        shutil.rmtree(folder, ignore_errors=True)
        raise
    finally:
        bscene.frame_set(current)
    return out


def _export_at_start(context, bscene, s, hand, tet_obj, f0, f1, rate, scale, folder) -> Export:
    nodes, tets = meshdata.read_tets(tet_obj)
    nodes = meshdata.transform(meshdata.matrix(tet_obj), nodes) * scale
    surface = meshdata.world_vertices(hand, bscene)
    faces = meshdata.triangles(hand.data)
    try:
        meshing.check_closed_surface(surface, faces)
    except meshing.MeshError as e:
        raise ExportError(f"The hand '{hand.name}': {e}") from None
    scale_warning = meshing.scale_warning(surface, "hand")
    if s.armature is None:
        seed = check_seed(bscene, nodes, tets, scale_warning).tolist()
    else:  # the bones hold the hand; a seed there is kept, unchecked
        seed = seed_world(bscene).tolist() if s.seed is not None else None

    data = {"format": scenes.format_name(), "bodies": []}
    try:
        param_props.to_scene(s, data, params.UI_SCENE)
    except param_props.SettingError as e:
        raise ExportError(str(e)) from None
    param_props.to_scene(hand.haptic_hand, data, params.UI_OBJECT, prefix="hand.")
    data["hand"].update(mesh=_write_obj(folder, "hand", surface, faces), tets=_write_tets(folder, "hand", nodes, tets),
                        palm_seed=seed, skeleton=skeleton_bones(bscene, nodes, scale_warning))
    data.update(dt=1.0 / rate, frames=f1 - f0,
                gravity=[param_props.decimal(g) for g in bscene.gravity] if bscene.use_gravity else [0.0, 0.0, 0.0])
    data["haptics"]["device"] = device_to_scene(s)
    links, moving = [], []
    for obj, role in _objects_with_roles(bscene):
        o = obj.haptic_hand
        link = BodyLink(obj.name, obj, role, rest_matrix(obj))
        if role == "PLANE":
            m = link.rest_matrix
            normal = m[:3, 2] / np.linalg.norm(m[:3, 2])
            spec = {"name": obj.name, "type": "plane", "point": (m[:3, 3] * scale).tolist(), "normal": normal.tolist()}
            param_props.to_scene(o, spec, params.UI_OBJECT, body_type="plane")
            data["bodies"].append(spec)
            links.append(link)
            continue
        if obj.type != "MESH":
            raise ExportError(f"'{obj.name}' is marked as {role.lower()} but is not a mesh: mark a mesh object, "
                              "or set its role to None")
        v, f = rest_vertices(obj, bscene), meshdata.triangles(obj.data)
        if len(f) == 0:
            raise ExportError(f"'{obj.name}' has no faces: give it a closed mesh or set its role to None")
        spec = {"name": obj.name, "type": BODY_TYPES[role], "mesh": _write_obj(folder, obj.name, v, f)}
        param_props.to_scene(o, spec, params.UI_OBJECT, body_type=spec["type"])
        if role == "SOFT":
            if obj.data.shape_keys is not None and not o.baked:
                raise ExportError(f"The soft body '{obj.name}' has shape keys: remove or apply them first")
            if not meshdata.has_tets(o.tet_object):
                raise ExportError(f"The soft body '{obj.name}' has no tet mesh: select it and press Tetrahedralize")
            bn, bt = meshdata.read_tets(o.tet_object)
            bn = meshdata.transform(meshdata.matrix(o.tet_object), bn) * scale
            spec["tets"] = _write_tets(folder, obj.name, bn, bt)
        elif role == "MOVING":
            moving.append((spec, link, _kinematic_centre(v, f)))
        data["bodies"].append(spec)
        links.append(link)

    # Sample the animated target, moving colliders and the armature at every frame of the range.
    target = s.target
    frames = list(range(f0, f1 + 1))
    times = [(f - f0) / rate for f in frames]
    target_m, moving_m, hand_m = [], [[] for _ in moving], []
    poses = pose_sampler(bscene, data)
    for f in frames:
        if target is not None or moving or s.armature is not None:
            bscene.frame_set(f)
        if target is not None:
            target_m.append(meshdata.matrix(target))
        for i, (_, link, _) in enumerate(moving):
            moving_m[i].append(meshdata.matrix(link.obj))
        if poses is not None:
            poses.sample(context.evaluated_depsgraph_get())
        hand_m.append(meshdata.matrix(hand))
    bscene.frame_set(f0)
    if poses is not None:
        data["skeleton"]["targets"] = poses.targets(times)
    trajectory, target_rest = [], None
    if target is not None:
        m0 = target_m[0]
        target_rest = (m0[:3, 3] * scale, meshdata.quaternion_xyzs(m0))
        for t, m in zip(times, target_m):
            rel = _relative_motion(m, m0)
            trajectory.append({"t": t, "position": ((m[:3, 3] - m0[:3, 3]) * scale).tolist(),
                               "quaternion": meshdata.quaternion_xyzs(rel).tolist()})
    else:
        trajectory.append({"t": 0.0, "position": [0.0, 0.0, 0.0], "quaternion": [0.0, 0.0, 0.0, 1.0]})
    data["device"].update(frame="handle_rest", trajectory=trajectory)
    for (spec, link, c0), mats in zip(moving, moving_m):
        points = []
        for t, m in zip(times, mats):
            rel = _relative_motion(m, mats[0])
            c = meshdata.transform(rel, (c0 / scale)[None])[0] * scale
            points.append({"t": t, "position": (c - c0).tolist(), "quaternion": meshdata.quaternion_xyzs(rel).tolist()})
        spec["trajectory"] = points

    (folder / "scene.json").write_text(json.dumps(data, indent=1))
    try:
        engine_scene = scenes.from_dict(data, folder)
    except scenes.SceneError as e:
        raise ExportError(in_blender_terms(str(e))) from None
    engine_scene.surface_vertices, engine_scene.surface_faces = surface, faces
    engine_scene.warnings += [scale_warning] if scale_warning else []
    engine_scene.nodes, engine_scene.tets = nodes, tets
    moves = any(not np.allclose(m, hand_m[0], rtol=0, atol=1e-9) for m in hand_m)
    return Export(engine_scene, hand, meshdata.matrix(hand), links, scale, f0, f1, rate, folder,
                  target_rest=target_rest, hand_matrices=np.array(hand_m) if moves else None)


def skeleton_bones(bscene, nodes: np.ndarray, scale_warning: str | None) -> list | None:
    """hand.skeleton from the armature (None without one); ExportError naming the first problem
    (Check Rig lists them all)."""
    if bscene.haptic_hand.armature is None:
        return None
    try:
        rig = armature.rig(bscene, nodes)
    except armature.RigError as e:
        raise ExportError(str(e)) from None
    if rig.problems:
        more = f" ({len(rig.problems) - 1} more problem(s): Check Rig lists them)" if len(rig.problems) > 1 else ""
        cause = f"; {scale_warning}" if scale_warning else ""
        raise ExportError(f"The skeleton: {rig.problems[0]}{more}{cause}")
    return rig.specs()


def pose_sampler(bscene, data: dict) -> armature_motion.PoseSampler | None:
    """What samples the armature's pose into skeleton.targets; None without an armature or when a
    tracking stream drives the bones instead."""
    s = bscene.haptic_hand
    bones = data["hand"]["skeleton"]
    if s.armature is None or data["skeleton"]["tracking"] is not None:
        return None
    return armature_motion.PoseSampler(s.armature, [b["name"] for b in bones], [b["parent"] for b in bones],
                                       meshdata.unit_scale(bscene))


def in_blender_terms(message: str) -> str:
    """A scene file's message about a field Blender derives from the scene itself (dt from the
    frame rate, gravity, ...), with where that value comes from in Blender, as the field's row of
    the parameter table says: the engine checks the value, the user fixes it in Blender."""
    path = re.sub(r"\[\d+\]", "[]", message.split(" = ", 1)[0])
    try:
        p = params.by_json(path)
    except KeyError:
        return message
    if not p.flags & params.UI_DERIVED or "in Blender, " not in p.description:
        return message
    return f"{message} (in Blender, {p.description.split('in Blender, ', 1)[1]})"


def handle_com(export: Export) -> np.ndarray:
    """The handle's rest centre of mass (m), as the engine computes it."""
    if export.handle_rest_com is None:
        model = scenes.build_model(export.scene)
        export.handle_rest_com = np.array(model.info()["handle_com"])
    return export.handle_rest_com
