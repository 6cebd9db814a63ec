"""The "Haptic Hand" tab of the 3D viewport's sidebar (N): Rig, Material, Bodies, Device,
Live, Bake."""

from __future__ import annotations

import bpy

from ..engine import params
from . import armature, background, bake_store, meshdata, ops_rig, param_props, runtime, scene_export


def mib(size: int) -> str:
    return f"{size / 2**20:.1f} MiB" if size >= 2**20 else f"{size / 2**10:.0f} KiB"


def deformed_meshes(scene) -> list:
    """The meshes a bake deforms: the hand and the soft bodies."""
    s = scene.haptic_hand
    out = [s.hand] if s.hand is not None and s.hand.type == "MESH" else []
    return out + [o for o in scene.objects if o.haptic_hand.role == "SOFT" and o.type == "MESH" and o != s.hand]


class _Panel:
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "Haptic Hand"


class HAPTIC_HAND_PT_main(_Panel, bpy.types.Panel):
    bl_idname = "HAPTIC_HAND_PT_main"
    bl_label = "Haptic Hand"

    def draw(self, context):
        s = context.scene.haptic_hand
        col = self.layout.column(align=True)
        rt = runtime.state
        if rt.live is not None:
            col.label(text="Live session running (Esc stops)", icon="REC")
        elif rt.bake is not None:
            col.label(text=f"Baking {rt.bake.progress * 100:.0f}% ({rt.bake.message})", icon="TIME")
        elif rt.tetrahedralize is not None:
            col.label(text=f"Tetrahedralizing {rt.tetrahedralize.progress * 100:.0f}%", icon="TIME")
        elif s.baked:
            col.label(text=f"Baked frames {s.baked_range}", icon="CHECKMARK")
        else:
            col.label(text="Author the rig, then go live or bake")


class HAPTIC_HAND_PT_rig(_Panel, bpy.types.Panel):
    bl_label = "Rig"
    bl_parent_id = "HAPTIC_HAND_PT_main"

    def draw(self, context):
        s = context.scene.haptic_hand
        layout = self.layout
        row = layout.row(align=True)
        row.prop(s, "hand")
        row.operator("haptic_hand.use_as_hand", text="", icon="EYEDROPPER")
        if s.hand is not None:
            draw_rows(layout, s.hand.haptic_hand, object_rows(None))
        box = layout.box()
        box.label(text="Tetrahedralize (active mesh)")
        obj = context.active_object
        if obj is not None and obj.type == "MESH" and not obj.haptic_hand.is_tet_mesh:
            draw_rows(box, obj.haptic_hand, object_rows(None, tetrahedralize=True))
            if len(obj.data.polygons):
                estimate = ops_rig.tet_estimate(obj, context.scene)
                over = s.tet_confirm_limit and estimate > s.tet_confirm_limit
                box.label(text=f"About {estimate} tets", icon="ERROR" if over else "INFO")
        box.prop(s, "tet_confirm_limit")
        background.draw(box, runtime.state.tetrahedralize, "Tetrahedralizing", "haptic_hand.tetrahedralize_cancel",
                        "haptic_hand.tetrahedralize", "MESH_ICOSPHERE")
        if s.hand is not None:
            tet_obj = s.hand.haptic_hand.tet_object
            if meshdata.has_tets(tet_obj):
                box.label(text=f"{len(tet_obj.data[meshdata.TETS_KEY]) // 4} tets, "
                               f"{len(tet_obj.data.vertices)} nodes", icon="INFO")
            else:
                box.label(text="The hand has no tets yet", icon="ERROR")
        box = layout.box()
        row = box.row(align=True)
        row.prop(s, "armature")
        row.operator("haptic_hand.use_armature", text="", icon="EYEDROPPER")
        if s.armature is not None:
            draw_skeleton(box, context)
        else:
            row = box.row(align=True)
            row.prop(s, "seed")
            row.operator("haptic_hand.place_seed", text="", icon="PIVOT_CURSOR")
            box.prop(s, "handle_radius")
            count = ops_rig.captured_count(context.scene)
            if count >= 0:
                box.label(text=f"Handle captures {count} nodes", icon="ERROR" if count < 4 else "CHECKMARK")
        layout.operator("haptic_hand.check_rig", icon="CHECKMARK")


def draw_skeleton(layout, context) -> None:
    """The skeleton's bones, each with what it captures (engine/skeleton.py's rule, as the palm
    seed's count), and the active bone's settings."""
    s = context.scene.haptic_hand
    layout.prop(s, "group_weight")
    try:
        rig = armature.rig(context.scene)
    except (armature.RigError, scene_export.ExportError) as e:
        layout.label(text=str(e), icon="ERROR")
        return
    col = layout.column(align=True)
    for b in rig.bones:
        held = f"radius {b.radius * 1000:.1f} mm" + (" (auto)" if b.auto_radius else "") if b.radius is not None \
            else "vertex group"
        limits = armature.limits_text(b.limits)
        col.label(text=f"{b.name}: {b.count} nodes, {held}" + (f", {limits}" if limits else ""),
                  icon="ERROR" if b.problems else "BONE_DATA")
    for problem in rig.problems:
        layout.label(text=problem, icon="ERROR")
    bone = s.armature.data.bones.active
    if bone is not None and bone.use_deform:
        box = layout.box()
        box.label(text=f"Bone '{bone.name}'")
        settings = bone.haptic_hand
        box.prop(settings, "capture")
        if settings.capture == "CAPSULE":
            row = box.row(align=True)
            row.prop(settings, "use_bone_radius", text="")
            sub = row.row(align=True)
            sub.active = settings.use_bone_radius
            sub.prop(settings, "bone_radius")
        box.prop(settings, "bone_drive_scale")


# Where the panel draws the parameter table's rows, so a new row shows up without a panel edit:
# the scene's rows by the first key of their scene-file path (these sections in Device, every
# other in Material and Contact; what drives a skeleton's bones greyed out without an
# armature), the advanced ones in Advanced; an object's tetrahedralize rows
# in Rig (for the active mesh), its other rows in Bodies (a body) or Rig (the hand).
DEVICE_SECTIONS = ("haptics", "device", "skeleton")
DRAWN_APART = ("handle_radius",)  # Rig draws it beside the palm seed and the captured count


def is_tetrahedralize(p: params.Param) -> bool:
    return "tetrahedralize" in p.keys


def scene_groups(advanced: bool, device: bool = False) -> list[list[params.Param]]:
    """The scene's rows a section draws, grouped by their scene-file section in the table's
    order: the advanced ones (all of them), else those of the Device section or of the others."""
    groups = {}
    for p in param_props.selected(params.UI_SCENE):
        if p.name in DRAWN_APART or bool(p.flags & params.UI_ADVANCED) != advanced:
            continue
        if advanced or (p.keys[0] in DEVICE_SECTIONS) == device:
            groups.setdefault(p.keys[0], []).append(p)
    return list(groups.values())


def object_rows(body_type: str | None, tetrahedralize: bool = False) -> list[params.Param]:
    """An object's rows: a body's of this type (None: the hand's), the tetrahedralize ones or the
    others; the plain ones before the advanced ones."""
    if tetrahedralize:  # each mesh's own settings, whatever its role (one name per setting)
        return [p for p in param_props.rows(params.UI_OBJECT) if is_tetrahedralize(p)]
    chosen = [p for p in param_props.selected(params.UI_OBJECT, body_type, prefix=None if body_type else "hand.")
              if not is_tetrahedralize(p)]
    return sorted(chosen, key=lambda p: bool(p.flags & params.UI_ADVANCED))


def draw_rows(layout, settings, rows: list[params.Param]) -> None:
    """Each row as its property on `settings`; a nullable number with the switch that gives it a
    value of its own."""
    for p in rows:
        if p.nullable and p.kind in params.NUMERIC_KINDS:
            row = layout.row(align=True)
            row.prop(settings, f"use_{p.name}", text="")
            sub = row.row(align=True)
            sub.active = getattr(settings, f"use_{p.name}")
            sub.prop(settings, p.name)
        else:
            layout.prop(settings, p.name)


def draw_groups(layout, settings, groups: list[list[params.Param]]) -> None:
    for rows in groups:
        draw_rows(layout, settings, rows)
        layout.separator()


class HAPTIC_HAND_PT_material(_Panel, bpy.types.Panel):
    bl_label = "Material and Contact"
    bl_parent_id = "HAPTIC_HAND_PT_main"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        s = context.scene.haptic_hand
        draw_groups(self.layout.column(align=True), s, scene_groups(advanced=False))


class HAPTIC_HAND_PT_advanced(_Panel, bpy.types.Panel):
    bl_label = "Advanced"
    bl_parent_id = "HAPTIC_HAND_PT_material"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        s = context.scene.haptic_hand
        draw_groups(self.layout.column(align=True), s, scene_groups(advanced=True))


class HAPTIC_HAND_PT_bodies(_Panel, bpy.types.Panel):
    bl_label = "Bodies"
    bl_parent_id = "HAPTIC_HAND_PT_main"

    def draw(self, context):
        layout = self.layout
        grid = layout.grid_flow(columns=2, align=True)
        for role, text in (("SOFT", "Soft"), ("RIGID", "Rigid"), ("MOVING", "Moving"), ("STATIC", "Static"),
                           ("PLANE", "Ground"), ("NONE", "None")):
            grid.operator("haptic_hand.mark_body", text=text).role = role
        obj = context.active_object
        if obj is not None and obj.haptic_hand.role not in ("NONE", "HAND"):
            o = obj.haptic_hand
            box = layout.box()
            box.label(text=f"{obj.name}: {o.role.lower()}")
            draw_rows(box, o, object_rows(scene_export.BODY_TYPES[o.role]))
            if o.role == "SOFT" and not meshdata.has_tets(o.tet_object):
                box.label(text="Needs tets: Rig > Tetrahedralize", icon="ERROR")
        marked = [o for o in context.scene.objects if o.haptic_hand.role not in ("NONE", "HAND")]
        for o in marked:
            layout.label(text=f"{o.name}: {o.haptic_hand.role.lower()}", icon="OBJECT_DATA")


class HAPTIC_HAND_PT_device(_Panel, bpy.types.Panel):
    bl_label = "Device"
    bl_parent_id = "HAPTIC_HAND_PT_main"

    def draw(self, context):
        s = context.scene.haptic_hand
        layout = self.layout
        layout.prop(s, "device")
        if s.device == "PLAYBACK":
            layout.prop(s, "device_file")
        elif s.device == "HID":
            layout.prop(s, "hid_device")
        layout.prop(s, "target")
        for rows in scene_groups(advanced=False, device=True):
            col = layout.column(align=True)
            col.active = rows[0].keys[0] != "skeleton" or s.armature is not None
            draw_rows(col, s, rows)


class HAPTIC_HAND_PT_live(_Panel, bpy.types.Panel):
    bl_label = "Live Session"
    bl_parent_id = "HAPTIC_HAND_PT_main"

    def draw(self, context):
        s = context.scene.haptic_hand
        layout = self.layout
        if runtime.state.live is not None:
            layout.operator("haptic_hand.live_stop", icon="CANCEL")
        else:
            layout.operator("haptic_hand.live", icon="PLAY")
        row = layout.row(align=True)
        row.prop(s, "live_record")
        sub = row.row(align=True)
        sub.active = s.live_record
        sub.prop(s, "live_recording", text="")
        layout.operator("haptic_hand.bake_recording", icon="RENDER_ANIMATION")


class HAPTIC_HAND_PT_bake(_Panel, bpy.types.Panel):
    bl_label = "Bake"
    bl_parent_id = "HAPTIC_HAND_PT_main"

    def draw(self, context):
        s = context.scene.haptic_hand
        layout = self.layout
        row = layout.row(align=True)
        row.prop(s, "bake_frame_start")
        row.prop(s, "bake_frame_end")
        layout.prop(s, "bake_format")
        draw_bake_size(layout, context.scene)
        background.draw(layout, runtime.state.bake, "Baking", "haptic_hand.bake_cancel", "haptic_hand.bake",
                        "RENDER_ANIMATION")
        if s.baked:
            layout.label(text=f"Baked {s.baked_range} ({s.baked_format.lower()})", icon="CHECKMARK")
            for name, path in bake_store.missing_caches(context.scene):
                layout.label(text=f"{name}: point cache {path} is missing", icon="ERROR")
                layout.label(text=f"Copy the folder {bake_store.bake_root().name} beside the .blend, or bake again")
            if s.bake_log:
                layout.label(text=f"Log: {s.bake_log}")
            layout.operator("haptic_hand.free_bake", icon="TRASH")


def draw_bake_size(layout, scene) -> None:
    """What the bake will store, before it starts: shape keys grow the .blend, point caches
    sit in files beside it."""
    s = scene.haptic_hand
    meshes = deformed_meshes(scene)
    frames = s.bake_frame_end - s.bake_frame_start + 1
    if not meshes or frames < 2:
        return
    vertices = sum(len(o.data.vertices) for o in meshes)
    if s.bake_format == "KEYS":
        layout.label(text=f"Shape keys add up to {mib(bake_store.keys_size(meshes, frames))} to the .blend "
                          f"({frames} frames, {vertices} vertices)", icon="INFO")
        layout.label(text=f"PC2 keeps it beside the .blend instead ({mib(bake_store.pc2_size(meshes, frames))})")
    else:
        root = bake_store.bake_root().name if bpy.data.filepath else "<blend name>_haptic"
        layout.label(text=f"Point caches: {mib(bake_store.pc2_size(meshes, frames))} in "
                          f"{root}/{bake_store.cache_dir(scene).name}/", icon="INFO")


classes = (HAPTIC_HAND_PT_main, HAPTIC_HAND_PT_rig, HAPTIC_HAND_PT_material, HAPTIC_HAND_PT_advanced,
           HAPTIC_HAND_PT_bodies,
           HAPTIC_HAND_PT_device, HAPTIC_HAND_PT_live, HAPTIC_HAND_PT_bake)


register, unregister = bpy.utils.register_classes_factory(classes)
