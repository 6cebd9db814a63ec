"""An armature made from a scene file's skeleton (File > Import, the sample scenes): one bone per
bone of `hand.skeleton` at its rest head and tail (world metres, the armature object at the
origin), each bone's settings as the file gives them (its radius set, or its node list kept as
a vertex group of the tet mesh named like the bone), and the hand skinned to it rigidly (each
render vertex weighted 1 to the bone whose rest segment is nearest), so the armature's action
shows the motion the targets ask for before anything is baked.
"""

from __future__ import annotations

import bpy
import numpy as np

from ..engine import skeleton as sk

ARMATURE_NAME = "Armature"


def new_armature(context, skeleton: sk.Skeleton, drive_scales, hand, tet_obj):
    """The armature object of `skeleton`, linked to the scene; the hand skinned to it."""
    data = bpy.data.armatures.new(ARMATURE_NAME)
    obj = bpy.data.objects.new(ARMATURE_NAME, data)
    context.scene.collection.objects.link(obj)
    obj.show_in_front = True
    _edit_bones(context, obj, skeleton)
    for bone, scale in zip(skeleton.bones, drive_scales):
        settings = data.bones[bone.name].haptic_hand
        settings.bone_drive_scale = float(scale)
        if bone.nodes is not None:
            settings.capture = "GROUP"
            group = tet_obj.vertex_groups.new(name=bone.name)
            group.add([int(i) for i in bone.nodes], 1.0, "REPLACE")
        else:
            settings.use_bone_radius = True
            settings.bone_radius_si = float(bone.radius)
    skin_rigidly(hand, obj, skeleton)
    return obj


def _edit_bones(context, obj, skeleton: sk.Skeleton) -> None:
    """The bones at their rest segments, in the skeleton's order (a zero-length bone, which
    Blender drops, gets a tail 1 mm along z)."""
    view_layer = context.view_layer
    active = view_layer.objects.active
    view_layer.objects.active = obj
    bpy.ops.object.mode_set(mode="EDIT")
    try:
        made = {}
        for bone in skeleton.bones:
            edit = obj.data.edit_bones.new(bone.name)
            head, tail = np.asarray(bone.head, dtype=float), np.asarray(bone.tail, dtype=float)
            if np.linalg.norm(tail - head) < 1e-6:
                tail = head + [0.0, 0.0, 1e-3]
            edit.head, edit.tail = head.tolist(), tail.tolist()
            edit.use_deform = True
            if bone.parent is not None:
                edit.parent = made[bone.parent]
            made[bone.name] = edit
    finally:
        bpy.ops.object.mode_set(mode="OBJECT")
        view_layer.objects.active = active


def skin_rigidly(hand, arm_obj, skeleton: sk.Skeleton) -> None:
    """Each render vertex in the vertex group of the bone whose rest segment is nearest (weight
    1), and an Armature modifier on the hand."""
    from . import meshdata

    vertices = meshdata.transform(meshdata.matrix(hand), meshdata.local_vertices(hand.data))
    distances = np.stack([sk.segment_distance(vertices, np.asarray(b.head, float), np.asarray(b.tail, float))
                          for b in skeleton.bones], axis=1)
    nearest = np.argmin(distances, axis=1)
    for b, bone in enumerate(skeleton.bones):
        group = hand.vertex_groups.get(bone.name) or hand.vertex_groups.new(name=bone.name)
        group.add(np.flatnonzero(nearest == b).tolist(), 1.0, "REPLACE")
    modifier = hand.modifiers.new("Armature", "ARMATURE")
    modifier.object = arm_obj
