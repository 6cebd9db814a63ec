"""The engine's JSON scene (docs/scene_format.md) -> Blender objects, with the add-on's settings
filled in: the hand and its stored tets, the palm seed, a target empty keyed along the device
trajectory, the bodies (soft ones with their tets, moving ones keyed along their scripts), and
a skeleton's armature (armature_build) with its targets keyed as its action.

The sample scenes of blender_scenes/ are built by this; File > Import > Haptic Hand Scene uses
it too. The Blender scene is in metres (unit scale 1) at the frame rate 1 / dt.
"""

from __future__ import annotations

from pathlib import Path

import bpy
import numpy as np

from ..engine import bodies as bodies_module
from ..engine import bone_drive, params
from ..engine import scene as scenes
from . import actions, armature_build, armature_motion, bake_store, meshdata, ops_rig, param_props, scene_export


class ImportError_(ValueError):
    """A scene that cannot be brought into Blender; the message names the problem and fix."""


def _link(context, obj):
    context.scene.collection.objects.link(obj)
    return obj


def _fcurves_of(obj):
    """The fcurves of obj's action (a new action if it has none)."""
    ad = obj.animation_data
    if ad is None or ad.action is None:
        action, slot, fcurves = actions.new_action(obj, f"{obj.name} motion")
        actions.assign_action(obj, action, slot)
        return fcurves
    if hasattr(ad.action, "slots"):
        from bpy_extras import anim_utils

        return anim_utils.action_ensure_channelbag_for_slot(ad.action, ad.action_slot).fcurves
    return ad.action.fcurves


def _keyed_motion(obj, start_location, points, rate: float, frame_start: int) -> None:
    """Key obj's location (start + offset) and quaternion at the trajectory's times."""
    obj.rotation_mode = "QUATERNION"
    frames = [frame_start + float(p.get("t", 0.0)) * rate for p in points]
    pos = np.array([p.get("position", [0, 0, 0]) for p in points], dtype=float) + start_location
    quat = np.array([p.get("quaternion", [0, 0, 0, 1]) for p in points], dtype=float)
    quat /= np.linalg.norm(quat, axis=1)[:, None]
    fcurves = _fcurves_of(obj)
    for i in range(3):
        actions.fcurve(fcurves, "location", i, frames, pos[:, i])
    wxyz = quat[:, [3, 0, 1, 2]]
    for i in range(4):
        actions.fcurve(fcurves, "rotation_quaternion", i, frames, wxyz[:, i])


def build(context, path, frame_start: int = 1) -> dict:
    """Add the scene at path to the current Blender scene; returns the objects by engine name
    ('hand', 'seed', 'target', and each body's name)."""
    path = Path(path)
    scene = scenes.load(path)
    data = scene.data
    if data["device"]["frame"] != "handle_rest":
        raise ImportError_("Only device.frame 'handle_rest' scenes can be imported: the target empty's motion "
                           "is relative to where it starts")
    bscene = context.scene
    s = bscene.haptic_hand
    rate = 1.0 / scene.dt
    bscene.unit_settings.system = "METRIC"
    bscene.unit_settings.scale_length = 1.0
    bscene.render.fps = int(round(rate))
    bscene.render.fps_base = round(rate) / rate
    bscene.frame_start, bscene.frame_end = frame_start, frame_start + scene.frames
    bscene.use_gravity = True
    bscene.gravity = data["gravity"]
    try:
        param_props.from_scene(s, data, params.UI_SCENE)
    except ValueError as e:
        raise ImportError_(str(e)) from None
    _paths_from(s, scene.base_dir)
    scene_export.device_from_scene(s, data["haptics"]["device"])

    scenes.load_hand_geometry(scene)
    objects = {}
    hand_obj = _link(context, bpy.data.objects.new("Hand", meshdata.new_mesh("Hand", scene.surface_vertices,
                                                                            scene.surface_faces)))
    hand_obj.haptic_hand.role = "HAND"
    param_props.from_scene(hand_obj.haptic_hand, data, params.UI_OBJECT, prefix="hand.")
    ops_rig.make_tet_object(context, hand_obj, scene.nodes, scene.tets)
    s.hand = hand_obj
    objects["hand"] = hand_obj
    if scene.skeleton is None or data["hand"]["palm_seed"] is not None:  # a skeleton needs no seed
        seed = _link(context, bpy.data.objects.new(ops_rig.SEED_NAME, None))
        seed.empty_display_type = "SPHERE"
        seed.parent = hand_obj
        seed.location = scene.palm_seed()
        s.seed = objects["seed"] = seed
    # the device's start: the palm seed, or a skeleton's root head (its motion is what counts)
    start = scene.palm_seed() if s.seed is not None else np.asarray(scene.skeleton.skeleton.bones[0].head, float)

    target = _link(context, bpy.data.objects.new("Device target", None))
    target.empty_display_type = "ARROWS"
    target.empty_display_size = 0.03
    _keyed_motion(target, start, data["device"]["trajectory"], rate, frame_start)
    s.target = target
    objects["target"] = target

    if scene.skeleton is not None:
        objects["armature"] = _add_armature(context, scene, hand_obj, frame_start)
    for spec in scene.bodies:
        objects[spec["name"]] = _add_body(context, spec, rate, frame_start)
    context.view_layer.update()
    ops_rig.update_captured(bscene)
    return objects


def _paths_from(s, base_dir: Path) -> None:
    """File paths of the scene's settings, which the file gives relative to itself, made
    absolute (Blender would read them relative to the .blend)."""
    for p in param_props.selected(params.UI_SCENE):
        value = getattr(s, p.name) if p.kind == params.KIND_PATH else ""
        if value and not value.startswith("//") and not Path(value).is_absolute():
            setattr(s, p.name, str((base_dir / value).resolve()))


def _add_armature(context, scene: scenes.Scene, hand_obj, frame_start: int):
    """The skeleton's armature, chosen in Rig > Skeleton, with skeleton.targets keyed as its
    action (one key per frame of the scene)."""
    rig = scene.skeleton
    obj = armature_build.new_armature(context, rig.skeleton, rig.drive_scales, hand_obj,
                                      hand_obj.haptic_hand.tet_object)
    context.scene.haptic_hand.armature = obj
    if rig.tracks:
        heads = np.array([b.head for b in rig.skeleton.bones], dtype=float)
        drive = bone_drive.BoneDrive(rig, heads, device=None, device_on=False)
        steps = np.arange(scene.frames + 1)
        armature_motion.key_targets(obj, drive, rig.skeleton, steps * scene.dt, frame_start + steps)
    return obj


def _add_body(context, spec: dict, rate: float, frame_start: int):
    name, kind = spec["name"], spec["type"]
    if kind == "plane":
        size = 0.6
        me = meshdata.new_mesh(name, np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]]) * size / 2,
                               [[0, 1, 2, 3]])
        obj = _link(context, bpy.data.objects.new(name, me))
        normal = np.asarray(spec["normal"], float)
        normal /= np.linalg.norm(normal)
        import mathutils

        obj.rotation_mode = "QUATERNION"
        obj.rotation_quaternion = mathutils.Vector((0, 0, 1)).rotation_difference(mathutils.Vector(normal))
        obj.location = spec["point"]
        obj.haptic_hand.role = "PLANE"
        param_props.from_scene(obj.haptic_hand, spec, params.UI_OBJECT, body_type=kind)
        return obj
    body = bodies_module.prepare(spec)
    position = np.asarray(spec["position"], dtype=float)
    if kind == "kinematic":
        # origin at the engine's centre of the body, so Blender turns it about the same point
        position = scene_export._kinematic_centre(body.vertices, body.faces)
    obj = _link(context, bpy.data.objects.new(name, meshdata.new_mesh(name, body.vertices - position, body.faces)))
    obj.location = position
    o = obj.haptic_hand
    o.role = {v: k for k, v in scene_export.BODY_TYPES.items()}[kind]
    try:
        param_props.from_scene(o, spec, params.UI_OBJECT, body_type=kind)
    except ValueError as e:
        raise ImportError_(f"body '{name}': {e}") from None
    if kind == "soft":
        ops_rig.make_tet_object(context, obj, body.nodes - position, body.tets)
    elif kind == "kinematic":
        _keyed_motion(obj, position, spec["trajectory"] or [{"t": 0.0}], rate, frame_start)
    return obj


class HAPTIC_HAND_OT_import_scene(bpy.types.Operator):
    """Import a Haptic Hand scene (.json): the hand rig, the bodies and the device trajectory"""

    bl_idname = "haptic_hand.import_scene"
    bl_label = "Import Haptic Hand Scene"
    bl_options = {"REGISTER", "UNDO"}

    filepath: bpy.props.StringProperty(subtype="FILE_PATH",
                                       description="The scene file (.json, docs/scene_format.md) to bring in")
    filter_glob: bpy.props.StringProperty(default="*.json", options={"HIDDEN"},
                                          description="The file browser lists scene files (.json) only")

    def invoke(self, context, event):
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    def execute(self, context):
        from ..engine import mesh as meshing

        if context.scene.haptic_hand.hand is not None:
            self.report({"ERROR"}, "This scene already has a hand: import into a new scene (Scene > New)")
            return {"CANCELLED"}
        try:
            build(context, self.filepath)
        except (scenes.SceneError, meshing.MeshError, bodies_module.BodyError, ImportError_, OSError) as e:
            self.report({"ERROR"}, f"Cannot import {self.filepath}: {e}")
            return {"CANCELLED"}
        except ImportError as e:  # procedural shapes are contoured by pyvista (vtk), not bundled
            self.report({"ERROR"}, f"Cannot import {self.filepath}: its procedural meshes need pyvista ({e}), which "
                                   "the add-on does not bundle: give the scene .obj meshes, or install pyvista into "
                                   "Blender's Python (<Blender's python> -m pip install pyvista)")
            return {"CANCELLED"}
        return {"FINISHED"}


def _menu(self, context):
    self.layout.operator(HAPTIC_HAND_OT_import_scene.bl_idname, text="Haptic Hand Scene (.json)")


classes = (HAPTIC_HAND_OT_import_scene,)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)
    bpy.types.TOPBAR_MT_file_import.append(_menu)


def unregister():
    bpy.types.TOPBAR_MT_file_import.remove(_menu)
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
