"""Settings the add-on keeps in the .blend: `Scene.haptic_hand` (the rig, material, device,
live session and bake) and `Object.haptic_hand` (what role an object plays).

Units: lengths in the scene's units (the engine works in metres: scene_export converts with
`unit_settings.scale_length`); the handle radius and contact thickness are in metres, as in
the engine's scene files.
"""

from __future__ import annotations

import bpy
from bpy.props import (BoolProperty, EnumProperty, FloatProperty, FloatVectorProperty, IntProperty, PointerProperty,
                       StringProperty)

ROLES = [
    ("NONE", "None", "Not part of the simulation"),
    ("HAND", "Hand", "The hand's render mesh (set it in the panel's Rig section)"),
    ("SOFT", "Soft body", "Deformable: simulated with its own tet mesh (tetrahedralize it)"),
    ("RIGID", "Rigid body", "Free rigid body pushed around by contact"),
    ("MOVING", "Moving collider", "Follows its own Blender animation; pushes, is not pushed"),
    ("STATIC", "Static collider", "Never moves"),
    ("PLANE", "Ground plane", "An infinite plane through the object's origin, normal along its local Z"),
]

DEVICES = [
    ("SIMULATED", "Simulated", "A simulated user's arm follows the target empty's animation"),
    ("PLAYBACK", "Playback", "Replay a recorded haptic log (.npz)"),
    ("OPENHAPTICS", "OpenHaptics", "Phantom Omni / Touch through OpenHaptics (libHD), when installed"),
    ("HID", "HID device", "A 6-DoF HID input device (SpaceMouse) through hidapi"),
    ("TARGET", "Viewport target", "Move the target empty with the mouse; it stands for the device"),
]

BAKE_FORMATS = [
    ("KEYS", "Shape keys", "One shape key per frame with keyed values, keyed transforms for rigid bodies"),
    ("PC2", "Point cache (PC2)", "A .pc2 file per deformable object played by a Mesh Cache modifier: "
                                 "for long bakes"),
]


def _hid_items(self, context):
    """6-DoF HID devices present now (the engine's hidapi discovery), for the device menu.
    Never raises."""
    items = [("NONE", "No HID device found", "Plug in a 3Dconnexion SpaceMouse")]
    try:
        from ..engine import devices

        found = []
        for d in devices.hid_devices():
            path = d["path"].decode(errors="replace") if isinstance(d["path"], bytes) else str(d["path"])
            found.append((path, d["product"], f"{d['product']} at {path} (input only, no force feedback)"))
        if found:
            items = found
    except Exception:
        pass
    _hid_items.cache = items  # Blender needs the strings kept alive
    return items


def _is_mesh(self, obj):
    return obj.type == "MESH" and not obj.haptic_hand.is_tet_mesh


def _is_empty(self, obj):
    return obj.type == "EMPTY"


def _radius_changed(self, context):
    from . import ops_rig

    ops_rig.update_captured(context.scene)


class HapticObjectSettings(bpy.types.PropertyGroup):
    role: EnumProperty(name="Role", items=ROLES, default="NONE")
    tet_object: PointerProperty(name="Tet mesh", type=bpy.types.Object,
                                description="This object's tetrahedral mesh (made by Tetrahedralize)")
    is_tet_mesh: BoolProperty(name="Is a tet mesh", default=False,
                              description="Set on tet-mesh objects made by Tetrahedralize")
    young_modulus: FloatProperty(name="Young's modulus", default=2e4, min=1.0, soft_max=1e7, unit="NONE",
                                 description="Stiffness of a soft body (Pa)")
    poisson_ratio: FloatProperty(name="Poisson ratio", default=0.35, min=0.0, max=0.49)
    density: FloatProperty(name="Density", default=400.0, min=1e-3, description="kg/m^3")
    rayleigh_beta: FloatProperty(name="Damping (β)", default=0.02, min=0.0, precision=4,
                                 description="Stiffness-proportional Rayleigh damping of a soft body (s)")
    friction: FloatProperty(name="Friction", default=0.6, min=0.0, soft_max=2.0,
                            description="Coulomb coefficient of this body's surface")
    fix_bottom: BoolProperty(name="Fix bottom", default=False,
                             description="Hold the soft body's lowest nodes still")
    reuse_factor: BoolProperty(name="Reuse factor", default=False,
                               description="Large soft bodies: solve on an earlier step's factor (CG to 1e-6) and keep "
                                           "its contact responses between factorizations, instead of factoring the "
                                           "body every step")
    # bake bookkeeping (set by the bake, cleared by Free Bake)
    baked: BoolProperty(default=False, options={"HIDDEN"})
    bake_made_basis: BoolProperty(default=False, options={"HIDDEN"})
    previous_action: PointerProperty(type=bpy.types.Action, options={"HIDDEN"})
    rest_matrix: FloatVectorProperty(size=16, options={"HIDDEN"})
    rest_rotation_mode: StringProperty(default="XYZ", options={"HIDDEN"})


class HapticSceneSettings(bpy.types.PropertyGroup):
    # --- rig ---
    hand: PointerProperty(name="Hand", type=bpy.types.Object, poll=_is_mesh,
                          description="The hand's render mesh (closed, manifold)")
    seed: PointerProperty(name="Palm seed", type=bpy.types.Object, poll=_is_empty,
                          description="Empty at the palm: the rigid handle captures the tet nodes within "
                                      "the radius around it")
    handle_radius: FloatProperty(name="Handle radius", default=0.03, min=1e-4, soft_max=0.2, precision=4,
                                 update=_radius_changed, description="Radius of the handle sphere (m)")
    captured_nodes: IntProperty(name="Captured nodes", default=0, min=0,
                                description="Tet nodes inside the handle sphere (updated when the radius "
                                            "changes)")
    edge_length_fac: FloatProperty(name="Edge length", default=0.1, min=0.01, max=1.0,
                                   description="Target tet edge length as a fraction of the bounding-box "
                                               "diagonal (smaller: more tets)")
    epsilon: FloatProperty(name="Envelope", default=0.002, min=1e-4, max=0.05, precision=4,
                           description="How far the tet boundary may stray from the surface, relative to "
                                       "the diagonal (smaller: closer fit, more tets)")
    coarsen: BoolProperty(name="Coarsen", default=True,
                          description="Coarsen the tet mesh as far as the quality allows")
    # --- material and springs ---
    young_modulus: FloatProperty(name="Young's modulus", default=5e4, min=1.0, soft_max=1e7,
                                 description="Stiffness of the flesh (Pa)")
    poisson_ratio: FloatProperty(name="Poisson ratio", default=0.3, min=0.0, max=0.49)
    density: FloatProperty(name="Density", default=1000.0, min=1e-3, description="kg/m^3")
    rayleigh_beta: FloatProperty(name="Damping (β)", default=0.01, min=0.0, precision=4,
                                 description="Stiffness-proportional Rayleigh damping (s)")
    spring_stiffness: FloatProperty(name="Spring stiffness", default=1e4, min=1e-3,
                                    description="Handle-to-flesh springs (N/m)")
    spring_damping: FloatProperty(name="Spring damping", default=10.0, min=0.0, description="N s/m")
    coupling_stiffness: FloatProperty(name="Coupling stiffness", default=5e3, min=1e-3,
                                      description="Virtual coupling between the device and the handle (N/m)")
    coupling_damping: FloatProperty(name="Coupling damping", default=50.0, min=0.0, description="N s/m")
    angular_stiffness: FloatProperty(name="Angular stiffness", default=50.0, min=0.0, description="N m/rad")
    angular_damping: FloatProperty(name="Angular damping", default=0.5, min=0.0, description="N m s/rad")
    time_step: FloatProperty(name="Time step", default=1.0 / 30.0, min=1e-4, max=0.1, precision=4,
                             description="Visual-loop step of a live session (s); bakes step once per frame")
    contact_thickness: FloatProperty(name="Contact thickness", default=1e-3, min=1e-5, precision=4,
                                     description="Gap kept between surfaces (m)")
    friction: FloatProperty(name="Hand friction", default=0.5, min=0.0, soft_max=2.0)
    self_collision: BoolProperty(name="Self collision", default=True, description="Fingers collide")
    world_threads: IntProperty(name="Simulation threads", default=2, min=1, max=2,
                               description="Threads of each visual-loop step: 2 runs collision detection and the "
                                           "other bodies beside the hand's solve (same results as 1); the haptic "
                                           "loop has its own thread either way")
    # --- device ---
    device: EnumProperty(name="Device", items=DEVICES, default="SIMULATED")
    device_file: StringProperty(name="Recording", subtype="FILE_PATH",
                                description="Haptic log (.npz) to play back")
    hid_device: EnumProperty(name="HID device", items=_hid_items)
    haptic_loop: BoolProperty(name="Haptic loop in bakes", default=True,
                              description="Bakes run the haptic loop (proxy handle, simulated arm) in lockstep "
                                          "and log every haptic step; off: the device drives the handle directly")
    haptic_rate: FloatProperty(name="Haptic rate", default=1000.0, min=100.0, max=10000.0,
                               description="Haptic-loop rate (Hz)")
    target: PointerProperty(name="Target", type=bpy.types.Object, poll=_is_empty,
                            description="Empty that stands for the device: its motion since the first "
                                        "frame moves the handle")
    # --- live session (state shown by the panel) ---
    live_running: BoolProperty(default=False, options={"SKIP_SAVE"})
    live_stop: BoolProperty(default=False, options={"SKIP_SAVE"})
    # --- bake ---
    bake_format: EnumProperty(name="Format", items=BAKE_FORMATS, default="KEYS")
    bake_frame_start: IntProperty(name="Start", default=1, min=0)
    bake_frame_end: IntProperty(name="End", default=60, min=1)
    bake_running: BoolProperty(default=False, options={"SKIP_SAVE"})
    bake_progress: FloatProperty(default=0.0, min=0.0, max=1.0, subtype="FACTOR", options={"SKIP_SAVE"})
    bake_cancel: BoolProperty(default=False, options={"SKIP_SAVE"})
    baked: BoolProperty(default=False, description="A bake is stored in this scene")
    baked_format: StringProperty(default="")
    baked_range: StringProperty(default="")
    bake_log: StringProperty(name="Haptic log", default="", description="Where the last bake saved its haptic log (relative to the .blend)")


classes = (HapticObjectSettings, HapticSceneSettings)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)
    bpy.types.Object.haptic_hand = PointerProperty(type=HapticObjectSettings)
    bpy.types.Scene.haptic_hand = PointerProperty(type=HapticSceneSettings)


def unregister():
    del bpy.types.Scene.haptic_hand
    del bpy.types.Object.haptic_hand
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
