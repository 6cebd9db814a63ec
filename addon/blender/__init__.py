"""Blender-facing code (bpy only): properties, operators, panels. Built in issue 5; until
then registering the add-on adds nothing to Blender."""


def register():
    pass


def unregister():
    pass
