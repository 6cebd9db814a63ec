"""Settings the add-on keeps in the .blend: `Scene.haptic_hand` (the rig, device, live session
and bake, and the scene-wide parameters), `Object.haptic_hand` (what role an object plays,
and its own parameters: material, friction, solver, tetrahedralize settings) and
`Bone.haptic_hand` (what a bone of the skeleton armature holds, and its drive's scale).

The simulation's parameters come from the parameter table (param_props): their defaults,
limits, units and tooltips are the engine's. Lengths are shown in the scene's units and stored
in metres.
"""

from __future__ import annotations

import bpy
from bpy.props import (BoolProperty, EnumProperty, FloatProperty, FloatVectorProperty, IntProperty, PointerProperty,
                       StringProperty)

from ..engine import devices, params
from . import armature, param_props

ROLES = [
    ("NONE", "None", "Not part of the simulation"),
    ("HAND", "Hand", "The hand's render mesh (set it in the panel's Rig section)"),
    ("SOFT", "Soft body", "Deformable: simulated with its own tet mesh (tetrahedralize it)"),
    ("RIGID", "Rigid body", "Free rigid body pushed around by contact"),
    ("MOVING", "Moving collider", "Follows its own Blender animation; pushes, is not pushed"),
    ("STATIC", "Static collider", "Never moves"),
    ("PLANE", "Ground plane", "An infinite plane through the object's origin, normal along its local Z"),
]

DEVICES = [(k.menu_id, k.label, k.description) for k in devices.KINDS]  # one list: engine/devices.py

BAKE_FORMATS = [
    ("KEYS", "Shape keys", "One shape key per frame with keyed values, keyed transforms for rigid bodies"),
    ("PC2", "Point cache (PC2)", "A .pc2 file per deformable object played by a Mesh Cache modifier: "
                                 "for long bakes"),
]


def _hid_items(self, context):
    """6-DoF HID devices present now (the engine's hidapi discovery), and the chosen one when it
    is not plugged in (so a scene file's hid:<path> survives an import), for the device menu.
    Never raises."""
    found = []
    try:
        from ..engine import devices

        for d in devices.hid_devices():
            path = d["path"].decode(errors="replace") if isinstance(d["path"], bytes) else str(d["path"])
            found.append((path, d["product"], f"{d['product']} at {path} (input only, no force feedback)"))
    except Exception:
        pass
    if self.hid_path and self.hid_path not in [f[0] for f in found]:
        found.append((self.hid_path, f"{self.hid_path} (not connected)", "The chosen HID device, not plugged in now"))
    items = found or [("NONE", "No HID device found", "Plug in a 3Dconnexion SpaceMouse")]
    items = [item + (i,) for i, item in enumerate(items)]
    _hid_items.cache = items  # Blender needs the strings kept alive
    return items


def _get_hid(self) -> int:
    """The menu shows the chosen device (hid_path), else the first one found."""
    return next((i for path, _, _, i in _hid_items(self, None) if path == self.hid_path), 0)


def _set_hid(self, value: int) -> None:
    path = next(path for path, _, _, i in _hid_items(self, None) if i == value)
    self.hid_path = "" if path == "NONE" else path


def _is_mesh(self, obj):
    return obj.type == "MESH" and not obj.haptic_hand.is_tet_mesh


def _is_empty(self, obj):
    return obj.type == "EMPTY"


def _is_armature(self, obj):
    return obj.type == "ARMATURE"


def _radius_changed(self, context):
    from . import ops_rig

    ops_rig.update_captured(context.scene)


def _frame_range_accessors(which: str):
    """Bake Start / End: the scene's frame range until the user sets one of their own."""
    stored = f"stored_bake_frame_{which}"

    def get(self):
        if self.bake_range_set:
            return getattr(self, stored)
        scene = self.id_data
        return scene.frame_start if which == "start" else scene.frame_end

    def set(self, value):
        if not self.bake_range_set:  # keep the other end where it is shown now
            other = "end" if which == "start" else "start"
            setattr(self, f"stored_bake_frame_{other}", getattr(self, f"bake_frame_{other}"))
            self.bake_range_set = True
        setattr(self, stored, value)

    return get, set


class HapticObjectSettings(bpy.types.PropertyGroup):
    """What an object is to the simulation; its material, friction, solver and tetrahedralize
    settings come from the parameter table (param_props)."""

    role: EnumProperty(name="Role", items=ROLES, default="NONE",
                       description="What this object is in the simulation")
    tet_object: PointerProperty(name="Tet mesh", type=bpy.types.Object,
                                description="This object's tetrahedral mesh (made by Tetrahedralize)")
    is_tet_mesh: BoolProperty(name="Is a tet mesh", default=False,
                              description="Set on tet-mesh objects made by Tetrahedralize")
    # bake bookkeeping (set by the bake, cleared by Free Bake)
    baked: BoolProperty(default=False, options={"HIDDEN"}, description="This object holds baked motion")
    bake_made_basis: BoolProperty(default=False, options={"HIDDEN"},
                                  description="The bake added this object's Basis shape key")
    previous_action: PointerProperty(type=bpy.types.Action, options={"HIDDEN"},
                                     description="The action the object had before the bake")
    previous_key_action: PointerProperty(type=bpy.types.Action, options={"HIDDEN"},
                                         description="The action the object's shape keys had before the bake")
    bake_keyed_transform: BoolProperty(default=False, options={"HIDDEN"},
                                       description="The bake keyed this object's transform (a rigid body)")
    rest_matrix: FloatVectorProperty(size=16, options={"HIDDEN"}, description="World matrix before the bake")
    rest_rotation_mode: StringProperty(default="XYZ", options={"HIDDEN"},
                                       description="Rotation mode before the bake")
    bake_muted_modifiers: StringProperty(default="", options={"HIDDEN"},
                                         description="The Armature modifiers a shape-key bake turned off, one a "
                                                     "line (Free Bake turns them back on)")


class HapticBoneSettings(bpy.types.PropertyGroup):
    """What a deforming bone of the skeleton armature holds (docs/blender.md, "Rigging"); its
    radius and drive scale are the parameter table's bone rows."""

    capture: EnumProperty(name="Capture", items=armature.CAPTURES, default="CAPSULE",
                          description="What the bone holds: the tet nodes near its segment, or those of its vertex "
                                      "group")
    use_bone_radius: BoolProperty(name="Set radius", default=False,
                                  description="Give the capsule a radius of its own (off: 1.15 times the limb's "
                                              "radius there, from the hand's mesh)")


class HapticSceneSettings(bpy.types.PropertyGroup):
    """The rig, the device, the live session and the bake; the simulation's parameters come from
    the parameter table (param_props)."""

    # --- rig ---
    hand: PointerProperty(name="Hand", type=bpy.types.Object, poll=_is_mesh,
                          description="The hand's render mesh (closed, manifold)")
    seed: PointerProperty(name="Palm seed", type=bpy.types.Object, poll=_is_empty,
                          description="Empty at the palm: the rigid handle captures the tet nodes within "
                                      "the radius around it (scene file: hand.palm_seed)")
    armature: PointerProperty(name="Armature", type=bpy.types.Object, poll=_is_armature,
                              description="The hand's armature: each deforming bone becomes a rigid handle that holds "
                                          "the flesh near it, driven by the armature's animation (scene file: "
                                          "hand.skeleton, skeleton.targets); empty: the palm seed's one handle")
    group_weight: FloatProperty(name="Group weight", default=0.5, min=0.0, max=1.0,
                                description="A bone captured by the hand's vertex group holds the flesh of the "
                                            "vertices weighted above this in its group; blended vertices stay soft")
    tet_confirm_limit: IntProperty(name="Confirm above", default=50000, min=0,
                                   description="Tetrahedralize asks before making more tets than this (its "
                                               "estimate); 0 never asks")
    captured_nodes: IntProperty(name="Captured nodes", default=0, min=0,
                                description="Tet nodes inside the handle sphere (updated when the radius "
                                            "changes)")
    # --- device ---
    device: EnumProperty(name="Device", items=DEVICES, default="SIMULATED",
                         description="What moves the hand: a simulated user, a recording, a haptic device, a "
                                     "SpaceMouse, or the target empty (scene file: haptics.device)")
    device_file: StringProperty(name="Recording", subtype="FILE_PATH", options=param_props.PATH_OPTIONS,
                                description="Haptic log (.npz) or CSV of device poses to play back (// is the "
                                            ".blend's folder)")
    hid_path: StringProperty(name="HID device path", options={"HIDDEN"},
                             description="The chosen HID device (scene file: haptics.device = \"hid:<path>\"); kept "
                                         "while it is unplugged")
    hid_device: EnumProperty(name="HID device", items=_hid_items, get=_get_hid, set=_set_hid,
                             description="Which 6-DoF HID device drives the hand")
    target: PointerProperty(name="Target", type=bpy.types.Object, poll=_is_empty,
                            description="Empty that stands for the device: its motion since the first "
                                        "frame moves the handle (scene file: device.trajectory)")
    # --- live session ---
    live_record: BoolProperty(name="Record", default=True,
                              description="Save the live session's device stream and the felt force (the haptic "
                                          "log) to the Recording file when it stops; Bake Recording replays it")
    live_recording: StringProperty(name="Recording file", subtype="FILE_PATH", default="//haptic_recording.npz",
                                   options=param_props.PATH_OPTIONS,
                                   description="Where a live session saves its recording (// is the .blend's "
                                               "folder)")
    # --- bake ---
    bake_format: EnumProperty(name="Format", items=BAKE_FORMATS, default="KEYS",
                              description="How the bake stores the motion")
    bake_range_set: BoolProperty(default=False, options={"HIDDEN"},
                                 description="The bake has a frame range of its own (else the scene's)")
    stored_bake_frame_start: IntProperty(default=1, options={"HIDDEN"}, description="The bake's own start frame")
    stored_bake_frame_end: IntProperty(default=250, options={"HIDDEN"}, description="The bake's own end frame")
    bake_frame_start: IntProperty(name="Start", min=0, get=_frame_range_accessors("start")[0],
                                  set=_frame_range_accessors("start")[1],
                                  description="First frame of the bake (the scene's start until you change it)")
    bake_frame_end: IntProperty(name="End", min=1, get=_frame_range_accessors("end")[0],
                                set=_frame_range_accessors("end")[1],
                                description="Last frame of the bake (the scene's end until you change it)")
    baked: BoolProperty(default=False, description="A bake is stored in this scene")
    baked_format: StringProperty(default="", description="The stored bake's format")
    baked_range: StringProperty(default="", description="The stored bake's frames")
    bake_log: StringProperty(name="Haptic log", default="",
                             description="Where the last bake saved its haptic log (relative to the .blend)")
    baked_files: StringProperty(default="", options={"HIDDEN"},
                                description="The stored bake's files, one a line (relative to the .blend): the next "
                                            "bake and Free Bake remove them")


def _add_table_properties() -> None:
    """The parameter table's rows as properties of the two settings blocks."""
    HapticSceneSettings.__annotations__.update(
        param_props.annotations(params.UI_SCENE, updates={"handle_radius": _radius_changed}))
    HapticObjectSettings.__annotations__.update(param_props.annotations(params.UI_OBJECT))
    for p in armature.bone_rows().values():
        HapticBoneSettings.__annotations__.update(param_props.row_properties(p))


classes = (HapticObjectSettings, HapticBoneSettings, HapticSceneSettings)


def register():
    _add_table_properties()
    for cls in classes:
        bpy.utils.register_class(cls)
    bpy.types.Object.haptic_hand = PointerProperty(type=HapticObjectSettings)
    bpy.types.Bone.haptic_hand = PointerProperty(type=HapticBoneSettings)
    bpy.types.Scene.haptic_hand = PointerProperty(type=HapticSceneSettings)


def unregister():
    del bpy.types.Scene.haptic_hand
    del bpy.types.Bone.haptic_hand
    del bpy.types.Object.haptic_hand
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
