"""The "Haptic Hand" tab of the 3D viewport's sidebar (N): Rig, Material, Bodies, Device,
Live, Bake."""

from __future__ import annotations

import bpy

from ..engine import params
from . import meshdata, ops_rig, param_props, scene_export


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
        if s.live_running:
            col.label(text="Live session running (Esc stops)", icon="REC")
        elif s.bake_running:
            col.label(text="Baking...", icon="TIME")
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
        box = layout.box()
        box.label(text="Tetrahedralize (active mesh)")
        obj = context.active_object
        if obj is not None and obj.type == "MESH" and not obj.haptic_hand.is_tet_mesh:
            o = obj.haptic_hand
            row = box.row(align=True)
            row.prop(o, "edge_length_fac")
            row.prop(o, "epsilon")
            box.prop(o, "coarsen")
        box.operator("haptic_hand.tetrahedralize", icon="MESH_ICOSPHERE")
        if s.hand is not None:
            tet_obj = s.hand.haptic_hand.tet_object
            if meshdata.has_tets(tet_obj):
                box.label(text=f"{len(tet_obj.data[meshdata.TETS_KEY]) // 4} tets, "
                               f"{len(tet_obj.data.vertices)} nodes", icon="INFO")
            else:
                box.label(text="The hand has no tets yet", icon="ERROR")
        box = layout.box()
        row = box.row(align=True)
        row.prop(s, "seed")
        row.operator("haptic_hand.place_seed", text="", icon="PIVOT_CURSOR")
        box.prop(s, "handle_radius")
        count = ops_rig.captured_count(context.scene)
        if count >= 0:
            box.label(text=f"Handle captures {count} nodes", icon="ERROR" if count < 4 else "CHECKMARK")
        layout.operator("haptic_hand.check_rig", icon="CHECKMARK")


def draw_rows(layout, settings, sections: tuple, advanced: bool, body_type: str | None = None,
              skip: tuple = ("handle_radius",)) -> None:
    """The parameter table's rows of these top-level sections (scene file keys), as kept on
    `settings`; advanced=True draws the rows marked advanced instead of the others."""
    for p in param_props.selected(params.UI_SCENE if body_type is None else params.UI_OBJECT, body_type):
        if p.keys[0] not in sections or bool(p.flags & params.UI_ADVANCED) != advanced or p.name in skip:
            continue
        if p.nullable and p.kind in params.NUMERIC_KINDS:
            row = layout.row(align=True)
            row.prop(settings, f"use_{p.name}", text="")
            sub = row.row(align=True)
            sub.active = getattr(settings, f"use_{p.name}")
            sub.prop(settings, p.name)
        else:
            layout.prop(settings, p.name)


SCENE_SECTIONS = ("material", "springs", "coupling", "contact", "hand", "solver")


class HAPTIC_HAND_PT_material(_Panel, bpy.types.Panel):
    bl_label = "Material and Contact"
    bl_parent_id = "HAPTIC_HAND_PT_main"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        s = context.scene.haptic_hand
        col = self.layout.column(align=True)
        for section in SCENE_SECTIONS:
            draw_rows(col, s, (section,), advanced=False)
            col.separator()


class HAPTIC_HAND_PT_advanced(_Panel, bpy.types.Panel):
    bl_label = "Advanced"
    bl_parent_id = "HAPTIC_HAND_PT_material"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        s = context.scene.haptic_hand
        col = self.layout.column(align=True)
        for section in SCENE_SECTIONS + ("haptics",):
            draw_rows(col, s, (section,), advanced=True)
            col.separator()


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
            body_type = scene_export.BODY_TYPES[o.role]
            sections = ("material", "density", "friction", "kinetic_friction", "fixed", "solver")
            draw_rows(box, o, sections, advanced=False, body_type=body_type)
            draw_rows(box, o, sections, advanced=True, body_type=body_type)
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
        draw_rows(layout, s, ("haptics", "device"), advanced=False)


class HAPTIC_HAND_PT_live(_Panel, bpy.types.Panel):
    bl_label = "Live Session"
    bl_parent_id = "HAPTIC_HAND_PT_main"

    def draw(self, context):
        s = context.scene.haptic_hand
        if s.live_running:
            self.layout.operator("haptic_hand.live_stop", icon="CANCEL")
        else:
            self.layout.operator("haptic_hand.live", icon="PLAY")


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
        if s.bake_running:
            layout.progress(factor=s.bake_progress, text=f"Baking {s.bake_progress * 100:.0f}%")
            layout.operator("haptic_hand.bake_cancel", icon="CANCEL")
        else:
            layout.operator("haptic_hand.bake", icon="RENDER_ANIMATION")
        if s.baked:
            layout.label(text=f"Baked {s.baked_range} ({s.baked_format.lower()})", icon="CHECKMARK")
            if s.bake_log:
                layout.label(text=f"Log: {s.bake_log}")
            layout.operator("haptic_hand.free_bake", icon="TRASH")


classes = (HAPTIC_HAND_PT_main, HAPTIC_HAND_PT_rig, HAPTIC_HAND_PT_material, HAPTIC_HAND_PT_advanced,
           HAPTIC_HAND_PT_bodies,
           HAPTIC_HAND_PT_device, HAPTIC_HAND_PT_live, HAPTIC_HAND_PT_bake)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)


def unregister():
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
