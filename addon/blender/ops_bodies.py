"""Marking the other objects of the scene: soft bodies, rigid bodies, moving colliders (they
follow their own Blender animation), static colliders, ground planes."""

from __future__ import annotations

import bpy

from . import meshdata
from .properties import ROLES

MARKABLE = [r for r in ROLES if r[0] != "HAND"]


def _candidates(context):
    hand = context.scene.haptic_hand.hand
    return [o for o in context.selected_objects if o != hand and not o.haptic_hand.is_tet_mesh]


class HAPTIC_HAND_OT_mark_body(bpy.types.Operator):
    """Set the role of the selected objects in the simulation"""

    bl_idname = "haptic_hand.mark_body"
    bl_label = "Mark Selected"
    bl_options = {"REGISTER", "UNDO"}

    role: bpy.props.EnumProperty(name="Role", items=MARKABLE, default="SOFT",
                                 description="What the selected objects become in the simulation")

    @classmethod
    def poll(cls, context):
        if context.mode != "OBJECT" or not _candidates(context):
            cls.poll_message_set("Select objects other than the hand (in Object Mode)")
            return False
        return True

    def execute(self, context):
        objs = _candidates(context)
        needs_mesh = self.role not in ("NONE", "PLANE")
        bad = [o.name for o in objs if needs_mesh and o.type != "MESH"]
        if bad:
            self.report({"ERROR"}, f"{', '.join(bad)} {'is' if len(bad) == 1 else 'are'} not a mesh: only meshes "
                                   f"can be {self.role.lower()} bodies (a ground plane can be any object)")
            return {"CANCELLED"}
        for o in objs:
            o.haptic_hand.role = self.role
        untet = [o.name for o in objs if self.role == "SOFT" and not meshdata.has_tets(o.haptic_hand.tet_object)]
        label = dict((r[0], r[1]) for r in ROLES)[self.role]
        self.report({"INFO"}, f"{len(objs)} object(s) marked {label}")
        if untet:
            self.report({"WARNING"}, f"{', '.join(untet)} need tets before a bake or live session: select each "
                                     "and press Tetrahedralize")
        return {"FINISHED"}


classes = (HAPTIC_HAND_OT_mark_body,)


register, unregister = bpy.utils.register_classes_factory(classes)
