"""Blender-facing code (bpy only): properties, operators, panels, the live session and the
bake. The engine (haptic_hand.engine) never imports anything from here.

Modules, one concern each: properties (settings stored in the .blend), meshdata (Blender
meshes <-> numpy), scene_export (Blender scene -> engine scene), scene_import (engine JSON
scene -> Blender objects), ops_rig (hand, tets, seed, radius), ops_bodies (roles of the other
objects), ops_bake (offline bake), live (modal live session), draw (viewport overlay), panel
(the sidebar tab).
"""

from . import draw, live, ops_bake, ops_bodies, ops_rig, panel, properties, scene_import

# Registration order: properties first (operators and panels refer to them), panels last.
_MODULES = (properties, ops_rig, ops_bodies, ops_bake, live, scene_import, panel, draw)


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
