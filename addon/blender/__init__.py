"""Blender-facing code (bpy only): properties, operators, panels, the live session and the
bake. The engine (haptic_hand.engine) never imports anything from here.

Modules, one concern each: properties (settings stored in the .blend), param_props (the
parameter table as properties), runtime (what runs now: never saved), meshdata (Blender meshes
<-> numpy), scene_export (Blender scene -> engine scene), scene_import (engine JSON scene ->
Blender objects), ops_rig (hand, tets in a child process, seed, radius), armature (the
armature's bones as the skeleton, what each holds), armature_motion (its animation <-> bone
targets), armature_build (an armature from a scene file's skeleton), ops_skeleton (Use Armature
as Skeleton, the bones' checks), ops_bodies (roles of the other objects), ops_bake (the bake in
a child process), bake_store (a bake written aside and swapped in, Free Bake), live (modal live
session and its recording), draw (viewport overlays), panel (the sidebar tab).
"""

from . import draw, live, ops_bake, ops_bodies, ops_rig, ops_skeleton, panel, properties, runtime, scene_import

# Registration order: properties first (operators and panels refer to them), panels last.
_MODULES = (properties, runtime, ops_rig, ops_skeleton, ops_bodies, ops_bake, live, scene_import, panel, draw)


def register():
    done = []
    try:
        for module in _MODULES:
            module.register()
            done.append(module)
    except Exception:
        for module in reversed(done):
            module.unregister()
        raise


def unregister():
    for module in reversed(_MODULES):
        module.unregister()
