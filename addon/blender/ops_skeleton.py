"""Authoring a skeleton hand: Use Armature as Skeleton, and what Check Rig says of the bones
(armature.rig's problems, each with its fix) before it runs the engine's checks."""

from __future__ import annotations

import bpy

from . import armature, scene_export


class HAPTIC_HAND_OT_use_armature(bpy.types.Operator):
    """Use the active armature as the hand's skeleton: each deforming bone becomes a rigid handle
    holding the flesh near it, driven by the armature's animation"""

    bl_idname = "haptic_hand.use_armature"
    bl_label = "Use Armature as Skeleton"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        obj = context.active_object
        if obj is None or obj.type != "ARMATURE" or context.mode not in ("OBJECT", "POSE"):
            cls.poll_message_set("Select the hand's armature (in Object or Pose Mode)")
            return False
        return True

    def execute(self, context):
        scene = context.scene
        scene.haptic_hand.armature = context.active_object
        try:
            rig = armature.rig(scene)
        except (armature.RigError, scene_export.ExportError) as e:
            self.report({"WARNING"}, f"'{context.active_object.name}' is the skeleton, but: {e}")
            return {"FINISHED"}
        held = int((rig.owner >= 0).sum())
        problems = f"; {len(rig.problems)} problem(s): Check Rig lists them" if rig.problems else ""
        self.report({"INFO"}, f"'{context.active_object.name}' is the skeleton: {len(rig.bones)} bones hold {held} of "
                              f"{len(rig.owner)} tet nodes{problems}")
        return {"FINISHED"}


def report_problems(operator, scene) -> bool:
    """Check Rig's first part with an armature: every problem of the bones as a WARNING report,
    then one ERROR naming them all. True when the bones can go on to the engine's checks."""
    if scene.haptic_hand.armature is None:
        return True
    try:
        rig = armature.rig(scene)
    except (armature.RigError, scene_export.ExportError) as e:
        operator.report({"ERROR"}, str(e))
        return False
    if not rig.problems:
        return True
    for problem in rig.problems:
        operator.report({"WARNING"}, problem)
    operator.report({"ERROR"}, f"The skeleton has {len(rig.problems)} problem(s): " + "; ".join(rig.problems))
    return False


classes = (HAPTIC_HAND_OT_use_armature,)


register, unregister = bpy.utils.register_classes_factory(classes)
