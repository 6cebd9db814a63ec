"""Haptic Hand: a Blender add-on that simulates a deformable tetrahedral hand held through a
haptic device, with a native C++ engine.

`engine` is pure Python and never imports bpy, so it is importable (and testable) outside
Blender; the Blender-facing code in `blender` is imported only when Blender registers the
add-on.
"""


def register():
    from . import blender

    blender.register()


def unregister():
    from . import blender

    blender.unregister()
