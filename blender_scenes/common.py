"""Shared by the scripts of blender_scenes/: import the add-on, build a sample scene into an
empty Blender file with a camera, light and colours for Workbench renders, and export it."""

from __future__ import annotations

import importlib.util
import pathlib
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "addon" / "engine" / "sample_scenes"
SCENES = {  # the .blend name -> the engine's sample scene it is built from
    "bunny": "bunny_press.json",
    "letters": "letters_push.json",
    "fingers": "finger_squeeze.json",
    "hand_close": "procedural_hand_close.json",  # the rigged hand: an armature of 16 bones closing the fingers
    # the grasping hand (16 bones, an opposing thumb): its action lifts a soft ball by friction,
    # or pinches a soft letter between the index finger's and the thumb's pads
    "hand_grasp": "grasp_ball_hand.json",
    "hand_pinch": "pinch_letter_hand.json",
}
# The rigged hand whose export (what its bake simulates) is kept beside its .blend, as the
# example of what Blender sends the engine; the others' command-line scenes are the engine
# samples they are built from, which tests/blender/test_skeleton_sample.py checks they export to.
EXPORTED = ("hand_close",)
COLOURS = {"hand": (0.85, 0.62, 0.5, 1.0), "soft": (0.45, 0.6, 0.9, 1.0), "plane": (0.55, 0.55, 0.52, 1.0),
           "other": (0.6, 0.75, 0.45, 1.0)}


def import_addon():
    """haptic_hand (the add-on's package), from the venv's editable install or addon/ itself."""
    try:
        import haptic_hand
    except ImportError:
        spec = importlib.util.spec_from_file_location("haptic_hand", ROOT / "addon" / "__init__.py",
                                                      submodule_search_locations=[str(ROOT / "addon")])
        haptic_hand = importlib.util.module_from_spec(spec)
        sys.modules["haptic_hand"] = haptic_hand
        spec.loader.exec_module(haptic_hand)
    return haptic_hand


def export(folder: pathlib.Path) -> None:
    """The open .blend's scene as the engine sees it, written to folder (scene.json and its
    meshes and tets; what was there is replaced): what a bake simulates, and what the command
    line runs (`python -m haptic_hand simulate <folder>/scene.json`)."""
    import shutil

    import bpy

    from haptic_hand.blender import scene_export

    written = scene_export.export(bpy.context)
    try:
        shutil.rmtree(folder, ignore_errors=True)
        shutil.copytree(written.folder, folder)
        folder.chmod(0o755)  # (the export's own folder is private: a temporary one)
    finally:
        written.cleanup()


def build(name: str, path: pathlib.Path, resolution=(960, 540)) -> dict:
    """Build the sample scene `name` (a key of SCENES) into a new .blend at path; returns the
    objects by engine name. The add-on must be registered."""
    import bpy

    from haptic_hand.blender import scene_import

    bpy.ops.wm.read_factory_settings(use_empty=True)
    objects = scene_import.build(bpy.context, SAMPLES / SCENES[name])
    scene = bpy.context.scene
    scene.name = name
    setup_render(scene, objects, resolution)
    path.parent.mkdir(parents=True, exist_ok=True)
    bpy.ops.wm.save_as_mainfile(filepath=str(path), compress=True)
    return objects


def setup_render(scene, objects: dict, resolution) -> None:
    """Workbench (CPU-free of any GPU need headless), object colours, a camera on the action."""
    import bpy
    import mathutils
    import numpy as np

    scene.render.engine = "BLENDER_WORKBENCH"
    scene.display.shading.light = "STUDIO"
    scene.display.shading.color_type = "OBJECT"
    scene.display.shading.show_shadows = True
    scene.display.shading.show_cavity = True
    scene.render.resolution_x, scene.render.resolution_y = resolution
    scene.render.resolution_percentage = 100
    scene.render.film_transparent = False
    if scene.world is None:
        scene.world = bpy.data.worlds.new("World")
    points = []
    for name, obj in objects.items():
        role = obj.haptic_hand.role
        obj.color = COLOURS["hand" if role == "HAND" else "soft" if role == "SOFT" else
                            "plane" if role == "PLANE" else "other"]
        if obj.type == "MESH" and role != "PLANE":
            points.append(np.array([obj.matrix_world @ v.co for v in obj.data.vertices]))
    points = np.concatenate(points)
    lo, hi = points.min(0), points.max(0)
    size = float(np.linalg.norm(hi - lo))
    centre = mathutils.Vector((lo + hi) / 2) - mathutils.Vector((0.0, 0.0, 0.08 * size))
    cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    scene.collection.objects.link(cam)
    cam.data.lens = 50
    direction = mathutils.Vector((-1.0, -1.3, 0.4)).normalized()
    cam.location = centre + direction * size * 1.9
    cam.rotation_euler = (centre - cam.location).to_track_quat("-Z", "Y").to_euler()
    cam.data.clip_start, cam.data.clip_end = 0.005, 50.0
    scene.camera = cam
