"""Keyframes written by the add-on: a fresh action for an object or a mesh's shape keys (slotted
actions on Blender 4.4 and newer), assigning it, and linear F-curves through given values. Used
by bakes (bake_store) and by imported skeleton motion (armature_motion)."""

from __future__ import annotations

import bpy
import numpy as np


def new_action(id_data, name: str):
    """A fresh action for id_data (an object, or a mesh's shape keys), not yet assigned;
    returns (action, slot or None, fcurves)."""
    action = bpy.data.actions.new(name)
    action.use_fake_user = False
    if hasattr(action, "slots"):  # Blender 4.4 and newer: slotted actions
        from bpy_extras import anim_utils

        slot = action.slots.new(id_type=id_data.id_type, name=id_data.name)
        return action, slot, anim_utils.action_ensure_channelbag_for_slot(action, slot).fcurves
    return action, None, action.fcurves


def assign_action(id_data, action, slot):
    """Give id_data the action (and its slot); returns the action it had."""
    ad = id_data.animation_data or id_data.animation_data_create()
    previous = ad.action
    ad.action = action
    if slot is not None:
        ad.action_slot = slot
    return previous


def fcurve(fcurves, path: str, index: int, frames, values) -> None:
    """A linear F-curve through (frames, values)."""
    fc = fcurves.new(path, index=index)
    fc.keyframe_points.add(len(frames))
    co = np.empty(2 * len(frames), dtype=np.float32)
    co[0::2], co[1::2] = frames, values
    fc.keyframe_points.foreach_set("co", co)
    for kp in fc.keyframe_points:
        kp.interpolation = "LINEAR"
    fc.update()
